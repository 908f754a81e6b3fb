"""Issue 45, item 1: the default restoration is never worse than the sensor image, at every edge and corner of a
frame, next to a bright band (the periodic window the Wiener filter's transform assumes; see WIENER_TAPER_PX)."""

import math

import pytest
import torch

from lenssim import LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import NoiseModel, add_poisson_noise
from pipeline.blur import PAPER_SCHEME, blur_windowed
from pipeline.quality import psnr_srgb
from pipeline.restoration import parse_restoration, restore
from pipeline.restoration.wiener import WIENER_TAPER_PX, window_taper

FRAME_PX = 384
"""Side (px) of the synthetic frame: one fitted Wiener window (384 px) spans it, so every window holds the bright band
at one end and the dark region at the other."""

CROP_PX = 128


def band_scene(size=FRAME_PX, bright=0.03, dark=0.004, ramp_px=64, seed=0):
    """Linear mono frame: a bright textured band over the top quarter, a raised-cosine ramp of ``ramp_px`` rows down
    to a dark, nearly flat region (texture +-30 % of its level), like the sky over the pier in issue 45's photo."""
    g = torch.Generator().manual_seed(seed)
    tex = torch.nn.functional.interpolate(torch.rand(1, 1, size // 8, size // 8, generator=g, dtype=torch.float64),
                                          size=(size, size), mode="bicubic", align_corners=False).clamp(0, 1)
    s = ((torch.arange(size, dtype=torch.float64)[:, None] - size // 4) / ramp_px).clamp(0, 1)
    level = bright + (dark - bright) * (0.5 - 0.5 * torch.cos(math.pi * s))
    return level * (0.7 + 0.6 * tex)  # (1, 1, size, size)


def edge_and_corner_boxes(size=FRAME_PX, crop=CROP_PX):
    """The centre, every edge midpoint and every corner: nine ``crop`` px boxes ``(r0, r1, c0, c1)``."""
    at = (0, (size - crop) // 2, size - crop)
    return [(r, r + crop, c, c + crop) for r in at for c in at]


@pytest.fixture(scope="module")
def band_frame():
    """The band scene through the RMS_W design 10 deg off axis at ISO 100 (3200 e-): ideal, noisy, PSF, centre,
    noise."""
    x = band_scene().float()  # float32, as simulate_crops works
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["rms_w_paper"])
    centre = (FRAME_PX / 2 - PAPER_CAMERA.geometry.radius_px(10.0), FRAME_PX / 2)  # the frame 10 deg below the axis
    y = blur_windowed(x, psf, scheme=PAPER_SCHEME, optical_center=centre)
    fwc = 3200.0
    return x, add_poisson_noise(y, fwc, seed=1), psf, centre, NoiseModel(fwc / float(y.amax()))


@pytest.mark.parametrize("method", ["wiener", "tv", "pnp", "tikhonov", "dct_wiener"])
def test_default_restoration_beats_the_sensor_image_beside_a_bright_band_at_every_edge_and_corner(method, band_frame):
    """Each method with its defaults. Before the taper the adaptive Wiener restored every one of these crops 5-10 dB
    below the sensor image (the window's wrap from the bright top to the dark bottom rang into the cores); with it
    each is 0.4-8 dB above. Plug-and-play and TV start from the Wiener. Tikhonov with its former weight (the white
    prior's noise-to-signal ratio) restored the dark bottom-left corner at 41.35 dB against the sensor image's 43.60;
    with SURE's (TIKHONOV_SURE_FACTOR) it is 44.24, its least margin 0.19 dB at the bottom-right corner."""
    x, noisy, psf, centre, noise = band_frame
    restored = restore(parse_restoration(method), noisy, psf, noise=noise, scheme=PAPER_SCHEME, optical_center=centre)
    for box in edge_and_corner_boxes():
        sensor, ours = psnr_srgb(x, noisy, box), psnr_srgb(x, restored, box)
        assert ours >= sensor, f"{method}, crop {box}: restored {ours:.2f} dB, sensor image {sensor:.2f} dB"


def test_window_taper_spares_the_core_and_reaches_zero_at_the_edges():
    core = 64
    for window in (256, 384, 448):
        t = window_taper(window, core, WIENER_TAPER_PX)
        n = min(WIENER_TAPER_PX, window // 4)  # a small window keeps its central half
        lo = window // 2 - core // 2
        assert t.shape == (window, window)
        assert bool((t[n:window - n, n:window - n] == 1).all())  # flat beyond the ramps: the core untouched
        assert bool((t[lo:lo + core, lo:lo + core] == 1).all())
        assert float(t[0].max()) < 1e-3 and float(t[:, -1].max()) < 1e-3  # near 0 on every edge
        ramp = t[window // 2, :n]
        assert bool((ramp.diff() > 0).all())  # rising
        # separable raised cosine, each pixel at its centre: 0.5 - 0.5 cos(pi (i + 1/2) / n)
        ref = 0.5 - 0.5 * torch.cos(math.pi * (torch.arange(n, dtype=torch.float64) + 0.5) / n)
        torch.testing.assert_close(ramp, ref, rtol=0, atol=1e-15)
        torch.testing.assert_close(t[:n, window // 2], ref, rtol=0, atol=1e-15)
        torch.testing.assert_close(t[window - n:, window // 2], ref.flip(0), rtol=0, atol=1e-15)
        torch.testing.assert_close(t, t[window // 2][:, None] * t[:, window // 2][None, :], rtol=0, atol=1e-15)
    assert bool((window_taper(256, 64, 0) == 1).all())
    # the cap: a core almost as wide as the window keeps its ramps outside the core
    t = window_taper(128, 96, 60)  # n = min(60, 32, 16)
    assert bool((t[16:112, 16:112] == 1).all()) and float(t[0, 64]) < 0.01


def test_wiener_taper_option_is_checked_and_zero_is_the_plain_window():
    with pytest.raises(ValueError, match="taper=-1"):
        parse_restoration("wiener:taper=-1")
    with pytest.raises(ValueError, match="taper='0.5'"):
        parse_restoration("wiener:taper=0.5")  # a width in px
    from pipeline.restoration import wiener_windowed
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["rms_w_paper"])
    with pytest.raises(ValueError, match="taper=-3"):
        wiener_windowed(torch.ones(1, 1, 8, 8), psf, noise=NoiseModel(100.0), taper=-3)
    assert parse_restoration("wiener").to_dict()["options"]["taper"] == WIENER_TAPER_PX
