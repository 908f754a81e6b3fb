"""Trace the end-to-end (MSE_R) trade-off without a grid, by gradient projection on iso-cost curves.

    python examples/tradeoff_autograd.py [--tradeoff results/repro/tradeoff.nc] [--levels 3 8 14 20]

For each chosen cost level (indices into the paper's 30 levels 0..2e-3) it starts from the
iso-cost point at s = -1.0 (a poor design, as the paper's Section 5 suggests), follows the quality
gradient projected orthogonally to the cost gradient, and prints the optimum and the number of
model evaluations, beside the grid-based trade-off of `lenssim reproduce` when its file is given.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from lenssim.design_opt import DifferentiableCriterion, optimise_on_iso_cost
from lenssim_studies.paper import PAPER_CAMERA, PAPER_COST_LEVELS, PAPER_GRID, PAPER_RHO0, REFERENCE_SNR_DB
from lenssim_studies.tradeoff import iso_cost_curve


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tradeoff", default="results/repro/tradeoff.nc")
    ap.add_argument("--levels", type=int, nargs="+", default=[3, 8, 14, 20])
    ap.add_argument("--snr", type=float, default=REFERENCE_SNR_DB)
    args = ap.parse_args()
    grid = None
    if Path(args.tradeoff).exists():
        import xarray as xr

        grid = xr.load_dataset(args.tradeoff).sel(criterion=f"mse_r@{args.snr:g}")
    print("| level C_a | start (s, Q_back) | autograd optimum (s, Q_back) | MSE_R | evaluations | grid-based optimum | MSE_R (grid) |")
    print("|---|---|---|---|---|---|---|")
    for j in args.levels:
        level = float(PAPER_COST_LEVELS[j])
        cs, cq, _ = iso_cost_curve(PAPER_CAMERA.lens, level, [-1.0])
        x0 = (-1.0, float(cq[0]))
        f = DifferentiableCriterion(PAPER_CAMERA, args.snr, "mse_r", rho0=PAPER_RHO0)
        t0 = time.perf_counter()
        r = optimise_on_iso_cost(f, x0, level, bounds={k: v[:2] for k, v in PAPER_GRID.items()})  # the paper's grid
        dt = time.perf_counter() - t0
        g = grid.isel(level=j) if grid is not None else None
        gtxt = f"({float(g['s']):.4f}, {float(g['Q_back']):.3f}) | {float(g['value']):.5f}" if g is not None else "- | -"
        print(f"| {level:.3e} | ({x0[0]:.3f}, {x0[1]:.3f}) | ({r.design['s']:.4f}, {r.design['Q_back']:.3f}) | {r.value:.5f} | "
              f"{r.evaluations} ({r.iterations} steps, {dt:.0f} s) | {gtxt} |", flush=True)


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown()  # no nanobind "leaked" noise at exit
