"""Robustness on the trade-off front of any lens (issue 30, item 5): the as-built Monte Carlo (tolerances per surface,
:mod:`lenssim.tolerancing`) at each optimum of a trade-off (:mod:`lenssim_studies.tradeoff`).

:func:`robust_front` takes the distinct designs among one criterion's optima per cost level (a design that is the
optimum at several levels is computed once), in ascending cost, and runs a resumable Monte Carlo of each
(:func:`lenssim_studies.tolerance.run_tolerance`, ``design_NN.nc``) on the trade-off's own sensor, numerics, SNRs and field
angles, every design with the same seed: common random numbers, the designs compared on the same draws of every
error term. Per design: its nominal ``mse_r``, the mean, p90 and max of ``mse_r`` as built (each copy restored with
its own PSFs) and the mean and p90 of ``mse_r_nominal`` (restored with the design's Wiener filter: the nominal
restoration penalty). Per cost level: the nominal optimum and the robust optimum, the design of best p90 ``mse_r``
as built among the distinct designs whose cost is within the level.

The Monte Carlo is real-ray (:func:`lenssim.tolerancing.lens_copies`) whatever route scored the trade-off; on the exact
route a design's nominal ``mse_r`` here is the trade-off's value (its image shift folded into the last thickness).
"""

from __future__ import annotations

import math
from pathlib import Path

from lenssim.model.tolerances import SurfaceTolerances
from lenssim.optics.sequential import SequentialLens
from lenssim.metrics import evaluation_angles

from .chunks import finished_result
from .tolerance import LensToleranceRun, run_tolerance, summarise_lens_tolerance
from .tradeoff import LensTradeoffRun, design_prescription, sequential_provider

__all__ = ["robust_front", "robustness_figure", "design_tolerance_run", "MAX_ROBUST_COPIES"]

MAX_ROBUST_COPIES = 10_000
"""Most copies per design (each traces its own wavefront tables: seconds a copy)."""


def _distinct_optima(res: dict, criterion: str) -> list[dict]:
    """The distinct designs among ``res``'s optima of ``criterion`` (``{"design", "cost"}``), in ascending cost (a tie
    in the order the levels first reach them)."""
    seen = {}
    for o in res["optima"][criterion]:
        if o is not None:
            seen.setdefault(tuple(sorted(o["design"].items())), {"design": dict(o["design"]), "cost": float(o["cost"])})
    return sorted(seen.values(), key=lambda d: d["cost"])


def design_tolerance_run(run: LensTradeoffRun, design: dict, tolerances: SurfaceTolerances, *, copies: int,
                         seed: int) -> LensToleranceRun:
    """The Monte Carlo of one design of ``run`` (:func:`lenssim_studies.tradeoff.design_prescription`: its solves
    applied, its image plane folded into the last thickness) on the trade-off's sensor, numerics, SNRs, correlation,
    field angles and table coarseness."""
    q = design_prescription(run, design)
    psf = sequential_provider(q, SequentialLens(q), pitch_um=run.pitch_um, sampling=run.sampling,
                              max_field_deg=run.max_field_deg, numerics=run.numerics, coarse=run.coarse)
    return LensToleranceRun(psf, tolerances, copies, seed, tuple(run.snr_db), run.rho0, run.numerics,
                            angles_deg=evaluation_angles(run.max_field_deg, run.angles), coarse=run.coarse)


def _summary_snr(run: LensTradeoffRun, criterion: str) -> float:
    """The SNR (dB) of the summaries: the one ``criterion`` names (``mse_r@33.6``), else the run's first."""
    _, at, snr = criterion.partition("@")
    return float(snr) if at else float(run.snr_db[0])


def robust_front(run: LensTradeoffRun, res: dict, tolerances: SurfaceTolerances, *, copies: int, seed: int,
                 out_dir: Path, criterion: str = "mse_r", show_progress=True) -> dict:
    """The as-built Monte Carlo at each distinct optimum of ``criterion`` in ``res``
    (:func:`lenssim_studies.tradeoff.tradeoff_json` of ``run``), each written to (and resumed from)
    ``out_dir/design_NN.nc``: see the module docstring. Returns ``{"criterion", "copies", "seed", "tolerances",
    "snr_db", "designs": [...], "levels": [{"cost", "nominal_optimum", "robust_optimum"}, ...], "nominal_optimum",
    "robust_optimum"}`` (indices into ``designs``, None where no valid design reaches a level; the overall nominal
    optimum is the largest level's, the overall robust optimum the best p90 of all). Every argument is checked, and every
    ``design_NN.nc`` already there is checked to be this run's, before any work."""
    if isinstance(copies, bool) or not isinstance(copies, int) or not 1 <= copies <= MAX_ROBUST_COPIES:
        raise ValueError(f"copies={copies!r} is not allowed: from 1 to {MAX_ROBUST_COPIES} manufactured copies per design")
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(f"seed={seed!r} is not allowed: an integer")
    if not isinstance(tolerances, SurfaceTolerances):
        raise ValueError(f"tolerances of type {type(tolerances).__name__} are not allowed: a SurfaceTolerances")
    if criterion not in res.get("optima", {}):
        raise ValueError(f"criterion {criterion!r} is not allowed: one of the trade-off's "
                         f"{', '.join(res.get('optima', {})) or '(none)'}")
    designs = _distinct_optima(res, criterion)
    if not designs:
        raise ValueError(f"the trade-off has no optimum of {criterion!r} at any cost level (no valid design)")
    for d in designs:
        if set(d["design"]) != set(run.names):
            raise ValueError(f"the trade-off's designs vary {', '.join(d['design'])}, not this run's "
                             f"{', '.join(run.names)}: res must be tradeoff_json() of this run")
    snr = _summary_snr(run, criterion)
    if not any(math.isclose(snr, s, abs_tol=1e-9) for s in run.snr_db):
        raise ValueError(f"criterion {criterion!r} names an SNR the run does not have: one of {list(run.snr_db)}")
    out_dir = Path(out_dir)
    runs = [design_tolerance_run(run, d["design"], tolerances, copies=copies, seed=seed) for d in designs]
    files = [f"design_{k:02d}.nc" for k in range(len(designs))]
    for r, f in zip(runs, files):  # a file of another run (other tolerances, copies, front) is refused now
        finished_result(out_dir / f, r.digest(), "tolerance run")
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for d, r, f in zip(designs, runs, files):
        ds = run_tolerance(r, out_dir / f, show_progress=show_progress,
                           attrs={"tradeoff_design": str(d["design"]), "tradeoff_criterion": criterion,
                                  "cost": d["cost"]})
        s = summarise_lens_tolerance(ds, snr)
        rows.append({"design": d["design"], "cost": d["cost"], "nominal": s["mse_r"]["nominal"],
                     "mean": s["mse_r"]["mean"], "p90": s["mse_r"]["p90"], "max": s["mse_r"]["max"],
                     "nominal_restoration_mean": s["mse_r_nominal"]["mean"],
                     "nominal_restoration_p90": s["mse_r_nominal"]["p90"], "file": f})
    index = {tuple(sorted(d["design"].items())): k for k, d in enumerate(designs)}

    def best_p90(among):
        return min(among, key=lambda k: (rows[k]["p90"], k)) if among else None

    levels = []
    for c, o in zip(res["levels"], res["optima"][criterion]):
        within = [k for k, d in enumerate(rows) if d["cost"] <= c * (1 + 1e-12) + 1e-15]  # as front() reads a level
        levels.append({"cost": float(c), "nominal_optimum": None if o is None else index[tuple(sorted(
            o["design"].items()))], "robust_optimum": best_p90(within)})
    return {"criterion": criterion, "copies": copies, "seed": seed, "tolerances": tolerances.to_dict(), "snr_db": snr,
            "designs": rows, "levels": levels, "nominal_optimum": levels[-1]["nominal_optimum"],
            "robust_optimum": best_p90(range(len(rows)))}


def robustness_figure(robust: dict, out_dir, title: str) -> Path:
    """Against the asphere cost, each optimum's nominal ``mse_r``, its copies' mean and p90 ``mse_r`` (restored with
    their own PSFs) and mean ``mse_r_nominal`` (restored with the design's filter), the robust optimum marked
    (``robustness.png``, ``.svg``); a log axis where the values span more than a decade."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from .figures import _save

    rows = robust["designs"]
    cost = np.asarray([d["cost"] for d in rows])
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    series = (("nominal", "the design (nominal)", "k", "o-"),
              ("mean", "as built, own PSFs: mean", "C0", "s-"),
              ("p90", "as built, own PSFs: p90", "C0", "v--"),
              ("nominal_restoration_mean", "as built, the design's filter: mean (nominal restoration)", "C3", "^-"))
    values = []
    for key, label, color, style in series:
        v = np.asarray([d[key] for d in rows])
        values.append(v)
        ax.plot(cost, v, style, color=color, label=label, ms=5)
    n = robust["nominal_optimum"]
    ax.plot([cost[n]], [rows[n]["nominal"]], "o", mfc="none", mec="C2", ms=13, mew=2,
            label=f"nominal optimum: C_a = {cost[n]:.3g}")
    k = robust["robust_optimum"]
    ax.plot([cost[k]], [rows[k]["p90"]], "*", color="C1", ms=16, zorder=5,
            label=f"robust optimum (best p90): C_a = {cost[k]:.3g}")
    v = np.concatenate(values)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size and v.max() > 10 * v.min():
        ax.set_yscale("log")
    ax.set_xlabel("asphere cost C_a (RMS slope departure)")
    ax.set_ylabel(f"MSE_R at {robust['snr_db']:g} dB")
    ax.set_title(f"{robust['copies']} copies per design (seed {robust['seed']}), optima of {robust['criterion']}",
                 fontsize=8)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, Path(out_dir), "robustness")
