"""Issue 46, item 2: where a sweep's work lies along its grid, counted in FFT work rather than in PSFs.

    python benchmarks/bench_sweep_work.py [CONFIG] [--time 121 61 0] [--device cpu] [--threads 2]

For every chunk of the sweep ``CONFIG`` (default ``paper_grid``; a chunk is one value of the first dimension: one s,
all 113 values of Q and 15 field angles): the FFT size each PSF needs (:func:`lenssim.optics.psf_bank.fft_size`, the
sweep's own choice; no transform is run here) and the chunk's FFT work, ``sum n^2 log2 n`` over its PSFs. Printed:
the smallest, mean and largest size of a few chunks and how many distinct sizes each holds (the OTF bank runs a batch
per size at least: on a GPU, the fewest kernel launches), each one's share of the grid's work, and the share of the
first and last tenth of the chunks.

With ``--time``: those chunks computed as :func:`lenssim_studies.sweep.run_sweep` computes them (on ``--device``),
each one's time, PSFs per second and work rate (``G n^2 log2 n`` per second), and the sizes it used checked against
the prediction. A work rate that stays level along the grid means the device is as busy on the first chunk as on the
last; PSFs per second do not, because the grid's PSFs differ in size by up to 8x along a side. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from lenssim import Design
from lenssim.io.resources import config_path
from lenssim.optics.psf_bank import fft_size, spectral_coefficients
from lenssim_studies.chunks import _compute_chunk, chunk_values  # one chunk, exactly as run_sweep computes it
from lenssim_studies.sweep import load_config


def predicted_sizes(cfg, i: int) -> torch.Tensor:
    """The FFT size (px) of every PSF of chunk ``i``: ``(*grid, A)``."""
    design = Design(chunk_values(cfg, i))
    alpha = torch.tensor(cfg.camera.lens.field_angles_deg, dtype=torch.float64)
    coeffs = spectral_coefficients(cfg.camera, design.map(lambda t: t[..., None]), alpha)  # (*grid, A, K, T)
    return fft_size(cfg.camera, coeffs, cfg.numerics)


def work(sizes: torch.Tensor) -> float:
    """``sum n^2 log2 n`` over the sizes (one unit: a transform of ``n x n`` points, up to its constant)."""
    n = sizes.to(torch.float64)
    return float((n * n * torch.log2(n)).sum())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("config", nargs="?", default="paper_grid")
    ap.add_argument("--time", type=int, nargs="*", default=[], metavar="CHUNK")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = load_config(config_path(args.config))
    if cfg.focus is not None or cfg.camera.channels:
        print(f"{args.config}: a sweep with a focus search or colour channels sizes its PSFs per focus or channel; "
              "this count covers the monochromatic, fixed-focus sweeps only")
        return 2
    first = cfg.values(cfg.dims[0])
    sizes = [predicted_sizes(cfg, i) for i in range(len(first))]
    works = np.array([work(s) for s in sizes])
    total = works.sum()
    print(f"{args.config}: {len(first)} chunks of {sizes[0].numel()} PSFs ({cfg.dims[0]} x "
          f"{' x '.join(cfg.dims[1:])} x {len(cfg.camera.lens.field_angles_deg)} angles); FFT work "
          f"{total / 1e9:.0f} G (n^2 log2 n)")
    shown = sorted(set([0, 1, len(first) // 2, len(first) - 1] + [i for i in args.time if 0 <= i < len(first)]))
    for i in shown:
        s = sizes[i]
        print(f"  chunk {i:4d} {cfg.dims[0]} = {first[i]:+.3f}: n {int(s.min())}-{int(s.max())} px, mean "
              f"{float(s.double().mean()):.0f}, {torch.unique(s).numel()} distinct sizes (a batch each at least); "
              f"{works[i] / total * 100:.2f}% of the work")
    distinct = [torch.unique(sz).numel() for sz in sizes]
    print(f"  distinct FFT sizes per chunk: {min(distinct)}-{max(distinct)}, {sum(distinct)} over the grid (the fewest "
          "batches a chunk-by-chunk sweep runs, whatever the device's memory)")
    tenth = max(1, len(first) // 10)
    print(f"  the first tenth of the chunks: {works[:tenth].sum() / total * 100:.1f}% of the work; the last tenth: "
          f"{works[-tenth:].sum() / total * 100:.1f}%; the largest chunk {works.max() / works.min():.1f}x the "
          "smallest")
    device = torch.device(args.device)
    for i in args.time:
        if not 0 <= i < len(first):
            print(f"  --time {i}: no such chunk (0 to {len(first) - 1})")
            continue
        t0 = time.perf_counter()
        chunk = _compute_chunk(cfg, i, device, None)
        if device.type == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter() - t0
        used = torch.from_numpy(np.asarray(chunk["fft_size"]))
        agree = "as predicted" if torch.equal(used.reshape(-1), sizes[i].reshape(-1).to(used.dtype)) else \
            f"NOT as predicted (work {work(used) / works[i]:.3f}x)"
        print(f"  chunk {i:4d} on {device.type}: {t:6.1f} s, {used.numel() / t:7.0f} PSFs/s, "
              f"{work(used) / t / 1e9:.3f} G/s (sizes {agree})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
