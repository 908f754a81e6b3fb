"""Issue 45: the total-variation restoration on the blur's operator (pipeline/restoration/total_variation.py), and the
noise-derived Tikhonov weight."""

import math

import numpy as np
import pytest
import torch

from lenssim import FunctionPSF
from lenssim_studies.paper import PAPER_CAMERA
from pipeline import NoiseModel, add_poisson_noise
from pipeline.blur import WindowScheme, blur_windowed
from pipeline.blur_operator import BlurOperator
from pipeline.quality import psnr_srgb
from pipeline.restoration import mean_noise_variance, parse_restoration, restore
from pipeline.restoration.tikhonov import tikhonov_windowed
from pipeline.restoration.total_variation import (image_divergence, image_gradient, operator_norm_bound,
                                                  total_variation_windowed, tv_denoise, tv_objective, tv_primal_dual)

SMALL = WindowScheme(64, 16, 32)


def gaussian_psf(sigma_px=1.5, n=64):
    r = torch.arange(n, dtype=torch.float64) - n // 2
    k = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * sigma_px ** 2))
    k[n // 2, n // 2 + 2] += 0.3  # asymmetric: a mirrored kernel is caught
    k /= k.sum()
    return FunctionPSF(lambda x, y, m: k[n // 2 - m // 2:n // 2 + m // 2, n // 2 - m // 2:n // 2 + m // 2]
                       .expand(len(x), m, m) / k[n // 2 - m // 2:n // 2 + m // 2, n // 2 - m // 2:n // 2 + m // 2]
                       .sum(), PAPER_CAMERA.geometry)


def scene(h=96, w=96, c=3, seed=0):
    """Piecewise flat blocks with a gentle texture: what TV restores well."""
    g = torch.Generator().manual_seed(seed)
    blocks = torch.rand(1, c, h // 16, w // 16, generator=g, dtype=torch.float64)
    x = torch.nn.functional.interpolate(blocks, size=(h, w), mode="nearest")
    return 0.05 + 0.8 * x


# --- the solver against independent references --------------------------------------------------------------------

def dense_gradient(h, w):
    """The forward-difference matrices (rows, cols) of an h x w image, written out entry by entry (Neumann: none
    across the last row and column)."""
    n = h * w
    Dr, Dc = np.zeros((n, n)), np.zeros((n, n))
    for i in range(h):
        for j in range(w):
            k = i * w + j
            if i + 1 < h:
                Dr[k, k], Dr[k, k + w] = -1, 1
            if j + 1 < w:
                Dc[k, k], Dc[k, k + 1] = -1, 1
    return Dr, Dc


def admm_reference(A, y, wts, mu, h, w, C, coupled, iterations=2000, rho=0.3):
    """ADMM (Boyd et al. 2011) on ``1/2 sum w (A u - y)^2 + mu sum |D u| + [u >= 0]`` for one image of ``C``
    channels, each ``h * w`` px, ``A`` dense (per channel), with the splits ``z = D u`` (grouped over the directions,
    and the channels where coupled) and ``v = u`` (non-negative): a different algorithm from the solver's."""
    Dr, Dc = dense_gradient(h, w)
    n = h * w
    D = np.vstack([Dr, Dc])
    u = np.zeros((C, n))
    z, lz, v, lv = np.zeros((C, 2 * n)), np.zeros((C, 2 * n)), np.zeros((C, n)), np.zeros((C, n))
    systems = [np.linalg.inv(A.T @ np.diag(wts[c]) @ A + rho * D.T @ D + rho * np.eye(n)) for c in range(C)]
    for _ in range(iterations):
        for c in range(C):
            u[c] = systems[c] @ (A.T @ (wts[c] * y[c]) + rho * D.T @ (z[c] - lz[c]) + rho * (v[c] - lv[c]))
        t = np.stack([D @ u[c] for c in range(C)]) + lz  # (C, 2n): rows then cols
        g = t.reshape(C, 2, n)
        norm = np.sqrt((g ** 2).sum(axis=(0, 1), keepdims=True)) if coupled else np.sqrt((g ** 2).sum(axis=1,
                                                                                                      keepdims=True))
        z = (g * np.maximum(1 - (mu / rho) / np.maximum(norm, 1e-300), 0)).reshape(C, 2 * n)
        lz = t - z
        v = np.maximum(u + lv, 0)
        lv = lv + u - v
    return v


@pytest.mark.parametrize("coupled", [True, False])
def test_primal_dual_reaches_the_minimum_an_independent_admm_finds(coupled):
    """A tiny problem (two channels of 7 x 6 px, a dense random non-negative blur whose last rows see no data, varying
    weights, u >= 0 active): Chambolle-Pock on the operator's callables and ADMM with the matrices written out reach
    the same minimiser and objective."""
    h, w, C, n = 7, 6, 2, 42
    rng = np.random.default_rng(0)
    A = rng.random((n, n)) ** 4
    A /= A.sum(axis=1, keepdims=True)
    A[-6:] = 0  # no data in the last row
    truth = rng.random((C, n)) * (rng.random((C, n)) > 0.3)
    y = np.stack([A @ truth[c] for c in range(C)]) + 0.2 * rng.standard_normal((C, n))
    wts = rng.uniform(0.5, 2.0, (C, n)) * (A.sum(axis=1) > 0)
    mu = 0.004
    ref = admm_reference(A, y, wts, mu, h, w, C, coupled)
    At = torch.from_numpy(A)

    def fwd(u):
        return (u.reshape(1, C, n) @ At.T).reshape(1, C, h, w)

    def adj(r):
        return (r.reshape(1, C, n) @ At).reshape(1, C, h, w)

    T = lambda a: torch.from_numpy(a).reshape(1, C, h, w)  # noqa: E731
    mu_t = torch.full((1, 1 if coupled else C, 1, 1), mu, dtype=torch.float64)
    ours = tv_primal_dual(T(y), fwd, adj, T(wts), mu_t, torch.zeros(1, C, h, w, dtype=torch.float64),
                          iterations=3000, norm=float(np.linalg.norm(A, 2)), coupled=coupled)
    E = lambda u: float(tv_objective(u, T(y), fwd, T(wts), mu_t, coupled=coupled)[0])  # noqa: E731
    assert abs(E(ours) - E(T(ref))) <= 1e-7 * E(T(ref))
    torch.testing.assert_close(ours, T(ref), rtol=0, atol=2e-3)
    assert float(ours.min()) >= 0 and float((T(ref) == 0).sum()) > 0  # the constraint is active
    assert float(ours.std()) > 0.05  # and the TV leaves structure


def test_gradient_and_divergence_are_each_other_s_negative_adjoint_and_the_written_out_differences():
    g = torch.Generator().manual_seed(1)
    u = torch.rand(2, 3, 7, 5, generator=g, dtype=torch.float64)
    q = torch.rand(2, 3, 2, 7, 5, generator=g, dtype=torch.float64)
    lhs = (image_gradient(u) * q).sum()
    rhs = -(u * image_divergence(q)).sum()
    assert abs(float(lhs - rhs)) < 1e-12 * float(lhs.abs())
    Dr, Dc = dense_gradient(7, 5)
    flat = u[1, 2].reshape(-1).numpy()
    np.testing.assert_allclose(image_gradient(u)[1, 2, 0].reshape(-1).numpy(), Dr @ flat, atol=1e-15)
    np.testing.assert_allclose(image_gradient(u)[1, 2, 1].reshape(-1).numpy(), Dc @ flat, atol=1e-15)


@pytest.mark.parametrize("coupled", [True, False])
def test_chambolle_s_projection_and_the_primal_dual_solver_agree_on_tv_denoising(coupled):
    """``tv_denoise`` (Chambolle 2004, the plug-and-play TV denoiser) and the primal-dual solver with ``A = I``, no
    constraint, weights 1: two algorithms, one objective, one minimiser."""
    g = torch.Generator().manual_seed(2)
    y = scene(32, 32, seed=3) + 0.05 * torch.randn(1, 3, 32, 32, generator=g, dtype=torch.float64)
    mu = torch.full((1, 1 if coupled else 3, 1, 1), 0.04, dtype=torch.float64)
    ident = lambda u: u.clone()  # noqa: E731
    a = tv_denoise(y, mu, iterations=3000, coupled=coupled)
    b = tv_primal_dual(y, ident, ident, torch.ones_like(y), mu, y, iterations=3000, norm=1.0, coupled=coupled,
                       nonneg=False)
    E = lambda u: float(tv_objective(u, y, ident, torch.ones_like(y), mu, coupled=coupled)[0])  # noqa: E731
    assert abs(E(a) - E(b)) <= 5e-5 * E(b)  # Chambolle's fixed step (1/8) converges the slower of the two
    torch.testing.assert_close(a, b, rtol=0, atol=2e-3)
    assert E(a) < E(y)  # and it denoises


def test_the_tv_denoiser_matches_scikit_image_s_chambolle_per_channel():
    """scikit-image's ``denoise_tv_chambolle`` minimises ``1/2 ||u - y||^2 + weight TV(u)`` per channel with the same
    forward differences (its ``channel_axis``): the per-channel ``tv_denoise`` finds the same image."""
    from skimage.restoration import denoise_tv_chambolle

    g = torch.Generator().manual_seed(4)
    y = scene(32, 32, seed=5) + 0.05 * torch.randn(1, 3, 32, 32, generator=g, dtype=torch.float64)
    ours = tv_denoise(y, 0.05, iterations=2000, coupled=False)
    ref = denoise_tv_chambolle(y[0].permute(1, 2, 0).numpy(), weight=0.05, eps=1e-12, max_num_iter=2000,
                               channel_axis=-1)
    ref = torch.from_numpy(ref).permute(2, 0, 1)[None]
    mu = torch.full((1, 3, 1, 1), 0.05, dtype=torch.float64)
    E = lambda u: float(tv_objective(u, y, lambda v: v, torch.ones_like(y), mu, coupled=False)[0])  # noqa: E731
    assert abs(E(ours) - E(ref)) <= 1e-4 * E(ref)  # both near the minimum of one objective (theirs the closer)
    torch.testing.assert_close(ours, ref, rtol=0, atol=1e-3)


# --- on the blur's operator -----------------------------------------------------------------------------------------

def blurred_noisy(c=3, seed=1, fwc=2000.0, dtype=torch.float64):
    psf = gaussian_psf()
    x = scene(c=c).to(dtype)
    y = blur_windowed(x, psf, scheme=SMALL)
    e = fwc / float(y.amax())
    return x, add_poisson_noise(y, fwc, seed=seed), psf, NoiseModel(e)


def test_the_norm_bound_holds_and_the_objective_falls_from_the_wiener_start():
    """Schur's bound on ``||A||`` is above the power iteration's estimate and within a few % of it; from the Wiener
    start the objective falls, step by step on average, towards its value after many iterations."""
    x, noisy, psf, noise = blurred_noisy()
    A = BlurOperator(psf, noisy.shape, scheme=SMALL)
    mask = torch.ones_like(noisy)
    v = torch.rand(noisy.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for _ in range(12):
        v = A.adjoint(A.forward(v))
        v /= v.norm()
    power = float(A.forward(v).norm() / v.norm())
    bound = operator_norm_bound(A, mask)
    assert power <= bound <= 1.3 * power  # column sums reach ~1.2 at the frame's edges (the reflect padding)
    from pipeline.restoration.wiener import wiener_windowed

    u0 = wiener_windowed(noisy, psf, noise=noise, scheme=SMALL, stats=64)
    var = noise.variance(A.forward(u0))
    s2 = mean_noise_variance(noise, A.forward(u0))
    wts, mu = s2 / var, torch.full((1, 1, 1, 1), 2e-4, dtype=torch.float64)
    E = lambda u: float(tv_objective(u, noisy, A.forward, wts, mu)[0])  # noqa: E731
    run = lambda k: tv_primal_dual(noisy, A.forward, A.adjoint, wts, mu, u0, iterations=k, norm=bound)  # noqa: E731
    energies = [E(u0)] + [E(run(k)) for k in (10, 30, 100)]
    assert energies[0] > energies[1] > energies[2] > energies[3]
    assert energies[2] - energies[3] < 0.5 * (energies[0] - energies[3])  # most of the way in 30 steps


def test_tv_restores_better_than_the_sensor_image_and_the_wiener_on_flat_blocks():
    x, noisy, psf, noise = blurred_noisy()
    tv = restore("tv", noisy, psf, noise=noise, scheme=SMALL)
    wiener = restore("wiener:stats=64", noisy, psf, noise=noise, scheme=SMALL)
    crop = (16, 80, 16, 80)
    assert psnr_srgb(x, tv, crop) > psnr_srgb(x, wiener, crop) > psnr_srgb(x, noisy, crop)


def test_tv_follows_the_batch_and_restores_a_region_as_the_whole():
    """Two images in a batch restore as each alone; a region's pixels with unknown boundaries come out finite and zero
    outside it."""
    _, a, psf, noise = blurred_noisy(seed=1)
    _, b, _, _ = blurred_noisy(seed=2)
    both = total_variation_windowed(torch.cat([a, b]), psf, noise=noise, scheme=SMALL, iterations=5)
    one = total_variation_windowed(b, psf, noise=noise, scheme=SMALL, iterations=5)
    torch.testing.assert_close(both[1:], one, rtol=0, atol=1e-12)
    part = total_variation_windowed(a, psf, noise=noise, scheme=SMALL, iterations=5, region=(20, 60, 30, 70))
    assert bool(torch.isfinite(part).all()) and float(part[..., :20, :].abs().max()) == 0
    assert float(part[..., 20:60, 30:70].min()) > 0


def test_tv_follows_the_input_s_device_and_dtype(device_dtype):
    device, dtype = device_dtype
    x, noisy, psf, noise = blurred_noisy(c=1)
    out = total_variation_windowed(noisy.to(device=device, dtype=dtype), psf, noise=noise, scheme=SMALL,
                                   iterations=4)
    assert out.device.type == device.type and out.dtype == dtype
    ref = total_variation_windowed(noisy, psf, noise=noise, scheme=SMALL, iterations=4)
    tol = 1e-10 if dtype == torch.float64 else 1e-4
    torch.testing.assert_close(out.cpu().double(), ref, rtol=0, atol=tol)


def test_bad_options_are_refused_in_one_line():
    for spec, msg in (("tv:iterations=0", "iterations=0 is not allowed"), ("tv:iterations=5000", "1 to 1000"),
                      ("tv:strength=0", "strength=0.0 is not allowed"), ("tv:strength=-1", "> 0"),
                      ("tv:coupled=maybe", "bool expected"), ("tv:lambda=3", "takes no option"),
                      ("tikhonov:weight=-1", "'sure' .* 'prior' .* or a finite number >= 0"),
                      ("tikhonov:weight=soft", "'sure'"), ("tikhonov:strength=0", "strength")):
        with pytest.raises(ValueError, match=msg) as err:
            parse_restoration(spec)
        assert "\n" not in str(err.value)
    x = torch.ones(1, 1, 16, 16)
    with pytest.raises(ValueError, match="NoiseModel"):
        total_variation_windowed(x, gaussian_psf(), noise=3.0, scheme=SMALL)


# --- Tikhonov's weight from the noise model ------------------------------------------------------------------------

def test_tikhonov_s_prior_weight_is_the_white_prior_s_noise_to_signal_ratio():
    """On a periodic image (period = window, no taper reaches a core), ``weight="prior"`` (the former default) is ``strength *
    TIKHONOV_NSR[0] * sigma_n^2 / sigma_x^2`` (order 0): the result equals the filter with that number given, computed here from the
    window's statistics; noise-free, it is the inverse filter (weight 0)."""
    from pipeline.restoration.tikhonov import TIKHONOV_NSR

    n = 64
    y0 = scene(n, n, c=1, seed=7)
    psf = gaussian_psf(1.0)
    tiled = y0.repeat(1, 1, 5, 5)
    noise = NoiseModel(400.0, 1e-6)
    centre = y0  # the statistics square covers the whole 64 px window: the period
    var_n = float(noise.variance(centre.mean()))
    H = torch.fft.rfft2(torch.fft.ifftshift(psf.psf_at_offsets(n) if hasattr(psf, "psf_at_offsets") else
                                            _kernel(psf, n)))
    cols = torch.full((n // 2 + 1,), 2.0, dtype=torch.float64)
    cols[0] = cols[-1] = 1
    gain = float(((H.abs() ** 2) * cols).sum() / n ** 2)
    var_x = (float(centre.var(correction=0)) - var_n) / gain
    w = 0.5 * TIKHONOV_NSR[0] * var_n / var_x
    scheme = WindowScheme(n, 32, 64)
    auto = tikhonov_windowed(tiled, psf, weight="prior", noise=noise, strength=0.5, order=0, scheme=scheme)
    given = tikhonov_windowed(tiled, psf, weight=w, order=0, scheme=scheme)
    mid = slice(2 * n, 3 * n)
    torch.testing.assert_close(auto[..., mid, mid], given[..., mid, mid], rtol=0, atol=1e-10)
    for rule in ("prior", "sure"):
        clean = tikhonov_windowed(tiled, psf, weight=rule, noise=NoiseModel(math.inf), scheme=scheme)
        torch.testing.assert_close(clean, tikhonov_windowed(tiled, psf, weight=0.0, scheme=scheme), rtol=0, atol=1e-12)


def _kernel(psf, n):
    rows = torch.tensor([0.0], dtype=torch.float64)
    return psf.fn(rows, rows, n)[0]
