import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lenssim import PAPER_CAMERA, Design, FunctionPSF, LensPSF
from pipeline.blur import (PAPER_SCHEME, WindowScheme, axis_positions, blur_exact, blur_windowed, core_irfft2,
                           tent_weights, window_centres)

E2E = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))


def texture(h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, 3, h, w, generator=g, dtype=torch.float64)
    return torch.nn.functional.avg_pool2d(x, 3, 1, 1)  # some correlation, full of detail


def test_blending_weights_are_a_partition_of_unity():
    t = tent_weights(64)
    acc = torch.zeros(64 * 6)
    for c in range(32, 64 * 6 - 32, 32):
        acc[c - 32:c + 32] += t
    assert torch.allclose(acc[64:-64], torch.ones(64 * 6 - 128, dtype=acc.dtype))
    assert window_centres(100, 32).tolist() == [0, 32, 64, 96, 128][:4] + ([128] if 99 > 96 else [])


def test_delta_psf_leaves_the_image_unchanged():
    img = texture(96, 80)

    def delta(rows, cols, n):
        p = torch.zeros(len(rows), n, n, dtype=torch.float64)
        p[:, n // 2, n // 2] = 1
        return p

    out = blur_windowed(img, FunctionPSF(delta, PAPER_CAMERA.geometry), scheme=WindowScheme(64, 16, 32))
    torch.testing.assert_close(out, img, rtol=0, atol=1e-12)


def test_windowed_blur_matches_exact_per_pixel_processing_above_70_db():
    """The paper: > 70 dB SNR of the windowed scheme (512/32/64) against one PSF per pixel."""
    img = texture(640, 640)
    # the checked pixels sit about 2,520 px (9 degrees) from the optical axis, up and left of it
    r0, c0 = 300, 300
    center = (r0 + 1400, c0 + 2100)
    rows, cols = torch.meshgrid(torch.arange(r0, r0 + 12), torch.arange(c0, c0 + 12), indexing="ij")
    win = blur_windowed(img, E2E, scheme=PAPER_SCHEME, optical_center=center,
                        region=(r0, r0 + 12, c0, c0 + 12))
    ref = blur_exact(img, E2E, rows.flatten(), cols.flatten(), n=512, optical_center=center)
    got = win[:, :, r0:r0 + 12, c0:c0 + 12].flatten(2)
    snr_db = 10 * math.log10(float((ref**2).sum() / ((ref - got) ** 2).sum()))
    print(f"windowed vs exact: {snr_db:.1f} dB")
    assert snr_db > 70
    field = math.degrees(math.atan(math.hypot(r0 - center[0], c0 - center[1]) * 1.5625e-3 / 25))
    assert 8 < field < 10


def test_blur_conserves_flux_and_rejects_bad_input():
    img = torch.ones(1, 1, 96, 96, dtype=torch.float64)
    out = blur_windowed(img, E2E, scheme=WindowScheme(256, 32, 64), optical_center=(48, 48))
    torch.testing.assert_close(out, img, rtol=0, atol=1e-9)  # a flat field stays flat (unit-sum PSFs)
    with pytest.raises(ValueError, match=r"expected a floating tensor of shape \(B, C, H, W\)"):
        blur_windowed(torch.ones(96, 96), E2E)
    with pytest.raises(ValueError, match="larger window"):
        blur_windowed(torch.ones(1, 1, 96, 96), LensPSF(PAPER_CAMERA, Design(s=-2.0, Q_back=-10.0)), scheme=WindowScheme(128, 32, 64),
                      optical_center=(2000, 3000))
    with pytest.raises(ValueError, match="stride=64, core=32"):
        WindowScheme(512, 64, 32)
    with pytest.raises(ValueError, match="window=511"):
        WindowScheme(511, 32, 64)


def test_pruned_inverse_transform_equals_the_full_one():
    g = torch.Generator().manual_seed(1)
    F = torch.fft.rfft2(torch.rand(2, 3, 128, 128, generator=g, dtype=torch.float64))
    full = torch.fft.irfft2(F, s=(128, 128))[..., 64 - 16:64 + 16, 64 - 16:64 + 16]
    torch.testing.assert_close(core_irfft2(F, 128, 32), full, rtol=0, atol=1e-14)


@pytest.mark.parametrize("dtype, tol", [(torch.float32, 2e-6), (torch.float64, 1e-13)])
def test_blur_precision_follows_the_image_dtype(dtype, tol):
    """float32 (the pipeline's working precision) vs the float64 result, relative to the image peak."""
    img = texture(160, 160)
    kw = dict(scheme=WindowScheme(256, 32, 64), optical_center=(80 + 900, 80 + 1200))
    ref = blur_windowed(img, E2E, **kw)
    out = blur_windowed(img.to(dtype), E2E, **kw)
    assert out.dtype == dtype
    assert float((out.double() - ref).abs().max() / ref.max()) < tol


def test_per_channel_psfs_blur_each_channel_with_its_own():
    """A provider may give one PSF per channel: each channel then equals a one-channel blur with that PSF."""
    img = texture(96, 96)

    def shifted(k):
        def fn(x, y, n):
            p = torch.zeros(len(x), n, n, dtype=torch.float64)
            p[:, n // 2 + k, n // 2] = 1
            return p
        return fn

    def three(x, y, n):
        return torch.stack([shifted(k)(x, y, n) for k in (0, 1, 2)], dim=1)

    geom = PAPER_CAMERA.geometry
    out = blur_windowed(img, FunctionPSF(three, geom, channels=3), scheme=WindowScheme(64, 16, 32))
    for k in range(3):
        ref = blur_windowed(img[:, k:k + 1], FunctionPSF(shifted(k), geom), scheme=WindowScheme(64, 16, 32))
        torch.testing.assert_close(out[:, k:k + 1], ref, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="3 channels and the image 2"):
        blur_windowed(img[:, :2], FunctionPSF(three, geom, channels=3), scheme=WindowScheme(64, 16, 32))


@settings(max_examples=200, deadline=None)
@given(length=st.integers(1, 700), stride=st.sampled_from([16, 32]), extra=st.sampled_from([2, 16, 32]),
       center=st.floats(-800, 1500, allow_nan=False))
def test_axis_grid_covers_every_pixel_and_is_symmetric_about_the_axis(length, stride, extra, center):
    core = stride + extra
    y = axis_positions(length, stride, core, center)
    steps = (y - center) / stride
    assert torch.allclose(steps, steps.round(), atol=1e-9)  # axis + k stride: mirror images of each other
    assert torch.allclose(y[1:] - y[:-1], torch.full_like(y[1:], stride), rtol=0, atol=1e-9)
    dist = (torch.arange(length, dtype=torch.float64)[:, None] - y[None, :]).abs().min(dim=1).values
    assert float(dist.max()) < core / 2  # every pixel has a positive tent weight
    assert bool(((y > -core / 2) & (y < length - 1 + core / 2)).all())  # no window without weight inside


@pytest.mark.parametrize("shift", [0.0, 0.5, 0.3])
def test_shifted_tents_are_a_partition_of_unity(shift):
    """Tents centred between pixels, one every 32 px (core 64): the weights of every pixel sum to one."""
    t = tent_weights(64, shift=shift)
    acc = torch.zeros(64 * 6, dtype=torch.float64)
    for anchor in range(32, 64 * 6 - 32, 32):
        acc[anchor - 32:anchor + 32] += t
    torch.testing.assert_close(acc[64:-64], torch.ones(64 * 6 - 128, dtype=acc.dtype), rtol=0, atol=1e-15)


@pytest.mark.parametrize("center", [(149.5, 169.5), (-600.5, -400.5), (150.0, 170.0), (120.0, -700.5)])
def test_mirrored_windows_get_exactly_the_psf_of_their_position(center):
    """One PSF per mirror group (flips and transpose of its spectrum) equals each window's own PSF."""
    geom = E2E.geometry

    def direct(x_mm, y_mm, n):  # the same PSFs, asked for position by position: no symmetry declared
        return E2E.psf_at_pixels(y_mm / geom.pitch_mm, x_mm / geom.pitch_mm, (0.0, 0.0), n, dtype=torch.float64)

    plain = FunctionPSF(direct, geom, extent=150)
    img = texture(300, 340)
    scheme = WindowScheme(256, 32, 64)
    got = blur_windowed(img, E2E, scheme=scheme, optical_center=center)
    ref = blur_windowed(img, plain, scheme=scheme, optical_center=center)
    torch.testing.assert_close(got, ref, rtol=0, atol=1e-13)


@pytest.mark.parametrize("center", [(319.5, 319.5), (319.3, 318.8)])
def test_axis_grid_near_the_axis_is_as_accurate_as_the_origin_grid(center):
    """Within 20 px of the axis, where the PSF changes fastest relative to its size, the paper's scheme is
    68.8 dB against one PSF per pixel (on this texture; 78.9 dB at 9 deg). The axis grid, with a window on the
    axis (between pixels here), matches the origin grid there to 0.1 dB."""
    img = texture(640, 640)
    rows, cols = torch.meshgrid(torch.arange(300, 340), torch.arange(300, 340), indexing="ij")
    ref = blur_exact(img, E2E, rows.flatten(), cols.flatten(), n=512, optical_center=center)
    snr = {}
    for anchor in ("axis", "origin"):
        win = blur_windowed(img, E2E, scheme=WindowScheme(anchor=anchor), optical_center=center,
                            region=(300, 340, 300, 340))
        got = win[:, :, rows.flatten(), cols.flatten()]
        snr[anchor] = 10 * math.log10(float((ref**2).sum() / ((ref - got) ** 2).sum()))
    assert snr["axis"] > snr["origin"] - 0.1 and snr["axis"] > 68


def test_stride_equal_to_core_is_refused():
    """Midway between two centres both tents are zero: such a scheme would divide by zero weight."""
    with pytest.raises(ValueError, match="need stride < core"):
        WindowScheme(64, 32, 32)
    with pytest.raises(ValueError, match="anchor='centre' is not allowed"):
        WindowScheme(anchor="centre")
