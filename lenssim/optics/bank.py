"""PSF and OTF banks that carry their sampling (as prysm's ``Wavefront`` carries wavelength and spacing).

A :class:`PSFBank` holds PSFs on the sensor's pixel grid with the pixel pitch (um), the wavelengths (um) and
weights they integrate, and where their origin lies; its :meth:`PSFBank.otf` is an :class:`OTFBank` whose
frequency axes are given in cycles/pixel and cycles/mm, so no caller infers a grid from a tensor's shape.
:meth:`lenssim.PSFProvider.bank` returns one for pixel positions of a frame.

The hot paths (the sweeps' quarter-plane OTF bank, the windowed blur) keep their bare tensors for speed; the
criteria receive theirs with its axes in :class:`lenssim.criteria.OTFContext`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["PSFBank", "OTFBank"]


@dataclass(frozen=True)
class PSFBank:
    """PSFs ``(P, n, n)`` or ``(P, C, n, n)`` (unit sum) sampled at ``pixel_pitch_um``; the origin (the chief ray's
    image point) at ``[n // 2, n // 2]`` if ``centered`` else at ``[0, 0]``; ``wavelengths_um`` and ``weights``: the
    spectrum they integrate (empty if unknown)."""

    psf: torch.Tensor
    pixel_pitch_um: float
    wavelengths_um: tuple[float, ...] = ()
    weights: tuple[float, ...] = ()
    centered: bool = True

    def __post_init__(self):
        if self.psf.ndim not in (3, 4) or self.psf.shape[-1] != self.psf.shape[-2]:
            raise ValueError(f"psf of shape {tuple(self.psf.shape)}: expected (P, n, n) or (P, C, n, n)")
        if not self.pixel_pitch_um > 0:
            raise ValueError(f"pixel_pitch_um={self.pixel_pitch_um!r} is not allowed: > 0 um")

    @property
    def n(self) -> int:
        """Samples per axis."""
        return int(self.psf.shape[-1])

    def coords_mm(self) -> torch.Tensor:
        """Sample positions ``(n,)`` (mm on the sensor) from the origin, along either axis, float64."""
        k = torch.arange(self.n, dtype=torch.float64, device=self.psf.device)
        k = k - self.n // 2 if self.centered else torch.where(k < (self.n + 1) // 2, k, k - self.n)
        return k * self.pixel_pitch_um * 1e-3

    def otf(self) -> OTFBank:
        """The OTFs (the DFT of the PSFs about their origin; ``H(0) = 1``) with their frequency axes."""
        p = torch.fft.ifftshift(self.psf, dim=(-2, -1)) if self.centered else self.psf
        return OTFBank(torch.fft.fft2(p), self.pixel_pitch_um, self.wavelengths_um, self.weights)


@dataclass(frozen=True)
class OTFBank:
    """OTFs ``(P, n, n)`` or ``(P, C, n, n)`` (complex, ``fft2`` layout: sample ``k`` at ``fftfreq(n)[k]`` cycles per
    pixel) of PSFs sampled at ``pixel_pitch_um``."""

    otf: torch.Tensor
    pixel_pitch_um: float
    wavelengths_um: tuple[float, ...] = ()
    weights: tuple[float, ...] = ()

    @property
    def n(self) -> int:
        return int(self.otf.shape[-1])

    @property
    def freq_cycles_per_pixel(self) -> torch.Tensor:
        """The frequency axis ``(n,)`` in cycles/pixel (``torch.fft.fftfreq``: 0, 1/n, ..., -1/n), float64."""
        return torch.fft.fftfreq(self.n, dtype=torch.float64, device=self.otf.device)

    @property
    def freq_cycles_per_mm(self) -> torch.Tensor:
        """The frequency axis ``(n,)`` in cycles/mm on the sensor, float64."""
        return self.freq_cycles_per_pixel / (self.pixel_pitch_um * 1e-3)

    @property
    def nyquist_cycles_per_mm(self) -> float:
        return 0.5 / (self.pixel_pitch_um * 1e-3)

    def mtf(self) -> torch.Tensor:
        """``|H|``, same shape as :attr:`otf`."""
        return self.otf.abs()
