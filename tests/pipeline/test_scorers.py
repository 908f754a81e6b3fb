"""The two scorers (issue 20): kornia on the images' device against scikit-image + colour-science on the host.

scikit-image's definitions are the reference (PSNR with data range 1; SSIM over 7 x 7 uniform windows with the
sample covariance, the 3 px border left out, the mean over channels). kornia must give them to float32 rounding,
in one channel and three, on every device and dtype, in bands (the band size forced small here) and for identical
images; a Gaussian-window SSIM (kornia's own ``kornia.metrics.ssim``) would not, which the last test shows.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import pipeline.quality as Q
from pipeline.quality import (SCORERS, encode_srgb, psnr_map_srgb, psnr_srgb, scores_encoded, ssim_srgb,
                              validate_scorer)


def _pair(C, H=150, W=190, seed=0, dtype=torch.float32, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, C, H, W, generator=g, dtype=torch.float64)
    x = torch.nn.functional.avg_pool2d(x, 5, stride=1, padding=2)  # some structure
    y = (x + 0.03 * torch.randn(x.shape, generator=g, dtype=torch.float64)).clamp(-0.1, 1.1)  # outside [0, 1] too
    return x.to(device=device, dtype=dtype), y.to(device=device, dtype=dtype)


@pytest.mark.parametrize("frame_path", [False, True], ids=["crop", "frame"])
@pytest.mark.parametrize("C", [1, 3])
def test_kornia_scores_are_scikit_image_s(C, frame_path, device_dtype, monkeypatch):
    """Crops get SSIM's moments in float64; frames (forced here) in float32 bands about each band's mean."""
    dev, dt = device_dtype
    x, y = _pair(C, dtype=dt, device=dev)
    monkeypatch.setattr(Q, "SSIM_BAND_ROWS", 40)  # several bands, the last one short
    if frame_path:
        monkeypatch.setattr(Q, "SSIM_FLOAT64_MAX_VALUES", 0)
    crop = (10, 140, 7, 180)
    assert psnr_srgb(x, y, crop, scorer="kornia") == pytest.approx(psnr_srgb(x, y, crop, scorer="skimage"), rel=1e-6)
    assert ssim_srgb(x, y, scorer="kornia") == pytest.approx(ssim_srgb(x, y, scorer="skimage"), abs=2e-6)
    torch.testing.assert_close(psnr_map_srgb(x, y, 64, scorer="kornia"), psnr_map_srgb(x, y, 64, scorer="skimage"),
                               rtol=1e-6, atol=0)
    enc = encode_srgb(x, scorer="kornia")
    assert enc.device.type == dev.type and enc.dtype == torch.float32 and enc.shape == x.shape
    torch.testing.assert_close(enc.cpu(), encode_srgb(x, scorer="skimage").cpu(), rtol=0, atol=2e-6)


def test_identical_images_score_infinity_and_one():
    x, _ = _pair(3)
    for name in SCORERS:
        assert psnr_srgb(x, x, scorer=name) == math.inf
        assert ssim_srgb(x, x, scorer=name) == pytest.approx(1.0, abs=1e-6)
        assert torch.isinf(psnr_map_srgb(x, x, 64, scorer=name)).all()


def test_psnr_is_its_closed_form():
    """An sRGB-encoded error of exactly 0.01 everywhere: PSNR = 40 dB by definition, for either scorer."""
    x = torch.full((1, 3, 32, 40), 0.5)
    ex = encode_srgb(x)
    from pipeline.colour_space import srgb_to_linear

    y = srgb_to_linear(ex + 0.01)  # its encoding is ex + 0.01
    for name in SCORERS:
        assert psnr_srgb(x, y, scorer=name) == pytest.approx(40.0, abs=1e-3)


def test_unknown_scorer_lists_the_valid_ones():
    with pytest.raises(ValueError, match="scorer 'matlab' is not known; valid: kornia, skimage"):
        validate_scorer("matlab")
    assert validate_scorer(None).name == Q.DEFAULT_SCORER == "kornia"


def test_frames_smaller_than_the_ssim_window_or_a_tile_are_refused():
    x, y = _pair(3, H=6, W=40)
    with pytest.raises(ValueError, match="smaller than SSIM's 7 x 7"):
        ssim_srgb(x, y, scorer="kornia")
    with pytest.raises(ValueError, match="smaller than one 64-px tile"):
        scores_encoded(encode_srgb(x), encode_srgb(y), tile=64, ssim=False)


def test_a_gaussian_window_ssim_is_another_number():
    """Why the kornia scorer builds scikit-image's SSIM from kornia's box filter instead of calling
    ``kornia.metrics.ssim`` (Gaussian window, sigma 1.5): on the same images that one differs at the 1e-2 level."""
    from kornia.metrics import ssim

    x, y = _pair(3)
    a, b = encode_srgb(x), encode_srgb(y)
    gauss = float(ssim(a, b, 7, max_val=1.0, padding="valid").mean())
    assert abs(gauss - ssim_srgb(x, y)) > 5e-3
    assert np.isfinite(gauss)
