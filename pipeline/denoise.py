"""Optional gentle denoising of the input photo before simulation (paper Section 3.3, off by default).

The paper makes its photos "closer to ideal" with a gentle denoiser that keeps the high spatial
frequencies. We use scikit-image's wavelet denoiser (BayesShrink, soft thresholding, noise level
estimated per channel), applied to the gamma-encoded image, with ``strength`` scaling the
estimated noise sigma (1 = the estimate; smaller is gentler).
"""

from __future__ import annotations

import numpy as np
import torch

from lenssim.validate import check_real

from .checks import check_scene
from .colour_space import linear_to_srgb, srgb_to_linear

__all__ = ["gentle_denoise", "DENOISE_WORKING_COPIES", "DENOISE_STRENGTH_RANGE"]

DENOISE_STRENGTH_RANGE = (1e-3, 2.0)
"""Strengths (multiples of the estimated noise sigma) the denoiser takes: below 1e-3 it removes nothing visible, and
below about 1e-160 its thresholds underflow to NaN."""

DENOISE_WORKING_COPIES = 12
"""Frame-sized float32 buffers :func:`gentle_denoise` holds at its peak (the image, its sRGB copy in float64, the
denoised float64 planes and scikit-image's wavelet temporaries), for the memory check before a run."""


def gentle_denoise(linear: torch.Tensor, strength: float = 0.5) -> torch.Tensor:
    """Denoise a linear ``(1, C, H, W)`` image in the sRGB domain; returns linear, same shape and dtype."""
    from skimage.restoration import denoise_wavelet, estimate_sigma

    check_real("strength", strength, *DENOISE_STRENGTH_RANGE)
    check_scene(linear, "image")
    enc = linear_to_srgb(linear.clamp(0, 1))[0].permute(1, 2, 0).double().cpu().numpy()
    multichannel = enc.shape[-1] > 1
    sig = np.atleast_1d(estimate_sigma(enc, channel_axis=-1) if multichannel else estimate_sigma(enc[..., 0]))
    out = np.empty_like(enc)
    for c in range(enc.shape[-1]):
        out[..., c] = denoise_wavelet(enc[..., c], sigma=float(sig[min(c, len(sig) - 1)]) * strength,
                                      mode="soft", method="BayesShrink", rescale_sigma=True)
    t = torch.from_numpy(np.clip(out, 0, 1)).permute(2, 0, 1)[None].to(linear.dtype)
    return srgb_to_linear(t).to(linear.device)
