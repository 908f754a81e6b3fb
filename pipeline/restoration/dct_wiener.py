"""The adaptive Wiener refined by a local DCT: a regularised inverse in each window of the blur, denoised in the
sliding 8 x 8 DCT by an empirical Wiener filter that knows the inverse's coloured noise, the adaptive Wiener as the
pilot.

In every window (the scheme, local PSFs and blending of :mod:`pipeline.blur`, the statistics of
:class:`pipeline.restoration.wiener.WindowModel`: local mean ``mu``, noise variance ``n2`` at it, signal variance
``s2``, image model ``P``) and channel:

1. the **pilot** ``p``: the adaptive Wiener filter, ``G = conj(H) P / (abs(H)^2 P + n2 / s2)`` on the tapered ``y - mu``;
2. the **regularised inverse** ``r``: the same filter with the noise term scaled by ``alpha`` < 1,
   ``G_r = conj(H) P / (abs(H)^2 P + alpha n2 / s2)``: sharper than the Wiener, noisier, its noise coloured with the
   power spectrum ``N(f) = n2 abs(H G_r)^2`` (white sensor noise of variance ``n2`` through the filter);
3. over the window's core and 7 px around it (so that every core pixel is covered by all 64 patches that contain
   it), every 8 x 8 patch of ``r`` and of ``p`` in the orthonormal 2-D DCT-II; each of ``r``'s coefficients ``c`` is
   shrunk by the empirical Wiener factor ``c_p^2 / (c_p^2 + v_j)``, ``c_p`` the pilot's coefficient and ``v_j`` the
   variance of coefficient ``j`` under the noise ``N`` (:func:`coefficient_noise_variance`: exact for stationary
   noise in the window, from its autocovariance over the patch's lags); with ``local_noise`` ``v_j`` is scaled per
   patch by the noise model at the patch's own mean over its value at the window's mean (the photon noise follows the
   local brightness within a window); a three-channel image is shrunk in the opponent colour space ([3]_, option
   ``colour``): ``r`` and ``p`` go through the orthonormal transform ``T`` (luminance and two colour differences),
   the channels' independent noise gives each transformed coefficient the variance ``sum_c T_kc^2 v_cj``, and the
   result comes back through ``T``'s transpose;
4. the patches back, each weighted by the inverse of its estimate's noise variance ``1 / sum_j v_j w_j^2`` ([1]_'s
   aggregation weights), averaged where they overlap; ``passes`` > 1 takes the result as the next pass's pilot.

The result keeps the core and is blended as the Wiener's. The Wiener's shrinkage is one factor per spatial
frequency over a window of hundreds of pixels; the DCT's is one per coefficient of each 8 x 8 patch, so it keeps an
edge sharp where the Wiener would smooth it and smooths a flat patch more than the Wiener can: the step from a linear
filter to a transform-domain shrinkage (the second stage of BM3D, here without block matching). No noise
(``NoiseModel(math.inf)``) and no blur give the identity.

References
----------
.. [1] K. Dabov, A. Foi, V. Katkovnik, K. Egiazarian, "Image restoration by sparse 3D transform-domain collaborative
   filtering", Proc. SPIE 6812, 681207 (2008) (the regularised inverse and regularised Wiener inverse, with coloured
   noise in the transform domain; the aggregation weights).
.. [2] G. Yu, G. Sapiro, "DCT image denoising: a simple and effective image denoising algorithm", Image Processing
   On Line 1, 292-296 (2011) (sliding 8 x 8 DCT shrinkage).
.. [3] K. Dabov, A. Foi, V. Katkovnik, K. Egiazarian, "Color image denoising via sparse 3D collaborative filtering
   with grouping constraint in luminance-chrominance space", Proc. IEEE ICIP 2007, I-313-I-316 (the opponent colour
   transform).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from lenssim import PSFProvider
from lenssim.torch_utils import HOST

from ..blur import PAPER_SCHEME, WindowScheme, apply_windowed, core_irfft2, window_chunk
from ..camera_chain import NoiseModel
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, register
from .wiener import (WIENER_FIT_LEAST_PX, WIENER_RHO0, WIENER_STATS_PX, WIENER_TAPER_PX, WindowModel,
                     check_wiener_options)

__all__ = ["dct_wiener_windowed", "dct_basis", "opponent_matrix", "opponent_variance", "coefficient_noise_variance",
           "dct_shrink", "DCT_PATCH_PX", "DCT_ALPHA", "DCT_PASSES", "DCT_LOCAL_NOISE", "DCT_COLOURS", "DCT_COLOUR",
           "MAX_DCT_PASSES", "DCT_LIVE_COPIES"]

DCT_PATCH_PX = 8
"""Side (px) of the DCT's patches ([2]_'s 8 x 8)."""

DCT_ALPHA = 0.1
"""Default noise weight of the regularised inverse relative to the Wiener's (0 < alpha <= 1; 1: the Wiener itself,
denoised again). sRGB PSNR (dB) of 256 px crops through the paper's sensor (benchmarks/bench_restoration_methods.py,
the Wiener beside it on the same noise draws, 2 CPU cores), on the 28 crop-ISOs of docs/restoration.md (three photos at
0/5/10 deg, both designs, ISO 400 and 100; the Wiener 37.36 dB). Channel by channel (``colour=rgb``): 0.5 37.69, 0.3
37.78, 0.2 37.83, 0.3 with 2 passes 37.84 at 1.2x the time of one pass (a lower weight gained on the sharp axis crops,
+0.8 to +2.4 dB at 0.1 on the pier's, and lost on the pier's 10 deg crops, where the channels' noise came back as
coloured blotches). In the opponent space (:data:`DCT_COLOUR`): 0.2 38.06, 0.15 38.12, 0.1 38.18 (E2E +1.04 / +1.15 at
ISO 400 / 100, RMS_W +0.54 / +0.55; above the Wiener on 26 of 28, -0.36 to +3.63 dB); none below the sensor image."""

DCT_PASSES = 1
"""Default number of shrinkage passes (each one's result the next one's pilot; :data:`DCT_ALPHA` for what 2 did)."""

DCT_LOCAL_NOISE = False
"""Default of ``local_noise`` (each patch's coefficient variances scaled by the noise model at the patch's mean over its
value at the window's mean). Measured on the 28 crop-ISOs of :data:`DCT_ALPHA`, channel by channel at ``alpha`` 0.3:
off 37.78 dB, on 37.67 (the Wiener 37.36); on gained 0.1 dB on the pier's 10 deg E2E crop at ISO 400 and lost up to
0.45 dB elsewhere (the portrait's RMS_W crop; a likely reason, not tested: the patch's mean is the pilot's, blurred by
the filter, not the brightness the noise came from)."""

DCT_COLOURS = ("opponent", "rgb")
"""The colour spaces the shrinkage may run in: ``opponent`` (:func:`opponent_matrix`: the shrinkage of a
three-channel image in luminance and two colour differences, each with its coefficients' noise variances mixed from the
channels') or ``rgb`` (each channel on its own). Images of another number of channels are shrunk channel by channel."""

DCT_COLOUR = "opponent"
"""Default colour space of the shrinkage (:data:`DCT_COLOURS`). A photo's channels are strongly correlated: in the
opponent space most of the signal is in the luminance and the colour differences hold mostly noise, which the
shrinkage then removes, where channel by channel it left coloured blotches (the pier's 10 deg crop, RMS_W design). On
the 28 crop-ISOs of :data:`DCT_ALPHA` at ``alpha`` 0.2: channel by channel 37.83 dB, opponent 38.06 (+0.23; +0.20 to
+0.30 on each design and ISO's mean)."""

MAX_DCT_PASSES = 8
"""Most passes a run may ask for."""

DCT_LIVE_COPIES = 6
"""Coefficient-sized tensors (``n^2`` values per pixel of the core and its 7 px band) a window holds at once in
:func:`dct_shrink` (the inverse's coefficients, the pilot's squared, the factors, the weighted product, the variances
per patch, the transposed convolution's output): with the Wiener's ``3 window^2`` they size the batches of windows
(:func:`pipeline.blur.window_chunk`'s budget)."""


def dct_basis(n: int = DCT_PATCH_PX, dtype=torch.float64, device=None) -> torch.Tensor:
    """The orthonormal 2-D DCT-II basis of ``n x n`` patches as convolution kernels ``(n^2, 1, n, n)``: kernel
    ``j = a n + b`` is ``M[a, i] M[b, k]`` with ``M[a, i] = sqrt(2 / n) cos(pi (i + 1/2) a / n)`` (``a = 0``: ``1 /
    sqrt(n)``), so ``conv2d(x, basis)`` gives every patch's coefficients (scipy's ``dctn(..., norm="ortho")``)."""
    i = torch.arange(n, dtype=torch.float64, device=HOST)
    M = torch.cos(math.pi * (i[None, :] + 0.5) * i[:, None] / n) * math.sqrt(2 / n)
    M[0] /= math.sqrt(2)
    return torch.einsum("ai,bk->abik", M, M).reshape(n * n, 1, n, n).to(dtype=dtype, device=device)


def opponent_matrix(dtype=torch.float64, device=None) -> torch.Tensor:
    """The orthonormal opponent colour transform ``(3, 3)`` (rows: luminance ``(R + G + B) / sqrt(3)``, red-blue
    ``(R - B) / sqrt(2)``, green-magenta ``(R - 2 G + B) / sqrt(6)``; BM3D's colour transform [3]_): ``T @ rgb``;
    its transpose is its inverse."""
    T = torch.tensor([[1.0, 1.0, 1.0], [1.0, 0.0, -1.0], [1.0, -2.0, 1.0]], dtype=torch.float64, device=HOST)
    return (T / T.norm(dim=1, keepdim=True)).to(dtype=dtype, device=device)


def opponent_variance(variance: torch.Tensor, dim: int) -> torch.Tensor:
    """The variances of the opponent channels' transform coefficients from those of three independent channels along
    ``dim`` (same shape): ``sum_c T_kc^2 v_c``, ``T`` :func:`opponent_matrix`."""
    T2 = opponent_matrix(variance.dtype, variance.device).square()
    return torch.movedim(torch.tensordot(T2, variance, dims=([1], [dim])), 0, dim)


def _basis_autocorrelation(basis: torch.Tensor) -> torch.Tensor:
    """``A_j(d) = sum_q b_j(q) b_j(q + d)`` for the lags ``d`` in ``[-(n-1), n-1]^2``: ``(n^2, 2n-1, 2n-1)``."""
    n = basis.shape[-1]
    padded = F.pad(basis, (n - 1,) * 4).transpose(0, 1)  # (1, n^2, 3n-2, 3n-2)
    return F.conv2d(padded, basis, groups=basis.shape[0])[0]


def coefficient_noise_variance(noise_psd: torch.Tensor, window: int, n: int = DCT_PATCH_PX,
                               autocorrelation: torch.Tensor | None = None) -> torch.Tensor:
    """Variance of each orthonormal DCT coefficient of an ``n x n`` patch of stationary noise whose power spectrum on a
    periodic ``window`` px grid is ``noise_psd`` ``(..., window, window // 2 + 1)`` (``rfft2`` layout; white noise of
    variance ``v`` per pixel: ``v`` everywhere). ``(..., n^2)``: ``sum_d R(d) A_j(d)`` over the lags of a patch, ``R`` the
    noise's autocovariance (``irfft2`` of its spectrum) and ``A_j`` the basis function's autocorrelation
    (``autocorrelation``: :func:`_basis_autocorrelation` of :func:`dct_basis`, where already made)."""
    if autocorrelation is None:
        autocorrelation = _basis_autocorrelation(dct_basis(n, noise_psd.dtype, noise_psd.device))
    m = n - 1
    R = torch.fft.irfft2(noise_psd, s=(window, window))
    R = torch.roll(R, shifts=(m, m), dims=(-2, -1))[..., : 2 * m + 1, : 2 * m + 1]  # lags -m .. m
    return R.reshape(R.shape[:-2] + (-1,)) @ autocorrelation.reshape(n * n, -1).T.to(R.dtype)


def dct_shrink(x: torch.Tensor, pilot: torch.Tensor, variance: torch.Tensor, *, passes: int = 1,
               basis: torch.Tensor | None = None) -> torch.Tensor:
    """Empirical Wiener shrinkage of ``x`` ``(N, 1, h, w)`` in the sliding DCT (module docstring, steps 3-4):
    ``variance`` the noise variance of each coefficient ``(N, n^2, 1, 1)`` or per patch ``(N, n^2, h-n+1, w-n+1)``,
    ``pilot`` the estimate whose coefficients set the factors (same shape as ``x``). Every pixel is averaged over the
    patches that contain it (a border pixel over fewer). Returns ``(N, 1, h, w)``."""
    if basis is None:
        basis = dct_basis(DCT_PATCH_PX, x.dtype, x.device)
    n = basis.shape[-1]
    tiny = torch.finfo(x.dtype).tiny
    ones = torch.ones((1, 1, n, n), dtype=x.dtype, device=x.device)
    c = F.conv2d(x, basis)
    eps = torch.finfo(x.dtype).eps
    scale = variance.sum(dim=1, keepdim=True).amax(dim=(-2, -1), keepdim=True)
    out = pilot
    for _ in range(passes):
        cp2 = F.conv2d(out, basis).square_()
        factor = cp2 / (cp2 + variance).clamp_min(tiny)
        # 1 / the estimate's noise variance, in units of the largest coefficient-summed variance (so finite without
        # noise: all weights 1, a plain average)
        residual = (factor.square() * variance).sum(dim=1, keepdim=True)
        weight = torch.where(scale > 0, scale / (residual + eps * scale), torch.ones_like(residual))
        out = F.conv_transpose2d(c * factor * weight, basis) / F.conv_transpose2d(weight, ones)
    return out


def dct_wiener_windowed(observed: torch.Tensor, psf: PSFProvider, *, noise: NoiseModel, alpha: float = DCT_ALPHA,
                        passes: int = DCT_PASSES, local_noise: bool = DCT_LOCAL_NOISE, colour: str = DCT_COLOUR,
                        rho0: float = WIENER_RHO0, stats: int = WIENER_STATS_PX, taper: int = WIENER_TAPER_PX,
                        scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None,
                        chunk: int | None = None, progress=None, floor: float = 1e-10) -> torch.Tensor:
    """Restore a linear sensor image ``(B, C, H, W)`` (module docstring) with the noise ``noise`` describes; the
    windows' transforms fitted to the local PSF as the Wiener's (``scheme.fit``, off where ``stats`` is over
    :data:`~pipeline.restoration.wiener.WIENER_FIT_LEAST_PX`). Returns the same shape."""
    check_image(observed, "observed")
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: expected a pipeline.camera_chain.NoiseModel")
    check_wiener_options({"stats": stats, "rho0": rho0, "taper": taper, "local": "window"}, scheme, "dct_wiener")
    _check_own(alpha, passes, colour, local_noise)
    fit = scheme.fit and stats <= WIENER_FIT_LEAST_PX  # as the Wiener's: the statistics need windows of ``stats`` px
    dtype, device = observed.dtype, observed.device
    model = WindowModel(noise, rho0=rho0, stats=stats, taper=taper, core=scheme.core, floor=floor,
                        dtype=dtype, device=device)
    basis = dct_basis(DCT_PATCH_PX, dtype, device)
    autocorrelation = _basis_autocorrelation(dct_basis(DCT_PATCH_PX, torch.float64, device)).to(dtype)
    mean_kernel = torch.full((1, 1, DCT_PATCH_PX, DCT_PATCH_PX), DCT_PATCH_PX ** -2, dtype=dtype, device=device)
    tiny = torch.finfo(dtype).eps ** 2  # guards the noise-free inverse filter (|H| = 0) against 0 / 0
    m = DCT_PATCH_PX - 1
    T = opponent_matrix(dtype, device)

    def restore(patches, H, core):
        win = patches.shape[-1]
        half = win // 2
        mu, var_n, HP, sx, P = model.terms(patches, H)
        spectrum = model.deviation_spectrum(patches, mu).mul_(H.conj().resolve_conj())
        G_r = P / (HP + alpha * var_n / sx).clamp_min(tiny)
        big = core + 2 * m
        r = core_irfft2(spectrum * G_r, win, big)
        p = core_irfft2(spectrum * (P / (HP + var_n / sx).clamp_min(tiny)), win, big)
        shape = r.shape[:-2]
        psd = (HP / P) * G_r.square() * var_n  # abs(H G_r)^2 n2
        v = coefficient_noise_variance(psd, win, autocorrelation=autocorrelation)
        v = v.expand(shape + v.shape[-1:])[..., None, None]  # (k, B, C, n^2, 1, 1)
        if local_noise:  # the noise model at each patch's mean over its value at the window's mean
            local = F.conv2d(p.reshape(-1, 1, big, big), mean_kernel)
            local = local.reshape(shape + (1,) + local.shape[-2:]) + mu[..., None]
            v = v * (noise.variance(local.clamp_min(0)) / var_n[..., None].clamp_min(tiny))
        opponent = colour == "opponent" and shape[-1] == 3
        if opponent:  # the channels' noise is independent: a coefficient's variance mixes as T^2
            r, p = (torch.einsum("kc,...chw->...khw", T, t) for t in (r, p))
            v = opponent_variance(v, dim=-4)
        v = v.reshape((-1,) + v.shape[-3:]).clamp_min(0)
        out = dct_shrink(r.reshape(-1, 1, big, big), p.reshape(-1, 1, big, big), v, passes=passes, basis=basis)
        out = out[..., m:m + core, m:m + core].reshape(shape + (core, core))
        if opponent:
            out = torch.einsum("kc,...khw->...chw", T, out)
        out = out + mu
        full = torch.zeros_like(patches)  # apply_windowed keeps the central core of a real result
        full[..., half - core // 2: half + core // 2, half - core // 2: half + core // 2] = out
        return full

    if chunk is None:  # the Wiener's batches, shrunk by what the shrinkage holds beyond a window's transform
        wiener = 3 * scheme.window ** 2
        chunk = max(1, window_chunk(observed, scheme.window) * wiener
                    // (wiener + DCT_LIVE_COPIES * DCT_PATCH_PX ** 2 * (scheme.core + 2 * m) ** 2))
    return apply_windowed(observed, psf, restore, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress, fit=fit, least_fit=WIENER_FIT_LEAST_PX)


def _check_own(alpha, passes, colour, local_noise):
    if not isinstance(local_noise, bool):
        raise ValueError(f"dct_wiener option local_noise={local_noise!r} is not allowed: true or false")
    if colour not in DCT_COLOURS:
        raise ValueError(f"dct_wiener option colour={colour!r} is not allowed: one of {', '.join(DCT_COLOURS)}")
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 < alpha <= 1:
        raise ValueError(f"dct_wiener option alpha={alpha!r} is not allowed: the inverse's noise weight relative to "
                         "the Wiener's, a number in (0, 1]")
    if isinstance(passes, bool) or not isinstance(passes, int) or not 1 <= passes <= MAX_DCT_PASSES:
        raise ValueError(f"dct_wiener option passes={passes!r} is not allowed: an integer in [1, {MAX_DCT_PASSES}]")


def _dct_wiener(observed, psf, *, noise, scheme, optical_center=None, region=None, progress=None, alpha=DCT_ALPHA,
                passes=DCT_PASSES, local_noise=DCT_LOCAL_NOISE, colour=DCT_COLOUR, stats=WIENER_STATS_PX,
                rho0=WIENER_RHO0, taper=WIENER_TAPER_PX):
    return dct_wiener_windowed(observed, psf, noise=noise, alpha=alpha, passes=passes, local_noise=local_noise,
                               colour=colour, stats=stats, rho0=rho0, taper=taper, scheme=scheme,
                               optical_center=optical_center, region=region, progress=progress)


def _check(options, scheme):
    check_wiener_options({**options, "local": "window"}, scheme, "dct_wiener")
    _check_own(options["alpha"], options["passes"], options["colour"], options["local_noise"])


register(RestorationMethod("dct_wiener", "Wiener + local DCT",
                           "regularised inverse in the blur's windows, empirical Wiener shrinkage in the sliding 8x8 "
                           "DCT with the adaptive Wiener as pilot, a colour image in the opponent space",
                           _dct_wiener, (("alpha", DCT_ALPHA), ("passes", DCT_PASSES), ("local_noise", DCT_LOCAL_NOISE),
                                         ("colour", DCT_COLOUR), ("stats", WIENER_STATS_PX), ("rho0", WIENER_RHO0),
                                         ("taper", WIENER_TAPER_PX)),
                           check=_check, memory=WorkingMemory()))  # per window batch, sized by DCT_LIVE_COPIES
