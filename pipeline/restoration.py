"""Adaptive local Wiener restoration in the windows of the blur (paper Section 3.3).

In every window (same scheme as :mod:`pipeline.blur`: local PSF at the window centre, cores
blended linearly) and for every channel:

* ``mu`` and ``var_y``: mean and variance of the observed image over the central ``stats`` x ``stats``
  pixels of the window (the local statistics);
* noise variance, signal dependent (Poisson): ``sigma_n^2 = mu / e + read_var``, where ``e`` is the
  number of electrons per unit of the linear image (``full_well / peak`` in the simulation);
* signal variance of the *unblurred* image: ``sigma_x^2 = max(var_y - sigma_n^2, floor) / <|H|^2 P>``
  (blur scales the variance of a signal with spectrum ``P`` by the mean of ``|H|^2 P``);
* Wiener filter with the paper's image model ``P`` (``rho0^|r|``, unit variance, the same spectrum
  as :func:`lenssim.image_psd`) scaled by ``sigma_x^2``:
  ``G = conj(H) sigma_x^2 P / (|H|^2 sigma_x^2 P + sigma_n^2)`` applied to ``y - mu``, then ``+ mu``.

With no blur (``H = 1``) and no noise (``e = inf``) this is the identity.
"""

from __future__ import annotations

import math

import torch

from collections.abc import Callable
from dataclasses import dataclass

from lenssim import PAPER_RHO0, PSFProvider, image_psd
from lenssim.validate import check_real

from .blur import PAPER_SCHEME, WindowScheme, apply_windowed
from .checks import check_image

__all__ = ["wiener_windowed", "richardson_lucy_windowed", "RestorationMethod", "RESTORATION_METHODS",
           "validate_method", "restore"]


def wiener_windowed(observed: torch.Tensor, psf: PSFProvider, *, electrons_per_unit: float,
                    read_noise_var: float = 0.0, rho0: float = PAPER_RHO0, stats: int = 128,
                    scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int | None = None,
                    progress=None, floor: float = 1e-10) -> torch.Tensor:
    """Restore a linear sensor image ``(B, C, H, W)`` blurred by the provider's PSFs, with Poisson noise.

    ``electrons_per_unit`` may be ``math.inf`` (no photon noise); ``read_noise_var`` is the read
    noise variance in squared image units. Returns the same shape.
    """
    check_image(observed, "observed")
    if not (isinstance(electrons_per_unit, (int, float)) and not isinstance(electrons_per_unit, bool)
            and electrons_per_unit > 0 and not math.isnan(electrons_per_unit)):
        raise ValueError(f"electrons_per_unit={electrons_per_unit!r} is not allowed: a number > 0 (inf: no noise)")
    check_real("read_noise_var", read_noise_var, 0.0)
    if not (isinstance(stats, int) and 2 <= stats <= scheme.window):
        raise ValueError(f"stats={stats!r} is not allowed: an integer in [2, window={scheme.window}]")
    win, half = scheme.window, scheme.window // 2
    P = image_psd(win, rho0, dtype=observed.dtype, device=observed.device)[:, : half + 1]
    P = P / P.mean()
    inv_e = 0.0 if math.isinf(electrons_per_unit) else 1.0 / electrons_per_unit
    w = torch.full((half + 1,), 2.0, dtype=P.dtype, device=P.device)
    w[0] = w[-1] = 1
    tiny = torch.finfo(observed.dtype).eps ** 2  # guards the noise-free inverse filter (|H| = 0) against 0 / 0

    def restore(patches, otf):
        centre = patches[..., half - stats // 2: half + stats // 2, half - stats // 2: half + stats // 2]
        mu = centre.mean(dim=(-2, -1), keepdim=True)
        var_y = centre.var(dim=(-2, -1), correction=0, keepdim=True)
        noise = mu.clamp_min(0) * inv_e + read_noise_var
        H = otf  # (k, 1, 1 or C, win, win/2+1)
        HP = (H.real.square() + H.imag.square()) * P
        # <|H|^2 P> over the full grid from the half-plane (rfft layout: inner columns count twice)
        gain = (HP * w).sum(dim=(-2, -1), keepdim=True) / (win * win)
        sx = (var_y - noise).clamp_min(floor) / gain
        # G = conj(H) sx P / (|H|^2 sx P + noise) = conj(H) P / (|H|^2 P + noise / sx), built in place
        G = HP + noise / sx
        torch.div(P, G.clamp_min_(tiny), out=G)
        out = torch.fft.rfft2(patches)
        dc = mu[..., 0, 0] * (win * win)  # the local mean's DC term: filter y - mu, then add mu back
        out[..., 0, 0] -= dc
        out.mul_(H.conj())
        torch.view_as_real(out).mul_(G[..., None])  # the real G scales both parts: no complex copy of G
        out[..., 0, 0] += dc
        return out  # spectrum: apply_windowed inverse transforms only the core

    return apply_windowed(observed, psf, restore, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress)


def richardson_lucy_windowed(observed: torch.Tensor, psf: PSFProvider, *, iterations: int = 30,
                             scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int = 4,
                             progress=None, eps: float = 1e-12) -> torch.Tensor:
    """Richardson-Lucy deconvolution (the non-linear, train-free comparison) in the blur's windows.

    Per window, with the local PSF ``h`` (circular convolution over the window, as the blur)::

        u_{k+1} = u_k * ( h~ conv ( y / (h conv u_k) ) ),   u_0 = 0.5,   h~ the mirrored PSF

    the same iteration as ``skimage.restoration.richardson_lucy`` (which the tests compare against).
    Non-negative input required; no regularisation (stop early with ``iterations``).
    """
    check_image(observed, "observed")
    if isinstance(iterations, bool) or not (isinstance(iterations, int) and iterations >= 1):
        raise ValueError(f"iterations={iterations!r} is not allowed: an integer >= 1")
    if (observed < 0).any():
        raise ValueError("observed image has negative values: Richardson-Lucy needs y >= 0")
    win = scheme.window

    def rl(patches, otf):
        H = otf
        conv = lambda x, F: torch.fft.irfft2(torch.fft.rfft2(x) * F, s=(win, win))  # noqa: E731
        u = torch.full_like(patches, 0.5)  # scikit-image's starting point
        for _ in range(iterations):
            ratio = patches / conv(u, H).clamp_min(eps)
            u = u * conv(ratio, H.conj())
        return u

    return apply_windowed(observed, psf, rl, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress)


@dataclass(frozen=True)
class RestorationMethod:
    """A restoration method: ``fn(observed, psf, *, electrons_per_unit, read_noise_var, scheme, optical_center,
    region, progress, **options) -> restored`` (linear ``(B, C, H, W)``), with a label for figures and
    tables and the options it takes (``{name: default}``)."""

    name: str
    label: str
    description: str
    fn: Callable
    options: tuple[tuple[str, object], ...] = ()


def _wiener(observed, psf, *, electrons_per_unit, read_noise_var=0.0, **kw):
    return wiener_windowed(observed, psf, electrons_per_unit=electrons_per_unit, read_noise_var=read_noise_var, **kw)


def _richardson_lucy(observed, psf, *, electrons_per_unit, read_noise_var=0.0, iterations=20, **kw):
    # the noise level does not enter the (unregularised) iteration, which needs a non-negative input
    return richardson_lucy_windowed(observed.clamp_min(0), psf, iterations=iterations, **kw)


RESTORATION_METHODS: dict[str, RestorationMethod] = {m.name: m for m in (
    RestorationMethod("wiener", "adaptive Wiener", "adaptive local Wiener filter in the blur's windows (paper)",
                      _wiener),
    RestorationMethod("richardson_lucy", "Richardson-Lucy", "windowed Richardson-Lucy deconvolution (non-linear, "
                      "no regularisation)", _richardson_lucy, (("iterations", 20),)),
)}
"""The registry of restoration methods: name -> :class:`RestorationMethod`."""


def validate_method(name: str) -> RestorationMethod:
    """The registered method ``name``; ``ValueError`` listing the valid names otherwise."""
    if name not in RESTORATION_METHODS:
        raise ValueError(f"restoration method {name!r} is not known; valid: {', '.join(RESTORATION_METHODS)}")
    return RESTORATION_METHODS[name]


def restore(method: str, observed: torch.Tensor, psf: PSFProvider, *, electrons_per_unit: float,
            read_noise_var: float = 0.0, options: dict | None = None, **kw) -> torch.Tensor:
    """Restore ``observed`` with the registered ``method`` (``options``: the method's own settings)."""
    m = validate_method(method)
    options = dict(options or {})
    bad = set(options) - {k for k, _ in m.options}
    if bad:
        raise ValueError(f"restoration method {method!r} takes no option(s) {sorted(bad)}; it takes "
                         f"{[k for k, _ in m.options] or 'none'}")
    return m.fn(observed, psf, electrons_per_unit=electrons_per_unit, read_noise_var=read_noise_var, **options, **kw)
