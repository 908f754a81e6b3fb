"""Total-variation restoration on the spatially varying blur: a primal-dual solver on the blur's own operator.

Over the region asked for (the data ``D``) and as far around it as the windows read (the estimate ``u``, with unknown
boundaries as in :mod:`pipeline.restoration.richardson_lucy`), with ``A`` the blur's operator
(:class:`pipeline.blur_operator.BlurOperator`) it minimises the noise-weighted least squares plus the isotropic total
variation::

    E(u) = 1/2 sum_{i in D} (A u - y)_i^2 / var_i  +  lam TV(u),        u >= 0 (option ``nonneg``)

``var_i = noise.variance((A u_0)_i)``, the camera chain's noise description (:class:`pipeline.camera_chain.NoiseModel`)
at the blurred warm start (a denoised estimate of the expected signal: the noisy data would give its dark noise
excursions too little variance). Written as ``sigma2 * E``, with ``sigma2`` the mean of ``var`` over the data
(:func:`mean_noise_variance`), the solver's weights ``w_i = sigma2 / var_i`` are of order one and the TV weight
``mu = lam sigma2`` is in image units; ``mu`` follows from the noise model (:func:`tv_weight`)::

    mu = strength * TV_STRENGTH * sigma2 / g,        g = mean |grad u_0| over the data

the MAP weight of a Laplacian prior on the gradient (scale ``g``) under Gaussian noise of variance ``sigma2``, with
the constant :data:`TV_STRENGTH` calibrated once on photos (its docstring) and ``strength`` a user's multiplier.
``TV(u) = sum |grad u|``, forward differences (none across the estimate's last row and column), the norm over the two
directions and, with ``coupled`` (default), over the colour channels too (one edge set for all channels).

The solver is Chambolle and Pock's primal-dual algorithm [1]_ on ``K = [A; grad]`` (the data term and the TV each by
their proximal maps, both closed forms), warm-started from the adaptive Wiener
(:func:`pipeline.restoration.wiener.wiener_windowed` over the data; the estimate's band around it starts at the
observed image): a few tens of iterations, each a forward and an adjoint pass of the operator. ``||A||`` is taken by
Schur's test (two passes: :func:`operator_norm_bound`). :func:`tv_denoise` (Chambolle's projection [2]_, the TV proximal map) is the same TV for a
plug-and-play scheme.

References
----------
.. [1] A. Chambolle, T. Pock, "A first-order primal-dual algorithm for convex problems with applications to imaging",
   J. Math. Imaging Vis. 40, 120-145 (2011), Algorithm 1 (theta = 1).
.. [2] A. Chambolle, "An algorithm for total variation minimization and applications", J. Math. Imaging Vis. 20,
   89-97 (2004).
.. [3] L. I. Rudin, S. Osher, E. Fatemi, "Nonlinear total variation based noise removal algorithms", Physica D 60,
   259-268 (1992).
"""

from __future__ import annotations

import torch

from lenssim import PSFProvider

from ..blur import PAPER_SCHEME, WindowScheme
from ..blur_operator import BlurOperator, RegionProblem
from ..camera_chain import NoiseModel
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, mean_noise_variance, register, windowed_margin
from .wiener import wiener_start

__all__ = ["total_variation_windowed", "tv_primal_dual", "tv_denoise", "tv_objective", "tv_weight", "image_gradient",
           "image_divergence", "TV_STRENGTH", "TV_ITERATIONS", "MAX_TV_ITERATIONS", "operator_norm_bound",
           "TV_CONTEXT_PX", "TV_STEP_RATIO", "TV_MEMORY"]

TV_STRENGTH = 0.3
"""The constant of the noise-derived TV weight ``mu = strength * TV_STRENGTH * sigma2 / g`` (module docstring;
dimensionless), at the default :data:`TV_ITERATIONS` (15) from the Wiener start: on the portrait's centre crop (E2E
design, ISO 400; sensor image 32.25 dB, adaptive Wiener 37.17) 0.3 / 1 / 3 restored 38.09 / 37.16 / 35.39 dB."""

TV_ITERATIONS = 15
"""Default primal-dual iterations from the Wiener start (each a forward and an adjoint pass of the operator)."""

MAX_TV_ITERATIONS = 1000
"""Most iterations a run may ask for: bounds the work (two operator passes each, 0.15-0.2 s for a 256 px crop on two
quiet CPU cores: a few minutes for 1000), far past the tens the warm start needs."""

TV_STEP_RATIO = 3.0
"""Primal over dual step (``tau / sigma = ratio^2``, ``tau sigma L^2 = 0.99^2``): the image moves in larger steps than
the duals. On a blurred (Gaussian, 1.5 px) noisy block scene from the Wiener start with the noise-derived weight, the
share of the objective's excess left after 15 iterations was 0.74 / 0.48 / 0.35 / 0.48 / 0.88 for ratios 0.3 / 1 / 3
/ 10 / 30 (and 9.6 at 100: too large a primal step oscillates)."""

TV_NORM_MARGIN = 1.02
"""Factor on the bound of ``||A||`` (:func:`operator_norm_bound`) before the step sizes are set."""

TV_CONTEXT_PX = 0
"""Observed pixels (px) around the region fitted as data besides the region's own (as Richardson-Lucy's)."""

TV_MEMORY = WorkingMemory(copies=12, operator=True)
"""What the solver holds beyond the adaptive Wiener (:class:`pipeline.restoration.WorkingMemory`), on a whole frame the
image itself: the Wiener start, the data mask, the blurred start, the noise variance and the weights, the estimate and
its extrapolation, the data dual, the TV dual (two images: rows and columns) and the gradient, projection and step
temporaries (image-sized), and the operator's. Measured as :data:`pipeline.restoration.richardson_lucy.RL_MEMORY`
(beyond the Wiener's peak, less the kept OTFs): 10.0 MiB at 256 px, 37.0 MiB at 512 px, i.e. 10.0 image and 1.5 padded
copies; declared 12 image copies."""

TV_FLOOR = 1e-12
"""Least mean gradient and noise variance (image units) a weight divides by: a flat or noise-free image."""


def image_gradient(u: torch.Tensor) -> torch.Tensor:
    """Forward differences of ``u`` ``(B, C, H, W)`` down the rows and along the columns: ``(B, C, 2, H, W)``, zero
    across the last row and column (Neumann)."""
    g = torch.zeros(u.shape[:2] + (2,) + u.shape[2:], dtype=u.dtype, device=u.device)
    g[:, :, 0, :-1] = u[..., 1:, :] - u[..., :-1, :]
    g[:, :, 1, :, :-1] = u[..., :, 1:] - u[..., :, :-1]
    return g


def image_divergence(q: torch.Tensor) -> torch.Tensor:
    """``-grad^T q`` for ``q`` ``(B, C, 2, H, W)``: the divergence, the negative adjoint of :func:`image_gradient`."""
    d = torch.zeros(q.shape[:2] + q.shape[3:], dtype=q.dtype, device=q.device)
    d[..., :-1, :] += q[:, :, 0, :-1]
    d[..., 1:, :] -= q[:, :, 0, :-1]
    d[..., :, :-1] += q[:, :, 1, :, :-1]
    d[..., :, 1:] -= q[:, :, 1, :, :-1]
    return d


def _norm_dims(coupled: bool):
    return (1, 2) if coupled else (2,)


def tv_objective(u, y, forward, weights, mu, *, coupled: bool = True) -> torch.Tensor:
    """``1/2 sum w (A u - y)^2 + sum mu |grad u|`` per image ``(B,)`` (``forward``: ``u -> A u``; ``weights`` 0
    outside the data; ``mu`` broadcast to ``(B, C or 1, 1, 1)``)."""
    r = forward(u) - y
    tv = image_gradient(u).square().sum(dim=_norm_dims(coupled), keepdim=True).sqrt()
    tv = (tv[:, :, 0] * mu) if not coupled else tv[:, 0, 0] * mu[:, 0]
    return 0.5 * (weights * r.square()).sum(dim=(1, 2, 3)) + tv.flatten(1).sum(dim=1)


def _project(q, mu, coupled):
    """``q`` projected onto ``|q| <= mu`` (pointwise norm over the directions, and the channels where coupled)."""
    n = q.square().sum(dim=_norm_dims(coupled), keepdim=True).sqrt_()
    return q.div_((n / mu.unsqueeze(2)).clamp_min_(1))


def tv_primal_dual(y, forward, adjoint, weights, mu, u0, *, iterations: int, norm: float, coupled: bool = True,
                   nonneg: bool = True, ratio: float = None, progress=None) -> torch.Tensor:
    """Chambolle-Pock (module docstring, [1]_) for ``min_u 1/2 sum w (A u - y)^2 + sum mu |grad u|`` (``u >= 0``
    with ``nonneg``), from ``u0``, ``iterations`` steps; ``forward``/``adjoint``: ``A`` and ``A^T`` on ``(B, C, H,
    W)``; ``weights`` (>= 0; 0 where there are no data) and ``y`` as ``A u``; ``mu`` ``(B, C or 1, 1, 1)`` (one
    per channel, or per image where ``coupled``); ``norm``: a bound on ``||A||``. ``progress(k)`` after step ``k``.

    The dual of the data term is its closed-form proximal map ``p <- w (p + s (A u - y)) / (w + s)``, of the TV the
    projection onto ``|q| <= mu``; steps ``t = 0.99 ratio / L``, ``s = 0.99 / (ratio L)``, ``L = sqrt(norm^2 + 8)``
    (``||grad||^2 <= 8``; ``ratio`` default :data:`TV_STEP_RATIO`)."""
    L = (norm * norm + 8.0) ** 0.5
    ratio = TV_STEP_RATIO if ratio is None else ratio
    tau, sigma = 0.99 * ratio / L, 0.99 / (ratio * L)
    u = u0.clone()
    ubar = u.clone()
    p = torch.zeros_like(y)
    q = torch.zeros(u.shape[:2] + (2,) + u.shape[2:], dtype=u.dtype, device=u.device)
    shrink = weights / (weights + sigma)  # the data term's proximal factor (0 without data)
    for k in range(iterations):
        p.add_(forward(ubar).sub_(y), alpha=sigma).mul_(shrink)
        q = _project(q.add_(image_gradient(ubar), alpha=sigma), mu, coupled)
        step = adjoint(p).sub_(image_divergence(q)).mul_(tau)
        new = (u - step).clamp_min_(0) if nonneg else u - step
        ubar = torch.mul(new, 2).sub_(u)
        u = new
        if progress is not None:
            progress(k)
    return u


def tv_denoise(y: torch.Tensor, mu, *, iterations: int = 100, coupled: bool = True) -> torch.Tensor:
    """The TV proximal map ``argmin_u 1/2 ||u - y||^2 + sum mu |grad u|`` of ``y`` ``(B, C, H, W)`` (``mu`` a number
    or a tensor broadcast to ``(B, C or 1, 1, 1)``) by Chambolle's projection [2]_: the dual ``q`` (``|q| <= 1``)
    iterates ``q <- (q + t grad(div q - y / mu)) / (1 + t |grad(div q - y / mu)|)``, ``t = 1/8``, and
    ``u = y - mu div q``. For a plug-and-play scheme's TV denoiser (on ``y``'s device and in its dtype)."""
    check_image(y, "y")
    if not isinstance(mu, torch.Tensor):
        mu = torch.full((1, 1, 1, 1), float(mu), dtype=y.dtype, device=y.device)
    mu = mu.clamp_min(TV_FLOOR)
    dims = _norm_dims(coupled)
    q = torch.zeros(y.shape[:2] + (2,) + y.shape[2:], dtype=y.dtype, device=y.device)
    t = 0.125
    for _ in range(iterations):
        g = image_gradient(image_divergence(q) - y / mu)
        n = g.square().sum(dim=dims, keepdim=True).sqrt()
        q = (q + t * g) / (1 + t * n)
    return y - mu * image_divergence(q)


def tv_weight(noise_var: torch.Tensor, u0: torch.Tensor, data, *, strength: float, coupled: bool) -> torch.Tensor:
    """The TV weight ``mu = strength * TV_STRENGTH * sigma2 / g`` (module docstring): ``noise_var`` ``(B, C, 1, 1)``
    the mean noise variance over the data, ``g`` the mean gradient norm of ``u0`` there (``data`` ``(r0, r1, c0,
    c1)``); ``(B, C, 1, 1)``, or ``(B, 1, 1, 1)`` (the channels' mean) where ``coupled``."""
    r0, r1, c0, c1 = data
    g = image_gradient(u0[..., r0:r1, c0:c1]).square().sum(dim=2).sqrt().mean(dim=(-2, -1), keepdim=True)
    mu = strength * TV_STRENGTH * noise_var / g.clamp_min(TV_FLOOR)
    return mu.mean(dim=1, keepdim=True) if coupled else mu


def operator_norm_bound(A: BlurOperator, mask: torch.Tensor) -> float:
    """A bound on ``||A||`` from two passes: ``||A||^2 <= max_i sum_j |A_ij| * max_j sum_i |A_ij|`` (Schur's test),
    the row sums ``A 1`` and column sums ``A^T 1`` where ``A >= 0`` (a blur by non-negative PSFs, blended by tents);
    :data:`TV_NORM_MARGIN` on top covers the transforms' rounding and a PSF's small negative lobes. ``mask``: ones
    over the operator's region, zeros elsewhere, like the images it maps. About 1 for a blur (its rows sum to 1)."""
    rows = float(A.forward(torch.ones_like(mask)).abs().amax())
    cols = float(A.adjoint(mask).abs().amax())
    return TV_NORM_MARGIN * (rows * cols) ** 0.5


def _check_options(iterations, context, strength, coupled, nonneg, prefix=""):
    if isinstance(iterations, bool) or not (isinstance(iterations, int) and 1 <= iterations <= MAX_TV_ITERATIONS):
        raise ValueError(f"{prefix}iterations={iterations!r} is not allowed: an integer from 1 to {MAX_TV_ITERATIONS}")
    if isinstance(context, bool) or not (isinstance(context, int) and context >= 0):
        raise ValueError(f"{prefix}context={context!r} is not allowed: an integer >= 0 (px)")
    if isinstance(strength, bool) or not (isinstance(strength, (int, float)) and 0 < strength < float("inf")):
        raise ValueError(f"{prefix}strength={strength!r} is not allowed: a finite number > 0 (a multiplier of the "
                         "noise-derived weight)")
    for k, v in (("coupled", coupled), ("nonneg", nonneg)):
        if not isinstance(v, bool):
            raise ValueError(f"{prefix}{k}={v!r} is not allowed: true or false")


def total_variation_windowed(observed: torch.Tensor, psf: PSFProvider, *, noise: NoiseModel,
                             iterations: int = TV_ITERATIONS, strength: float = 1.0, coupled: bool = True,
                             nonneg: bool = True, scheme: WindowScheme = PAPER_SCHEME, optical_center=None,
                             region=None, context: int = TV_CONTEXT_PX, progress=None) -> torch.Tensor:
    """TV restoration of ``observed`` ``(B, C, H, W)`` (linear) on the windowed blur of ``psf`` (module docstring):
    ``region = (r0, r1, c0, c1)`` the pixels restored (zeros elsewhere; default all), fitted with the observed pixels
    up to ``context`` px around it; ``strength`` multiplies the noise-derived weight; ``iterations`` primal-dual
    steps from the adaptive Wiener. ``progress(k)`` is called with shares of the region's windows."""
    check_image(observed, "observed")
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: expected a pipeline.camera_chain.NoiseModel")
    _check_options(iterations, context, strength, coupled, nonneg)
    problem = RegionProblem(observed, psf, scheme=scheme, optical_center=optical_center, region=region, context=context)
    y, A, d = problem.y, problem.A, problem.local_data
    u0 = wiener_start(problem, observed, psf, noise=noise, scheme=scheme)  # the observed image beyond the data
    if nonneg:
        u0.clamp_min_(0)
    mask = problem.mask()
    blurred = A.forward(u0)  # the blurred start: a denoised expected signal, where the noise is evaluated
    var = noise.variance(blurred).clamp_min(TV_FLOOR)
    sigma2 = mean_noise_variance(noise, blurred[..., d[0]:d[1], d[2]:d[3]]).clamp_min(TV_FLOOR)
    weights = mask * sigma2 / var
    mu = tv_weight(sigma2, u0, d, strength=strength, coupled=coupled)
    norm = operator_norm_bound(A, mask)
    step = problem.ticks(iterations, progress)

    u = tv_primal_dual(y, A.forward, A.adjoint, weights, mu, u0, iterations=iterations, norm=norm, coupled=coupled, nonneg=nonneg, progress=step)
    return problem.place(u, observed)


def _check(options, scheme):
    _check_options(options["iterations"], TV_CONTEXT_PX, options["strength"], options["coupled"], options["nonneg"],
                   prefix="tv option ")


def _tv(observed, psf, *, noise, scheme, optical_center=None, region=None, progress=None, iterations=TV_ITERATIONS,
        strength=1.0, coupled=True, nonneg=True):
    return total_variation_windowed(observed, psf, noise=noise, iterations=iterations, strength=strength,
                                    coupled=coupled, nonneg=nonneg, scheme=scheme, optical_center=optical_center,
                                    region=region, progress=progress)


register(RestorationMethod(
    "tv", "total variation", "total-variation restoration on the windowed blur's operator (primal-dual, weight from "
    "the noise model, from the adaptive Wiener)", _tv,
    (("iterations", TV_ITERATIONS), ("strength", 1.0), ("coupled", True), ("nonneg", True)),
    margin=lambda scheme: windowed_margin(scheme) + TV_CONTEXT_PX, check=_check, memory=TV_MEMORY))
