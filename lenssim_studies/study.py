"""What white light does to the paper's conclusions (a study over glasses, with the image plane optimised).

For each glass, the paper's lens (f = 25 mm, f/6.25, 15 field angles) is seen through a colour camera
(RGB sensitivities x illuminant from colour-science, :func:`lenssim.model.spectrum.channel_spectra`); the
criteria are the means over the three channels. ``paper`` stands for the paper's own model (n = 1.5, one
wavelength, 0.5 um, for every colour), the baseline. The steps:

1. **Common focus plane** ``z0``: the best MSE_R plane of the paper's end-to-end design (Brent search).
   A dispersive singlet's best plane is set mostly by its axial colour, so one plane serves the grid.
2. **Design landscapes at z0**: a sweep over ``(s, Q_back)`` (:func:`lenssim.sweep.run_sweep`, resumable),
   then the paper's trade-off (exact iso-cost curves, :func:`lenssim.tradeoff.tradeoff`), Fig. 6 and
   Table 1 (:mod:`lenssim.figures`).
3. **Optima with the focus free**: from each criterion's grid optimum, a Nelder-Mead search over
   ``(s, Q_back, focus_shift_um)`` for RMS_W, MSE_S and MSE_R (at the reference SNR). The sequential
   designs (RMS_W, MSE_S optimal, each focused by its own criterion) are then scored by MSE_R against
   the end-to-end one (Table 1 with the focus optimised).
4. **A second asphere at equal cost**: at the end-to-end optimum's cost ``C*``, a search over
   ``(s, Q_front, focus)`` with ``Q_back`` solved so that the summed cost of both aspheres stays ``C*``
   (bisection on the back conic, :func:`lenssim.optics.cost.slope_departure_cost`).

Everything is written into one folder: ``report.md``, ``summary.json`` and per glass the sweep, the
trade-off figures and Table 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from lenssim.model.camera import Camera
from lenssim.optics.cost import slope_departure_cost
from lenssim.criteria import CRITERIA, lens_criteria
from lenssim.model.design import Design
from lenssim.io.files import atomic_write_text, json_text
from lenssim.focus import best_focus
from lenssim.model.lens import Lens
from lenssim.metrics import evaluate
from lenssim.model.numerics import FAST_NUMERICS, Numerics
from .paper import PAPER_CAMERA, PAPER_COST_LEVELS, PAPER_DESIGNS, PAPER_SNR_DB, REFERENCE_SNR_DB
from lenssim.optics.psf_bank import spectral_coefficients
from lenssim.model.spectrum import channel_spectra
from lenssim.validate import check_int
from lenssim_studies.paper import PAPER_RHO0

__all__ = ["WhiteLightStudy", "study_camera", "criterion_value", "white_light_study", "STUDY_GRID",
           "exact_along_tradeoff", "exact_tradeoff_report", "EXACT_STUDY_LEVELS", "parabola_minimum"]

EXACT_STUDY_LEVELS = tuple(float(v) for v in np.linspace(2e-4, 2e-3, 10))
"""Iso-cost levels C_a of the exact-vs-third-order comparison (the upper 9/10 of the paper's range)."""

STUDY_GRID = {"s": (-1.5, 0.25, 0.125), "Q_back": (-10.0, 1.2, 0.8)}
"""Default design grid of the study: 15 shape factors x 15 back conics around the paper's optima (the
paper's grid is 122 x 113; the optima are refined off the grid with the focus free, step 3)."""

SEARCH_STEPS = {"s": 0.05, "Q_back": 0.5, "Q_front": 0.5, "focus_shift_um": 25.0}
"""Initial Nelder-Mead simplex steps per parameter (shape factor, conics, focus in um)."""

STUDY_FOCUS_BOUNDS_UM = (-1200.0, 600.0)
"""Image-plane range of the study (um): N-SF5's F-C axial colour (~0.64 mm) with room on either side."""


@dataclass(frozen=True)
class WhiteLightStudy:
    """Settings of :func:`white_light_study`."""

    glasses: tuple[str, ...] = ("N-BK7", "N-SF5", "PMMA")
    sensitivities: str = "Nikon 5100 (NPL)"
    illuminant: str = "D65"
    per_channel: int | None = None
    """Wavelengths per channel, each its own; None: the 5 nm table integrated by the shared quadrature
    (:func:`lenssim.model.spectrum.shared_quadrature` under ``numerics.spectral_tol``)."""
    grid: dict = field(default_factory=lambda: dict(STUDY_GRID))
    snr_db: tuple[float, ...] = PAPER_SNR_DB
    reference_snr_db: float = REFERENCE_SNR_DB
    numerics: Numerics = FAST_NUMERICS
    levels: tuple[float, ...] = tuple(float(v) for v in PAPER_COST_LEVELS)
    """Iso-cost levels C_a of the trade-off (Fig. 6): the paper's 30."""
    max_evaluations: int = 60
    """Nelder-Mead budget per refined optimum (each evaluation ~1-2 s for 48 wavelengths on 2 cores)."""
    q_front: bool = True

    def __post_init__(self):
        if not self.glasses:
            raise ValueError("glasses: name at least one glass (e.g. N-BK7) or 'paper'")
        check_int("max_evaluations", self.max_evaluations, 4, 10_000)
        if self.reference_snr_db not in self.snr_db:
            raise ValueError(f"reference_snr_db={self.reference_snr_db:g} must be one of snr_db {list(self.snr_db)}")
        from .config import grid_count

        for name, (start, stop, step) in self.grid.items():
            grid_count(start, stop, step)
        for glass in self.glasses:  # every glass, spectrum, illuminant and sampling now, before any work
            study_camera(glass, self)


def study_camera(glass: str, study: WhiteLightStudy) -> Camera:
    """The paper's camera in ``glass`` behind the study's colour channels (``paper``: the paper's model)."""
    if glass == "paper":
        return PAPER_CAMERA
    lens = Lens.from_dict({**PAPER_CAMERA.lens.to_dict(), "glass": glass, "refractive_index": None})
    return Camera(lens, PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum,
                  channels=channel_spectra(study.sensitivities, study.illuminant, study.per_channel))


def _node_counts(study: WhiteLightStudy) -> str:
    """The shared wavelengths each glass of the study takes, e.g. ``N-BK7 17, N-SF5 24``."""
    parts = []
    for glass in study.glasses:
        cam = study_camera(glass, study).with_quadrature(study.numerics.spectral_tol)
        if cam.channels:
            parts.append(f"{glass} {len(cam.channels[0])}")
    return ", ".join(parts) or "none"


def criterion_value(camera: Camera, design: Design, criterion: str, snr_db: float, numerics: Numerics) -> dict:
    """Every criterion of one design (channel means) as floats, at ``snr_db``; the design criteria
    (``rms_w``, ``cost``) alone when ``criterion`` is one of them (no OTFs are computed)."""
    if CRITERIA[criterion].from_otf is None:
        d64 = design.to(torch.float64).broadcast()
        vals = {}
        for name, c in lens_criteria().items():
            if c.from_otf is None:
                per = [c.from_design(cam, d64, spectral_coefficients(cam, d64), numerics)
                       for cam in camera.with_quadrature(numerics.spectral_tol).channel_cameras()]
                vals[name] = float(torch.stack([torch.as_tensor(v, dtype=torch.float64) for v in per]).mean())
        return vals
    r = evaluate(camera, design, [snr_db], numerics=numerics, rho0=PAPER_RHO0)
    return {name: float(r[name].reshape(-1)[0]) for name in lens_criteria()}


def _nelder_mead(f: Callable[[np.ndarray], float], x0, steps, max_evaluations: int, bounds):
    """Bounded Nelder-Mead (scipy) from ``x0``; the initial simplex steps inward where a bound is near."""
    from scipy.optimize import minimize

    lo, hi = np.array([b[0] for b in bounds]), np.array([b[1] for b in bounds])
    x0 = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    steps = np.where(x0 + np.asarray(steps) > hi, -np.asarray(steps), np.asarray(steps))
    simplex = np.vstack([x0] + [x0 + np.eye(len(x0))[i] * steps[i] for i in range(len(x0))])
    res = minimize(f, x0, method="Nelder-Mead", bounds=list(zip(lo, hi)),
                   options={"initial_simplex": simplex, "maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-7})
    return res.x, float(res.fun), int(res.nfev)


def _bounds(study: WhiteLightStudy, names) -> list[tuple[float, float]]:
    """The study's design domain: the grid's range for ``s`` and for both conics (the paper bounds |Q| by its
    grid, where third order holds), :data:`STUDY_FOCUS_BOUNDS_UM` for the focus."""
    q = study.grid["Q_back"]
    box = {"s": tuple(study.grid["s"][:2]), "Q_back": (q[0], q[1]), "Q_front": (q[0], q[1]),
           "focus_shift_um": STUDY_FOCUS_BOUNDS_UM}
    return [box[k] for k in names]


def _refine(camera, start: dict, criterion: str, study: WhiteLightStudy, log) -> dict:
    """Nelder-Mead over ``(s, Q_back, focus_shift_um)`` from ``start`` for ``criterion`` at the reference SNR."""
    names = ("s", "Q_back", "focus_shift_um")
    snr = study.reference_snr_db

    def f(x):
        d = Design(dict(zip(names, (float(v) for v in x))))
        try:
            camera.lens.check_design(d)
            return criterion_value(camera, d, criterion, snr, study.numerics)[criterion]
        except ValueError:  # outside the physical lenses (e.g. beyond the conic's limit): not a candidate
            return math.inf

    x, v, nfev = _nelder_mead(f, [start[k] for k in names], [SEARCH_STEPS[k] for k in names], study.max_evaluations,
                              _bounds(study, names))
    design = Design(dict(zip(names, (float(t) for t in x))))
    vals = criterion_value(camera, design, "mse_r", snr, study.numerics)
    log(f"  {criterion} optimum: s = {x[0]:.4f}, Q_back = {x[1]:.3f}, focus {x[2]:+.1f} um: {criterion} = {v:.5g} "
        f"({nfev} evaluations)")
    return {"criterion": criterion, "design": dict(zip(names, (float(t) for t in x))), "value": v, "evaluations": nfev,
            "mse_r": vals["mse_r"], "mse_s": vals["mse_s"], "rms_w": vals["rms_w"], "cost_Ca": vals["cost"]}


def _solve_q_back(lens: Lens, s: float, q_front: float, level: float, q_min: float = STUDY_GRID["Q_back"][0]):
    """``Q_back`` in ``[q_min, 0]`` with the summed cost of both aspheres equal to ``level`` (None if no such conic)."""
    cost = lambda qb: float(slope_departure_cost(lens, Design(s=s, Q_front=q_front, Q_back=qb)))  # noqa: E731
    try:
        if cost(0.0) > level or cost(q_min) < level:
            return None
        lo, hi = 0.0, q_min  # cost(lo) <= level <= cost(hi)
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if cost(mid) <= level else (lo, mid)
        return 0.5 * (lo + hi)
    except ValueError:
        return None


def _second_asphere(camera, e2e: dict, study: WhiteLightStudy, log) -> dict:
    """The best MSE_R over ``(s, Q_front, focus)`` at the end-to-end optimum's cost, ``Q_back`` solved for it."""
    level = e2e["cost_Ca"]
    snr = study.reference_snr_db

    def design_of(x):
        qb = _solve_q_back(camera.lens, float(x[0]), float(x[1]), level)
        return None if qb is None else Design(s=float(x[0]), Q_front=float(x[1]), Q_back=qb,
                                              focus_shift_um=float(x[2]))

    def f(x):
        d = design_of(x)
        if d is None:
            return math.inf
        try:
            camera.lens.check_design(d)
            return criterion_value(camera, d, "mse_r", snr, study.numerics)["mse_r"]
        except ValueError:
            return math.inf

    start = e2e["design"]
    # start from a small front conic of the sign that helps the end-to-end design, at the same total cost
    best = None
    for q0 in (-0.5, 0.5):
        x0 = [start["s"], q0, start["focus_shift_um"]]
        if design_of(x0) is None:
            continue
        x, v, nfev = _nelder_mead(f, x0, [SEARCH_STEPS[k] for k in ("s", "Q_front", "focus_shift_um")],
                                  study.max_evaluations // 2, _bounds(study, ("s", "Q_front", "focus_shift_um")))
        if best is None or v < best[1]:
            best = (x, v, nfev)
    if best is None or not math.isfinite(best[1]):
        log("  second asphere: no design at this cost")
        return {}
    x, v, nfev = best
    d = design_of(x)
    out = {"design": {k: float(t.reshape(())) for k, t in d.values.items()}, "mse_r": v,
           "cost_Ca": float(slope_departure_cost(camera.lens, d)), "mse_r_relative_to_one_asphere": v / e2e["mse_r"]}
    log(f"  Q_front free at C_a = {level:.3e}: s = {x[0]:.4f}, Q_front = {x[1]:.3f}, Q_back = "
        f"{out['design']['Q_back']:.3f}, focus {x[2]:+.1f} um: MSE_R {v:.5g} ({100 * (v / e2e['mse_r'] - 1):+.2f}%)")
    return out


def _study_glass(glass: str, study: WhiteLightStudy, out: Path, log, show_progress: bool) -> dict:
    from .figures import TABLE1_CRITERIA, fig4_landscapes, fig6_performance_vs_cost, table1
    from .sweep import SweepConfig, run_sweep
    from .tradeoff import find_optimum, tradeoff

    camera = study_camera(glass, study)
    snr = study.reference_snr_db
    e2e_paper = PAPER_DESIGNS["end_to_end_paper"]
    log(f"{glass}: best focus of the paper's end-to-end design (MSE_R at {snr:g} dB)")
    z0 = best_focus(camera, e2e_paper, "mse_r", snr, bounds_um=STUDY_FOCUS_BOUNDS_UM, tol_um=2.0,
                    numerics=study.numerics, rho0=PAPER_RHO0).focus_shift_um
    z0 = round(z0, 1)
    cfg = SweepConfig(camera=camera, grid=dict(study.grid), snr_db=study.snr_db, numerics=study.numerics,
                      fixed={"focus_shift_um": z0})
    log(f"  z0 = {z0:+.1f} um; sweep of {cfg.n_designs()} designs at z0")
    gdir = out / glass
    gdir.mkdir(parents=True, exist_ok=True)
    ds = run_sweep(cfg, gdir / "sweep.nc", show_progress=show_progress)
    trade = tradeoff(ds, camera.lens, study.levels, criteria=TABLE1_CRITERIA)
    trade.to_netcdf(gdir / "tradeoff.nc")
    fig4_landscapes(ds, gdir, snr)
    fig6_performance_vs_cost(trade, gdir)
    _, _, rows = table1(ds, gdir, snr)
    optima = {}
    for crit in ("rms_w", "mse_s", "mse_r"):
        g = find_optimum(ds, crit, snr)
        start = {**g["design"], "focus_shift_um": z0}
        optima[crit] = _refine(camera, start, crit, study, log)
    best = optima["mse_r"]["mse_r"]
    for crit in optima:
        optima[crit]["mse_r_relative"] = optima[crit]["mse_r"] / best
    second = _second_asphere(camera, optima["mse_r"], study, log) if study.q_front else {}
    return {"glass": glass, "camera": camera.to_dict(), "focus_z0_um": z0, "table1_at_z0": rows,
            "optima_focus_free": optima, "second_asphere": second,
            # iso-cost levels the grid does not reach have no optimum and are left out
            "tradeoff_mse_r_at_levels": {f"{lv:.3e}": float(v) for lv, v in zip(
                trade["level"].values, trade["value"].sel(criterion=f"mse_r@{snr:g}").values) if np.isfinite(v)}}


def _report(results: list[dict], study: WhiteLightStudy) -> str:
    snr = study.reference_snr_db
    lines = [f"# White light and the paper's conclusions (MSE at {snr:g} dB)", "",
             f"Colour channels: {study.sensitivities} under {study.illuminant}, " + (
                 f"{study.per_channel} wavelengths per channel" if study.per_channel else
                 f"the 5 nm table integrated with wavelengths shared by the channels (indicator <= "
                 f"{study.numerics.spectral_tol:g} px: {_node_counts(study)})") + "; criteria are channel means. `paper` is the paper's one-wavelength model. Optima refined with "
             f"the image plane free (bounded Nelder-Mead, at most {study.max_evaluations} evaluations, within s "
             f"{study.grid['s'][0]:g}..{study.grid['s'][1]:g}, conics {study.grid['Q_back'][0]:g}.."
             f"{study.grid['Q_back'][1]:g}, focus {STUDY_FOCUS_BOUNDS_UM[0]:g}..{STUDY_FOCUS_BOUNDS_UM[1]:g} um).", "",
             "| glass | design (optimises) | s | Q_back | focus (um) | MSE_R | relative to end-to-end | C_a |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results:
        for crit, label in (("rms_w", "RMS_W (sequential)"), ("mse_s", "MSE_S (sequential)"), ("mse_r", "MSE_R (end-to-end)")):
            o = r["optima_focus_free"][crit]
            d = o["design"]
            lines.append(f"| {r['glass']} | {label} | {d['s']:.3f} | {d['Q_back']:.2f} | {d['focus_shift_um']:+.1f} | "
                         f"{o['mse_r']:.5f} | {o['mse_r_relative']:.3f} | {o['cost_Ca']:.3e} |")
    lines += ["", "Second asphere (Q_front free) at the end-to-end optimum's cost:", "",
              "| glass | s | Q_front | Q_back | focus (um) | MSE_R | change | C_a |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        q = r["second_asphere"]
        if q:
            d = q["design"]
            lines.append(f"| {r['glass']} | {d['s']:.3f} | {d['Q_front']:.2f} | {d['Q_back']:.2f} | "
                         f"{d['focus_shift_um']:+.1f} | {q['mse_r']:.5f} | "
                         f"{100 * (q['mse_r_relative_to_one_asphere'] - 1):+.2f}% | {q['cost_Ca']:.3e} |")
    lines += ["", "Per glass (folder of that name): `fig4_landscapes` and `fig6_performance_vs_cost` (at the common "
              "plane z0), `table1.md` (grid optima at z0), `sweep.nc`, `tradeoff.nc`.", ""]
    for r in results:
        lines.append(f"* {r['glass']}: common plane z0 = {r['focus_z0_um']:+.1f} um (best MSE_R plane of the paper's "
                     "end-to-end design)")
    return "\n".join(lines) + "\n"


def white_light_study(out_dir, study: WhiteLightStudy = WhiteLightStudy(), *, log: Callable[[str], None] = print,
                      show_progress: bool = True) -> Path:
    """Run the study for every glass of ``study`` into ``out_dir`` (created; each glass's sweep resumes if
    interrupted). Returns the path of ``report.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for glass in study.glasses:
        study_camera(glass, study)  # every glass and spectrum name checked before any work
    for glass in study.glasses:
        results.append(_study_glass(glass, study, out, log, show_progress))
    summary = {"study": {"glasses": list(study.glasses), "sensitivities": study.sensitivities,
                         "illuminant": study.illuminant, "per_channel": study.per_channel,
                         "grid": {k: list(v) for k, v in study.grid.items()}, "snr_db": list(study.snr_db),
                         "reference_snr_db": study.reference_snr_db, "numerics": study.numerics.to_dict(),
                         "max_evaluations": study.max_evaluations}, "results": results}
    atomic_write_text(out / "summary.json", json_text(summary))
    report = out / "report.md"
    atomic_write_text(report, _report(results, study))
    return report


def parabola_minimum(x, y) -> tuple[float, float]:
    """The minimum ``(x, y)`` of samples ``y`` at evenly spaced ``x``: the vertex of the parabola through the least
    sample and its two neighbours, or the least sample itself at an end or where the three are not convex."""
    k = int(np.argmin(y))
    if 0 < k < len(y) - 1:
        den = y[k - 1] - 2 * y[k] + y[k + 1]
        if den > 0:
            t = 0.5 * (y[k - 1] - y[k + 1]) / den
            return x[k] + t * (x[k + 1] - x[k]), y[k] - 0.25 * (y[k - 1] - y[k + 1]) * t
    return x[k], y[k]


def exact_along_tradeoff(levels=EXACT_STUDY_LEVELS, *, camera: Camera = PAPER_CAMERA, snr_db: float = REFERENCE_SNR_DB,
                         s_range=(-1.5, 0.25), s_step: float = 0.02, exact_points: int = 7,
                         numerics: Numerics = FAST_NUMERICS, log: Callable[[str], None] = print) -> list[dict]:
    """The end-to-end trade-off (best MSE_R on each iso-cost curve, Q_back < 0 branch) with third-order and
    exact (ray-traced, :mod:`lenssim.optics.exact_wavefront`) wavefronts, for a one-wavelength camera.

    On each level the curve ``C_a(s, Q_back) = level`` is solved exactly (:func:`lenssim.tradeoff.iso_cost_curve`)
    at ``s`` every ``s_step``; third-order MSE_R is evaluated at every point (one batched evaluation) and its
    minimum refined by a parabola through the three best. The exact MSE_R is evaluated there and at
    ``exact_points`` curve points around it (every ``s_step``), whose parabola gives the exact optimum.
    Returns one dict per level: ``third_order`` and ``exact`` optima (``s``, ``Q_back``, ``mse_r``) and
    ``exact_at_third_order`` (the exact MSE_R of the third-order optimum).
    """
    from lenssim.metrics import exact_criteria
    from .tradeoff import iso_cost_curve

    s_all = np.arange(s_range[0], s_range[1] + 1e-12, s_step)
    rows = []
    parabola = parabola_minimum

    def on_curve(level, s_vals):
        cs, cq, cb = iso_cost_curve(camera.lens, level, s_vals)
        keep = cb < 0
        return cs[keep], cq[keep]

    def exact_mse_r(s_, q_):
        return float(exact_criteria(camera, Design(s=float(s_), Q_back=float(q_)), [snr_db], numerics=numerics, rho0=PAPER_RHO0)["mse_r"][0])

    for level in levels:
        cs, cq = on_curve(float(level), s_all)
        if len(cs) < 3:
            continue
        r = evaluate(camera, Design(s=torch.from_numpy(cs), Q_back=torch.from_numpy(cq)), [snr_db], numerics=numerics, rho0=PAPER_RHO0)
        v3 = r["mse_r"][:, 0].numpy()
        s3, m3 = parabola(cs, v3)
        s3c, q3c = on_curve(float(level), [s3])
        s3, q3 = float(s3c[0]), float(q3c[0])
        k = int(np.argmin(np.abs(cs - s3)))
        lo = max(0, min(k - exact_points // 2, len(cs) - exact_points))
        pick = np.arange(lo, min(len(cs), lo + exact_points))
        ve = np.array([exact_mse_r(cs[i], cq[i]) for i in pick])
        se, me = parabola(cs[pick], ve)
        sec, qec = on_curve(float(level), [se])
        row = {"level": float(level),
               "third_order": {"s": s3, "Q_back": q3, "mse_r": float(m3)},
               "exact_at_third_order": exact_mse_r(s3, q3),
               "exact": {"s": float(sec[0]), "Q_back": float(qec[0]), "mse_r": float(me)},
               "exact_on_sample_edge": bool(int(np.argmin(ve)) in (0, len(ve) - 1))}
        rows.append(row)
        log(f"  C_a = {level:.2e}: third order s = {s3:.3f} Q = {q3:.2f} MSE_R {m3:.5f} (exact there "
            f"{row['exact_at_third_order']:.5f}); exact optimum s = {row['exact']['s']:.3f} MSE_R {me:.5f}")
    return rows


def exact_tradeoff_report(rows: list[dict], snr_db: float = REFERENCE_SNR_DB) -> str:
    """Markdown table of :func:`exact_along_tradeoff`."""
    lines = ["| C_a | third-order optimum s / Q_back | MSE_R third order | MSE_R exact there | exact optimum s / Q_back "
             "| MSE_R exact optimum | gain of re-optimising |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        t, e = r["third_order"], r["exact"]
        lines.append(f"| {r['level']:.1e} | {t['s']:.3f} / {t['Q_back']:.2f} | {t['mse_r']:.5f} | "
                     f"{r['exact_at_third_order']:.5f} ({100 * (r['exact_at_third_order'] / t['mse_r'] - 1):+.1f}%) | "
                     f"{e['s']:.3f} / {e['Q_back']:.2f} | {e['mse_r']:.5f} | "
                     f"{100 * (e['mse_r'] / r['exact_at_third_order'] - 1):+.2f}% |")
    return f"MSE_R at {snr_db:g} dB along the end-to-end trade-off (Q_back < 0 branch):\n\n" + "\n".join(lines) + "\n"
