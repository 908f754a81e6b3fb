"""Blur windows of a coarser stride where the PSF varies slowly (issue 33): the interpolation-error estimate against
closed forms, the zoned blur against one PSF per pixel and against the paper's stride, and the crops' scores."""

import math

import pytest
import torch

from lenssim import FunctionPSF, LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_SENSOR
from pipeline.blur import (StrideZones, WindowScheme, blur_exact, blur_windowed,
                           choose_stride_zones, interpolation_error_db, window_count)

GEOM = PAPER_CAMERA.geometry
SMALL = WindowScheme(128, 16, 32)


def _gauss(n, sx, sy):
    """Gaussians ``(P, n, n)`` of per-PSF widths ``sx``, ``sy`` (px), centred at ``[n//2, n//2]``, unit sum."""
    r = torch.arange(n, dtype=torch.float64) - n // 2
    g = torch.exp(-0.5 * ((r[None, None, :] / sx[:, None, None]) ** 2 + (r[None, :, None] / sy[:, None, None]) ** 2))
    return g / g.sum(dim=(-2, -1), keepdim=True)


def _mix(weight):
    """A PSF field ``(1 - t) A + t B`` of two fixed Gaussians, ``t = weight(x_mm, y_mm)``."""
    def fn(x, y, n):
        t = weight(torch.as_tensor(x, dtype=torch.float64), torch.as_tensor(y, dtype=torch.float64))
        a = _gauss(n, torch.full_like(t, 1.5), torch.full_like(t, 1.5))
        b = _gauss(n, torch.full_like(t, 4.0), torch.full_like(t, 2.0))
        return (1 - t)[:, None, None] * a + t[:, None, None] * b
    return fn


def test_the_error_estimate_against_closed_forms():
    """A PSF field linear in position is interpolated exactly by the tents (no error); a quadratic one with an error
    growing as the stride squared: 12.04 dB (a factor 4 in amplitude) per doubling of the stride."""
    pitch = GEOM.pitch_mm
    linear = FunctionPSF(_mix(lambda x, y: 0.5 + 1e-3 * (x + y) / pitch), GEOM)
    radii = torch.tensor([0.0, 200.0])
    assert (interpolation_error_db(linear, SMALL, 1, radii, (0.0, 0.0)) > 250).all()
    quad = FunctionPSF(_mix(lambda x, y: 1e-6 * ((x / pitch) ** 2 + (y / pitch) ** 2)), GEOM)
    e1, e2 = (interpolation_error_db(quad, SMALL, m, radii, (0.0, 0.0)) for m in (1, 2))
    assert (e1 - e2).tolist() == pytest.approx([20 * math.log10(4)] * 2, abs=1e-6)
    # a shift-invariant PSF: every stride is exact, so the whole frame takes the coarsest
    flat = FunctionPSF(_mix(lambda x, y: torch.zeros_like(x)), GEOM)
    assert choose_stride_zones(flat, (1, 1, 400, 600), SMALL) == StrideZones((), (2,))


def test_zones_are_checked():
    with pytest.raises(ValueError, match="one multiple"):
        StrideZones((100.0,), (1,))
    with pytest.raises(ValueError, match="not increasing"):
        StrideZones((200.0, 100.0), (1, 2, 1))


@pytest.fixture(scope="module")
def e2e():
    return LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])


def test_the_paper_lens_zones_and_the_zoned_blur_against_one_psf_per_pixel(e2e):
    """The E2E design on the paper's full sensor: the paper's stride near the axis (where the PSF turns fastest with
    the azimuth), twice it beyond (3.4x fewer windows). Inside the first ring the zoned blur is the paper's, bit for
    bit; beyond it, on a textured scene (smoothed noise, harsher than a photo), > 70 dB from one PSF per pixel and from
    the paper's stride (measured 72-83 dB and 75-86 dB)."""
    shape = (1, 1, PAPER_SENSOR.height_px, PAPER_SENSOR.width_px)
    zones = choose_stride_zones(e2e, shape)
    assert zones.multiples == (1, 2) and 300 < zones.edges_px[0] < 900
    assert window_count(shape, zones=zones) < 0.35 * window_count(shape)
    g = torch.Generator().manual_seed(3)
    H, W = shape[-2:]
    size = 640
    inner = (..., slice(288, -288), slice(288, -288))
    for r in (0.5 * zones.edges_px[0], zones.edges_px[0] + 200, 3000.0):
        r0 = int(H / 2 - 0.5 + r / math.sqrt(2)) - size // 2
        c0 = int(W / 2 - 0.5 + r / math.sqrt(2)) - size // 2
        img = torch.rand(1, 1, size + 2, size + 2, generator=g, dtype=torch.float64) ** 2
        img = torch.nn.functional.avg_pool2d(img, 3, stride=1)
        oc = ((H - 1) / 2 - r0, (W - 1) / 2 - c0)
        zoned = blur_windowed(img, e2e, optical_center=oc, zones=zones)
        paper = blur_windowed(img, e2e, optical_center=oc)
        if r < zones.edges_px[0]:
            assert torch.equal(zoned[inner], paper[inner])
            continue
        rows = torch.randint(288, size - 288, (12,), generator=g)
        cols = torch.randint(288, size - 288, (12,), generator=g)
        exact = blur_exact(img, e2e, rows, cols, n=512, optical_center=oc)
        db = lambda a, b: -10 * math.log10(float((a - b).square().mean()))  # noqa: E731
        assert db(zoned[..., rows, cols], exact) > 70
        assert db(zoned[inner], paper[inner]) > 70


def test_zones_chosen_over_a_region_blur_it_as_the_frame_s_do(e2e):
    """A crop's zones (estimated only where its windows reach) blur its region exactly as the whole frame's zones."""
    shape = (1, 1, PAPER_SENSOR.height_px, PAPER_SENSOR.width_px)
    frame = choose_stride_zones(e2e, shape)
    H, W = shape[-2:]
    r0, c0 = H // 2 - 300, W // 2 + 200  # a 400 px region across the first ring's edge
    region = (r0, r0 + 400, c0, c0 + 400)
    local = choose_stride_zones(e2e, shape, region=region)
    assert local.multiples == (1, 2)  # the region crosses the first ring's edge
    R0, C0 = r0 - 400, c0 - 400
    img = torch.rand(1, 1, 1200, 1200, generator=torch.Generator().manual_seed(4))
    oc = ((H - 1) / 2 - R0, (W - 1) / 2 - C0)
    br = (400, 800, 400, 800)
    a = blur_windowed(img, e2e, optical_center=oc, region=br, zones=frame)
    b = blur_windowed(img, e2e, optical_center=oc, region=br, zones=local)
    assert torch.equal(a, b)


def test_a_zoned_blur_is_a_blend_of_local_convolutions():
    """With a delta PSF the zoned blur is the identity; with one Gaussian everywhere it equals the unzoned blur."""
    delta = FunctionPSF(lambda x, y, n: torch.zeros(len(x), n, n).index_put_(
        (torch.arange(len(x)), torch.full((len(x),), n // 2), torch.full((len(x),), n // 2)), torch.tensor(1.0)), GEOM)
    img = torch.rand(1, 2, 150, 170, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    zones = StrideZones((40.0, 90.0), (1, 2, 1))
    assert torch.allclose(blur_windowed(img, delta, scheme=SMALL, zones=zones), img, atol=1e-12)
    same = FunctionPSF(_mix(lambda x, y: torch.zeros_like(x)), GEOM)
    a = blur_windowed(img, same, scheme=SMALL, zones=zones)
    b = blur_windowed(img, same, scheme=SMALL)
    assert torch.allclose(a, b, atol=1e-12)


def test_crops_with_auto_zones(e2e):
    """simulate_crops with ``blur_zones="auto"``: each crop's blurred image > 70 dB from the paper's stride. (Its
    noise is another draw: a count that flips shifts every later Poisson draw, so the scores agree only to the noise's
    own spread, ~0.03 dB on a 256 px crop; the whole 24 MP frame's are within 0.01 dB, docs/performance.md.)"""
    from pipeline.scene import resolution_scene
    from pipeline.simulate import simulate_crops

    scene = resolution_scene(1100, 1600, seed=2, geometry=PAPER_CAMERA.geometry)
    boxes = [(422, 678, 672, 928), (0, 256, 0, 256)]
    kw = dict(seed=1, sensor=PAPER_SENSOR, dtype=torch.float64)
    ref = simulate_crops(scene, e2e, 3200.0, boxes, **kw)
    zoned = simulate_crops(scene, e2e, 3200.0, boxes, blur_zones="auto", **kw)
    for a, b in zip(ref, zoned):
        d = (a.images["blurred"] - b.images["blurred"]).square().mean()
        assert -10 * math.log10(max(float(d), 1e-30)) > 70
        for k in ("sensor", "wiener"):
            assert a.scores[k]["psnr_db"] == pytest.approx(b.scores[k]["psnr_db"], abs=0.1)


def test_the_estimates_are_kept_per_provider(e2e, monkeypatch):
    """A second choice over the same frame (another crop, command or design view) estimates nothing again and gives
    the same zones."""
    import pipeline.blur as blur

    shape = (1, 1, 900, 1300)
    first = choose_stride_zones(e2e, shape)
    calls = []
    real = blur.interpolation_error_db
    monkeypatch.setattr(blur, "interpolation_error_db", lambda *a, **k: calls.append(1) or real(*a, **k))
    assert choose_stride_zones(e2e, shape) == first and not calls
    choose_stride_zones(e2e, (1, 1, 901, 1300))  # other radii: estimated
    assert calls


def test_a_zoned_wiener_restoration():
    """The Wiener restoration in stride rings (issue 46's lever): with a delta PSF and no noise it is the identity;
    inside the inner ring, beyond the reach of the outer ring's windows, it is the unzoned restoration bit for bit;
    the per-pixel filter refuses zones."""
    from pipeline import NoiseModel
    from pipeline.restoration.wiener import wiener_windowed

    delta = FunctionPSF(lambda x, y, n: torch.zeros(len(x), n, n, dtype=torch.float64).index_put_(
        (torch.arange(len(x)), torch.full((len(x),), n // 2), torch.full((len(x),), n // 2)),
        torch.tensor(1.0, dtype=torch.float64)), GEOM)
    img = torch.rand(1, 2, 300, 320, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    scheme = WindowScheme(128, 16, 32, fit=False)
    zones = StrideZones((100.0,), (1, 2))
    out = wiener_windowed(img, delta, noise=NoiseModel(math.inf), scheme=scheme, zones=zones, taper=0)
    assert torch.allclose(out, img, atol=1e-10)
    blur = FunctionPSF(_mix(lambda x, y: (x.square() + y.square()).sqrt() / 0.4), GEOM)
    noisy = blur_windowed(img, blur, scheme=scheme) + 0.01 * torch.randn(
        img.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    plain = wiener_windowed(noisy, blur, noise=NoiseModel(1e4), scheme=scheme)
    zoned = wiener_windowed(noisy, blur, noise=NoiseModel(1e4), scheme=scheme, zones=zones)
    # about the optical centre (the frame's): an outer-ring window is used where its tent (64 px core) reaches into its
    # ring, so from up to 32 px inside the edge, and its tent reaches 32 px further in: pixels within 36 px are clear
    cy, cx = 150, 160
    inner = slice(cy - 25, cy + 25), slice(cx - 25, cx + 25)
    assert torch.equal(zoned[..., inner[0], inner[1]], plain[..., inner[0], inner[1]])
    assert not torch.allclose(zoned, plain)  # the outer ring is restored with other windows
    with pytest.raises(ValueError, match="zones are not allowed with local='pixel'"):
        wiener_windowed(noisy, blur, noise=NoiseModel(1e4), scheme=scheme, zones=zones, local="pixel")
