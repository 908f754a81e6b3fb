"""Windows that grow where a PSF outgrows the scheme's window (the corners of a white-light design, issue 21)."""

import math

import pytest
import torch

from lenssim import Design, FunctionPSF, LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_SENSOR
from pipeline.blur import (FIT_MARGIN_PX, MAX_WINDOW_PX, WindowScheme, _extents, blur_exact, blur_windowed,
                           grown_window, largest_window, scheme_positions, window_sizes)
from pipeline.noise import NoiseModel
from pipeline.restoration import richardson_lucy_windowed, wiener_windowed
from pipeline.restoration.tikhonov import tikhonov_windowed
from pipeline.simulate import simulate_crops

E2E = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))


def texture(h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, 3, h, w, generator=g, dtype=torch.float64)
    return torch.nn.functional.avg_pool2d(x, 3, 1, 1)


def disc_psf(radius_px: float, extent: int) -> FunctionPSF:
    """The same uniform disc (unit sum) everywhere, ``extent`` px declared."""
    def fn(x, y, n):
        d = torch.arange(n, dtype=torch.float64) - n // 2
        p = ((d[:, None] ** 2 + d[None, :] ** 2) <= radius_px**2).to(torch.float64)
        return (p / p.sum()).expand(len(x), n, n).clone()
    return FunctionPSF(fn, PAPER_CAMERA.geometry, extent=extent)


DISC = disc_psf(50, 101)  # 101 px + a 32 px core: over a 128 px window, which grows to 240 px
SMALL = WindowScheme(128, 16, 32)


def test_a_window_grows_only_where_its_psf_and_core_do_not_fit():
    ext = torch.tensor([0, 50, 96, 97, 101, 300])
    for fit in (False, True):
        sizes = window_sizes(ext, SMALL, fit).tolist()
        assert sizes[3:] == [grown_window(97 + 32), grown_window(133), grown_window(332)]
        assert sizes[:3] == [128, 128, 128]  # no fitted size below 128 px; 96 + 32 fits exactly
    assert grown_window(133) == 240  # 133 + the 64 px margin, rounded up to a size of 2, 3 and 5
    assert grown_window(332) == 400
    for need in range(100, 2000, 37):  # holds the need and its margin; a multiple of 16 with no prime above 5
        w = grown_window(need)
        assert need + FIT_MARGIN_PX <= w < need + FIT_MARGIN_PX + 0.25 * (need + FIT_MARGIN_PX) + 16 and w % 16 == 0
        k = w
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        assert k == 1
    assert largest_window(DISC, (1, 3, 200, 200), SMALL) == 240
    assert largest_window(disc_psf(20, 41), (1, 3, 200, 200), SMALL) == 128
    assert largest_window(DISC, (1, 3, 200, 200), WindowScheme(512, 32, 64)) == 512
    # a lens PSF grows with the field: a region about the axis keeps the scheme's window, the whole frame does not
    mid = WindowScheme(256, 32, 64)
    assert largest_window(E2E, (1, 3, 4000, 6000), mid, region=(1900, 2100, 2900, 3100)) == 256
    assert largest_window(E2E, (1, 3, 4000, 6000), mid) > 256
    with pytest.raises(ValueError, match=f"over the {MAX_WINDOW_PX} px allowed"):
        blur_windowed(texture(64, 64), disc_psf(20, 5000), scheme=SMALL)


@pytest.mark.parametrize("name", ["blur", "blur_fit", "wiener", "tikhonov", "richardson_lucy"])
def test_grown_windows_equal_a_scheme_of_that_window(name):
    """Where every window grows, each pass equals the same pass with the grown size as the scheme's window."""
    img = texture(96, 80)
    big = WindowScheme(240, 16, 32)
    run = {
        "blur": lambda s: blur_windowed(img, DISC, scheme=WindowScheme(s.window, 16, 32, fit=False)),
        "blur_fit": lambda s: blur_windowed(img, DISC, scheme=s),
        "wiener": lambda s: wiener_windowed(img, DISC, noise=NoiseModel(1e4), scheme=s),
        "tikhonov": lambda s: tikhonov_windowed(img, DISC, weight=1e-3, scheme=s),
        "richardson_lucy": lambda s: richardson_lucy_windowed(img, DISC, iterations=3, scheme=s),
    }[name]
    grown, ref = run(SMALL), run(big)
    torch.testing.assert_close(grown, ref, rtol=0, atol=1e-12)
    assert float((grown - img).abs().max()) > 1e-3  # the PSF did act


def test_grown_windows_keep_a_flat_field_flat():
    """A lens PSF on a grown grid: its pedestal is the scheme grid's, taken out uniformly over the larger grid, so the
    blur keeps unit gain (a pedestal taken out on the larger grid's own terms would leave its difference in)."""
    img = torch.ones(1, 1, 96, 96, dtype=torch.float64)
    center = (48 + 1400, 48 + 2100)  # 2,524 px (9 degrees) from the axis: a 262 px support
    out = blur_windowed(img, E2E, scheme=SMALL, optical_center=center)
    assert E2E.pedestal_fractions(128)[0] > E2E.pedestal_fractions(512)[0] + 1e-4  # the two grids' pedestals differ
    torch.testing.assert_close(out, img, rtol=0, atol=1e-9)


def test_blur_across_grown_and_scheme_windows_matches_one_psf_per_pixel_above_70_db():
    """The region sits where the lens PSF's support plus the core crosses the 256 px window: windows of 256 px and
    grown ones blend there; the result against one PSF per pixel (the paper's > 70 dB standard)."""
    img = texture(640, 640)
    r0, c0 = 300, 300
    center = (r0 + 1243, c0 + 1864)  # 2,240 px from the axis
    scheme = WindowScheme(256, 16, 32)
    py = scheme_positions(640, scheme, center[0])
    px = scheme_positions(640, scheme, center[1])
    Y, X = torch.meshgrid(py[(py > r0 - 16) & (py < r0 + 28)], px[(px > c0 - 16) & (px < c0 + 28)], indexing="ij")
    sizes = window_sizes(_extents(E2E, Y.flatten(), X.flatten(), center, True), scheme, True)
    assert 256 in sizes.tolist() and int(sizes.max()) > 256  # both kinds blend over the region
    rows, cols = torch.meshgrid(torch.arange(r0, r0 + 12), torch.arange(c0, c0 + 12), indexing="ij")
    ref = blur_exact(img, E2E, rows.flatten(), cols.flatten(), n=512, optical_center=center)
    win = blur_windowed(img, E2E, scheme=scheme, optical_center=center, region=(r0, r0 + 12, c0, c0 + 12))
    got = win[:, :, r0:r0 + 12, c0:c0 + 12].flatten(2)
    snr_db = 10 * math.log10(float((ref**2).sum() / ((ref - got) ** 2).sum()))
    print(f"grown and scheme windows vs one PSF per pixel: {snr_db:.1f} dB")
    assert snr_db > 70


def test_a_crop_reads_as_far_as_its_grown_windows(monkeypatch):
    """A crop's restoration reads the blurred image half a grown window beyond the crop: the crop equals the whole
    image's result up to its noise (1e9 electrons), which it would not with margins of the scheme's window."""
    import pipeline.simulate as sim

    img = texture(720, 720)
    box = (330, 390, 330, 390)
    blurred = blur_windowed(img, DISC, scheme=SMALL)
    whole = wiener_windowed(blurred, DISC, noise=NoiseModel(1e9 / float(img.amax())), scheme=SMALL)[..., 330:390, 330:390]

    def crop_error():
        res = simulate_crops(img, DISC, 1e9, [box], scheme=SMALL, methods=("wiener",), sensor=PAPER_SENSOR,
                             dtype=torch.float64)[0]
        torch.testing.assert_close(res.images["blurred"], blurred[..., 330:390, 330:390], rtol=0, atol=1e-12)
        return float((res.images["wiener"] - whole).abs().mean())

    err = crop_error()
    monkeypatch.setattr(sim, "largest_window", lambda psf, shape, scheme, **kw: scheme.window)  # the scheme's margins
    err_scheme = crop_error()
    print(f"crop vs whole image: {err:.2e} (margins of the scheme's window: {err_scheme:.2e})")
    assert err < 2e-3 and err_scheme > 0.1
