"""The paper's conclusion under each restoration (issue 45, item 4): designs ranked by what a restoration reaches.

The paper ranks designs by ``MSE_R``, the closed-form error of the Wiener-restored image (:mod:`lenssim.criteria.mse`):
a linear restoration of a stationary image model. Whether its conclusion (the end-to-end design beats the RMS_W design
after restoration, and at every asphere cost) holds for another restoration is an empirical question; this study
answers it on photos:

1. **Designs**: any named designs (e.g. the paper's ``end_to_end_paper`` and ``rms_w_paper``) and the iso-cost optima
   of chosen criteria at chosen asphere costs (:func:`iso_cost_optima`: on the exact iso-cost curve
   ``C_a(s, Q_back) = C`` of :func:`lenssim_studies.tradeoff.iso_cost_curve`, ``Q_back < 0`` branch, every design of
   the curve evaluated in one batch and the best refined by a parabola, as in
   :func:`lenssim_studies.study.exact_along_tradeoff`).
2. **Empirical scores**: each design's camera simulated on the same crops of the same photos with the same noise draws
   (:func:`pipeline.simulate_crops`, the machinery of ``lenssim psnr-table``), restored by each method; per crop the
   sRGB PSNR and SSIM against the ideal image and the empirical ``MSE_R``: the mean squared error of the restored
   linear image against the ideal one divided by the ideal crop's variance (the paper's unit signal variance).
3. **Closed form beside it**: ``MSE_R`` (and ``MSE_S`` for the sensor image) of each design at the SNR the study
   assigns to each ISO, field-averaged, and the ranking it predicts.

The rankings are compared per method and ISO (Kendall's tau against the closed form) and for chosen pairs of designs
(the paper's two designs; the ``MSE_R`` and ``RMS_W`` optima at each cost): which one wins, by how much.
Each design's crops are one unit of work, written to ``OUT.partial/`` as it finishes: a rerun with the same settings
resumes there. The library takes no paper value as a default: the caller names the camera, designs, SNRs and levels.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lenssim.criteria import CRITERIA
from lenssim.io.files import atomic_write_text, json_text
from lenssim.metrics import evaluate
from lenssim.model.camera import Camera
from lenssim.model.design import Design
from lenssim.model.numerics import Numerics
from lenssim.optics.psf_provider import LensPSF

from .study import parabola_minimum

__all__ = ["RankingStudy", "iso_cost_optima", "optimum_name", "closed_form", "ranking_angles", "rank_designs", "ranking_tables",
           "ranking_report", "write_ranking", "MAX_RANKING_DESIGNS", "MAX_RANKING_METHODS", "MAX_RANKING_PHOTOS",
           "MAX_RANKING_CROPS", "SENSOR"]

MAX_RANKING_DESIGNS = 24
"""Most designs one ranking takes (each is a full simulation of every crop: minutes per design on 2 CPU cores)."""

MAX_RANKING_METHODS = 8
"""Most restoration methods one ranking takes."""

MAX_RANKING_PHOTOS = 16
"""Most photos one ranking takes."""

MAX_RANKING_CROPS = 64
"""Most crops (photos x angles) per design: bounds the work and the memory of one unit (each crop keeps its images per
ISO and method until it is scored)."""

SENSOR = "sensor"
"""The row of the sensor image (no restoration): its closed form is ``MSE_S``."""

OPTIMUM_SEP = "@"
"""``CRITERION@COST``: the name of an iso-cost optimum (e.g. ``mse_r@0.0005``)."""


def optimum_name(criterion: str, level: float) -> str:
    """The name of ``criterion``'s optimum on the iso-cost level ``level``, e.g. ``mse_r@0.0005``."""
    return f"{criterion}{OPTIMUM_SEP}{level:g}"


def iso_cost_optima(camera: Camera, levels, criteria, snr_db: float, rho0: float, *, s_range: tuple[float, float],
                    s_step: float, Q_range: tuple[float, float], numerics: Numerics) -> dict[str, Design]:
    """The best design of each of ``criteria`` (registered names, each minimised or maximised by its sense) on each
    iso-cost level ``C_a = level`` of ``levels`` (> 0): the curve solved exactly at ``s`` every ``s_step`` over
    ``s_range`` (``Q_back`` in ``Q_range``, its ``Q_back < 0`` branch), every curve point evaluated at ``snr_db`` in one
    batch, the best refined by a parabola in ``s`` and put back on the curve. ``{optimum_name(c, level): Design}``;
    a level whose curve has fewer than three points in the range is refused (``ValueError``)."""
    from .tradeoff import iso_cost_curve

    s_all = np.arange(s_range[0], s_range[1] + 1e-12, s_step)
    out = {}
    for level in levels:
        level = float(level)
        if not (math.isfinite(level) and level > 0):
            raise ValueError(f"cost level {level!r} is not allowed: a finite C_a > 0")
        cs, cq, cb = iso_cost_curve(camera.lens, level, s_all, Q_range)
        keep = cb < 0
        cs, cq = cs[keep], cq[keep]
        if len(cs) < 3:
            raise ValueError(f"cost level {level:g}: its iso-cost curve (Q_back < 0) has {len(cs)} point(s) for s in "
                             f"[{s_range[0]:g}, {s_range[1]:g}] and Q_back in [{Q_range[0]:g}, 0): choose a level "
                             "the range reaches")
        r = evaluate(camera, Design(s=torch.from_numpy(cs), Q_back=torch.from_numpy(cq)), [snr_db], numerics=numerics,
                     rho0=rho0)
        for c in criteria:
            crit = CRITERIA[c]
            v = r[c].reshape(len(cs), -1)[:, 0].numpy() * crit.sign  # minimised whatever the sense
            s_opt, _ = parabola_minimum(cs, v)
            s_on, q_on, b_on = iso_cost_curve(camera.lens, level, [s_opt], Q_range)
            q = float(q_on[b_on < 0][0]) if (b_on < 0).any() else float(cq[int(np.argmin(v))])
            s = float(s_on[b_on < 0][0]) if (b_on < 0).any() else float(cs[int(np.argmin(v))])
            out[optimum_name(c, level)] = Design(s=s, Q_back=q, name=optimum_name(c, level),
                                                 description=f"best {crit.label} at C_a = {level:g} ({snr_db:g} dB)")
    return out


def closed_form(camera: Camera, designs: dict[str, Design], snr_db, rho0: float, numerics: Numerics) -> dict:
    """Per design name: ``cost`` (C_a), ``rms_w`` and ``mse_r`` / ``mse_s`` at each SNR of ``snr_db`` (``{snr: value}``,
    field averages, unit signal variance), ``alpha_deg`` (the camera's field angles) and ``mse_r_alpha`` /
    ``mse_s_alpha`` (``{snr: [value per field angle]}``), from one :func:`lenssim.metrics.evaluate` per design."""
    out = {}
    for name, d in designs.items():
        r = evaluate(camera, d, list(snr_db), numerics=numerics, rho0=rho0)
        out[name] = {"cost": float(r["cost"].reshape(-1)[0]), "rms_w": float(r["rms_w"].reshape(-1)[0]),
                     "alpha_deg": [float(a) for a in r["alpha_deg"].reshape(-1)]}
        for k in ("mse_r", "mse_s"):
            out[name][k] = {float(s): float(v) for s, v in zip(snr_db, r[k].reshape(-1))}
            per = r[f"{k}_alpha"].reshape(len(out[name]["alpha_deg"]), len(snr_db))
            out[name][f"{k}_alpha"] = {float(s): [float(v) for v in per[:, j]] for j, s in enumerate(snr_db)}
        for k, v in out[name].items():
            flat = v if isinstance(v, list) else [v] if not isinstance(v, dict) else \
                [x for vv in v.values() for x in (vv if isinstance(vv, list) else [vv])]
            if not all(math.isfinite(x) for x in flat):
                raise ValueError(f"design {name!r}: its closed-form {k} is not finite")
    return out


@dataclass(frozen=True)
class RankingStudy:
    """What :func:`rank_designs` runs: ``designs`` ``{name: Design}`` on ``camera``, restored by ``methods``
    (:class:`pipeline.restoration.Restoration`), at ``isos`` (``full_wells`` e- each, and ``snr_db`` each: the SNR of
    the closed-form criterion), at crops of ``crop_px`` at ``angles_deg`` (those that fit each photo), noise from
    ``seed`` (crop ``k`` of a photo: ``seed + k`` at every ISO and design), ``rho0`` and ``numerics`` of the criterion;
    ``pairs``: ``(label, design_a, design_b)`` compared head to head in the report."""

    camera: Camera
    designs: dict
    methods: tuple
    isos: tuple[int, ...]
    full_wells: tuple[float, ...]
    snr_db: tuple[float, ...]
    angles_deg: tuple[float, ...]
    crop_px: int
    seed: int
    rho0: float
    numerics: Numerics
    pairs: tuple = ()

    def __post_init__(self):
        if not 2 <= len(self.designs) <= MAX_RANKING_DESIGNS:
            raise ValueError(f"{len(self.designs)} designs: give 2 to {MAX_RANKING_DESIGNS} (a ranking compares designs)")
        if not 1 <= len(self.methods) <= MAX_RANKING_METHODS:
            raise ValueError(f"{len(self.methods)} restoration methods: give 1 to {MAX_RANKING_METHODS}")
        names = [m.name for m in self.methods]
        if len(set(names)) != len(names) or SENSOR in names:
            raise ValueError(f"restoration methods {names}: give each method once")
        if not (len(self.isos) == len(self.full_wells) == len(self.snr_db) >= 1) or len(set(self.isos)) != len(self.isos):
            raise ValueError(f"ISOs {list(self.isos)}: give each once, with a full well and an SNR each")
        if not self.angles_deg or len(set(self.angles_deg)) != len(self.angles_deg):
            raise ValueError(f"crop angles {list(self.angles_deg)}: give at least one, each once")
        for label, a, b in self.pairs:
            for d in (a, b):
                if d not in self.designs:
                    raise ValueError(f"pair {label!r}: design {d!r} is not one of the study's")

    def digest(self, photos) -> str:
        """A checksum of everything that decides the results (a rerun resumes only a run with the same one)."""
        key = {"designs": {k: d.complete().floats() for k, d in self.designs.items()},
               "methods": [[m.name, sorted(m.options.items())] for m in self.methods], "isos": list(self.isos),
               "wells": list(self.full_wells), "angles": list(self.angles_deg), "crop": self.crop_px,
               "seed": self.seed, "photos": [[src, list(ideal.shape)] for src, ideal in photos],
               "camera": repr(self.camera)}
        return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _nmse(ideal: torch.Tensor, img: torch.Tensor) -> float:
    """The empirical MSE_R: mean squared error of ``img`` against ``ideal`` (linear) over the ideal's variance."""
    ideal, img = ideal.to(torch.float64), img.to(torch.float64)
    return float((img - ideal).square().mean() / ideal.var(unbiased=False))


def _design_unit(study: RankingStudy, name: str, photos, angles: dict, progress=None) -> list[dict]:
    """Every crop record of one design: photo, angle, ISO, method (and the sensor image), PSNR, SSIM, NMSE."""
    from pipeline import crop_at_field_angle, simulate_crops

    psf = LensPSF(study.camera, study.designs[name])
    rows = []
    for source, ideal in photos:
        boxes = [crop_at_field_angle(ideal.shape, a, study.crop_px, study.camera.geometry) for a in angles[source]]
        per_iso = simulate_crops(ideal, psf, list(study.full_wells), boxes, seed=study.seed, methods=study.methods,
                                 sensor=study.camera.sensor, blur_zones="auto", progress=progress)
        for iso, results in zip(study.isos, per_iso):
            for angle, res in zip(angles[source], results):
                for m in (SENSOR, *(r.name for r in study.methods)):
                    sc = res.scores[m]
                    row = {"design": name, "photo": source, "angle_deg": angle, "iso": iso, "method": m,
                           "psnr_db": sc["psnr_db"], "ssim": sc["ssim"], "nmse": _nmse(res.ideal, res.images[m])}
                    for k in ("psnr_db", "ssim", "nmse"):
                        if not math.isfinite(row[k]):
                            raise ValueError(f"{k} of {name} / {source} / {angle:g} deg / ISO {iso} / {m} is not "
                                             "finite (identical images?): not written")
                    rows.append(row)
    return rows


def ranking_angles(shapes, crop_px: int, geometry, angles_deg) -> dict:
    """``{source: angles}``: for each photo of ``shapes`` (``[(source, shape)]``) the angles of ``angles_deg`` whose
    ``crop_px`` crop fits it (:func:`pipeline.simulate.fitting_angles`; not others: every design sees the same crops;
    where fewer than two fit, those within its reach, else the axis). Refuses (``ValueError``) more than
    :data:`MAX_RANKING_PHOTOS` photos or :data:`MAX_RANKING_CROPS` crops."""
    from pipeline.simulate import fitting_angles

    if len(shapes) > MAX_RANKING_PHOTOS or not shapes:
        raise ValueError(f"{len(shapes)} photos: give 1 to {MAX_RANKING_PHOTOS}")
    out = {}
    for src, shape in shapes:
        fit = fitting_angles(shape, crop_px, geometry, tuple(angles_deg))
        if not set(fit) <= set(angles_deg):
            fit = tuple(a for a in angles_deg if a <= max(fit)) or (0.0,)
        out[src] = fit
    crops = sum(len(a) for a in out.values())
    if crops > MAX_RANKING_CROPS:
        raise ValueError(f"{crops} crops per design (photos x angles): at most {MAX_RANKING_CROPS}")
    return out


def rank_designs(study: RankingStudy, photos, out, *, log: Callable[[str], None] = print, progress=None) -> dict:
    """Run ``study`` on ``photos`` (``[(source, ideal)]``: linear ``(1, C, H, W)`` tensors or
    :class:`pipeline.photo.Photo`) and write ``ranking.csv``, ``ranking_crops.csv`` and ``ranking.md`` into ``out``
    (atomically, every file at the end; each design's crops go to ``OUT.partial/`` as they finish, and a rerun with
    the same settings resumes there; another run's partial folder is refused). Returns :func:`ranking_tables`."""
    from .chunks import partial_folder

    angles = ranking_angles([(src, ideal.shape) for src, ideal in photos], study.crop_px, study.camera.geometry,
                            study.angles_deg)
    crops = sum(len(a) for a in angles.values())
    snrs = sorted(set(study.snr_db))
    theory = closed_form(study.camera, study.designs, snrs, study.rho0, study.numerics)  # before the long work
    out = Path(out)
    part = out.parent / f"{out.name}.partial"
    digest = study.digest(photos)
    rows = []
    with partial_folder(part, "ranking.json", digest, {"designs": list(study.designs)},
                        f"{part} holds another ranking's partial results (other designs, photos or settings): "
                        "remove it or choose another --out"):
        for i, name in enumerate(study.designs):
            unit = part / f"design_{i:03d}.chunk"  # JSON; not .json: partial_folder keeps a folder with chunks
            got = None
            if unit.exists():
                try:
                    got = json.loads(unit.read_text())
                    got = got["rows"] if got.get("design") == name and got.get("digest") == digest else None
                except (ValueError, OSError, KeyError, AttributeError):
                    got = None
            if got is None:
                log(f"design {i + 1}/{len(study.designs)}: {name} ({crops} crops x {len(study.isos)} ISOs x "
                    f"{len(study.methods)} methods)")
                got = _design_unit(study, name, photos, angles, progress)
                atomic_write_text(unit, json_text({"design": name, "digest": digest, "rows": got}))
            else:
                log(f"design {i + 1}/{len(study.designs)}: {name}: resumed from {unit.name}")
            rows.extend(got)
    tables = ranking_tables(study, rows, theory)
    write_ranking(out, study, rows, tables, angles)
    shutil.rmtree(part, ignore_errors=True)
    return tables


def _ranks(values: dict, sign: float) -> dict:
    """Rank 1 for the best of ``values`` ``{name: v}`` (``sign`` +1: the least is best; -1: the greatest)."""
    order = sorted(values, key=lambda k: (sign * values[k], k))
    return {k: i + 1 for i, k in enumerate(order)}


def _kendall_tau(a: dict, b: dict) -> float:
    """Kendall's tau-a of two rankings ``{name: rank}`` of the same names (1: the same order; -1: reversed)."""
    names = sorted(a)
    n = len(names)
    if n < 2:
        return float("nan")
    s = sum(np.sign(a[names[i]] - a[names[j]]) * np.sign(b[names[i]] - b[names[j]])
            for i in range(n) for j in range(i + 1, n))
    return float(s) / (n * (n - 1) / 2)


def ranking_tables(study: RankingStudy, rows: list[dict], theory: dict) -> dict:
    """Means over crops per (design, ISO, method), each method's PSNR ranking and the closed form's, their Kendall
    tau, and the pairs head to head. ``{"means": [...], "agreement": [...], "pairs": [...]}``."""
    methods = (SENSOR, *(m.name for m in study.methods))
    means = []
    agreement = []
    by = {}
    for iso, snr in zip(study.isos, study.snr_db):
        for m in methods:
            crit = "mse_s" if m == SENSOR else "mse_r"
            psnr, ssim, nmse = {}, {}, {}
            for d in study.designs:
                sel = [r for r in rows if r["design"] == d and r["iso"] == iso and r["method"] == m]
                psnr[d] = sum(r["psnr_db"] for r in sel) / len(sel)
                ssim[d] = sum(r["ssim"] for r in sel) / len(sel)
                nmse[d] = sum(r["nmse"] for r in sel) / len(sel)
            cf = {d: theory[d][crit][float(snr)] for d in study.designs}
            at = {d: float(np.mean([np.interp(r["angle_deg"], theory[d]["alpha_deg"], theory[d][f"{crit}_alpha"][float(snr)])
                                    for r in rows if r["design"] == d and r["iso"] == iso and r["method"] == m]))
                  for d in study.designs}  # the closed form at the crops' field angles (mean over the crops)
            r_psnr, r_ssim, r_nmse, r_cf = _ranks(psnr, -1), _ranks(ssim, -1), _ranks(nmse, 1), _ranks(cf, 1)
            r_at = _ranks(at, 1)
            for d, design in study.designs.items():
                row = {"design": d, **design.complete().floats(), "cost": theory[d]["cost"], "rms_w": theory[d]["rms_w"],
                       "iso": iso, "snr_db": snr, "method": m, "crops": len([r for r in rows if r["design"] == d and
                                                                            r["iso"] == iso and r["method"] == m]),
                       "psnr_db": psnr[d], "ssim": ssim[d], "nmse": nmse[d], "rank_psnr": r_psnr[d],
                       "rank_ssim": r_ssim[d], "rank_nmse": r_nmse[d], "closed_form": crit,
                       "closed_form_value": cf[d], "rank_closed_form": r_cf[d], "closed_form_at_crops": at[d],
                       "rank_closed_form_at_crops": r_at[d]}
                means.append(row)
                by[(d, iso, m)] = row
            agreement.append({"iso": iso, "method": m, "closed_form": crit,
                              "tau_psnr": _kendall_tau(r_psnr, r_cf), "tau_ssim": _kendall_tau(r_ssim, r_cf),
                              "tau_nmse": _kendall_tau(r_nmse, r_cf),
                              "tau_psnr_at_crops": _kendall_tau(r_psnr, r_at),
                              "best_psnr": min(r_psnr, key=r_psnr.get), "best_closed_form": min(r_cf, key=r_cf.get),
                              "best_closed_form_at_crops": min(r_at, key=r_at.get)})
    pairs = []
    for label, a, b in study.pairs:
        for iso in study.isos:
            for m in methods:
                ra, rb = by[(a, iso, m)], by[(b, iso, m)]
                pairs.append({"pair": label, "a": a, "b": b, "iso": iso, "method": m,
                              "psnr_a_minus_b_db": ra["psnr_db"] - rb["psnr_db"],
                              "ssim_a_minus_b": ra["ssim"] - rb["ssim"],
                              "nmse_a_over_b": ra["nmse"] / rb["nmse"],
                              "closed_form_a_over_b": ra["closed_form_value"] / rb["closed_form_value"],
                              "closed_form_at_crops_a_over_b": ra["closed_form_at_crops"] / rb["closed_form_at_crops"]})
    return {"means": means, "agreement": agreement, "pairs": pairs}


def _csv(rows: list[dict]) -> str:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows([keys] + [[r.get(k, "") for k in keys] for r in rows])
    return buf.getvalue()


def ranking_report(study: RankingStudy, tables: dict, angles: dict) -> str:
    """The Markdown report: per ISO, designs x methods (mean PSNR and its rank) beside the closed form; the agreement
    of each method's ranking with the closed form's; the pairs head to head."""
    methods = (SENSOR, *(m.name for m in study.methods))
    label = lambda r: r.method.label + (f" ({', '.join(f'{k}={v}' for k, v in r.options.items())})"  # noqa: E731
                                        if r.options else "")
    where = "; ".join(f"{Path(s).name}: {', '.join(f'{a:g}' for a in a_)} deg" for s, a_ in angles.items())
    lines = [f"Mean over crops of {study.crop_px} px ({where}), sRGB PSNR [dB] against the ideal image and its rank "
             f"among the designs (1: best), beside the closed-form criterion (MSE_R of the Wiener restoration; MSE_S of "
             f"the sensor image), field-averaged, unit signal variance, and its rank. Restorations: "
             f"{'; '.join(label(r) for r in study.methods)}. The same noise draws for every design (seed {study.seed}).",
             ""]
    by = {(r["design"], r["iso"], r["method"]): r for r in tables["means"]}
    for iso, snr in zip(study.isos, study.snr_db):
        lines += [f"### ISO {iso} (closed form at {snr:g} dB)", "",
                  "| design | s | Q_back | C_a | MSE_R closed form (rank) | MSE_R closed form at the crops (rank) | "
                  "MSE_S closed form at the crops (rank) | " + " | ".join(f"PSNR {m} (rank)" for m in methods) + " |",
                  "|---|---|---|---|---|---|---|" + "---|" * len(methods)]
        for d in study.designs:
            r0 = by[(d, iso, methods[1])]
            rs = by[(d, iso, SENSOR)]
            cells = " | ".join(f"{by[(d, iso, m)]['psnr_db']:.2f} ({by[(d, iso, m)]['rank_psnr']})" for m in methods)
            lines.append(f"| {d} | {r0['s']:.3f} | {r0['Q_back']:.2f} | {r0['cost']:.2e} | "
                         f"{r0['closed_form_value']:.5f} ({r0['rank_closed_form']}) | "
                         f"{r0['closed_form_at_crops']:.5f} ({r0['rank_closed_form_at_crops']}) | "
                         f"{rs['closed_form_at_crops']:.5f} ({rs['rank_closed_form_at_crops']}) | {cells} |")
        lines.append("")
    lines += ["### Agreement with the closed form", "",
              "Kendall's tau of each method's ranking (by mean PSNR, SSIM and empirical MSE_R) against the closed "
              "form's, field-averaged (1: the same order, -1: reversed), of the PSNR ranking against the closed form at "
              "the crops' field angles, and the best design by each.", "",
              "| ISO | method | tau PSNR | tau SSIM | tau MSE_R empirical | tau PSNR vs at the crops | best by PSNR | "
              "best by closed form | best by closed form at the crops |", "|---|---|---|---|---|---|---|---|---|"]
    for a in tables["agreement"]:
        lines.append(f"| {a['iso']} | {a['method']} | {a['tau_psnr']:+.2f} | {a['tau_ssim']:+.2f} | "
                     f"{a['tau_nmse']:+.2f} | {a['tau_psnr_at_crops']:+.2f} | {a['best_psnr']} | "
                     f"{a['best_closed_form']} | {a['best_closed_form_at_crops']} |")
    if tables["pairs"]:
        lines += ["", "### Head to head", "",
                  "PSNR and SSIM of the first design minus the second's (positive: the first wins), and the ratio of "
                  "their errors, empirical and closed form (below 1: the first wins).", "",
                  "| pair | ISO | method | PSNR a - b [dB] | SSIM a - b | MSE_R a / b empirical | closed form a / b | "
                  "closed form at the crops a / b |", "|---|---|---|---|---|---|---|---|"]
        for p in tables["pairs"]:
            lines.append(f"| {p['pair']} ({p['a']} vs {p['b']}) | {p['iso']} | {p['method']} | "
                         f"{p['psnr_a_minus_b_db']:+.2f} | {p['ssim_a_minus_b']:+.3f} | {p['nmse_a_over_b']:.3f} | "
                         f"{p['closed_form_a_over_b']:.3f} | {p['closed_form_at_crops_a_over_b']:.3f} |")
    return "\n".join(lines) + "\n"


def write_ranking(out, study: RankingStudy, rows: list[dict], tables: dict, angles: dict) -> None:
    """``ranking.csv`` (means and ranks), ``ranking_crops.csv`` (every crop), ``agreement.csv``, ``pairs.csv`` and
    ``ranking.md`` into ``out``, all at once (a staged folder moved into place)."""
    from lenssim.io.files import staged_output_dir

    for r in tables["means"]:
        for k, v in r.items():
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{k} of {r['design']} / ISO {r['iso']} / {r['method']} is not finite: not written")
    md = ranking_report(study, tables, angles)
    with staged_output_dir(Path(out)) as stage:
        atomic_write_text(stage / "ranking.csv", _csv(tables["means"]))
        atomic_write_text(stage / "ranking_crops.csv", _csv(rows))
        atomic_write_text(stage / "agreement.csv", _csv(tables["agreement"]))
        if tables["pairs"]:
            atomic_write_text(stage / "pairs.csv", _csv(tables["pairs"]))
        atomic_write_text(stage / "ranking.md", md)
