"""Photon (Poisson) noise of the paper's sensor (Section 3.2-3.3).

The blurred linear image's maximum is scaled to the full-well capacity (electrons), each pixel is
Poisson-sampled, and the result is scaled back. FWC: 3,200 e- at ISO 100 (the expected level,
SNR ~27.6 dB), 800 at ISO 400 and 12,800 at ISO 25. Randomness comes only from the explicit
``generator`` (or ``seed``), so results are reproducible.
"""

from __future__ import annotations

import torch

__all__ = ["ISO_FULL_WELL", "full_well_for_iso", "add_poisson_noise"]

ISO_FULL_WELL = {25: 12800.0, 100: 3200.0, 400: 800.0}


def full_well_for_iso(iso: int) -> float:
    """Full-well capacity (electrons) of the paper's sensor at ``iso`` (25, 100 or 400)."""
    if iso not in ISO_FULL_WELL:
        raise ValueError(f"iso={iso!r} is not allowed: one of {sorted(ISO_FULL_WELL)} (or give full_well directly)")
    return ISO_FULL_WELL[iso]


def add_poisson_noise(image: torch.Tensor, full_well: float, *, generator: torch.Generator | None = None,
                      seed: int | None = None) -> torch.Tensor:
    """Poisson noise on a linear image ``(B, C, H, W)`` >= 0, with its maximum at ``full_well`` electrons.

    Exactly one of ``generator`` and ``seed`` must be given. Returns the same shape, dtype and device.
    """
    if (generator is None) == (seed is None):
        raise ValueError("give exactly one of generator= or seed= (noise must be reproducible)")
    if not (full_well > 0):
        raise ValueError(f"full_well={full_well!r} is not allowed: must be > 0 electrons")
    if image.ndim != 4:
        raise ValueError(f"image has shape {tuple(image.shape)}: expected (B, C, H, W)")
    if (image < 0).any():
        raise ValueError("image has negative values: Poisson noise needs a linear image >= 0")
    if generator is None:
        generator = torch.Generator(device=image.device).manual_seed(int(seed))
    peak = image.amax()
    if peak <= 0:
        return image.clone()
    scale = full_well / peak
    electrons = torch.poisson((image * scale).to(torch.float64), generator=generator)
    return (electrons / scale).to(image.dtype)
