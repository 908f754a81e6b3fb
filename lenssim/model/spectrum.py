"""The light the lens images: wavelengths (um) with relative weights.

The paper works at one wavelength, 0.5 um (:data:`lenssim.paper.PAPER_SPECTRUM`). A PSF for a
spectrum is the weighted sum of the unit-sum PSFs at each wavelength on the sensor's fixed pixel
grid (each wavelength has its own pupil scale), so its OTF is the weighted sum of the OTFs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Spectrum", "channel_spectra", "camera_sensitivity_names", "DEFAULT_WAVELENGTHS_PER_CHANNEL"]

DEFAULT_WAVELENGTHS_PER_CHANNEL = 16
"""Wavelengths per colour channel (equal-weight quadrature of sensitivity x illuminant); chosen by the
convergence test in tests/lenssim/test_colour.py: per-channel MSE_R of the paper's end-to-end design in N-BK7
focused at the d line (the harshest case: blue and red 1-2 waves out of focus) within 0.7% of the 32-wavelength
value (measured 0.23 / 0.19 / 0.64% for R / G / B; against 48 wavelengths 0.26 / 0.21 / 0.50%; with 5
wavelengths up to 4%)."""


@dataclass(frozen=True)
class Spectrum:
    """Wavelengths ``wavelengths_um`` (> 0) with weights (>= 0, normalised here to sum 1)."""

    wavelengths_um: tuple[float, ...]
    weights: tuple[float, ...]
    name: str = ""

    def __post_init__(self):
        try:
            lam = tuple(float(v) for v in self.wavelengths_um)
            w = tuple(float(v) for v in self.weights)
        except (TypeError, ValueError):
            raise ValueError(f"spectrum {self.wavelengths_um!r} / {self.weights!r} is not allowed: "
                             "sequences of numbers") from None
        if not lam or len(lam) != len(w):
            raise ValueError(f"spectrum: {len(lam)} wavelengths and {len(w)} weights; give at least one of each, "
                             "equally many")
        if not all(math.isfinite(v) and v > 0 for v in lam):
            raise ValueError(f"wavelengths_um={lam!r} is not allowed: finite values > 0 um")
        if not all(math.isfinite(v) and v >= 0 for v in w) or not sum(w) > 0:
            raise ValueError(f"weights={w!r} is not allowed: finite values >= 0 with a positive sum")
        total = sum(w)
        object.__setattr__(self, "wavelengths_um", lam)
        object.__setattr__(self, "weights", tuple(v / total for v in w))
        if not self.name:
            object.__setattr__(self, "name", f"monochromatic {lam[0]:g} um" if len(lam) == 1
                               else f"{len(lam)} wavelengths {min(lam):g}-{max(lam):g} um")

    @classmethod
    def monochromatic(cls, wavelength_um: float) -> "Spectrum":
        return cls((wavelength_um,), (1.0,))

    def __len__(self) -> int:
        return len(self.wavelengths_um)

    @property
    def reference_um(self) -> float:
        """Weighted mean wavelength (um): the unit of wavefront errors reported in waves."""
        if len(self.wavelengths_um) == 1:
            return self.wavelengths_um[0]
        return sum(l * w for l, w in zip(self.wavelengths_um, self.weights))

    @property
    def shortest_um(self) -> float:
        return min(self.wavelengths_um)

    def to_dict(self) -> dict:
        return {"wavelengths_um": list(self.wavelengths_um), "weights": list(self.weights), "name": self.name}


def camera_sensitivity_names() -> list[str]:
    """Camera RGB sensitivities that colour-science ships (``colour.MSDS_CAMERA_SENSITIVITIES``)."""
    import colour

    return sorted(colour.MSDS_CAMERA_SENSITIVITIES)


def channel_spectra(camera: str = "Nikon 5100 (NPL)", illuminant: str = "D65",
                    per_channel: int = DEFAULT_WAVELENGTHS_PER_CHANNEL) -> tuple[Spectrum, ...]:
    """One :class:`Spectrum` per colour channel: the camera's spectral sensitivity times the illuminant,
    both from colour-science's data sets, sampled at ``per_channel`` wavelengths.

    Quadrature: the channel's weight ``w(lambda)`` (5 nm table, piecewise constant) is cut into
    ``per_channel`` bins of equal weight; each bin contributes its weighted mean wavelength with its
    weight. Channels in the camera's order (red, green, blue).
    """
    import colour
    import numpy as np

    if camera not in colour.MSDS_CAMERA_SENSITIVITIES:
        raise ValueError(f"camera sensitivities {camera!r} are not known; choose from {', '.join(camera_sensitivity_names())}")
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"illuminant {illuminant!r} is not known; e.g. D65, A, D50")
    if isinstance(per_channel, bool) or not isinstance(per_channel, int) or not 1 <= per_channel <= 64:
        raise ValueError(f"per_channel={per_channel!r} is not allowed: a whole number in [1, 64]")
    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    lam_nm = np.asarray(msds.wavelengths, dtype=np.float64)
    ill = colour.SDS_ILLUMINANTS[illuminant].copy().align(colour.SpectralShape(lam_nm[0], lam_nm[-1], lam_nm[1] - lam_nm[0]))
    e = np.asarray(ill.values, dtype=np.float64)
    out = []
    for c, label in enumerate(msds.labels):
        w = np.clip(np.asarray(msds.values[:, c], dtype=np.float64), 0, None) * e
        cdf = np.concatenate([[0.0], np.cumsum(w)]) / w.sum()
        edges = np.linspace(0, 1, per_channel + 1)
        lams, weights = [], []
        for a, b in zip(edges[:-1], edges[1:]):
            # share of each 5 nm sample inside the bin [a, b] of cumulative weight
            share = np.clip(np.minimum(cdf[1:], b) - np.maximum(cdf[:-1], a), 0, None) * w.sum()
            lams.append(float((share * lam_nm).sum() / share.sum()) * 1e-3)
            weights.append(float(share.sum()))
        out.append(Spectrum(tuple(lams), tuple(weights), name=f"{camera} {label}, {illuminant}, {per_channel} wavelengths"))
    return tuple(out)
