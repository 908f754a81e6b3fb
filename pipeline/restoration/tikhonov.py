"""Tikhonov (regularised inverse) restoration in the blur's windows.

In every window, with the local OTF ``H`` (the same windows, PSFs and blending as the blur)::

    X(f) = conj(H(f)) Y(f) / (|H(f)|^2 + weight)          (f != 0),    X(0) = Y(0)

the minimiser of ``||h * x - y||^2 + weight ||x - mean||^2`` (zero-order Tikhonov regularisation of the
deconvolution, with the window's mean left as it is: ``H(0) = 1``, so its exact inverse there is 1). ``weight``
trades noise amplification against sharpness (``weight -> 0``: the inverse filter; larger: smoother). By default
(``weight="noise"``) it follows from the noise model in every window: the noise-to-signal ratio of a white image
prior (the Wiener filter of a flat spectrum, the MAP weight of a Gaussian prior on ``x - mean``)::

    weight = strength * TIKHONOV_NSR[order] * sigma_n^2 / power,    power = max(P_y - n sigma_n^2, floor) / gain

with option ``order`` 0, the penalty ``weight ||x - mean||^2``: ``P_y`` the window's variance, ``n = 1``, ``gain = <|H|^2>``;
order 1 (the default), the penalty ``weight ||grad x||^2`` (the filter ``conj(H) / (|H|^2 + weight |D|^2)``, ``|D|^2``
the forward differences' transfer; Gonzalez and Woods' constrained least squares with the gradient for the Laplacian):
``P_y`` the mean squared differences down and across, summed, ``n = 4``, ``gain = <|H|^2 |D|^2> / <|D|^2>``.
``sigma_n^2``: the noise variance at the window's mean (:func:`pipeline.restoration.mean_noise_variance`), ``var_y``
the window's variance, both over the Wiener's central statistics square (:data:`pipeline.restoration.wiener.
WIENER_STATS_PX`); :data:`TIKHONOV_NSR` calibrated once (its docstring), ``strength`` a user's multiplier; a number
``weight=`` overrides it. The window's deviation from its mean is tapered towards the window's edges as the Wiener's
(:func:`pipeline.restoration.wiener.window_taper`, :data:`pipeline.restoration.wiener.WIENER_TAPER_PX`: the
transform's periodic window would otherwise wrap a bright edge onto a dark one and ring into the core). Linear in
each window, one transform per window.

References
----------
.. [1] A. N. Tikhonov, V. Y. Arsenin, *Solutions of Ill-Posed Problems* (Winston, 1977).
.. [2] R. C. Gonzalez, R. E. Woods, *Digital Image Processing*, 4th ed. (Pearson, 2018), Section 5.9
   (constrained least squares filtering).

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
from lenssim.validate import check_real

from ..blur import PAPER_SCHEME, WindowScheme, apply_windowed
from ..camera_chain import NoiseModel
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, mean_noise_variance, register
from .wiener import WIENER_STATS_PX, WIENER_TAPER_PX, window_taper

__all__ = ["tikhonov_windowed", "TIKHONOV_WEIGHT", "TIKHONOV_NSR", "TIKHONOV_MEMORY"]

TIKHONOV_WEIGHT = "noise"
"""Default weight: from the noise model in each window (module docstring); a number overrides it."""

TIKHONOV_ORDERS = (0, 1)
"""What the regulariser penalises: the image's deviation from its mean (0) or its gradient (1)."""

TIKHONOV_ORDER = 1
"""Default order (module docstring): on the portrait's centre crop (E2E and RMS_W designs, ISO 400) order 0 stayed below
the sensor image at every weight tried (best 30.51 dB against 32.25 / 20.42 against 21.48)."""

TIKHONOV_NSR = {0: 30.0, 1: 10.0}
"""The constant of the noise-derived weight ``strength * TIKHONOV_NSR[order] * sigma_n^2 / power`` per order (module
docstring), measured on the portrait's centre crop at ISO 400. E2E design (sensor image 32.25 dB, adaptive Wiener
37.17): order 0, the best of 3 / 10 / 30 / 100 / 300 (22.43 / 26.87 / 30.51 / 28.86 / 24.01 dB); order 1, of 0.3 / 1 /
3 / 10 / 30: 31.23 / 35.05 / 37.42 / 37.41 / 35.42 dB. RMS_W design (sensor 21.48, Wiener 30.72), order 1: 13.29 /
17.34 / 20.93 / 23.90 / 25.56 dB. 3 fell below the sensor image there; 10 has the best mean of those tried."""

TIKHONOV_FLOOR = 1e-10
"""Least signal variance (squared image units) the noise-derived weight divides by (a flat window)."""

TIKHONOV_MEMORY = WorkingMemory(padded=1)
"""What the filter holds beyond the adaptive Wiener (:class:`pipeline.restoration.WorkingMemory`): the same windowed
pass, with the regulariser's and the blur's spectra per window batch. Measured beyond the Wiener's peak as
:data:`pipeline.restoration.richardson_lucy.RL_MEMORY`: +1.6 MiB at 256 px and +1.1 MiB at 512 px (on the whole-frame
command at 512 px, paper windows: 4 MiB less than the Wiener); declared one padded image, above both."""


def _weight(weight, prefix=""):
    """``weight`` as ``"noise"`` or a float >= 0 (a number, or its text from the command line)."""
    if isinstance(weight, str) and weight.strip() == "noise":
        return "noise"
    try:
        return check_real("weight", float(weight) if isinstance(weight, str) else weight, 0.0)
    except ValueError:
        shown = weight if isinstance(weight, (int, float)) else repr(weight)
        raise ValueError(f"{prefix}weight={shown} is not allowed: 'noise' (from the noise model) or a finite number "
                         ">= 0") from None


def _penalty(win: int, order: int, dtype, device) -> torch.Tensor:
    """The regulariser's transfer on the rfft half-plane of a ``win`` px window: 1 (order 0) or ``|D(f)|^2 = 4
    sin^2(pi f_r) + 4 sin^2(pi f_c)`` (order 1: the forward differences down and across, f in cycles per px)."""
    if order == 0:
        return torch.ones(win, win // 2 + 1, dtype=dtype, device=device)
    fr = torch.fft.fftfreq(win, dtype=dtype, device=device)
    fc = torch.fft.rfftfreq(win, dtype=dtype, device=device)
    return 4 * torch.sin(torch.pi * fr)[:, None] ** 2 + 4 * torch.sin(torch.pi * fc)[None, :] ** 2


def tikhonov_windowed(observed: torch.Tensor, psf: PSFProvider, *, weight=TIKHONOV_WEIGHT,
                      noise: NoiseModel | None = None, strength: float = 1.0, order: int = TIKHONOV_ORDER, scheme: WindowScheme = PAPER_SCHEME,
                      optical_center=None, region=None, chunk: int | None = None, taper: int = WIENER_TAPER_PX,
                      progress=None) -> torch.Tensor:
    """Restore a linear image ``(B, C, H, W)`` blurred by the provider's PSFs with the Tikhonov-regularised
    inverse ``conj(H) / (|H|^2 + weight)`` in the blur's windows: ``weight`` a number >= 0, or ``"noise"`` (the
    default: from ``noise``, a :class:`pipeline.camera_chain.NoiseModel`, times ``strength``; module docstring).
    ``taper``: the band (px) along each window's edges over which its deviation from its mean is tapered (0: none).
    Returns the same shape."""
    check_image(observed, "observed")
    weight = _weight(weight)
    if weight == "noise" and not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: weight='noise' needs a pipeline.camera_chain.NoiseModel")
    strength = check_real("strength", strength, 0.0, lo_open=True)
    if order not in TIKHONOV_ORDERS or isinstance(order, bool):
        raise ValueError(f"order={order!r} is not allowed: 0 (the image) or 1 (its gradient)")
    if isinstance(taper, bool) or not (isinstance(taper, int) and taper >= 0):
        raise ValueError(f"taper={taper!r} is not allowed: a width in px, an integer >= 0 (0: no taper)")
    tiny = torch.finfo(observed.dtype).eps ** 2  # weight 0 where |H| = 0: no 0 / 0
    tapers = {}

    def op(patches, otf):
        H = otf
        win = patches.shape[-1]
        if win not in tapers:
            tapers[win] = window_taper(win, scheme.core, taper, patches.dtype, patches.device)
        half, s = win // 2, min(WIENER_STATS_PX, win) // 2
        mu = patches.mean(dim=(-2, -1), keepdim=True)
        spec = torch.fft.rfft2((patches - mu).mul_(tapers[win]))
        dc = spec[..., 0, 0] + mu[..., 0, 0] * (win * win)
        H2 = H.real.square() + H.imag.square()
        R = _penalty(win, order, patches.dtype, patches.device)
        if weight == "noise":  # the Gaussian prior's noise-to-signal ratio, over the central statistics square
            centre = patches[..., half - s: half + s, half - s: half + s]
            var_n = mean_noise_variance(noise, centre)
            if order == 0:  # the signal's variance; the noise adds var_n
                power = centre.var(dim=(-2, -1), correction=0, keepdim=True) - var_n
            else:  # its gradient's power (both directions); a difference of two pixels adds 2 var_n in each
                power = (centre.diff(dim=-2).square().mean(dim=(-2, -1), keepdim=True)
                         + centre.diff(dim=-1).square().mean(dim=(-2, -1), keepdim=True) - 4 * var_n)
            cols = torch.full((win // 2 + 1,), 2.0, dtype=H2.dtype, device=H2.device)
            cols[0] = cols[-1] = 1  # the rfft half-plane's inner columns count twice
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
                           "(linear; weight from the noise model, or given)", _tikhonov,
                           (("weight", TIKHONOV_WEIGHT), ("strength", 1.0), ("order", TIKHONOV_ORDER)), check=_check,
                           memory=TIKHONOV_MEMORY))
