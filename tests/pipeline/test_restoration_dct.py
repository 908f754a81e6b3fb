"""The adaptive Wiener refined by a local DCT (pipeline/restoration/dct_wiener.py): the transform, the coloured noise
in it, the shrinkage and aggregation against brute force, the identity, and its gain on a blurred noisy scene."""

import math

import numpy as np
import pytest
import scipy.fft
import torch

from pipeline import NoiseModel, add_poisson_noise
from pipeline.blur import blur_windowed
from pipeline.quality import psnr_srgb
from pipeline.restoration import parse_restoration, restore
from pipeline.restoration.dct_wiener import (coefficient_noise_variance, dct_basis, dct_shrink, opponent_matrix,
                                             opponent_variance)

from .test_restoration_pnp import SCHEME, delta_psf, kernel_psf, scene


def test_the_basis_gives_scipys_orthonormal_dct_of_every_patch():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 1, 11, 13, generator=g, dtype=torch.float64)
    coeffs = torch.nn.functional.conv2d(x, dct_basis(8))  # (1, 64, 4, 6)
    for i, j in [(0, 0), (3, 5), (2, 1)]:
        want = scipy.fft.dctn(x[0, 0, i:i + 8, j:j + 8].numpy(), norm="ortho")
        np.testing.assert_allclose(coeffs[0, :, i, j].reshape(8, 8).numpy(), want, atol=1e-12)


def test_coefficient_variance_of_white_noise_is_its_variance():
    psd = torch.full((3, 32, 17), 0.7, dtype=torch.float64)
    torch.testing.assert_close(coefficient_noise_variance(psd, 32), torch.full((3, 64), 0.7, dtype=torch.float64))


def test_coefficient_variance_of_coloured_noise_against_monte_carlo():
    """White noise filtered on a periodic 32 px grid by a low-pass ``G``: each DCT coefficient's variance over many
    patches and draws against the formula (standard error of a variance over ~10^5 samples: 0.5%)."""
    n = 32
    fy = torch.fft.fftfreq(n, dtype=torch.float64)[:, None]
    fx = torch.fft.rfftfreq(n, dtype=torch.float64)[None, :]
    G = torch.exp(-(fy ** 2 + fx ** 2) / (2 * 0.12 ** 2)) + 0.2 * torch.cos(2 * math.pi * 3 * fx)
    g = torch.Generator().manual_seed(3)
    white = torch.randn(400, 1, n, n, generator=g, dtype=torch.float64) * 0.5  # variance 0.25
    coloured = torch.fft.irfft2(torch.fft.rfft2(white) * G, s=(n, n))
    c = torch.nn.functional.conv2d(coloured, dct_basis(8))  # (400, 64, 25, 25), every patch of every draw
    measured = c.square().mean(dim=(0, 2, 3))
    predicted = coefficient_noise_variance(0.25 * G.square(), n)
    torch.testing.assert_close(measured, predicted, rtol=0.03, atol=1e-6)
    assert predicted.max() / predicted.min() > 20  # really coloured: the test tells coefficients apart


def test_shrinkage_and_aggregation_against_a_patch_loop():
    g = torch.Generator().manual_seed(4)
    h, w = 12, 11
    x = torch.randn(1, 1, h, w, generator=g, dtype=torch.float64)
    pilot = x + 0.3 * torch.randn(1, 1, h, w, generator=g, dtype=torch.float64)
    var = 0.1 + torch.rand(1, 64, h - 7, w - 7, generator=g, dtype=torch.float64)
    got = dct_shrink(x, pilot, var)[0, 0].numpy()
    num, den = np.zeros((h, w)), np.zeros((h, w))
    xs, ps, vs = x[0, 0].numpy(), pilot[0, 0].numpy(), var[0].numpy()
    for i in range(h - 7):
        for j in range(w - 7):
            c = scipy.fft.dctn(xs[i:i + 8, j:j + 8], norm="ortho")
            cp = scipy.fft.dctn(ps[i:i + 8, j:j + 8], norm="ortho")
            v = vs[:, i, j].reshape(8, 8)
            f = cp ** 2 / (cp ** 2 + v)
            wgt = 1 / (f ** 2 * v).sum()
            num[i:i + 8, j:j + 8] += wgt * scipy.fft.idctn(c * f, norm="ortho")
            den[i:i + 8, j:j + 8] += wgt
    np.testing.assert_allclose(got, num / den, rtol=1e-10, atol=1e-12)


def test_without_blur_or_noise_the_image_comes_back():
    x = scene(64, channels=3)
    out = restore("dct_wiener:stats=64", x, delta_psf(), noise=NoiseModel(math.inf), scheme=SCHEME)
    torch.testing.assert_close(out, x, rtol=0, atol=1e-9)


@pytest.mark.parametrize("electrons", [300.0, 3000.0])
def test_it_restores_a_blurred_noisy_scene_better_than_the_wiener(electrons):
    """A scene of sharp edges and flat regions (where a per-patch shrinkage has the most to gain over one filter per
    window), blurred and with photon noise; both restorations on the same draw."""
    x = scene(96, channels=1)
    x = torch.where(x > 0.5, 0.8, 0.15).to(torch.float64) + 0.1 * scene(96, channels=1, seed=5)
    psf = kernel_psf()
    blurred = blur_windowed(x, psf, scheme=SCHEME)
    y = add_poisson_noise(blurred, electrons, generator=torch.Generator().manual_seed(6))
    noise = NoiseModel(electrons)
    sensor = psnr_srgb(y.clamp(0, 1), x)
    wiener = psnr_srgb(restore("wiener:stats=64", y, psf, noise=noise, scheme=SCHEME).clamp(0, 1), x)
    dct = psnr_srgb(restore("dct_wiener:stats=64", y, psf, noise=noise, scheme=SCHEME).clamp(0, 1), x)
    assert wiener > sensor
    assert dct > wiener + 0.3, (sensor, wiener, dct)


@pytest.mark.parametrize("spec, words", [("dct_wiener:alpha=0", "alpha=0.0 is not allowed"),
                                         ("dct_wiener:alpha=1.5", "alpha=1.5 is not allowed"),
                                         ("dct_wiener:passes=0", "passes=0 is not allowed"),
                                         ("dct_wiener:rho0=1", "dct_wiener option rho0=1.0"),
                                         ("dct_wiener:local_noise=3", "local_noise='3'.*not allowed"),
                                         ("dct_wiener:colour=lab", "colour='lab' is not allowed: one of opponent, rgb")])
def test_bad_options_are_refused_in_one_line(spec, words):
    with pytest.raises(ValueError, match=words):
        parse_restoration(spec)


def test_the_function_refuses_a_local_noise_that_is_not_a_flag():
    from pipeline.restoration.dct_wiener import dct_wiener_windowed

    with pytest.raises(ValueError, match="local_noise=3 is not allowed"):
        dct_wiener_windowed(scene(64), delta_psf(), noise=NoiseModel(100.0), stats=64, scheme=SCHEME, local_noise=3)


def test_the_opponent_transform_is_orthonormal_along_bm3ds_colour_directions():
    T = opponent_matrix()
    torch.testing.assert_close(T @ T.T, torch.eye(3, dtype=torch.float64), rtol=0, atol=1e-15)
    bm3d = torch.tensor([[1 / 3, 1 / 3, 1 / 3], [1 / 2, 0, -1 / 2], [1 / 4, -1 / 2, 1 / 4]], dtype=torch.float64)
    torch.testing.assert_close(T, bm3d / bm3d.norm(dim=1, keepdim=True), rtol=0, atol=1e-15)


def test_opponent_coefficient_variances_against_monte_carlo():
    """Three independent channels of white noise (variances 0.1, 0.4, 0.9), each coloured by its own filter, through
    the opponent transform: each opponent channel's DCT coefficient variances against the formula."""
    n = 32
    fy = torch.fft.fftfreq(n, dtype=torch.float64)[:, None]
    fx = torch.fft.rfftfreq(n, dtype=torch.float64)[None, :]
    G = torch.stack([torch.exp(-(fy ** 2 + fx ** 2) / (2 * w ** 2)) for w in (0.08, 0.15, 0.3)])  # (3, n, n/2+1)
    var = torch.tensor([0.1, 0.4, 0.9], dtype=torch.float64)
    g = torch.Generator().manual_seed(8)
    white = torch.randn(800, 3, n, n, generator=g, dtype=torch.float64) * var.sqrt()[:, None, None]
    coloured = torch.fft.irfft2(torch.fft.rfft2(white) * G, s=(n, n))
    opp = torch.einsum("kc,bchw->bkhw", opponent_matrix(), coloured).reshape(-1, 1, n, n)
    c = torch.nn.functional.conv2d(opp, dct_basis(8)).reshape(800, 3, 64, -1)
    measured = c.square().mean(dim=(0, 3))  # (3, 64)
    per_channel = coefficient_noise_variance(var[:, None, None] * G.square(), n)  # (3, 64)
    predicted = opponent_variance(per_channel, dim=0)
    torch.testing.assert_close(measured, predicted, rtol=0.03, atol=1e-6)
    assert not torch.allclose(predicted, per_channel, rtol=0.2)  # the mixing matters here


def test_a_colour_scene_restores_better_in_the_opponent_space():
    """A scene whose channels share their detail (a tinted grey scene with a faint colour of its own), blurred and
    with photon noise: the shrinkage in the opponent space against channel by channel, on the same draw."""
    grey = scene(64, channels=1)
    x = torch.cat([0.9 * grey, grey, 0.7 * grey], dim=1) + 0.03 * scene(64, channels=3, seed=9)
    psf = kernel_psf()
    y = add_poisson_noise(blur_windowed(x, psf, scheme=SCHEME), 300.0, generator=torch.Generator().manual_seed(10))
    noise = NoiseModel(300.0)
    rgb = psnr_srgb(restore("dct_wiener:stats=64,colour=rgb", y, psf, noise=noise, scheme=SCHEME).clamp(0, 1), x)
    opponent = psnr_srgb(restore("dct_wiener:stats=64", y, psf, noise=noise, scheme=SCHEME).clamp(0, 1), x)
    assert opponent > rgb + 0.3, (rgb, opponent)


@pytest.mark.parametrize("colour", ["opponent", "rgb"])
def test_local_noise_in_either_colour_space_stays_finite_and_near_the_global_noise(colour):
    x = scene(48, channels=3)
    psf = kernel_psf()
    y = add_poisson_noise(blur_windowed(x, psf, scheme=SCHEME), 1000.0, generator=torch.Generator().manual_seed(11))
    spec = f"dct_wiener:stats=64,colour={colour}"
    plain = restore(spec, y, psf, noise=NoiseModel(1000.0), scheme=SCHEME)
    local = restore(spec + ",local_noise=true", y, psf, noise=NoiseModel(1000.0), scheme=SCHEME)
    assert torch.isfinite(local).all()
    assert 0 < float((local - plain).abs().max()) < 0.1
