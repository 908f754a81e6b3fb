"""``lenssim study as-built``: the paper's trade-off for manufactured lenses, and its conjecture tested (issue 19,
item 4).

For each design strategy (the optimum of RMS_W, MSE_S or MSE_R) on each iso-cost level ``C_a`` of the trade-off,
``N`` as-built lenses (the same seeded errors for every design: common random numbers, the figure error scaled by
each design's own ``C_a``) give the distribution of MSE_R restored with the nominal PSFs (and with each lens's own).
Then a robust search: on the levels around the end-to-end strategy's best as-built level, the curve points around
its nominal optimum are evaluated and the design with the lowest 90th-percentile as-built MSE_R is reported, against
the paper's nominal end-to-end design. Each design's Monte Carlo is stored (with a checksum) as it finishes, so a
killed study resumes.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from lenssim import __version__
from lenssim.io.files import atomic_write_text, json_text
from lenssim.metrics import evaluate
from lenssim.model.camera import Camera
from lenssim.model.design import Design
from lenssim.model.numerics import FAST_NUMERICS, Numerics
from lenssim.model.tolerances import GRADES, Tolerances
from lenssim.tolerancing import as_built_criteria
from lenssim.validate import ResumeWarning

from .chunks import read_stamped_chunk, write_stamped_chunk
from .tolerance import TOLERANCE_FIELD_ANGLES, AtFieldAngles, Digested, markdown_table, spread
from .tradeoff import iso_cost_curve

__all__ = ["AsBuiltStudy", "as_built_study", "AS_BUILT_LEVELS", "STRATEGIES", "STUDY_LENSES"]

AS_BUILT_LEVELS = tuple(float(v) for v in np.linspace(0.0, 2e-3, 11))
"""Iso-cost levels ``C_a`` of the study: the paper's range 0..2e-3 every 2e-4."""
STRATEGIES = ("rms_w", "mse_s", "mse_r")
"""The paper's three design strategies: the optimum of each criterion on an iso-cost curve."""
STUDY_LENSES = 120
"""As-built lenses per design (the report gives the bootstrap standard error of each 90th percentile)."""


@dataclass(frozen=True)
class AsBuiltStudy(Digested, AtFieldAngles):
    """Settings of the study: camera, tolerances, lenses per design, seed, SNR (dB) and ``rho0`` of the image model,
    levels, the curve's ``s`` range and step, the field angles of the Monte Carlo, numerics, and the robust search
    (``robust_levels`` levels on each side of the best one, ``robust_points`` curve steps on each side)."""

    camera: Camera
    rho0: float
    snr_db: float
    tolerances: Tolerances = field(default_factory=lambda: GRADES["commercial"])
    n_lenses: int = STUDY_LENSES
    seed: int = 0
    levels: tuple[float, ...] = AS_BUILT_LEVELS
    s_range: tuple[float, float] = (-1.5, 0.25)
    s_step: float = 0.02
    field_angles_deg: tuple[float, ...] = TOLERANCE_FIELD_ANGLES
    numerics: Numerics = field(default_factory=lambda: FAST_NUMERICS)
    robust_levels: int = 1
    robust_points: int = 2

    def to_dict(self) -> dict:
        return {"camera": self.camera.to_dict(), "rho0": self.rho0, "snr_db": self.snr_db,
                "tolerances": self.tolerances.to_dict(), "n_lenses": self.n_lenses, "seed": self.seed,
                "levels": list(self.levels), "s_range": list(self.s_range), "s_step": self.s_step,
                "field_angles_deg": list(self.field_angles_deg), "numerics": self.numerics.to_dict(),
                "robust_levels": self.robust_levels, "robust_points": self.robust_points,
                "lenssim_version": __version__}


def _curve(study: AsBuiltStudy, level: float):
    s_all = np.arange(study.s_range[0], study.s_range[1] + 1e-12, study.s_step)
    cs, cq, _ = iso_cost_curve(study.camera.lens, level, s_all)
    return cs, cq


def nominal_optima(study: AsBuiltStudy, log: Callable[[str], None] = print) -> list[dict]:
    """Per level: the curve (``s``, ``Q_back``), each point's nominal criteria, and each strategy's optimum (index)."""
    rows = []
    for level in study.levels:
        cs, cq = _curve(study, float(level))
        if len(cs) == 0:
            continue
        r = evaluate(study.eval_camera, Design(s=torch.from_numpy(cs), Q_back=torch.from_numpy(cq)), [study.snr_db],
                     numerics=study.numerics, rho0=study.rho0)
        vals = {k: (r[k][:, 0] if r[k].ndim == 2 else r[k]).numpy() for k in STRATEGIES}
        best = {k: int(np.argmin(vals[k])) for k in STRATEGIES}
        rows.append({"level": float(level), "s": cs, "Q_back": cq, "values": vals, "best": best})
        log(f"  C_a = {level:.1e}: " + ", ".join(f"{k} optimum s = {cs[best[k]]:.2f} Q = {cq[best[k]]:.2f}"
                                                   for k in STRATEGIES))
    return rows


def _design_file(out: Path, study: AsBuiltStudy, s: float, q: float) -> Path:
    key = hashlib.sha256(f"{study.digest()}|{s!r}|{q!r}".encode()).hexdigest()[:20]
    return out / "designs" / f"{key}.npz"


def as_built_design(study: AsBuiltStudy, s: float, q: float, out: Path) -> dict:
    """The Monte Carlo of one design ``(s, Q_back)``, from its stored file if intact: ``mse_r`` and ``mse_r_nominal``
    ``(N,)`` at the study's SNR (the file stamped as a chunk of a tolerance run: :func:`write_stamped_chunk`, its
    digest the file's name, a hash of the study's digest and the design)."""
    path = _design_file(out, study, s, q)
    keys = ("mse_r", "mse_r_nominal")
    if path.exists():
        chunk = read_stamped_chunk(path, keys, path.stem, 0, run="as-built study", rows_key="mse_r",
                                   rows=study.n_lenses, what="lenses")
        if not isinstance(chunk, str):
            return chunk
        warnings.warn(f"as-built study file {str(path)!r} is damaged or of another design ({chunk}); computing it "
                      "again", ResumeWarning, stacklevel=2)
        path.unlink()
    lenses = study.tolerances.sample(study.n_lenses, seed=study.seed)
    r = as_built_criteria(study.eval_camera, Design(s=s, Q_back=q), lenses, [study.snr_db], rho0=study.rho0,
                          numerics=study.numerics)
    chunk = {k: r[k][:, 0].numpy() for k in keys}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_stamped_chunk(path, chunk, path.stem, 0)
    return chunk


def _design_stats(study: AsBuiltStudy, s: float, q: float, out: Path) -> dict:
    """The spread of one design's Monte Carlo (:func:`as_built_design`) restored with the nominal PSFs and with each
    lens's own: mean, 90th percentile and its bootstrap relative standard error
    (:func:`lenssim_studies.tolerance.spread`)."""
    mc = as_built_design(study, s, q, out)
    return {name: {k: v for k, v in spread(mc[key], study.seed).items() if k in ("mean", "p90", "p90_rel_se")}
            for name, key in (("nominal_restoration", "mse_r_nominal"), ("calibrated", "mse_r"))}


def as_built_study(study: AsBuiltStudy, out, *, reference: Design | None = None, log: Callable[[str], None] = print,
                   show_progress: bool = True) -> dict:
    """Run (or resume) the study into ``out``; returns its results (also ``as_built.json``, ``report.md`` and the
    figure ``fig6_as_built.png/.svg``). ``reference``: the nominal end-to-end design the robust optimum is compared
    with (default: the best nominal MSE_R over the levels)."""
    from .progress import progress_bar

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log(f"nominal optima on {len(study.levels)} iso-cost levels")
    opt = nominal_optima(study, log)
    bar = progress_bar(total=len(opt) * len(STRATEGIES), unit="design", show=show_progress,
                       desc=f"as-built ({study.n_lenses} lenses per design)")
    table = []
    for row in opt:
        for k in STRATEGIES:
            i = row["best"][k]
            s, q = float(row["s"][i]), float(row["Q_back"][i])
            mc = _design_stats(study, s, q, out)
            table.append({"strategy": k, "level": row["level"], "s": s, "Q_back": q,
                          "nominal_mse_r": float(row["values"]["mse_r"][i]), "calibrated": mc["calibrated"],
                          "nominal_restoration": mc["nominal_restoration"]})
            bar.update(1)
    bar.close()
    # the robust search around the end-to-end strategy's best as-built level
    e2e = [t for t in table if t["strategy"] == "mse_r"]
    best_level = min(range(len(e2e)), key=lambda j: e2e[j]["nominal_restoration"]["p90"])
    cand = []
    for j in range(max(0, best_level - study.robust_levels), min(len(opt), best_level + study.robust_levels + 1)):
        row = opt[j]
        i0 = row["best"]["mse_r"]
        for i in range(max(0, i0 - study.robust_points), min(len(row["s"]), i0 + study.robust_points + 1)):
            cand.append((row["level"], float(row["s"][i]), float(row["Q_back"][i]), float(row["values"]["mse_r"][i])))
    log(f"robust search: {len(cand)} designs around C_a = {e2e[best_level]['level']:.1e}")
    robust = []
    bar = progress_bar(total=len(cand), unit="design", show=show_progress, desc="robust")
    for level, s, q, nom in cand:
        robust.append({"level": level, "s": s, "Q_back": q, "nominal_mse_r": nom, **_design_stats(study, s, q, out)})
        bar.update(1)
    bar.close()
    if reference is None:
        ref_row = min(e2e, key=lambda t: t["nominal_mse_r"])
        reference = Design(s=ref_row["s"], Q_back=ref_row["Q_back"])
    rs, rq = float(reference["s"]), float(reference["Q_back"])
    from lenssim.optics.cost import slope_departure_cost

    ref_cost = float(slope_departure_cost(study.camera.lens, Design(s=rs, Q_back=rq).to(torch.float64)))
    r_nom = float(evaluate(study.eval_camera, Design(s=rs, Q_back=rq), [study.snr_db], numerics=study.numerics,
                           rho0=study.rho0)["mse_r"][0])
    ref = {"s": rs, "Q_back": rq, "level": ref_cost, "nominal_mse_r": r_nom, **_design_stats(study, rs, rq, out)}
    best_robust = min(robust + [ref], key=lambda r: r["nominal_restoration"]["p90"])  # the reference is a candidate
    result = {"study": study.to_dict(), "table": table, "robust": robust, "robust_best": best_robust,
              "reference": ref}
    atomic_write_text(out / "as_built.json", json_text(result))
    _figure(result, out, study)
    atomic_write_text(out / "report.md", report(result, study))
    return result


LABELS = {"rms_w": "RMS_W (optical)", "mse_s": "MSE_S (sensor image)", "mse_r": "MSE_R (end-to-end)"}
COLOURS = {"rms_w": "tab:green", "mse_s": "tab:orange", "mse_r": "tab:blue"}


def _figure(result: dict, out: Path, study: AsBuiltStudy) -> None:
    from .figures import _plt, _save

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    for k in STRATEGIES:
        rows = [t for t in result["table"] if t["strategy"] == k]
        c = np.array([t["level"] for t in rows]) * 1e3
        ax.plot(c, [t["nominal_mse_r"] for t in rows], "-", color=COLOURS[k], lw=1.2, label=f"{LABELS[k]}: nominal")
        ax.plot(c, [t["nominal_restoration"]["mean"] for t in rows], "--", color=COLOURS[k], lw=1.2,
                label="as-built mean")
        ax.plot(c, [t["nominal_restoration"]["p90"] for t in rows], ":", color=COLOURS[k], lw=1.6,
                label="as-built 90th percentile")
    rb = result["robust_best"]
    ax.plot([rb["level"] * 1e3], [rb["nominal_restoration"]["p90"]], "k*", ms=10,
            label="robust design (its 90th percentile)")
    ax.set_xlabel("cost C_a (slope departure, x 1e-3)")
    ax.set_ylabel(f"MSE_R at {study.snr_db:g} dB, restored with the nominal PSFs")
    ax.set_title(f"Fig. 6 as built: {study.n_lenses} lenses per design, tolerances of the study", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    ax.set_yscale("log")
    fig.tight_layout()
    _save(fig, out, "fig6_as_built", dpi=120)


def report(result: dict, study: AsBuiltStudy) -> str:
    """Markdown: the as-built Table 1 (per strategy, the best level nominally and as built), the per-level table and
    the robust design."""
    lines = [f"# As-built trade-off ({study.n_lenses} lenses per design, seed {study.seed}, {study.snr_db:g} dB)", "",
             "Tolerances: " + ", ".join(f"{k} = {v:g}" for k, v in study.tolerances.to_dict().items()
                                        if not isinstance(v, bool) and v) + ".", "",
             "## As-built Table 1: the best cost level of each strategy", ""]
    best = []
    for k in STRATEGIES:
        rows = [t for t in result["table"] if t["strategy"] == k]
        a = min(rows, key=lambda t: t["nominal_mse_r"])
        b = min(rows, key=lambda t: t["nominal_restoration"]["p90"])
        best.append((LABELS[k], f"{a['level']:.1e}, {a['s']:.2f} / {a['Q_back']:.2f}, {a['nominal_mse_r']:.5f}",
                     f"{b['level']:.1e}, {b['s']:.2f} / {b['Q_back']:.2f}, {b['nominal_restoration']['p90']:.5f} "
                     f"(s.e. {100 * b['nominal_restoration']['p90_rel_se']:.1f}%)", f"{b['nominal_mse_r']:.5f}"))
    lines += markdown_table(("strategy", "best nominal: C_a, s / Q_back, MSE_R", "best as built (90th pct, nominal "
                             "restoration): C_a, s / Q_back, p90", "its nominal MSE_R"), best)
    lines += ["", "## Per level", ""] + markdown_table(
        ("C_a", "strategy", "s / Q_back", "MSE_R nominal", "as built, calibrated: mean / p90",
         "as built, nominal restoration: mean / p90"),
        [(f"{t['level']:.1e}", t["strategy"], f"{t['s']:.2f} / {t['Q_back']:.2f}", f"{t['nominal_mse_r']:.5f}",
          f"{t['calibrated']['mean']:.5f} / {t['calibrated']['p90']:.5f}",
          f"{t['nominal_restoration']['mean']:.5f} / {t['nominal_restoration']['p90']:.5f}") for t in result["table"]])
    rb, ref = result["robust_best"], result["reference"]
    gain = 100 * (rb["nominal_restoration"]["p90"] / ref["nominal_restoration"]["p90"] - 1)
    lines += ["", "## Robust design (lowest 90th-percentile as-built MSE_R, nominal restoration)", "",
              f"* searched: {len(result['robust'])} designs on the levels around the end-to-end strategy's best "
              "as-built level, common random numbers;",
              f"* robust design: s = {rb['s']:.3f}, Q_back = {rb['Q_back']:.3f}, C_a = {rb['level']:.2e}: p90 "
              f"{rb['nominal_restoration']['p90']:.5f}, nominal MSE_R {rb['nominal_mse_r']:.5f};",
              f"* the nominal end-to-end design: s = {ref['s']:.3f}, Q_back = {ref['Q_back']:.3f}, C_a = "
              f"{ref['level']:.2e}: p90 {ref['nominal_restoration']['p90']:.5f}, nominal MSE_R {ref['nominal_mse_r']:.5f};",
              f"* gain in the 90th percentile: {gain:+.1f}%, at a cost C_a {rb['level'] / ref['level']:.2f}x the "
              "nominal end-to-end design's" if ref["level"] else f"* gain in the 90th percentile: {gain:+.1f}%"]
    return "\n".join(lines) + "\n"
