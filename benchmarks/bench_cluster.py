"""Sweep throughput in one process and on 1 and 2 local dask workers, side by side in one run.

    python benchmarks/bench_cluster.py [--config FILE_OR_NAME] [--fast]

Default: the paper's s range in steps of 0.125 (15 chunks) x Q_back -10..1.2 in steps of 0.2 x 15 angles,
fast numerics (12,825 PSFs; long enough per chunk that the workers' start-up does not dominate).

Each run writes the same sweep into a fresh temporary folder (nothing is reused); the table gives the wall
time, the throughput in PSFs per second and the ratio to the single-process run, and checks that every
cluster file is byte-identical to the single-process one.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

from lenssim.model.numerics import FAST_NUMERICS
from lenssim.io.resources import config_path
from lenssim_studies.sweep import SweepConfig, load_config, run_sweep


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", help="sweep config (file or built-in name; default: the grid above)")
    ap.add_argument("--fast", action="store_true", help="the fast numerics (oversample 1)")
    args = ap.parse_args()
    if args.config:
        cfg = load_config(config_path(args.config))
        if args.fast:
            cfg.numerics = FAST_NUMERICS
    else:
        cfg = SweepConfig(grid={"s": (-1.5, 0.25, 0.125), "Q_back": (-10.0, 1.2, 0.2)}, numerics=FAST_NUMERICS)
    n_psf = cfg.n_designs() * len(cfg.lens.field_angles_deg)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        threads = torch.get_num_threads()
        runs = (("one process", {}), ("1 local worker", {"workers": 1}),
                (f"2 local workers, {threads} torch threads per task", {"workers": 2}),
                ("2 local workers, 1 torch thread per task", {"workers": 2, "worker_threads": 1}))
        for label, kw in runs:
            out = Path(d) / f"run{len(rows)}.nc"
            t0 = time.perf_counter()
            run_sweep(cfg, out, device="cpu", show_progress=False, **kw)
            rows.append((label, time.perf_counter() - t0, out.read_bytes()))
            print(f"  {label}: {rows[-1][1]:.1f} s", flush=True)
    base_t, base_bytes = rows[0][1], rows[0][2]
    print(f"\n{args.config or 'default grid'} ({cfg.n_designs()} designs x {len(cfg.lens.field_angles_deg)} angles = {n_psf} PSFs, "
          f"{len(cfg.values(cfg.dims[0]))} chunks, oversample {cfg.numerics.oversample})\n")
    print("| run | wall time [s] | PSF/s | vs one process | file identical |")
    print("|---|---|---|---|---|")
    for label, t, data in rows:
        print(f"| {label} | {t:.1f} | {n_psf / t:.0f} | {base_t / t:.2f}x | {'yes' if data == base_bytes else 'NO'} |")
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())  # no nanobind "leaked" noise at exit
