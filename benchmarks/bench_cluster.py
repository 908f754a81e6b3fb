"""Sweep throughput in one process and on 1 and 2 local dask workers, side by side in one run.

    python benchmarks/bench_cluster.py [--config small_grid] [--fast]

Each run writes the same sweep into a fresh temporary folder (nothing is reused); the table gives the wall
time, the throughput in PSFs per second and the ratio to the single-process run, and checks that every
cluster file is byte-identical to the single-process one.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from lenssim.numerics import FAST_NUMERICS
from lenssim.resources import config_path
from lenssim.sweep import load_config, run_sweep


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="small_grid", help="sweep config (file or built-in name)")
    ap.add_argument("--fast", action="store_true", help="the fast numerics (oversample 1)")
    args = ap.parse_args()
    cfg = load_config(config_path(args.config))
    if args.fast:
        cfg.numerics = FAST_NUMERICS
    n_psf = cfg.n_designs() * len(cfg.lens.field_angles_deg)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for label, kw in (("one process", {}), ("1 local worker", {"workers": 1}), ("2 local workers", {"workers": 2})):
            out = Path(d) / f"{label.replace(' ', '_')}.nc"
            t0 = time.perf_counter()
            run_sweep(cfg, out, device="cpu", show_progress=False, **kw)
            rows.append((label, time.perf_counter() - t0, out.read_bytes()))
            print(f"  {label}: {rows[-1][1]:.1f} s", flush=True)
    base_t, base_bytes = rows[0][1], rows[0][2]
    print(f"\n{args.config} ({cfg.n_designs()} designs x {len(cfg.lens.field_angles_deg)} angles = {n_psf} PSFs, "
          f"{len(cfg.values(cfg.dims[0]))} chunks, oversample {cfg.numerics.oversample})\n")
    print("| run | wall time [s] | PSF/s | vs one process | file identical |")
    print("|---|---|---|---|---|")
    for label, t, data in rows:
        print(f"| {label} | {t:.1f} | {n_psf / t:.0f} | {base_t / t:.2f}x | {'yes' if data == base_bytes else 'NO'} |")
    return 0 if all(r[2] == base_bytes for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
