"""The adaptive Wiener's bank evaluation (``wiener:bank=N``, issue 46 item 3): the paper's filter with windows at twice
the stride and its statistics at half of it, a bank of filters per window interpolated per pixel in ``log K``."""

import math

import numpy as np
import pytest
import torch

from lenssim import Design, FunctionPSF, LensPSF
from lenssim_studies.paper import PAPER_CAMERA
from pipeline import NoiseModel, add_poisson_noise
from pipeline.blur import PAPER_SCHEME, WindowScheme, blur_windowed, window_count
from pipeline.restoration import Restoration, parse_restoration
from pipeline.restoration.wiener import (WIENER_BANK_LEVELS, WIENER_BANK_MOST_LEVELS, bank_scheme, chebyshev_gauss, lagrange_weights,
                                         wiener_windowed)

from .test_restoration import delta, scene  # smooth colour blobs with a band of fine bars; a delta PSF

E2E = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))
SCHEME = WindowScheme(256, 32, 64)


def test_chebyshev_gauss_nodes_are_the_chebyshev_roots_with_the_least_nodal_polynomial():
    """Against numpy's Chebyshev roots on [-1, 1] mapped to [0, 1], and the minimax property the bank relies on: the
    nodal polynomial ``prod (t - t_j)`` peaks at ``2^(1 - 2n)`` on [0, 1], below the Chebyshev-Lobatto nodes' (both
    ends included) and evenly spaced nodes'."""
    t = np.linspace(0.0, 1.0, 20001)
    for n in (3, 4, 6):
        nodes = np.array(chebyshev_gauss(n))
        roots = np.sort(np.polynomial.chebyshev.chebroots([0] * n + [1]))
        np.testing.assert_allclose(nodes, (roots + 1) / 2, rtol=0, atol=1e-14)
        peak = lambda x: float(np.abs(np.prod(t[:, None] - np.asarray(x)[None, :], axis=1)).max())  # noqa: E731
        assert peak(nodes) == pytest.approx(2.0 ** (1 - 2 * n), rel=1e-6)
        lobatto = (1 - np.cos(np.pi * np.arange(n) / (n - 1))) / 2
        assert peak(nodes) < 0.7 * peak(lobatto) and peak(nodes) < peak(np.linspace(0, 1, n))


def test_lagrange_weights_reproduce_polynomials_of_their_degree():
    """Against numpy's own polynomial fit through the same nodes: the weights interpolate any polynomial of degree
    ``n - 1`` exactly and sum to 1."""
    t = torch.linspace(-0.2, 1.2, 29, dtype=torch.float64)
    for n in (3, 4, 6):
        nodes = chebyshev_gauss(n)
        assert 0 < nodes[0] and nodes[-1] < 1 and list(nodes) == sorted(nodes)
        coeffs = np.random.default_rng(n).normal(size=n)
        values = np.polyval(coeffs, nodes)
        w = lagrange_weights(t, nodes)
        ours = sum(v * wj for v, wj in zip(values, w))
        np.testing.assert_allclose(ours.numpy(), np.polyval(coeffs, t.numpy()), rtol=0, atol=1e-12)
        np.testing.assert_allclose(sum(w).numpy(), 1.0, rtol=0, atol=1e-13)


def test_bank_without_blur_or_noise_is_the_identity():
    x = scene()
    out = wiener_windowed(x, FunctionPSF(delta, PAPER_CAMERA.geometry), noise=NoiseModel(math.inf), scheme=SCHEME,
                          bank=4)
    torch.testing.assert_close(out, x, rtol=0, atol=1e-9)


def test_bank_with_equal_statistics_is_the_paper_s_filter_in_its_windows():
    """An image periodic over 16 px (the points' step): every point's box holds the same values, so every point has the
    window's own noise-to-signal ratio, the bank's filters coincide, and the bank is the paper's evaluation in its
    windows (twice the stride and core), to rounding: the windows, their means, the deviation's spectrum, the filter
    and the cores' placement are the paper's. Without blur the filter is a smoothing ``P / (P + K)``; compared where
    every box lies inside the image."""
    yy, xx = torch.meshgrid(*(torch.arange(512, dtype=torch.float64),) * 2, indexing="ij")
    x = 0.4 + 0.25 * torch.sin(2 * math.pi * yy / 16) * torch.cos(2 * math.pi * xx / 8) + 0.1 * torch.cos(
        2 * math.pi * (yy + 2 * xx) / 16)
    x = torch.stack([x, 0.8 * x, 0.5 + 0.5 * x]).double()[None]
    kw = dict(noise=NoiseModel(200.0), region=(192, 320, 192, 320))
    psf = FunctionPSF(delta, PAPER_CAMERA.geometry)
    bank = wiener_windowed(x, psf, scheme=SCHEME, bank=3, **kw)[..., 192:320, 192:320]
    paper = wiener_windowed(x, psf, scheme=bank_scheme(SCHEME), **kw)[..., 192:320, 192:320]
    assert float((paper - x[..., 192:320, 192:320]).abs().max()) > 0.01  # the filter smooths: a test of it
    torch.testing.assert_close(bank, paper, rtol=0, atol=1e-10)


@pytest.mark.parametrize("center", [(96 + 700, 96 + 900), (96.5 + 300, 95.5 + 200)])
def test_bank_is_nearer_the_filter_at_a_fine_stride_than_the_paper_s_stride(center):
    """The rule of issue 46, item 3: the filter the windows stand for, evaluated at a stride of 8 px (cores of 16), is
    the reference. The bank (windows at twice the stride, statistics at half of it) must be at least as near it as the
    windows at the stride, on an image whose statistics change within a window (flat blobs, fine bars), at two places
    of the field (one with the axis between pixels, where the windows lie half a pixel before their anchor pixels).
    Small windows (256 px, statistics over 64) keep it fast; the photos' crops at the paper's scheme are in
    docs/performance.md."""
    x = scene(256, 256, seed=2)[:, 1:2].contiguous()
    y = blur_windowed(x, E2E, scheme=SCHEME, optical_center=center)
    fwc = 800.0
    noisy = add_poisson_noise(y, fwc, seed=5)
    kw = dict(noise=NoiseModel(fwc / float(y.amax())), optical_center=center, region=(64, 192, 64, 192), stats=64)
    reference = wiener_windowed(noisy, E2E, scheme=WindowScheme(256, 8, 16), fit=False, **kw)[..., 64:192, 64:192]
    paper = wiener_windowed(noisy, E2E, scheme=SCHEME, **kw)[..., 64:192, 64:192]
    bank = wiener_windowed(noisy, E2E, scheme=SCHEME, bank=WIENER_BANK_LEVELS, **kw)[..., 64:192, 64:192]
    coarse = wiener_windowed(noisy, E2E, scheme=bank_scheme(SCHEME), **kw)[..., 64:192, 64:192]

    def db(a):
        return -10 * math.log10(float((a - reference).square().mean()))

    print(f"against the stride-8 filter: paper {db(paper):.1f} dB, bank {db(bank):.1f} dB, "
          f"paper's evaluation at the bank's stride {db(coarse):.1f} dB")
    assert db(bank) > db(paper) > db(coarse)  # the bank's statistics, not its coarser windows, set its error


def test_bank_progress_counts_the_scheme_s_windows():
    x = scene()
    center = (96 + 700, 96 + 900)
    calls = []
    wiener_windowed(x, E2E, noise=NoiseModel(3200.0), scheme=SCHEME, optical_center=center, bank=3,
                    progress=calls.append)
    assert sum(calls) == window_count(x.shape, SCHEME, center) and all(k > 0 for k in calls)
    assert len(calls) > 1


def test_bank_options_are_checked_before_any_work():
    assert parse_restoration("wiener:bank=4").options["bank"] == 4
    for bad in ("2", "9", "1.5", "-3"):
        with pytest.raises(ValueError, match="bank"):
            parse_restoration(f"wiener:bank={bad}")
    with pytest.raises(ValueError, match="not with local='pixel'"):
        parse_restoration("wiener:bank=3,local=pixel")
    # the bank's windows take twice the core: refused where that is over the window
    with pytest.raises(ValueError, match="2x the core"):
        Restoration("wiener", {"bank": 3}).check(WindowScheme(128, 32, 96))
    with pytest.raises(ValueError, match=f"from 3 to {WIENER_BANK_MOST_LEVELS}"):
        wiener_windowed(scene(), E2E, noise=NoiseModel(100.0), scheme=SCHEME, bank=True)
    # its windows reach further: the crop margin grows by a core
    assert Restoration("wiener", {"bank": 3}).margin(PAPER_SCHEME) == Restoration("wiener").margin(PAPER_SCHEME) + 64


def test_bank_follows_the_device_and_dtype(device_dtype):
    """The bank runs where its input lies and in its precision (kornia's device x dtype cases; CUDA where a GPU is
    present), the same result as on the CPU in float64 to the precision's rounding."""
    device, dtype = device_dtype
    x = scene()
    center = (96 + 700, 96 + 900)
    noisy = add_poisson_noise(blur_windowed(x, E2E, scheme=SCHEME, optical_center=center), 800.0, seed=6)
    kw = dict(noise=NoiseModel(800.0), scheme=SCHEME, optical_center=center, stats=64, bank=4)
    want = wiener_windowed(noisy, E2E, **kw)
    got = wiener_windowed(noisy.to(device=device, dtype=dtype), E2E, **kw)
    assert got.device.type == device.type and got.dtype == dtype
    tol = 1e-9 if dtype == torch.float64 else 1e-5  # float32: 2.3e-7 on this CPU
    torch.testing.assert_close(got.cpu().double(), want, rtol=0, atol=tol)
