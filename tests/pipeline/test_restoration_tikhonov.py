"""Tikhonov's weight chosen by SURE (issue 45): against the textbook risk estimate minimised by scipy, its options."""

import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize_scalar

from lenssim import FunctionPSF
from lenssim_studies.paper import PAPER_CAMERA
from pipeline import NoiseModel
from pipeline.blur import WindowScheme
from pipeline.restoration import parse_restoration
from pipeline.restoration.tikhonov import TIKHONOV_SURE_FACTOR, tikhonov_windowed

N = 64
"""Side (px) of the periodic test image: one window (64 px, core 64: no taper anywhere), whose SURE square is the
whole window."""

SCHEME = WindowScheme(N, 32, 64)


def _kernel():
    """A lopsided 5 x 3 box with a heavier pixel to its right, normalised (the blur, ``(N, N)``, centred)."""
    k = torch.zeros(N, N, dtype=torch.float64)
    k[N // 2 - 2:N // 2 + 3, N // 2 - 1:N // 2 + 2] = 1.0
    k[N // 2, N // 2 + 2] = 3.0
    return k / k.sum()


def _observed(noise: NoiseModel, seed=3):
    """One period: a smooth random scene circularly blurred by :func:`_kernel`, plus Gaussian noise of the noise
    model's variance at each pixel (seeded)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.nn.functional.interpolate(torch.rand(1, 1, N // 4, N // 4, generator=g, dtype=torch.float64),
                                        size=(N, N), mode="bicubic", align_corners=False)[0, 0] * 0.5 + 0.2
    x = x + 0.05 * torch.rand(N, N, generator=g, dtype=torch.float64)  # some fine texture as well
    H = torch.fft.fft2(torch.fft.ifftshift(_kernel()))
    y = torch.fft.ifft2(H * torch.fft.fft2(x)).real
    return y + noise.variance(y).sqrt() * torch.randn(N, N, generator=g, dtype=torch.float64)


def _textbook_sure_weight(y, noise: NoiseModel, order: int) -> float:
    """The weight minimising Stein's unbiased estimate of the predicted risk, written out on the full plane (complex
    FFTs, the residual in the image domain)::

        SURE(w) = ||h * x_w - y||^2 + 2 sigma^2 trace(A_w) - N^2 sigma^2,    A_w = |H|^2 / (|H|^2 + w R) (f != 0), 1 (f = 0)

    ``sigma^2`` the noise model at the image's mean; minimised over ln w by scipy's bounded Brent from the best of a
    grid; times :data:`TIKHONOV_SURE_FACTOR`."""
    H = torch.fft.fft2(torch.fft.ifftshift(_kernel()))
    Y = torch.fft.fft2(y)
    R = torch.ones(N, N, dtype=torch.float64)
    if order == 1:  # |FFT|^2 of the stencils [1, -1] down and across
        down, across = torch.zeros(N, N, dtype=torch.float64), torch.zeros(N, N, dtype=torch.float64)
        down[0, 0], down[1, 0] = -1.0, 1.0
        across[0, 0], across[0, 1] = -1.0, 1.0
        R = torch.fft.fft2(down).abs() ** 2 + torch.fft.fft2(across).abs() ** 2
    var = float(noise.variance(y.mean()))
    H2 = H.abs() ** 2

    def sure(log_w):
        A = H2 / (H2 + math.exp(log_w) * R)
        A[0, 0] = 1.0  # the mean passes as it is
        fit = torch.fft.ifft2(A * Y).real  # h * x_w
        return float(((fit - y) ** 2).sum() + 2 * var * A.sum() - N * N * var)

    grid = np.arange(-25.0, 8.0, 0.5)
    k = int(np.argmin([sure(s) for s in grid]))
    best = minimize_scalar(sure, bounds=(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]), method="bounded",
                           options={"xatol": 1e-7})
    return TIKHONOV_SURE_FACTOR * math.exp(best.x)


def _psf():
    return FunctionPSF(lambda xx, yy, m: _kernel().expand(len(xx), m, m), PAPER_CAMERA.geometry)


def _restore(tile, **kw):
    out = tikhonov_windowed(tile.repeat(3, 3)[None, None], _psf(), scheme=SCHEME, **kw)
    return out[0, 0, N:2 * N, N:2 * N]


@pytest.mark.parametrize("order", [0, 1])
def test_sure_weight_is_the_minimiser_of_the_textbook_risk_estimate(order):
    """On a periodic image (its period the window: every window sees the same data, no taper), the default weight is
    the one minimising SURE written out independently (:func:`_textbook_sure_weight`): the result equals the filter
    with that number given, far closer than to the filter with a weight 2 % off (the test can tell)."""
    noise = NoiseModel(2000.0, 1e-5)
    y = _observed(noise)
    w = _textbook_sure_weight(y, noise, order)
    assert 1e-6 < w / TIKHONOV_SURE_FACTOR < 10  # an interior minimum
    auto = _restore(y, noise=noise, order=order)
    given = _restore(y, weight=w, order=order)
    off = _restore(y, weight=1.02 * w, order=order)
    err, scale = float((auto - given).abs().max()), float((off - given).abs().max())
    assert scale > 1e-6  # 2 % in the weight moves the result
    assert err < 0.1 * scale, f"SURE's weight is off: {err:.3g} against {scale:.3g} for 2 %"
    # strength multiplies the chosen weight
    torch.testing.assert_close(_restore(y, noise=noise, order=order, strength=3.0),
                               _restore(y, weight=3.0 * w, order=order), rtol=0, atol=10 * err + 1e-12)


def test_more_noise_gets_a_larger_weight_and_no_noise_the_inverse_filter():
    """Against the textbook minimiser at two noise levels (the weight rises with the noise), and noise-free: weight 0,
    the inverse filter, exactly."""
    quiet, loud = NoiseModel(20000.0), NoiseModel(200.0)
    y = _observed(quiet)
    weights = [_textbook_sure_weight(y, noise, 1) for noise in (quiet, loud)]
    assert weights[1] > 3 * weights[0]
    for noise, w in zip((quiet, loud), weights):
        given = _restore(y, weight=w)
        tol = 0.1 * float((_restore(y, weight=1.02 * w) - given).abs().max())
        torch.testing.assert_close(_restore(y, noise=noise), given, rtol=0, atol=tol)
    torch.testing.assert_close(_restore(y, noise=NoiseModel(math.inf)), _restore(y, weight=0.0), rtol=0, atol=0)


def test_weight_options_are_checked_in_one_line():
    assert parse_restoration("tikhonov").to_dict()["options"] == {"weight": "sure", "strength": 1.0, "order": 1}
    assert parse_restoration("tikhonov:weight=prior").options == {"weight": "prior"}
    assert parse_restoration("tikhonov:weight=sure,strength=2").options == {"weight": "sure", "strength": 2.0}
    for spec, msg in (("tikhonov:weight=noise", "weight='noise' is not allowed: 'sure' .* 'prior' .* >= 0"),
                      ("tikhonov:weight=-1", "weight=-1.0 is not allowed: 'sure'"),
                      ("tikhonov:weight=inf", "finite number"), ("tikhonov:strength=0", "strength"),
                      ("tikhonov:order=2", "order=2 is not allowed: 0 .* or 1")):
        with pytest.raises(ValueError, match=msg) as err:
            parse_restoration(spec)
        assert "\n" not in str(err.value) and "tikhonov option" in str(err.value)
    y = torch.ones(1, 1, 8, 8)
    psf = _psf()  # refused before any PSF is asked for
    for weight in ("sure", "prior"):
        with pytest.raises(ValueError, match=f"weight='{weight}' needs a pipeline.camera_chain.NoiseModel"):
            tikhonov_windowed(y, psf, weight=weight, noise=None)
    with pytest.raises(ValueError, match="weight='soft' is not allowed"):
        tikhonov_windowed(y, psf, weight="soft", noise=NoiseModel(100.0))
