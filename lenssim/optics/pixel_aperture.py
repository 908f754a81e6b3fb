"""The pixel aperture: a pixel integrates the optical image over its light-sensitive area, a centred square of side
``sqrt(fill_factor)`` pixels (the sensor's ``fill_factor``; microlenses make it close to 1 on modern sensors).

Its transfer function is the box's, ``MTF(fy, fx) = sinc(a fy) sinc(a fx)`` with ``a = sqrt(fill_factor)`` px and
``f`` in cycles/pixel (``sinc(x) = sin(pi x) / (pi x)``; e.g. Boreman, *Modulation Transfer Function in Optical and
Electro-Optical Systems*, SPIE 2001, ch. 2). Every design criterion sees it as part of the system OTF
(:class:`lenssim.criteria.OTFContext` multiplies it in when the camera's sensor has a fill factor), and the image
pipeline's PSFs through :class:`PixelAperturePSF`. ``None``: point sampling (the paper).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .psf_provider import DerivedPSF, PSFProvider
from ..torch_utils import tensor_of

__all__ = ["pixel_aperture_side_px", "pixel_aperture_mtf", "apply_pixel_aperture", "PixelAperturePSF"]


def pixel_aperture_side_px(fill_factor: float) -> float:
    """The side (px) of the square light-sensitive area of a pixel of ``fill_factor`` (0, 1]."""
    if isinstance(fill_factor, bool) or not isinstance(fill_factor, (int, float)) or not 0 < fill_factor <= 1:
        raise ValueError(f"fill_factor={fill_factor!r} is not allowed: a fraction in (0, 1]")
    return math.sqrt(fill_factor)


def pixel_aperture_mtf(fy: torch.Tensor, fx: torch.Tensor, fill_factor: float) -> torch.Tensor:
    """``sinc(a fy) sinc(a fx)`` on the grid ``fy[:, None], fx[None, :]`` (cycles/pixel); ``a`` the aperture's side."""
    a = pixel_aperture_side_px(fill_factor)
    return torch.sinc(a * fy)[:, None] * torch.sinc(a * fx)[None, :]


def apply_pixel_aperture(psf: torch.Tensor, fill_factor: float) -> torch.Tensor:
    """PSFs ``(..., n, n)`` (centred at ``[n//2, n//2]``, unit sum) convolved with the pixel aperture: their DFT times
    :func:`pixel_aperture_mtf` at the DFT's frequencies (exact for PSFs band-limited to the pixel Nyquist frequency,
    as a Fourier-optics PSF sampled at ``lambda F# / 2`` is), same shape and dtype, unit sum."""
    n = psf.shape[-1]
    f = torch.fft.fftfreq(n, dtype=torch.float64, device=psf.device)
    h = torch.fft.fft2(torch.fft.ifftshift(psf.to(torch.float64), dim=(-2, -1)))
    out = torch.fft.fftshift(torch.fft.ifft2(h * pixel_aperture_mtf(f, f, fill_factor)).real, dim=(-2, -1))
    return (out / out.sum(dim=(-2, -1), keepdim=True)).to(psf.dtype)


@dataclass(frozen=True)
class PixelAperturePSF(DerivedPSF):
    """The PSFs of ``base`` integrated over pixels of ``fill_factor`` (:func:`apply_pixel_aperture`)."""

    base: PSFProvider
    fill_factor: float

    def __post_init__(self):
        pixel_aperture_side_px(self.fill_factor)

    def psf_at_pixels(self, rows, cols, optical_center, n: int, *, centered: bool = True, dtype=None, device=None):
        # the square aperture keeps the mirror symmetry about rows, columns and diagonals (base's flag holds)
        p = self.base.psf_at_pixels(rows, cols, optical_center, n, centered=True, dtype=dtype, device=device)
        p = apply_pixel_aperture(p, self.fill_factor)
        return p if centered else torch.fft.ifftshift(p, dim=(-2, -1))

    def extent_px(self, rows, cols, optical_center) -> int:
        e = int(self.base.extent_px(rows, cols, optical_center))
        return e + 2 if e else 0

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        e = tensor_of(self.base.extents_px(rows, cols, optical_center)).to(torch.int64)
        return torch.where(e > 0, e + 2, e)

    def derivation(self) -> str:
        return f"pixel aperture {self.fill_factor!r}"
