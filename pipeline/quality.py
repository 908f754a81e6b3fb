"""Image quality against the ideal image, in the gamma-encoded (sRGB) space as the paper reports.

PSNR and SSIM from scikit-image (``data_range = 1``), over the whole frame or a crop
``(r0, r1, c0, c1)``. Inputs are linear ``(1, C, H, W)`` tensors in [0, 1]; they are encoded with
:func:`pipeline.colour_space.linear_to_srgb` and clipped to [0, 1] first.
"""

from __future__ import annotations

import torch

from .colour_space import linear_to_srgb

__all__ = ["psnr_srgb", "ssim_srgb"]


def _prep(ref: torch.Tensor, test: torch.Tensor, crop):
    if ref.shape != test.shape or ref.ndim != 4 or ref.shape[0] != 1:
        raise ValueError(f"shapes {tuple(ref.shape)} and {tuple(test.shape)}: expected two equal (1, C, H, W) tensors")
    if crop is not None:
        r0, r1, c0, c1 = crop
        ref, test = ref[..., r0:r1, c0:c1], test[..., r0:r1, c0:c1]
    # float32 (the precision of the encoded values): scikit-image then works in float32; a 24 MP
    # SSIM + PSNR peaks at 3.0 GB instead of 4.7 GB (and takes 25 s instead of 34 s) here
    enc = lambda t: linear_to_srgb(t.clamp(0, 1))[0].permute(1, 2, 0).float().cpu().numpy()  # noqa: E731
    return enc(ref), enc(test)


def psnr_srgb(ref: torch.Tensor, test: torch.Tensor, crop=None) -> float:
    """PSNR (dB) of ``test`` against ``ref`` in sRGB, data range 1."""
    from skimage.metrics import peak_signal_noise_ratio

    a, b = _prep(ref, test, crop)
    if (a == b).all():
        return float("inf")
    return float(peak_signal_noise_ratio(a, b, data_range=1.0))


def ssim_srgb(ref: torch.Tensor, test: torch.Tensor, crop=None) -> float:
    """SSIM of ``test`` against ``ref`` in sRGB (scikit-image defaults, 7 x 7 windows)."""
    from skimage.metrics import structural_similarity

    a, b = _prep(ref, test, crop)
    return float(structural_similarity(a, b, data_range=1.0, channel_axis=-1)) if a.shape[-1] > 1 else \
        float(structural_similarity(a[..., 0], b[..., 0], data_range=1.0))


