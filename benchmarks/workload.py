"""What the issue-33 benchmarks share (imported by the scripts beside it, run as ``python benchmarks/NAME.py``): the
fixed FFT workload every time is also given in units of, so machines compare, and the agreement of two images in dB."""

from __future__ import annotations

import math
import time

import torch

REFERENCE_PAIRS = 200
"""float32 ``rfft2``/``irfft2`` pairs of a 4 x 3 x 512 x 512 tensor in the reference workload."""


def reference_seconds(pairs: int = REFERENCE_PAIRS) -> float:
    """Wall time (s) of the reference workload (one warm-up pair first)."""
    x = torch.rand(4, 3, 512, 512)
    torch.fft.irfft2(torch.fft.rfft2(x), s=x.shape[-2:])
    t0 = time.perf_counter()
    for _ in range(pairs):
        torch.fft.irfft2(torch.fft.rfft2(x), s=x.shape[-2:])
    return time.perf_counter() - t0


def agreement_db(a: torch.Tensor, b: torch.Tensor) -> float:
    """10 log10(1 / mean square difference) of two linear images (dB, signal peak 1; inf if identical)."""
    d = float((a.double() - b.double()).square().mean())
    return math.inf if d == 0 else -10 * math.log10(d)
