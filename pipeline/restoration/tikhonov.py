"""Tikhonov (regularised inverse) restoration in the blur's windows.

In every window, with the local OTF ``H`` (the same windows, PSFs and blending as the blur)::

    X(f) = conj(H(f)) Y(f) / (|H(f)|^2 + weight)          (f != 0),    X(0) = Y(0)

the minimiser of ``||h * x - y||^2 + weight ||x - mean||^2`` (zero-order Tikhonov regularisation of the
deconvolution, with the window's mean left as it is: ``H(0) = 1``, so its exact inverse there is 1). Unlike
the Wiener filter it needs no image or noise model: ``weight`` alone trades noise amplification against
sharpness (``weight -> 0``: the inverse filter; larger: smoother). Linear, one transform per window.

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
from ..checks import check_image
from . import RestorationMethod, register

__all__ = ["tikhonov_windowed", "TIKHONOV_WEIGHT"]

TIKHONOV_WEIGHT = 1e-2
"""Default regularisation weight (relative to ``|H(0)|^2 = 1``): the best of 1e-3, 3e-3, 1e-2, 3e-2, 1e-1 for the
paper's end-to-end lens at ISO 100 on a 256 px crop of the generated scene 6.4 deg off axis (measured
sRGB PSNR 22.18 dB against the adaptive Wiener's 21.91; 3e-3 was best at ISO 25, 3e-2 at ISO 400)."""


def tikhonov_windowed(observed: torch.Tensor, psf: PSFProvider, *, weight: float = TIKHONOV_WEIGHT,
                      scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int | None = None,
                      progress=None) -> torch.Tensor:
    """Restore a linear image ``(B, C, H, W)`` blurred by the provider's PSFs with the Tikhonov-regularised
    inverse ``conj(H) / (|H|^2 + weight)`` in the blur's windows (``weight >= 0``). Returns the same shape."""
    check_image(observed, "observed")
    weight = check_real("weight", weight, 0.0)
    tiny = torch.finfo(observed.dtype).eps ** 2  # weight 0 where |H| = 0: no 0 / 0

    def op(patches, otf):
        H = otf
        spec = torch.fft.rfft2(patches)
        dc = spec[..., 0, 0].clone()
        G = (H.real.square() + H.imag.square() + weight).clamp_min_(tiny)
        out = spec.mul_(H.conj().resolve_conj()).div_(G)
        out[..., 0, 0] = dc  # the window's mean passes as it is
        return out  # spectrum: apply_windowed inverse transforms only the core

    return apply_windowed(observed, psf, op, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress)


def _tikhonov(observed, psf, *, scheme, optical_center=None, region=None, progress=None, weight=TIKHONOV_WEIGHT):
    return tikhonov_windowed(observed, psf, weight=weight, scheme=scheme, optical_center=optical_center,
                             region=region, progress=progress)


register(RestorationMethod("tikhonov", "Tikhonov", "Tikhonov-regularised inverse filter in the blur's windows "
                           "(linear, no image or noise model)", _tikhonov, (("weight", TIKHONOV_WEIGHT),),
                           check=lambda o, scheme: check_real("tikhonov option weight", o["weight"], 0.0)))
