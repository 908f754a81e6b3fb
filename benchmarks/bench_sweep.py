"""The paper sweep's cost with the accurate default numerics and with the fast preset, side by side.

    python benchmarks/bench_sweep.py [--every 16]

Runs every ``--every``-th value of s of the paper grid (all 113 values of Q, 15 field angles) with
both numerics in one process, and projects the full grid (122 values of s) from the measured time per
chunk. Prints the PSF throughput and the peak resident memory of each run. The baseline is the default
numerics with the OTF bank's PSF -> OTF stage as it was before issue 11's second round (commit 77a70cc:
y-transform first, on zero-padded columns), kept below as :func:`otf_from_psf_half_77a70cc`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

import lenssim.optics.psf_bank as psf_bank

from lenssim.model.numerics import DEFAULT_NUMERICS, FAST_NUMERICS
from lenssim.io.resources import config_path
from lenssim_studies.sweep import load_config, run_sweep

sys.path.insert(0, str(Path(__file__).parent))
from bench_pipeline import PeakRSS  # noqa: E402


def otf_from_psf_half_77a70cc(p_half, n, oversample, area):
    """The PSF -> OTF stage of the OTF bank at commit 77a70cc (the baseline of this benchmark)."""
    h = n // 2
    B = p_half.shape[0]
    m = n * int(oversample)
    if m != n:
        p_half = p_half.clone()
        p_half[:, h] *= 0.5
        p_half[..., h] *= 0.5
        p_half = torch.cat([p_half[:, : h + 1], p_half.new_zeros(B, m - n - 1, h + 1), p_half[:, h:]], dim=1)
        p_half = torch.nn.functional.pad(p_half, (0, m // 2 - h))
    hm = m // 2
    g = torch.fft.rfft(p_half, dim=-2)
    del p_half
    scale = float(m / area)
    g_re = torch.fft.irfft(g.real, n=m, dim=-1)[..., : hm + 1].mul_(scale)
    g_im = torch.fft.irfft(g.imag, n=m, dim=-1)[..., : hm + 1].mul_(scale)
    del g
    return torch.complex(g_re, g_im)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=int, default=16, help="take every N-th value of s (default 16: 8 chunks)")
    args = ap.parse_args()
    full = load_config(config_path("paper_grid"))
    s_all = full.values("s")
    start, stop, step = full.grid["s"]
    picked = s_all[::args.every]
    rows = []
    with tempfile.TemporaryDirectory() as d:
        current = psf_bank._otf_from_psf_half
        try:
            runs = (("default, baseline (77a70cc)", DEFAULT_NUMERICS, otf_from_psf_half_77a70cc),
                    ("default (oversample 2)", DEFAULT_NUMERICS, current),
                    ("fast (oversample 1)", FAST_NUMERICS, current))
            for label, numerics, stage2 in runs:
                psf_bank._otf_from_psf_half = stage2
                cfg = load_config(config_path("paper_grid"))  # a frozen config: replaced, not assigned to
                cfg = dataclasses.replace(cfg, grid={"s": (float(picked[0]), float(picked[-1]), step * args.every),
                                                     **{k: v for k, v in cfg.grid.items() if k != "s"}},
                                          numerics=numerics)
                n_psf = cfg.n_designs() * len(cfg.lens.field_angles_deg)
                with PeakRSS() as mem:
                    t0 = time.perf_counter()
                    run_sweep(cfg, Path(d) / f"{len(rows)}.nc", device="cpu", show_progress=False)
                    t = time.perf_counter() - t0
                per_chunk = t / len(cfg.values("s"))
                rows.append((label, len(cfg.values("s")), n_psf, t, per_chunk * len(s_all), mem.peak))
                print(f"  {label}: {t:.1f} s", flush=True)
        finally:  # the library's own stage back, whatever happened
            psf_bank._otf_from_psf_half = current
    print(f"\npaper grid, every {args.every}th of {len(s_all)} values of s ({np.round(picked, 3).tolist()}), "
          f"all {len(full.values('Q_back'))} Q_back, {len(full.lens.field_angles_deg)} angles\n")
    print("| numerics | chunks | PSFs | time [s] | PSF/s | projected full grid [min] | peak RSS [GiB] |")
    print("|---|---|---|---|---|---|---|")
    for label, k, n, t, proj, peak in rows:
        print(f"| {label} | {k} | {n} | {t:.1f} | {n / t:.0f} | {proj / 60:.1f} | {peak:.2f} |")
    print(f"\nbaseline / default: {rows[0][3] / rows[1][3]:.2f}x; default / fast: {rows[1][3] / rows[2][3]:.2f}x")
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())  # no nanobind "leaked" noise at exit
