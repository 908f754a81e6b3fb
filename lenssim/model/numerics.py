"""Numerical settings, named once: every FFT-size rule, pupil sampling and cost quadrature reads them.

``DEFAULT_NUMERICS`` is the accurate setting that meets the 0.2%-of-4x-size convergence criterion
on the paper's designs (docs/reproduction.md); ``FAST_NUMERICS`` drops the 2x frequency
oversampling of the MSE integrals (MSE_R field error <= 0.3%, the fast sweep preset).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

from .spectrum import DEFAULT_SPECTRAL_TOL

__all__ = ["Numerics", "DEFAULT_NUMERICS", "FAST_NUMERICS"]


@dataclass(frozen=True)
class Numerics:
    """Sampling and size rules.

    fill : at most ``fill`` x the Nyquist limit (0.5 wave per pupil sample) of pupil phase, and the
        geometric PSF within ``fill`` of the FFT grid (see :func:`lenssim.optics.psf_bank.fft_size`).
    margin_px : pixels of diffraction margin added to the geometric PSF diameter.
    min_size : smallest FFT size (samples).
    oversample : frequency grid of the MSE integrals = ``oversample`` x the FFT size.
    supersample : sub-samples per axis for the anti-aliased pupil rim.
    cost_points : radii of the slope-departure cost quadrature.
    chunk_bytes : working memory per chunk of OTFs in the metrics (cache-sized on a CPU).
    max_fft_size : largest FFT size a PSF may ask for (samples): a design whose wavefront slope needs
        more is refused before any work (an oversampled OTF of 4096 points holds ~1.6 GB).
    spectral_tol : error indicator bound (px) of the wavelengths shared by colour channels on one table
        (:func:`lenssim.model.spectrum.shared_quadrature`); smaller takes more wavelengths.
    """

    fill: float = 0.5
    margin_px: int = 16
    min_size: int = 256
    oversample: int = 2
    supersample: int = 8
    cost_points: int = 101
    chunk_bytes: int = 32 * 2**20
    max_fft_size: int = 4096
    spectral_tol: float = DEFAULT_SPECTRAL_TOL

    def __post_init__(self):
        if not (isinstance(self.fill, (int, float)) and 0 < self.fill <= 1):
            raise ValueError(f"fill={self.fill!r} is not allowed: must be in (0, 1]")
        for k, lo in (("margin_px", 0), ("min_size", 16), ("oversample", 1), ("supersample", 1), ("cost_points", 2),
                      ("chunk_bytes", 1), ("max_fft_size", 16)):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{k}={v!r} is not allowed: an integer >= {lo}")
        object.__setattr__(self, "fill", float(self.fill))
        if isinstance(self.spectral_tol, bool) or not (isinstance(self.spectral_tol, (int, float))
                                                        and math.isfinite(self.spectral_tol) and self.spectral_tol > 0):
            raise ValueError(f"spectral_tol={self.spectral_tol!r} is not allowed: a number > 0 (px)")
        object.__setattr__(self, "spectral_tol", float(self.spectral_tol))

    def replace(self, **kw) -> "Numerics":
        return replace(self, **kw)

    def to_dict(self) -> dict:
        return asdict(self)


DEFAULT_NUMERICS = Numerics()
FAST_NUMERICS = Numerics(oversample=1)
