"""Tikhonov (regularised inverse) restoration in the blur's windows.

In every window, with the local OTF ``H`` (the same windows, PSFs and blending as the blur)::

    X(f) = conj(H(f)) Y(f) / (|H(f)|^2 + weight)          (f != 0),    X(0) = Y(0)

the minimiser of ``||h * x - y||^2 + weight ||x - mean||^2`` (zero-order Tikhonov regularisation of the
deconvolution, with the window's mean left as it is: ``H(0) = 1``, so its exact inverse there is 1). ``weight``
trades noise amplification against sharpness (``weight -> 0``: the inverse filter; larger: smoother). By default
(``weight="sure"``) it is chosen in every window from the window's own data and the noise model, by Stein's unbiased
risk estimate (SURE) of the predicted error ``||h * (x_w - x)||^2`` (Mallows' C_L, the unbiased predictive risk
estimator of the Tikhonov literature [3]_)::

    SURE(w) = ||h * x_w - y||^2 + 2 sigma_n^2 tr(A_w) - N sigma_n^2,    A_w = H conj(H) / (|H|^2 + w R)

over the window's central square (:data:`pipeline.restoration.wiener.WIENER_STATS_PX`) and as much again around it,
tapered to zero beyond the square (:func:`pipeline.restoration.wiener.window_taper`), so the weight follows the scene
where the core is restored (the whole window's data let a bright band beside a dark region set the dark region's
weight). In the square's Fourier domain, with ``P_f = |Y_f|^2 / N`` and ``q_f = w R_f / (|H_f|^2 + w R_f)`` (the
residual's share of frequency ``f``; the mean passes as it is, so ``f = 0`` is left out)::

    SURE(w) = sum_f P_f q_f^2 - 2 s^2 sum_f q_f + const,    s^2 = sigma_n^2 <taper^2>

minimised over ``ln w`` per window and channel (:func:`sure_log_weight`: a coarse grid, then bisection on the sign of
the derivative ``sum_f q_f (1 - q_f) (P_f q_f - s^2)``, all windows at once; the frequencies grouped by ``ln(|H|^2 /
R)`` in bins of :data:`TIKHONOV_BIN_NATS`, within which ``q`` is one number). ``sigma_n^2``: the noise model at the
square's taper-weighted mean (:meth:`pipeline.camera_chain.NoiseModel.variance`). SURE's weight alone restored a
smooth dark region beside a bright one below its sensor image: the chosen weight is multiplied by
:data:`TIKHONOV_SURE_FACTOR` (measured; its docstring), and by ``strength`` (a user's multiplier).

``weight="prior"`` (the former default): the noise-to-signal ratio of a white image prior (the Wiener filter of a flat
spectrum, the MAP weight of a Gaussian prior on ``x - mean``)::

    weight = strength * TIKHONOV_NSR[order] * sigma_n^2 / power,    power = max(P_y - n sigma_n^2, floor) / gain

with ``P_y`` the window's variance, ``n = 1``, ``gain = <|H|^2>`` (order 0), or (order 1) the mean squared differences
down and across, summed, ``n = 4``, ``gain = <|H|^2 |D|^2> / <|D|^2>``; ``sigma_n^2`` the noise variance at the
window's mean (:func:`pipeline.restoration.mean_noise_variance`), both over the Wiener's central statistics square;
:data:`TIKHONOV_NSR` calibrated once (its docstring). A number ``weight=`` gives the weight itself.

``order`` 0 penalises ``weight ||x - mean||^2`` (``R = 1``); order 1 (the default) ``weight ||grad x||^2`` (the filter
``conj(H) / (|H|^2 + weight |D|^2)``, ``R = |D|^2`` the forward differences' transfer; Gonzalez and Woods' constrained
least squares with the gradient for the Laplacian). The window's deviation from its mean is tapered towards the
window's edges as the Wiener's (:func:`pipeline.restoration.wiener.window_taper`,
:data:`pipeline.restoration.wiener.WIENER_TAPER_PX`: the transform's periodic window would otherwise wrap a bright edge
onto a dark one and ring into the core). Linear in
each window, one transform per window.

References
----------
.. [1] A. N. Tikhonov, V. Y. Arsenin, *Solutions of Ill-Posed Problems* (Winston, 1977).
.. [2] R. C. Gonzalez, R. E. Woods, *Digital Image Processing*, 4th ed. (Pearson, 2018), Section 5.9
   (constrained least squares filtering).
.. [3] P. C. Hansen, *Rank-Deficient and Discrete Ill-Posed Problems* (SIAM, 1998), Section 7 (the choice of the
   regularisation parameter); C. M. Stein, "Estimation of the mean of a multivariate normal distribution", Ann.
   Statist. 9(6), 1135-1151 (1981).

Examples
--------
A delta PSF with no regularisation restores the image exactly:

>>> import math, torch
>>> from lenssim import FieldGeometry, FunctionPSF
>>> from pipeline import NoiseModel, WindowScheme
>>> from pipeline.restoration import restore
>>> def delta(x_mm, y_mm, n):
...     p = torch.zeros(len(x_mm), n, n, dtype=torch.float64)
...     p[:, n // 2, n // 2] = 1
...     return p
>>> x = torch.rand(1, 1, 64, 64, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
>>> psf = FunctionPSF(delta, FieldGeometry(focal_length_mm=25.0, pixel_pitch_um=1.5625))
>>> y = restore("tikhonov:weight=0", x, psf, noise=NoiseModel(math.inf), scheme=WindowScheme(64, 16, 32))
>>> bool(torch.allclose(y, x, atol=1e-12))
True
"""

from __future__ import annotations

import torch

from lenssim import PSFProvider
from lenssim.torch_utils import abs_square, broadcast_shape, centred_variance
from lenssim.validate import check_real

from ..blur import PAPER_SCHEME, WindowScheme, apply_windowed
from ..camera_chain import NoiseModel
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, mean_noise_variance, register
from .wiener import WIENER_STATS_PX, WIENER_TAPER_PX, window_taper

__all__ = ["tikhonov_windowed", "sure_log_weight", "TIKHONOV_WEIGHT", "TIKHONOV_RULES", "TIKHONOV_NSR",
           "TIKHONOV_SURE_FACTOR", "TIKHONOV_MEMORY"]

TIKHONOV_WEIGHT = "sure"
"""Default weight: chosen in each window by SURE from the window's data and the noise model (module docstring); a
number overrides it."""

TIKHONOV_RULES = ("sure", "prior")
"""The weights chosen from the data and the noise model, by name (module docstring): SURE, or the white prior's
noise-to-signal ratio (the former default)."""

TIKHONOV_ORDERS = (0, 1)
"""What the regulariser penalises: the image's deviation from its mean (0) or its gradient (1)."""

TIKHONOV_ORDER = 1
"""Default order (module docstring): on the portrait's centre crop (E2E and RMS_W designs, ISO 400) order 0 stayed below
the sensor image at every weight tried (best 30.51 dB against 32.25 / 20.42 against 21.48)."""

TIKHONOV_NSR = {0: 30.0, 1: 10.0}
"""The constant of ``weight="prior"``, the former default, ``strength * TIKHONOV_NSR[order] * sigma_n^2 / power`` per
order (module docstring), measured on the portrait's centre crop at ISO 400. E2E design (sensor image 32.25 dB, adaptive Wiener
37.17): order 0, the best of 3 / 10 / 30 / 100 / 300 (22.43 / 26.87 / 30.51 / 28.86 / 24.01 dB); order 1, of 0.3 / 1 /
3 / 10 / 30: 31.23 / 35.05 / 37.42 / 37.41 / 35.42 dB. RMS_W design (sensor 21.48, Wiener 30.72), order 1: 13.29 /
17.34 / 20.93 / 23.90 / 25.56 dB. 3 fell below the sensor image there; 10 has the best mean of those tried."""

TIKHONOV_SURE_FACTOR = 6.0
"""What SURE's weight is multiplied by (module docstring). SURE's own weight minimises the estimated predicted error
over the window's central square, but on the synthetic band beside a dark region (tests/pipeline/test_restoration_edges.py,
RMS_W design, 10 deg, ISO 100) the restored dark corners were better at 6x that weight in linear error as well (their
linear PSNR 15.30 / 19.37 dB at 1x / 6x, the sensor image's 18.87), and weighting SURE's frequencies towards the restored
image's error (by ``1 / (|H|^2 + 0.01)``) moved them by 0.25 dB or less, and so weighted (0.01 or 0.001) over the
whole window instead of the square by 1.0 dB or less, all still 2.9 dB or more below (the noise there is the
model's: variance 4.14e-8 measured, 4.09e-8 modelled): why is not established. Measured on the 28 crop-ISOs of benchmarks/bench_restoration_methods.py (the three photos
of issue 45, 256 px at 0 / 5 / 10 deg, E2E and RMS_W designs, ISO 400 and 100): mean PSNR (dB) E2E 400 / E2E 100 /
RMS_W 400 / RMS_W 100, all; crops below the sensor image (least margin, dB); and the least margin over the nine crops of
the synthetic band beside a dark region (tests/pipeline/test_restoration_edges.py):

* factor 1: 38.82 / 40.36 / 35.49 / 36.34, 37.75; 1 below (-0.20, pier sunset, RMS_W, 10 deg, ISO 100); band -3.52;
* 2: 38.67 / 40.30 / 35.51 / 36.39, 37.72; none (+0.61); band -1.82 (its dark bottom corners);
* 4: 38.05 / 39.68 / 35.25 / 36.14, 37.28; none (+1.23); band -0.41;  5: band -0.06;
* **6**: 37.57 / 39.18 / 35.01 / 35.91, 36.92; none (+1.36); band +0.19;
* 8: 37.21 / 38.80 / 34.83 / 35.73, 36.64; none (+1.00); band +0.50.

6 is the least with no crop below its sensor image on either. Beside them: the adaptive Wiener 38.21 / 39.69 / 35.33 /
36.23, 37.36, none (+0.94), band +0.38; ``weight="prior"`` 33.96 / 37.62 / 28.72 / 32.37, 33.16, 5 below (-3.34, the
misty forest's dark 10 deg crop), band -3.53. Other rules tried (factor 1): SURE over the whole window instead of the
central square, 37.47, 1 below (-1.13, the pier crop above), band -2.77 at the bottom-left corner; generalised
cross-validation over the whole window within 0.01 dB of it; Morozov's discrepancy principle (the residual at the
noise's energy) over the square 36.98 / 39.74 / 33.87 / 35.22, 36.45, none (+1.04), band -1.11; the maximum-likelihood
scale of a ``1 / |D|^2`` prior over the square 37.53, 1 below (-0.35), band -3.14 (times 4: -0.18); a second pass
minimising the restored image's error with the first pass's restoration as the signal, band -4.76."""

TIKHONOV_LOG_WEIGHTS = (-30.0, 10.0)
"""The range of ``ln(weight)`` SURE searches (about 1e-13 to 2e4: from the inverse filter to the window's mean; with
``|H|^2 <= 1`` and ``R <= 8`` both ends are far beyond any weight a noisy window chooses)."""

TIKHONOV_BIN_NATS = 0.02
"""Width of the bins of ``ln(|H|^2 / R)`` SURE groups the frequencies in: one ``q = w R / (|H|^2 + w R)`` per bin (at
its centre) is within ``0.01 q (1 - q)`` of each frequency's, and the search's sums run over 3000 bins instead of the
square's 33 000 frequencies (256 px). Summed over a whole 512 px window's frequencies at each of 24 bisection steps,
SURE took ~3x the former weight's time per crop; binned, the default took 1.24x ``weight="prior"``'s (the portrait's
centre crop, one process, a loaded 2-core machine)."""

TIKHONOV_BIN_MARGIN_NATS = 10.0
"""Beyond the searched range of ``ln w`` the bins extend this far; frequencies further out land in the end bins,
where ``q`` is within ``exp(-10)`` of 0 or 1 at every searched weight."""

TIKHONOV_GRID_NATS = 0.5
"""Step of the coarse grid of ``ln w`` on which SURE's least value is found before the bisection refines it."""

TIKHONOV_BISECTIONS = 20
"""Bisections of the grid step around the least value: ``ln w`` to ``2 * 0.5 / 2^20`` (1e-6)."""

TIKHONOV_FLOOR = 1e-10
"""Least signal variance (squared image units) the noise-derived weight divides by (a flat window)."""

TIKHONOV_MEMORY = WorkingMemory(padded=1)
"""What the filter holds beyond the adaptive Wiener (:class:`pipeline.restoration.WorkingMemory`): the same windowed
pass, with the regulariser's and the blur's spectra per window batch. Measured beyond the Wiener's peak as
:data:`pipeline.restoration.richardson_lucy.RL_MEMORY`: +1.6 MiB at 256 px and +1.1 MiB at 512 px (on the whole-frame
command at 512 px, paper windows: 4 MiB less than the Wiener); declared one padded image, above both."""


def _weight(weight, prefix=""):
    """``weight`` as one of :data:`TIKHONOV_RULES` or a float >= 0 (a number, or its text from the command line)."""
    if isinstance(weight, str) and weight.strip() in TIKHONOV_RULES:
        return weight.strip()
    try:
        return check_real("weight", float(weight) if isinstance(weight, str) else weight, 0.0)
    except ValueError:
        shown = weight if isinstance(weight, (int, float)) else repr(weight)
        raise ValueError(f"{prefix}weight={shown} is not allowed: 'sure' (chosen by SURE from the data and the noise "
                         "model), 'prior' (the white prior's noise-to-signal ratio) or a finite number >= 0") from None


def _penalty(win: int, order: int, dtype, device) -> torch.Tensor:
    """The regulariser's transfer on the rfft half-plane of a ``win`` px window: 1 (order 0) or ``|D(f)|^2 = 4
    sin^2(pi f_r) + 4 sin^2(pi f_c)`` (order 1: the forward differences down and across, f in cycles per px)."""
    if order == 0:
        return torch.ones(win, win // 2 + 1, dtype=dtype, device=device)
    fr = torch.fft.fftfreq(win, dtype=dtype, device=device)
    fc = torch.fft.rfftfreq(win, dtype=dtype, device=device)
    return 4 * torch.sin(torch.pi * fr)[:, None] ** 2 + 4 * torch.sin(torch.pi * fc)[None, :] ** 2


def _half_plane_counts(win: int, dtype, device) -> torch.Tensor:
    """How many frequencies of the full ``win`` x ``win`` plane each column of its rfft half-plane stands for: 1 in
    the first and the Nyquist columns, 2 in the others."""
    cols = torch.full((win // 2 + 1,), 2.0, dtype=dtype, device=device)
    cols[0] = cols[-1] = 1
    return cols


def sure_log_weight(log_ratio: torch.Tensor, power: torch.Tensor, counts: torch.Tensor,
                    noise_power: torch.Tensor) -> torch.Tensor:
    """``ln w`` minimising ``SURE(w) = sum_f power_f q_f^2 - 2 noise_power sum_f counts_f q_f`` with ``q_f = w / (w +
    exp(log_ratio_f))`` (module docstring), within :data:`TIKHONOV_LOG_WEIGHTS`, for each window and channel.

    ``log_ratio``: ``ln(|H|^2 / R)`` and ``power`` (``|Y|^2 / N``), ``(..., h, w)`` broadcasting against each other;
    ``counts`` ``(h, w)``: the frequencies each entry stands for (0 where it is left out); ``noise_power``: ``s^2``,
    ``(..., 1, 1)``. Returns ``(..., 1, 1)``. The frequencies are grouped in bins of ``log_ratio``
    (:data:`TIKHONOV_BIN_NATS`); the least value on a grid of :data:`TIKHONOV_GRID_NATS` is refined by
    :data:`TIKHONOV_BISECTIONS` bisections on the sign of the derivative."""
    lo, hi = TIKHONOV_LOG_WEIGHTS
    start = lo - TIKHONOV_BIN_MARGIN_NATS
    nb = round((hi - lo + 2 * TIKHONOV_BIN_MARGIN_NATS) / TIKHONOV_BIN_NATS)
    idx = ((log_ratio - start) / TIKHONOV_BIN_NATS).floor_().clamp_(0, nb - 1).long()
    shape = broadcast_shape(log_ratio.shape, power.shape)
    sets = shape[:-2]

    def binned(values):  # (*sets, nb): the sum of ``values`` in each bin, per window and channel
        ix = idx.expand(shape).reshape(-1, shape[-2] * shape[-1])
        ix = ix + torch.arange(ix.shape[0], device=ix.device)[:, None] * nb
        return torch.bincount(ix.reshape(-1), weights=values.expand(shape).reshape(-1),
                              minlength=ix.shape[0] * nb).reshape(*sets, nb)

    p, c = binned(power), binned(counts.to(power.dtype))
    s2 = noise_power.reshape(noise_power.shape[:-2] + (1,))
    centres = start + (torch.arange(nb, dtype=power.dtype, device=power.device) + 0.5) * TIKHONOV_BIN_NATS
    grid = torch.arange(lo, hi + TIKHONOV_GRID_NATS / 2, TIKHONOV_GRID_NATS, dtype=power.dtype, device=power.device)
    qg = torch.sigmoid(grid[:, None] - centres[None, :])  # (grid, bins): q = w / (w + |H|^2 / R)
    risk = p @ qg.square().T - 2 * s2 * (c @ qg.T)
    best = grid[risk.argmin(dim=-1, keepdim=True)]
    a, b = (best - TIKHONOV_GRID_NATS).clamp(lo, hi), (best + TIKHONOV_GRID_NATS).clamp(lo, hi)
    for _ in range(TIKHONOV_BISECTIONS):
        m = 0.5 * (a + b)
        q = torch.sigmoid(m - centres)
        rising = (q * (1 - q) * (p * q - s2 * c)).sum(dim=-1, keepdim=True) > 0
        a, b = torch.where(rising, a, m), torch.where(rising, m, b)
    return (0.5 * (a + b))[..., None]


def _sure_weight(patches: torch.Tensor, H2: torch.Tensor, R: torch.Tensor, noise: NoiseModel) -> torch.Tensor:
    """SURE's weight per window and channel, ``(k, B, C, 1, 1)`` (module docstring), from the windows ``patches``
    ``(k, B, C, win, win)``, ``|H|^2`` and ``R`` on the window's rfft half-plane: over the smallest square dividing the
    window that holds twice the Wiener's statistics square (whose half-plane is every ``win / side``-th of the
    window's frequencies), the square tapered beyond its middle half. 0 where there is no noise."""
    win = patches.shape[-1]
    side = min(d for d in range(min(2 * WIENER_STATS_PX, win), win + 1) if win % d == 0)
    step, lo = win // side, (win - side) // 2
    taper = window_taper(side, min(WIENER_STATS_PX, side), side // 4, patches.dtype, patches.device)
    square = patches[..., lo:lo + side, lo:lo + side]
    t2 = taper.square()
    mean = (square * t2).sum(dim=(-2, -1), keepdim=True) / t2.sum()
    spec = torch.fft.rfft2((square - mean).mul_(taper))
    counts = _half_plane_counts(side, patches.dtype, patches.device).expand(side, -1).clone()
    counts[0, 0] = 0  # the mean passes as it is: no residual, no degree of freedom
    power = abs_square(spec).mul_(counts / (side * side))
    noise_power = noise.variance(mean) * t2.mean()
    R_sub = R[::step, ::step].clone()
    R_sub[0, 0] = 1  # left out (counts 0); keeps the logarithm finite
    tiny = torch.finfo(patches.dtype).tiny
    log_ratio = H2[..., ::step, ::step].clamp_min(tiny).log() - R_sub.log()
    w = TIKHONOV_SURE_FACTOR * sure_log_weight(log_ratio, power, counts, noise_power).exp()
    return torch.where(noise_power > 0, w, torch.zeros_like(w))


def tikhonov_windowed(observed: torch.Tensor, psf: PSFProvider, *, weight=TIKHONOV_WEIGHT,
                      noise: NoiseModel | None = None, strength: float = 1.0, order: int = TIKHONOV_ORDER,
                      scheme: WindowScheme = PAPER_SCHEME,
                      optical_center=None, region=None, chunk: int | None = None, taper: int = WIENER_TAPER_PX,
                      progress=None) -> torch.Tensor:
    """Restore a linear image ``(B, C, H, W)`` blurred by the provider's PSFs with the Tikhonov-regularised
    inverse ``conj(H) / (|H|^2 + weight R)`` in the blur's windows: ``weight`` a number >= 0, ``"sure"`` (the default)
    or ``"prior"`` (from the window's data and ``noise``, a :class:`pipeline.camera_chain.NoiseModel`, times
    ``strength``; module docstring).
    ``taper``: the band (px) along each window's edges over which its deviation from its mean is tapered (0: none).
    Returns the same shape."""
    check_image(observed, "observed")
    weight = _weight(weight)
    if weight in TIKHONOV_RULES and not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: weight={weight!r} needs a pipeline.camera_chain.NoiseModel")
    strength = check_real("strength", strength, 0.0, lo_open=True)
    if order not in TIKHONOV_ORDERS or isinstance(order, bool):
        raise ValueError(f"order={order!r} is not allowed: 0 (the image) or 1 (its gradient)")
    if isinstance(taper, bool) or not (isinstance(taper, int) and taper >= 0):
        raise ValueError(f"taper={taper!r} is not allowed: a width in px, an integer >= 0 (0: no taper)")
    tiny = torch.finfo(observed.dtype).eps ** 2  # weight 0 where |H| = 0: no 0 / 0
    tapers = {}

    def op(patches, otf, core):
        H = otf
        win = patches.shape[-1]
        if win not in tapers:
            tapers[win] = window_taper(win, scheme.core, taper, patches.dtype, patches.device)
        half, s = win // 2, min(WIENER_STATS_PX, win) // 2
        mu = patches.mean(dim=(-2, -1), keepdim=True)
        spec = torch.fft.rfft2((patches - mu).mul_(tapers[win]))
        dc = spec[..., 0, 0] + mu[..., 0, 0] * (win * win)
        H2 = abs_square(H)
        R = _penalty(win, order, patches.dtype, patches.device)
        if weight == "sure":
            w = strength * _sure_weight(patches, H2, R, noise)
        elif weight == "prior":  # the Gaussian prior's noise-to-signal ratio, over the central statistics square
            centre = patches[..., half - s: half + s, half - s: half + s]
            var_n = mean_noise_variance(noise, centre)
            if order == 0:  # the signal's variance; the noise adds var_n
                power = centred_variance(centre, centre.mean(dim=(-2, -1), keepdim=True), (-2, -1)) - var_n
            else:  # its gradient's power (both directions); a difference of two pixels adds 2 var_n in each
                power = (centre.diff(dim=-2).square().mean(dim=(-2, -1), keepdim=True)
                         + centre.diff(dim=-1).square().mean(dim=(-2, -1), keepdim=True) - 4 * var_n)
            cols = _half_plane_counts(win, H2.dtype, H2.device)
            gain = (H2 * R * cols).sum(dim=(-2, -1), keepdim=True) / (R * cols).sum()  # the blur's share of it
            w = strength * TIKHONOV_NSR[order] * var_n / (power.clamp_min(TIKHONOV_FLOOR) / gain)
        else:
            w = weight
        G = (H2 + w * R).clamp_min_(tiny)
        out = spec.mul_(H.conj().resolve_conj()).div_(G)
        out[..., 0, 0] = dc  # the window's mean passes as it is
        return out  # spectrum: apply_windowed inverse transforms only the core

    return apply_windowed(observed, psf, op, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress)


def _tikhonov(observed, psf, *, noise, scheme, optical_center=None, region=None, progress=None,
              weight=TIKHONOV_WEIGHT, strength=1.0, order=TIKHONOV_ORDER):
    return tikhonov_windowed(observed, psf, weight=weight, noise=noise, strength=strength, order=order, scheme=scheme,
                             optical_center=optical_center, region=region, progress=progress)


def _check(options, scheme):
    _weight(options["weight"], "tikhonov option ")
    check_real("tikhonov option strength", options["strength"], 0.0, lo_open=True)
    if options["order"] not in TIKHONOV_ORDERS:
        raise ValueError(f"tikhonov option order={options['order']!r} is not allowed: 0 (the image) or 1 (its "
                         "gradient)")


register(RestorationMethod("tikhonov", "Tikhonov", "Tikhonov-regularised inverse filter in the blur's windows "
                           "(linear in each window; weight chosen by SURE from the data and the noise model, or given)",
                           _tikhonov,
                           (("weight", TIKHONOV_WEIGHT), ("strength", 1.0), ("order", TIKHONOV_ORDER)), check=_check,
                           memory=TIKHONOV_MEMORY))
