import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lenssim import Design, FunctionPSF, LensPSF

from lenssim_studies.paper import PAPER_CAMERA
from pipeline.blur import (WindowScheme, axis_positions, blur_exact, blur_windowed, core_irfft2,
                           FIT_SIZES, fitted_windows, fold_psf, tent_weights, window_centres)

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
    ref = blur_exact(img, E2E, rows.flatten(), cols.flatten(), n=512, optical_center=center)
    for fit in (True, False):  # windows fitted to the PSF (default), and all of 512 px (the paper's)
        win = blur_windowed(img, E2E, scheme=WindowScheme(fit=fit), optical_center=center,
                            region=(r0, r0 + 12, c0, c0 + 12))
        got = win[:, :, r0:r0 + 12, c0:c0 + 12].flatten(2)
        snr_db = 10 * math.log10(float((ref**2).sum() / ((ref - got) ** 2).sum()))
        print(f"windowed (fit={fit}) vs exact: {snr_db:.1f} dB")
        assert snr_db > 70
    field = math.degrees(math.atan(math.hypot(r0 - center[0], c0 - center[1]) * 1.5625e-3 / 25))
    assert 8 < field < 10


def test_blur_conserves_flux_and_rejects_bad_input():
    img = torch.ones(1, 1, 96, 96, dtype=torch.float64)
    out = blur_windowed(img, E2E, scheme=WindowScheme(256, 32, 64), optical_center=(48, 48))
    torch.testing.assert_close(out, img, rtol=0, atol=1e-9)  # a flat field stays flat (unit-sum PSFs)
    with pytest.raises(ValueError, match=r"expected a floating tensor of shape \(B, C, H, W\)"):
        blur_windowed(torch.ones(96, 96), E2E)
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


class _SupportOfE2E(FunctionPSF):
    """A function provider that knows E2E's support position by position (so its windows get the same sizes) and
    its pedestal (so the blur convolves it apart, as it does E2E's)."""

    def extents_px(self, rows, cols, optical_center):
        return E2E.extents_px(rows, cols, optical_center)

    def pedestal_fractions(self, n):
        return E2E.pedestal_fractions(n)


@pytest.mark.parametrize("fit", [False, True])
@pytest.mark.parametrize("center", [(149.5, 169.5), (-600.5, -400.5), (150.0, 170.0), (120.0, -700.5)])
def test_mirrored_windows_get_exactly_the_psf_of_their_position(center, fit):
    """One PSF per mirror group (flips and transpose of its spectrum) equals each window's own PSF, in windows of
    the scheme's size and in windows fitted to the PSF (a mirror group shares one size)."""
    geom = E2E.geometry

    def direct(x_mm, y_mm, n):  # the same PSFs, asked for position by position: no symmetry declared
        return E2E.psf_at_pixels(y_mm / geom.pitch_mm, x_mm / geom.pitch_mm, (0.0, 0.0), n, dtype=torch.float64)

    plain = _SupportOfE2E(direct, geom, extent=150)
    img = texture(300, 340)
    scheme = WindowScheme(256, 32, 64, fit=fit)
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
    with pytest.raises(ValueError, match="fit='no' is not allowed"):
        WindowScheme(fit="no")


def _dft_flip(p):
    """The PSF mirrored about its centre at [0, 0] (DFT order): index i -> -i mod n, along the rows."""
    return p[..., (-torch.arange(p.shape[-2])) % p.shape[-2], :]


@pytest.mark.parametrize("w", [96, 100, 128, 250, 256])
def test_folding_keeps_the_sum_and_commutes_with_the_mirror_flips_and_transpose(w):
    g = torch.Generator().manual_seed(3)
    p = torch.rand(2, 256, 256, generator=g, dtype=torch.float64)
    p = p / p.sum(dim=(-2, -1), keepdim=True)
    f = fold_psf(p, w)
    assert f.shape == (2, w, w)
    torch.testing.assert_close(f.sum(dim=(-2, -1)), torch.ones(2, dtype=torch.float64), rtol=0, atol=1e-14)
    torch.testing.assert_close(fold_psf(_dft_flip(p), w), _dft_flip(f), rtol=0, atol=1e-15)
    torch.testing.assert_close(fold_psf(p.transpose(-2, -1), w), f.transpose(-2, -1), rtol=0, atol=1e-15)
    # a brute-force fold: every offset d in (-n/2, n/2) to d mod w, the row and column at n/2 half to each side
    n = 256
    ref = torch.zeros(2, w, w, dtype=torch.float64)
    for i in range(n):
        for di, wi in (((i + n // 2) % n - n // 2, 1.0),) if i != n // 2 else ((n // 2, 0.5), (-n // 2, 0.5)):
            for j in range(0, n, 37):  # every 37th column is enough to catch a misplaced row
                for dj, wj in (((j + n // 2) % n - n // 2, 1.0),) if j != n // 2 else ((n // 2, 0.5), (-n // 2, 0.5)):
                    ref[:, di % w, dj % w] += wi * wj * p[:, i, j]
    cols = sorted({((j + n // 2) % n - n // 2) % w for j in range(0, n, 37)})
    sub = torch.zeros_like(p)
    sub[:, :, ::37] = p[:, :, ::37]
    torch.testing.assert_close(fold_psf(sub, w)[:, :, cols], ref[:, :, cols], rtol=0, atol=1e-15)


def test_fitted_sizes_hold_the_need_and_its_margin():
    need = torch.tensor([0, 65, 192, 193, 300, 385, 449, 512])
    got = fitted_windows(need, 512).tolist()
    assert got == [512, 256, 256, 288, 384, 512, 512, 512]
    assert fitted_windows(torch.tensor([100, 300]), 320).tolist() == [256, 320]  # never above the scheme's window
    assert all(w % 2 == 0 for w in FIT_SIZES) and list(FIT_SIZES) == sorted(FIT_SIZES)


@pytest.mark.parametrize("center", [(511.5, 511.5), (511.5 - 1800, 511.5 - 2500)])
def test_fitted_windows_are_as_accurate_as_the_paper_windows_on_a_structured_scene(center, monkeypatch):
    """Against one PSF per pixel, on the default scene's sharp targets (32 pixels; on the axis, where the PSF is
    small and changes fastest, and ~10 deg off it), windows fitted to the PSF lose at most 0.5 dB to the
    512 px windows. Windows of 96-224 px without the margin lose 2.3 dB on the axis (checked below)."""
    import pipeline.blur as blur_module
    from pipeline import resolution_scene

    scene = resolution_scene(1024, 1024, seed=1, tile=128, spacing=256, geometry=PAPER_CAMERA.geometry).double()
    g = torch.Generator().manual_seed(0)
    rows, cols = torch.randint(300, 724, (32,), generator=g), torch.randint(300, 724, (32,), generator=g)
    ref = blur_exact(scene, E2E, rows, cols, n=512, optical_center=center)

    def snr(fit):
        out = blur_windowed(scene, E2E, optical_center=center, scheme=WindowScheme(fit=fit), region=(300, 724, 300, 724))
        return 10 * math.log10(float((ref**2).sum() / ((ref - out[:, :, rows, cols]) ** 2).sum()))

    paper, fitted = snr(False), snr(True)
    assert fitted > paper - 0.5 and paper > 64
    if center[0] > 0:  # the margin and the least size are what keep it so
        monkeypatch.setattr(blur_module, "FIT_MARGIN_PX", 0)
        monkeypatch.setattr(blur_module, "FIT_SIZES", (96, 128, 160, 192, 224) + FIT_SIZES)
        assert snr(True) < paper - 1.5


def test_fitted_windows_give_the_paper_windows_result_where_the_psf_has_compact_support():
    """A PSF that is zero beyond its support: the core of a window fitted to it sees the same linear convolution
    as the 512 px window, to rounding (the fit changes nothing but the cost)."""
    geom = E2E.geometry

    def compact(x_mm, y_mm, n):  # E2E's PSFs cut to a disc of 40 px radius (support 80 px + a margin)
        p = E2E.psf_at_pixels(y_mm / geom.pitch_mm, x_mm / geom.pitch_mm, (0.0, 0.0), n, dtype=torch.float64)
        d = torch.arange(n, dtype=torch.float64) - n // 2
        r = torch.hypot(d[:, None], d[None, :])
        p = p * (r <= 40)
        return p / p.sum(dim=(-2, -1), keepdim=True)

    psf = FunctionPSF(compact, geom, extent=84)
    img = texture(200, 230)
    center = (100 + 600, 115 + 900)
    fitted = blur_windowed(img, psf, optical_center=center)
    paper = blur_windowed(img, psf, optical_center=center, scheme=WindowScheme(fit=False))
    assert int(fitted_windows(torch.tensor([84 + 64]), 512)) == 256
    torch.testing.assert_close(fitted, paper, rtol=0, atol=1e-13)
    # the lens's own PSFs have a diffraction tail beyond any support: the fitted windows (which really are smaller)
    # wrap its far part elsewhere, so the two differ, but by less than 1e-4 of the signal (away from the frame's
    # edges, whose reflected padding the two sample at different places)
    img, center = texture(640, 640), (320 + 600, 320 + 900)
    fitted = blur_windowed(img, E2E, optical_center=center, region=(300, 340, 300, 340))
    paper = blur_windowed(img, E2E, optical_center=center, scheme=WindowScheme(fit=False), region=(300, 340, 300, 340))
    snr_db = 10 * math.log10(float((paper**2).sum() / ((paper - fitted) ** 2).sum()))
    assert 80 < snr_db < 200, snr_db


def test_lens_psf_support_grows_with_the_field_and_bounds_the_largest():
    rows = torch.tensor([2000.0, 2000.0, 2000.0, 200.0])
    cols = torch.tensor([3000.0, 3600.0, 5000.0, 200.0])
    ext = E2E.extents_px(rows, cols, (2000.0, 3000.0))
    assert ext.dtype == torch.int64 and ext.shape == (4,)
    assert ext[0] < ext[1] < ext[2] < ext[3]
    assert int(ext.max()) == E2E.extent_px(rows, cols, (2000.0, 3000.0))
    assert [E2E.extent_px(rows[i:i + 1], cols[i:i + 1], (2000.0, 3000.0)) for i in range(4)] == ext.tolist()
    assert E2E.extent_px(torch.zeros(0), torch.zeros(0), (0.0, 0.0)) == E2E.numerics.margin_px  # no position


def test_psf_batches_are_bounded_in_bytes_and_do_not_change_the_blur(monkeypatch):
    """Windows whose PSFs are computed together: PSF_BATCH (mirror groups) or PSF_BATCH_OWN (a PSF per window) where
    PSF_BATCH_BYTES allows, fewer for colour PSFs and grown windows, never fewer than the transforms' batch; the batch
    size does not change a single bit of the blur."""
    import pipeline.blur as blur

    img = torch.zeros(1, 3, 8, 8, dtype=torch.float32)
    assert blur.psf_batch(img, 512, 1, 3) == blur.PSF_BATCH == 64  # 64 x 512 x 257 x 8 B = 67 MB
    colour = blur.psf_batch(img, 512, 3, 3)
    assert colour == blur.PSF_BATCH_BYTES // (3 * 512 * 257 * 8) < blur.PSF_BATCH
    assert blur.psf_batch(img, 4096, 1, 1) == blur.PSF_BATCH_BYTES // (4096 * 2049 * 8) == 1  # 67 MB a window
    assert blur.psf_batch(img, 4096, 3, 1) == 1 and blur.psf_batch(img, 512, 3, 50) == 50
    assert blur.psf_batch(img, 512, 1, 3, symmetric=False) == blur.PSF_BATCH_OWN == 16  # a PSF per window
    x = texture(300, 340).float()
    scheme = WindowScheme(256, 32, 64)
    center = (149.5, 169.5)
    big = blur_windowed(x, E2E, scheme=scheme, optical_center=center)
    monkeypatch.setattr(blur, "PSF_BATCH", 1)  # one mirror group at a time
    assert torch.equal(blur_windowed(x, E2E, scheme=scheme, optical_center=center), big)
