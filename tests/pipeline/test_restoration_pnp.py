"""Plug-and-play restoration (pipeline/restoration/pnp.py): the data step, the wavelet ISTA, the dispatcher's checks."""

import math

import pytest
import torch

from lenssim import FunctionPSF

from lenssim_studies.paper import PAPER_CAMERA
from pipeline import NoiseModel, add_poisson_noise
from pipeline.blur import WindowScheme, blur_windowed
from pipeline.blur_operator import BlurOperator
from pipeline.quality import psnr_srgb
from pipeline.restoration import parse_restoration, restore
from pipeline.restoration.pnp import PNP_DENOISERS, conjugate_gradient, hqs_data_step, pnp_windowed

SCHEME = WindowScheme(64, 16, 32)


def kernel_psf(n=64, dtype=torch.float64):
    """A fixed, asymmetric blur (a mirrored kernel would be caught), unit sum."""
    psf = torch.zeros(n, n, dtype=dtype)
    psf[n // 2 - 2:n // 2 + 3, n // 2 - 1:n // 2 + 2] = 1.0
    psf[n // 2, n // 2 + 2] = 3.0
    psf /= psf.sum()
    return FunctionPSF(lambda x, y, m: psf.to(x.dtype).expand(len(x), m, m), PAPER_CAMERA.geometry)


def delta_psf():
    def fn(x, y, m):
        p = torch.zeros(len(x), m, m, dtype=torch.float64)
        p[:, m // 2, m // 2] = 1
        return p
    return FunctionPSF(fn, PAPER_CAMERA.geometry)


def scene(size=96, channels=1, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, channels, size // 8, size // 8, generator=g, dtype=torch.float64)
    x = torch.nn.functional.interpolate(x, size=(size, size), mode="bicubic", align_corners=False).clamp(0, 1)
    return (0.1 + 0.8 * x).to(dtype)


@pytest.mark.parametrize("denoiser", ["wavelet", "nlm", "tv"])
def test_without_blur_or_noise_the_image_comes_back(denoiser):
    x = scene(64, channels=3)
    out = restore(f"pnp:denoiser={denoiser}", x, delta_psf(), noise=NoiseModel(math.inf), scheme=SCHEME)
    torch.testing.assert_close(out, x, rtol=0, atol=1e-9)


def test_conjugate_gradient_solves_a_dense_system():
    g = torch.Generator().manual_seed(1)
    n = 6
    m = torch.randn(2, 3, n, n, generator=g, dtype=torch.float64)
    M = m @ m.transpose(-1, -2) + 0.5 * torch.eye(n, dtype=torch.float64)  # 2 x 3 independent SPD systems
    b = torch.randn(2, 3, n, 1, generator=g, dtype=torch.float64)
    x, Mx = conjugate_gradient(lambda v: M @ v, b, torch.zeros_like(b), n)  # n steps: exact in exact arithmetic
    torch.testing.assert_close(x, torch.linalg.solve(M, b), rtol=1e-8, atol=1e-10)
    torch.testing.assert_close(Mx, M @ x, rtol=1e-8, atol=1e-10)  # the product kept along the steps


def test_data_step_with_a_delta_psf_is_the_closed_form():
    """With a delta PSF ``A`` is the identity on the data: the data step is ``(s W y + mu z) / (s^2 W + mu)``
    pixel by pixel (where ``W`` is 0, beyond the data, ``z``)."""
    g = torch.Generator().manual_seed(2)
    shape = (1, 2, 12, 12)
    y, z, xi0 = (torch.rand(shape, generator=g, dtype=torch.float64) for _ in range(3))
    A = BlurOperator(delta_psf(), shape, scheme=WindowScheme(16, 4, 8), region=(2, 10, 3, 11))
    weight = torch.zeros(shape, dtype=torch.float64)
    weight[..., 2:10, 3:11] = 1 + torch.rand(1, 2, 8, 8, generator=g, dtype=torch.float64)
    s = 0.5 + torch.rand(shape, generator=g, dtype=torch.float64)
    mu = 0.3
    # diagonal entries in [0.3, 4.5]: CG's error falls by (sqrt(15) - 1) / (sqrt(15) + 1) ~ 0.6 a step, 1e-11 in 50
    got, normal = hqs_data_step(A, weight, s, xi0, z, mu, y=y, steps=50)
    want = (s * weight * y + mu * z) / (s * s * weight + mu)
    torch.testing.assert_close(got, want, rtol=1e-8, atol=1e-10)
    torch.testing.assert_close(normal, s * s * weight * got, rtol=1e-8, atol=1e-10)  # S A^T W A S xi, kept
    # from there, with the product given, the next step needs no extra pass and reaches the same solution
    again, _ = hqs_data_step(A, weight, s, got, z, 2 * mu, y=y, steps=50, normal_xi=normal)
    torch.testing.assert_close(again, (s * weight * y + 2 * mu * z) / (s * s * weight + 2 * mu), rtol=1e-8, atol=1e-10)


def test_data_step_is_the_direct_solve_on_a_tiny_blur():
    """On a 12 x 12 image the operator's matrix is built column by column (brute force) and the normal equations of
    the data step solved directly."""
    n = 12
    shape = (1, 1, n, n)
    A = BlurOperator(kernel_psf(16), shape, scheme=WindowScheme(16, 4, 8), region=(2, 10, 2, 10))
    Amat = A.forward(torch.eye(n * n, dtype=torch.float64).reshape(n * n, 1, n, n)).reshape(n * n, n * n).T  # columns
    g = torch.Generator().manual_seed(3)
    y, z = torch.rand(shape, generator=g, dtype=torch.float64), torch.rand(shape, generator=g, dtype=torch.float64)
    weight = torch.zeros(shape, dtype=torch.float64)
    weight[..., 2:10, 2:10] = 1 + torch.rand(1, 1, 8, 8, generator=g, dtype=torch.float64)
    s = 0.5 + torch.rand(shape, generator=g, dtype=torch.float64)
    mu = 0.2
    S, Wd = torch.diag(s.flatten()), torch.diag(weight.flatten())
    M = S @ Amat.T @ Wd @ Amat @ S + mu * torch.eye(n * n, dtype=torch.float64)
    want = torch.linalg.solve(M, S @ Amat.T @ Wd @ y.flatten() + mu * z.flatten()).reshape(shape)
    got, _ = hqs_data_step(A, weight, s, torch.zeros(shape, dtype=torch.float64), z, mu, y=y, steps=60)
    torch.testing.assert_close(got, want, rtol=1e-7, atol=1e-9)


def blurred_noisy(size=96, channels=1, batch=1, seed=4, dtype=torch.float64):
    x = torch.cat([scene(size, channels, seed + b, dtype) for b in range(batch)])
    psf = kernel_psf()
    y = blur_windowed(x, psf, scheme=SCHEME)
    fwc = 2000.0
    noisy = add_poisson_noise(y, fwc, seed=seed)
    return x, psf, noisy, NoiseModel(fwc / float(y.amax()), signal_independent_var=1e-6)


def test_wavelet_ista_decreases_its_objective_and_beats_the_sensor_image():
    x, psf, noisy, noise = blurred_noisy(channels=2)
    trace = []
    out = pnp_windowed(noisy, psf, noise=noise, denoiser="wavelet", iterations=6, scheme=SCHEME, trace=trace)
    assert len(trace) == 7
    for before, after in zip(trace, trace[1:]):
        assert (after <= before * (1 + 1e-12)).all(), (before, after)
    assert (trace[-1] < trace[0]).all()
    assert psnr_srgb(x, out) > psnr_srgb(x, noisy) + 1


@pytest.mark.parametrize("denoiser", ["wavelet", "tv"])
def test_a_batch_restores_as_its_images_one_by_one(denoiser):
    x, psf, noisy, noise = blurred_noisy(size=64, channels=2, batch=2)
    both = pnp_windowed(noisy, psf, noise=noise, denoiser=denoiser, iterations=2, scheme=SCHEME)
    for b in range(2):
        one = pnp_windowed(noisy[b:b + 1], psf, noise=noise, denoiser=denoiser, iterations=2, scheme=SCHEME)
        torch.testing.assert_close(both[b:b + 1], one, rtol=1e-9, atol=1e-12)


def test_restores_on_the_input_s_device_and_dtype(device_dtype):
    device, dtype = device_dtype
    x, psf, noisy, noise = blurred_noisy(size=64, dtype=dtype)
    out = restore("pnp:iterations=2", noisy.to(device), psf, noise=noise, scheme=SCHEME)
    assert out.device.type == device.type and out.dtype == dtype and bool(torch.isfinite(out).all())


def test_refusals_are_one_line():
    cases = [("pnp:denoiser=median", "denoiser='median' is not allowed: one of wavelet, nlm, tv, bm3d"),
             ("pnp:iterations=0", "iterations=0"), ("pnp:strength=-1", "strength=-1"),
             ("pnp:domain=log", "domain='log'")]
    try:
        import bm3d  # noqa: F401
    except ImportError:
        cases.append(("pnp:denoiser=bm3d", "pip install bm3d"))
    for spec, msg in cases:
        with pytest.raises(ValueError) as err:
            parse_restoration(spec)
        assert msg in str(err.value) and "\n" not in str(err.value)
    assert set(PNP_DENOISERS) == {"wavelet", "nlm", "tv", "bm3d"}
    with pytest.raises(ValueError, match="noise is a float"):
        pnp_windowed(torch.ones(1, 1, 8, 8), kernel_psf(), noise=1.0, scheme=SCHEME)
