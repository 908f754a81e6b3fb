"""Plug-and-play restoration on the spatially varying blur: wavelet sparsity (ISTA) and classical denoisers (HQS),
warm-started from the adaptive Wiener.

The problem is posed on the blur's own operator (:class:`pipeline.blur_operator.BlurOperator`, set up over the region
and ``context`` px around it as :func:`pipeline.restoration.richardson_lucy_windowed` does: the data ``y``, the
estimate reaching as far beyond as the windows read, unknown boundaries). The noise enters twice, both from the
method's ``noise`` (:class:`pipeline.camera_chain.NoiseModel`) evaluated on the Wiener estimate ``u0``
(:func:`pipeline.restoration.wiener_windowed` over the same region, its statistics over at most the window; outside it, where the estimate only feeds light
into the data, the observed image):

* the data term is the noise-weighted least squares ``1/2 ||A u - y||^2_W``, ``W = 1 / noise.variance(A u0)``
  (the variance at the expected observed signal; floored at the variance of one photo-electron's signal, so that
  a black pixel without read noise keeps a finite weight);
* the prior acts on the estimate in units of its local noise, ``xi = u / s`` with ``s = sqrt(noise.variance(u0))``
  (option ``domain="stabilised"``, the default: the first-order variance-stabilising transform around the Wiener
  estimate, the generalised Anscombe transform's slope; ``domain="linear"``: ``s`` the root-mean-square noise over the
  data, one number, the prior in the linear domain). In ``xi`` the sensor's noise has unit variance everywhere, so
  each denoiser's ``sigma`` follows from the noise model: 1 (times the option ``strength``) at the end.

Then, by ``denoiser``:

* ``wavelet``: proximal gradient (ISTA [1]_) on the convex objective
  ``F(xi) = 1/2 ||A s xi - y||^2_W + kappa ||Psi xi||_1`` (``Psi``: the orthonormal wavelet's detail coefficients,
  :data:`PNP_WAVELET`, periodised over ``xi`` zero-padded to a multiple of ``2^levels``; the padding's pixels are free
  variables the data do not see), step ``1 / L`` with ``L`` an upper bound of ``||W^1/2 A S||^2`` (the product of
  the non-negative matrix's largest row and column sums), so ``F`` never increases; ``kappa`` =
  :data:`PNP_WAVELET_THRESHOLD` x ``strength``. Soft thresholding is the exact proximal map.
* ``nlm``, ``tv``, ``bm3d``: half-quadratic splitting [2]_: ``xi`` <- a few conjugate-gradient steps on
  ``(S A^T W A S + mu_k) xi = S A^T W y + mu_k z`` from the last ``xi``; ``z`` <- the denoiser at ``sigma_k`` on ``xi``;
  ``sigma_k`` falling geometrically from :data:`PNP_SIGMA_START` to 1 (times ``strength``), ``mu_k =``
  :data:`PNP_LAMBDA` ``/ sigma_k^2`` (the schedule of [2]_ in units of the noise). Non-local means and TV are
  scikit-image's (``denoise_nl_means`` with its ``sigma``, ``denoise_tv_chambolle``), BM3D the ``bm3d`` package's
  (not a dependency: ``pip install bm3d``).

The operator, the conjugate gradients and ISTA's gradient steps run on the input's device and in its dtype; the
denoisers are numpy (PyWavelets, scikit-image, bm3d): each denoising step moves the estimate to the host in float64
and back. Batched over the images of ``observed`` (the denoisers image by image).

With no noise (``NoiseModel(math.inf)``) there is no prior: the Wiener start refined by least squares.

References
----------
.. [1] I. Daubechies, M. Defrise, C. De Mol, "An iterative thresholding algorithm for linear inverse problems with a
   sparsity constraint", Comm. Pure Appl. Math. 57(11), 1413-1457 (2004).
.. [2] K. Zhang, Y. Li, W. Zuo, L. Zhang, L. Van Gool, R. Timofte, "Plug-and-play image restoration with deep denoiser
   prior", IEEE TPAMI 44(10), 6360-6376 (2022) (half-quadratic splitting with a falling denoiser level).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from lenssim import PSFProvider

from ..blur import PAPER_SCHEME, WindowScheme
from ..blur_operator import BlurOperator, RegionProblem
from ..camera_chain import NoiseModel
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, register, windowed_margin
from .wiener import wiener_start
from .wiener import WIENER_PIXEL_STATS_PX

__all__ = ["pnp_windowed", "conjugate_gradient", "hqs_data_step", "PNP_DENOISERS", "PNP_DENOISER", "PNP_DOMAINS", "PNP_ITERATIONS", "PNP_STRENGTH",
           "PNP_CG_STEPS", "PNP_SIGMA_START", "PNP_LAMBDA", "PNP_WAVELET", "PNP_WAVELET_LEVELS",
           "PNP_WAVELET_THRESHOLD", "PNP_NLM_H", "PNP_TV_WEIGHT", "MAX_PNP_ITERATIONS", "PNP_CONTEXT_PX",
           "PNP_DENOISE_MARGIN_PX", "PNP_MEMORY"]

PNP_DENOISERS = ("wavelet", "nlm", "tv", "bm3d")
"""The priors (module docstring); ``bm3d`` needs the ``bm3d`` package, which is not a dependency."""

PNP_DENOISER = "tv"
"""The default prior. sRGB PSNR (dB) of 256 px crops through the paper's sensor (simulate_crops, the defaults
otherwise; times as multiples of the adaptive Wiener's in the same process, on two heavily loaded CPU cores): forest
5 deg, E2E design, ISO 400: Wiener 38.88, ``tv`` 39.18 (5.1x), ``wavelet`` 38.98 (1.8x; strength 2: 38.98),
``nlm`` 38.62 (5.9x); pier sunset 10 deg, RMS_W design, ISO 400: Wiener 32.25, ``tv`` 32.68 (strength 2: 32.70;
``domain=linear``: 32.61), ``wavelet`` at strength 3 32.35. With ``tv`` over forest 5 deg, pier 10 deg and portrait
0 deg, both designs, ISO 400 and 100 (benchmarks/bench_restoration_methods.py, 12 crop-ISOs): +0.28 dB over the Wiener
on average (-0.23 to +0.93 per crop; E2E +0.43 / +0.38 dB at ISO 400 / 100, RMS_W +0.18 / +0.12), none below the
sensor image, 6.4-9.6x the Wiener's mean time per photo."""

PNP_DOMAINS = ("stabilised", "linear")
"""Where the prior acts: on the estimate over its local noise (stabilised, the default) or on the linear image (module
docstring). Measured with ``tv`` on the pier sunset crop of :data:`PNP_DENOISER`: stabilised 32.68 dB, linear 32.61 dB
(one crop: the stabilised domain is the one the signal-dependent noise asks for, and it did no worse)."""

PNP_ITERATIONS = 4
"""Default number of outer iterations (ISTA steps, or HQS rounds of data step and denoising): with
:data:`PNP_CG_STEPS` and ``tv`` 4-5x the Wiener's time per 256 px crop (measured, :data:`PNP_DENOISER`), inside the
issue's 10x; 8 iterations of 3 steps took 13x (``tv``) and 22x (``nlm``) on a test scene."""

MAX_PNP_ITERATIONS = 200
"""Most outer iterations a run may ask for (each a few passes of the blur's operator and a denoising of the estimate:
0.2-2 s for a 256 px crop on two CPU cores, so minutes for 200)."""

PNP_STRENGTH = 1.0
"""Default multiplier of the prior's strength (the denoiser's sigma, the wavelet threshold): 1 is the level the
noise model gives."""

PNP_CG_STEPS = 2
"""Conjugate-gradient steps per HQS data step (each a forward and an adjoint pass of the operator), warm-started from
the last estimate."""

PNP_SIGMA_START = 2.0
"""The HQS denoiser's first level, in units of the sensor noise (falls geometrically to 1 x ``strength``): the Wiener
start is already denoised, so the schedule starts low (not tuned: see :data:`PNP_DENOISER` for what was measured)."""

PNP_LAMBDA = 0.23
"""Weight of the prior in HQS: ``mu_k = PNP_LAMBDA / sigma_k^2`` ([2]_'s value, in units of the noise; not tuned
here)."""

PNP_WAVELET = "db4"
"""The orthonormal wavelet of the sparsity prior (Daubechies, 4 vanishing moments)."""

PNP_WAVELET_LEVELS = 3
"""Decomposition levels of the wavelet prior."""

PNP_WAVELET_THRESHOLD = 1.0
"""The wavelet prior's weight ``kappa`` in units of the sensor noise (soft threshold ``kappa / L`` per ISTA step)."""

PNP_NLM_H = 0.8
"""Non-local means' filtering parameter ``h`` over its ``sigma`` (scikit-image's recommended ~0.8 with fast mode)."""

PNP_TV_WEIGHT = 1.0
"""TV denoising weight per unit of the denoiser's sigma (scikit-image's ``weight``; scale-equivariant)."""

PNP_DENOISE_MARGIN_PX = 16
"""The HQS denoisers work on the data and this many px around them (px; the rest of the estimate, which only feeds
light into the data, is left to the data step): the estimate reaches half a window beyond the data, up to ten times
the data's pixels for a 256 px crop, and the denoiser's time grows with its area. 16 px covers the support of
non-local means' patches and search window (2 + 5 px) and lets TV's smoothing run out beyond the data's edge."""

PNP_CONTEXT_PX = 0
"""Observed pixels (px) around the region fitted as data besides the region's own (as Richardson-Lucy's)."""

PNP_MEMORY = {"wavelet": WorkingMemory(copies=10, operator=True),
              "tv": WorkingMemory(copies=18, operator=True),
              "nlm": WorkingMemory(copies=20, operator=True),
              "bm3d": WorkingMemory(copies=64, operator=True)}
"""What the restoration holds beyond the adaptive Wiener (:class:`pipeline.restoration.WorkingMemory`) by denoiser, on a
whole frame the image itself (no tiles: the region is the frame): the Wiener start, the data mask, the noise weights
and scale ``s``, ``A^T W y``, the estimate ``xi`` and ``z``; for HQS the conjugate gradients' right-hand side,
residual, direction and products, for ISTA the gradient and the padded estimate (image-sized, float32); the denoisers'
float64 copies on the host (the estimate moved there, its channels-last copy, the denoiser's own arrays, the stacked
result: two float32 copies each) and the wavelet coefficients; and the operator's. Measured beyond the Wiener's peak,
less the kept OTFs, as :data:`pipeline.restoration.richardson_lucy.RL_MEMORY` (2 iterations; MiB at 256 px / 512 px,
and the image and padded copies they give): wavelet 9.7 / 34.4 (8.2 and 2.1), tv 14.9 / 55.5 (15.4 and 2.0), nlm
14.5 / 55.6 (16.6 and 1.2); bm3d (the ``bm3d`` package's own arrays; not a dependency) 27.8 / 162.5, and 387.5 at
768 px (1 iteration): 37 / 54 / 57 images, growing faster than the area at first. Declared above each image count
(the padded ones are the operator's): wavelet 10, tv 18, nlm 20, bm3d 64."""


def conjugate_gradient(apply, b: torch.Tensor, x: torch.Tensor, steps: int, dims=(-2, -1), Ax=None):
    """``steps`` conjugate-gradient steps on ``apply(x) = b`` (``apply`` symmetric positive definite) from ``x``, the
    systems over ``dims`` independent (one per image and channel: inner products over ``dims`` alone). ``Ax``:
    ``apply(x)`` where known (saves a product). Returns ``x`` and ``apply(x)`` (kept along: no further product)."""
    Ax = apply(x) if Ax is None else Ax
    r = b - Ax
    p = r.clone()
    rr = (r * r).sum(dim=dims, keepdim=True)
    tiny = torch.finfo(b.dtype).tiny
    for _ in range(steps):
        Ap = apply(p)
        pAp = (p * Ap).sum(dim=dims, keepdim=True)
        alpha = torch.where(pAp > 0, rr / pAp.clamp_min(tiny), torch.zeros_like(pAp))
        x = x + alpha * p
        Ax = Ax + alpha * Ap
        r = r - alpha * Ap
        rr_new = (r * r).sum(dim=dims, keepdim=True)
        p = r + torch.where(rr > 0, rr_new / rr.clamp_min(tiny), torch.zeros_like(rr)) * p
        rr = rr_new
    return x, Ax


def hqs_data_step(A: BlurOperator, weight: torch.Tensor, s: torch.Tensor, xi: torch.Tensor, z: torch.Tensor,
                  mu: float, *, y: torch.Tensor | None = None, rhs: torch.Tensor | None = None,
                  steps: int = PNP_CG_STEPS, normal_xi: torch.Tensor | None = None):
    """The HQS data step: ``steps`` conjugate-gradient steps from ``xi`` towards
    ``argmin 1/2 ||A (s xi) - y||^2_W + mu/2 ||xi - z||^2``, i.e. ``(S A^T W A S + mu) xi = S A^T W y + mu z``
    (``rhs``: ``S A^T W y`` where already computed, else from ``y``; ``normal_xi``: ``S A^T W A S xi`` where known).
    Returns the new ``xi`` and its ``S A^T W A S xi`` (for the next step: two passes of the operator fewer)."""
    if rhs is None:
        rhs = s * A.adjoint(weight * y)
    Ax = None if normal_xi is None else normal_xi + mu * xi
    xi, Ax = conjugate_gradient(lambda v: s * A.adjoint(weight * A.forward(s * v)) + mu * v, rhs + mu * z, xi, steps,
                                Ax=Ax)
    return xi, Ax - mu * xi


def _host(x: torch.Tensor) -> np.ndarray:
    return x.detach().to(device="cpu", dtype=torch.float64).numpy()


def _wavelet_shrink(xi: torch.Tensor, threshold: torch.Tensor) -> torch.Tensor:
    """Soft thresholding of the orthonormal wavelet's detail coefficients of ``xi`` (periodised; its sides
    multiples of ``2^levels``) at ``threshold`` (one per image and channel, ``(B, C, 1, 1)``): the proximal map of
    ``threshold ||Psi xi||_1``."""
    import pywt

    thr = _host(threshold)
    coeffs = pywt.wavedec2(_host(xi), PNP_WAVELET, mode="periodization", level=PNP_WAVELET_LEVELS, axes=(-2, -1))
    coeffs = [coeffs[0]] + [tuple(np.sign(d) * np.maximum(np.abs(d) - thr, 0) for d in level)
                            for level in coeffs[1:]]
    out = pywt.waverec2(coeffs, PNP_WAVELET, mode="periodization", axes=(-2, -1))
    return torch.from_numpy(out).to(dtype=xi.dtype, device=xi.device)


def _wavelet_l1(xi: torch.Tensor) -> np.ndarray:
    """``||Psi xi||_1`` per image and channel ``(B, C)``."""
    import pywt

    coeffs = pywt.wavedec2(_host(xi), PNP_WAVELET, mode="periodization", level=PNP_WAVELET_LEVELS, axes=(-2, -1))
    return sum(np.abs(d).sum(axis=(-2, -1)) for level in coeffs[1:] for d in level)


def _denoise(name: str, xi: torch.Tensor, sigma: float) -> torch.Tensor:
    """The classical denoiser ``name`` at noise level ``sigma`` on each image of ``xi`` ``(B, C, H, W)`` (host,
    float64)."""
    from skimage.restoration import denoise_nl_means, denoise_tv_chambolle

    out = []
    for img in _host(xi):
        hwc = np.ascontiguousarray(np.moveaxis(img, 0, -1))
        if name == "nlm":
            d = denoise_nl_means(hwc, h=PNP_NLM_H * sigma, sigma=sigma, fast_mode=True, channel_axis=-1)
        elif name == "tv":
            d = denoise_tv_chambolle(hwc, weight=PNP_TV_WEIGHT * sigma, channel_axis=-1)
        else:  # bm3d (checked importable before any work)
            import bm3d

            d = np.stack([bm3d.bm3d(hwc[..., c], sigma_psd=sigma) for c in range(hwc.shape[-1])], axis=-1)
        out.append(np.moveaxis(d, -1, 0))
    return torch.from_numpy(np.stack(out)).to(dtype=xi.dtype, device=xi.device)


def _check_options(denoiser, iterations, strength, domain, prefix=""):
    if denoiser not in PNP_DENOISERS:
        raise ValueError(f"{prefix}denoiser={denoiser!r} is not allowed: one of {', '.join(PNP_DENOISERS)}")
    if denoiser == "bm3d":
        try:
            import bm3d  # noqa: F401
        except ImportError:
            raise ValueError(f"{prefix}denoiser='bm3d' needs the bm3d package, which is not installed: "
                             "pip install bm3d") from None
    if isinstance(iterations, bool) or not (isinstance(iterations, int) and 1 <= iterations <= MAX_PNP_ITERATIONS):
        raise ValueError(f"{prefix}iterations={iterations!r} is not allowed: an integer from 1 to "
                         f"{MAX_PNP_ITERATIONS}")
    if isinstance(strength, bool) or not (isinstance(strength, (int, float)) and math.isfinite(strength)
                                          and strength >= 0):
        raise ValueError(f"{prefix}strength={strength!r} is not allowed: a finite number >= 0 (1: the level the "
                         "noise model gives; 0: no prior)")
    if domain not in PNP_DOMAINS:
        raise ValueError(f"{prefix}domain={domain!r} is not allowed: one of {', '.join(PNP_DOMAINS)}")


def pnp_windowed(observed: torch.Tensor, psf: PSFProvider, *, noise: NoiseModel, denoiser: str = PNP_DENOISER,
                 iterations: int = PNP_ITERATIONS, strength: float = PNP_STRENGTH, domain: str = "stabilised",
                 scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None,
                 context: int = PNP_CONTEXT_PX, progress=None, trace: list | None = None) -> torch.Tensor:
    """Plug-and-play restoration of ``observed`` ``(B, C, H, W)`` (linear) on the windowed blur of ``psf`` with the
    noise ``noise`` describes (module docstring): ``region = (r0, r1, c0, c1)`` the pixels restored (zeros elsewhere;
    default all), fitted with the observed pixels up to ``context`` px around it. ``trace``: a list that the wavelet
    ISTA appends its objective ``F`` to (before the first step and after each; ``(B, C)``, per image and channel). ``progress(k)`` is called after each
    iteration with its share of the region's windows."""
    check_image(observed, "observed")
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: expected a pipeline.camera_chain.NoiseModel")
    _check_options(denoiser, iterations, strength, domain)
    if isinstance(context, bool) or not (isinstance(context, int) and context >= 0):
        raise ValueError(f"context={context!r} is not allowed: an integer >= 0 (px)")
    problem = RegionProblem(observed, psf, scheme=scheme, optical_center=optical_center, region=region, context=context)
    y, A, d = problem.y, problem.A, problem.local_data
    inside = problem.mask()
    u = wiener_start(problem, observed, psf, noise=noise, scheme=scheme)  # the observed image beyond the data
    # the noise: variance floored at one photo-electron's signal; none at all -> plain least squares, no prior
    floor = noise.variance(1.0 / noise.electrons_per_unit) if math.isfinite(noise.electrons_per_unit) else 0.0
    floor = max(floor, noise.signal_independent_var)
    noisy = floor > 0
    if noisy:
        weight = inside / noise.variance(A.forward(u)).clamp_min(floor)
        var_u = noise.variance(u).clamp_min(floor)
        if domain == "stabilised":
            s = var_u.sqrt()
        else:  # one number per image and channel: the root-mean-square noise over the data
            s = (var_u * inside).sum(dim=(-2, -1), keepdim=True).div(inside.sum(dim=(-2, -1), keepdim=True)).sqrt()
            s = s.expand_as(u)
    else:
        weight, s, strength = inside, torch.ones_like(u), 0.0
    Aty = A.adjoint(weight * y)

    tick = problem.ticks(iterations, progress)

    xi = u / s
    if denoiser == "wavelet":
        xi = _ista(A, y, Aty, weight, s, xi, strength * PNP_WAVELET_THRESHOLD, iterations, tick, trace)
    else:
        rhs = s * Aty
        sigmas = [PNP_SIGMA_START * (1.0 / PNP_SIGMA_START) ** (k / max(iterations - 1, 1)) for k in range(iterations)]
        z, normal_xi = xi, None
        m = PNP_DENOISE_MARGIN_PX
        box = (max(d[0] - m, 0), d[1] + m, max(d[2] - m, 0), d[3] + m)
        for k, sig in enumerate(sigmas):
            mu = PNP_LAMBDA / sig ** 2 if strength > 0 else 0.0
            xi, normal_xi = hqs_data_step(A, weight, s, xi, z, mu, rhs=rhs, normal_xi=normal_xi)
            if strength > 0:
                z = xi.clone()
                z[..., box[0]:box[1], box[2]:box[3]] = _denoise(denoiser, xi[..., box[0]:box[1], box[2]:box[3]],
                                                                sig * strength)
                xi = z if k == iterations - 1 else xi
            tick(k)
    return problem.place(xi * s, observed)


def _ista(A, y, Aty, weight, s, xi, kappa, iterations, tick, trace):
    """ISTA on ``1/2 ||A s xi - y||^2_W + kappa ||Psi xi||_1`` (module docstring) from ``xi``."""
    # L <= (max row sum) (max column sum) of the non-negative W^1/2 A S
    root_w = weight.sqrt()
    rows = (root_w * A.forward(s)).amax(dim=(-2, -1), keepdim=True)
    cols = (s * A.adjoint(root_w)).amax(dim=(-2, -1), keepdim=True)
    step = 1.0 / (rows * cols).clamp_min(torch.finfo(xi.dtype).tiny)  # per image and channel
    h, w = xi.shape[-2:]
    m = 2 ** PNP_WAVELET_LEVELS
    ph, pw = -h % m, -w % m  # free pixels padding xi to the wavelet's period (the data do not see them)
    ext = torch.nn.functional.pad(xi, (0, pw, 0, ph), mode="replicate") if ph or pw else xi

    def objective(e):  # per image and channel
        r = A.forward(s * e[..., :h, :w]) - y
        return (0.5 * (weight * r * r).sum(dim=(-2, -1)).to(device="cpu", dtype=torch.float64).numpy()
                + kappa * _wavelet_l1(e))

    if trace is not None:
        trace.append(objective(ext))
    for k in range(iterations):
        grad = torch.zeros_like(ext)
        grad[..., :h, :w] = s * (A.adjoint(weight * A.forward(s * ext[..., :h, :w])) - Aty)
        ext = ext - step * grad
        if kappa > 0:
            ext = _wavelet_shrink(ext, step * kappa)
        if trace is not None:
            trace.append(objective(ext))
        tick(k)
    return ext[..., :h, :w]


def _check(options, scheme):
    _check_options(options["denoiser"], options["iterations"], options["strength"], options["domain"],
                   prefix="pnp option ")
    if scheme is not None and WIENER_PIXEL_STATS_PX > scheme.window - scheme.core:  # the Wiener start's own rule
        raise ValueError(f"the pnp restoration (from the Wiener) needs a window at least {WIENER_PIXEL_STATS_PX} px "
                         f"larger than the core; window={scheme.window}, core={scheme.core}")


def _pnp(observed, psf, *, noise, scheme, optical_center=None, region=None, progress=None, denoiser=PNP_DENOISER,
         iterations=PNP_ITERATIONS, strength=PNP_STRENGTH, domain="stabilised"):
    return pnp_windowed(observed, psf, noise=noise, denoiser=denoiser, iterations=iterations, strength=strength,
                        domain=domain, scheme=scheme, optical_center=optical_center, region=region, progress=progress)


register(RestorationMethod(
    "pnp", "plug-and-play", "plug-and-play on the windowed blur's operator from the Wiener: wavelet sparsity (ISTA) or "
    "a classical denoiser (non-local means, TV, BM3D; half-quadratic splitting), its level from the noise model",
    _pnp, (("denoiser", PNP_DENOISER), ("iterations", PNP_ITERATIONS), ("strength", PNP_STRENGTH),
           ("domain", "stabilised")),
    margin=lambda scheme: windowed_margin(scheme) + PNP_CONTEXT_PX, check=_check,
    memory=lambda options: PNP_MEMORY[options["denoiser"]]))
