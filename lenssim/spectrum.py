"""The light the lens images: wavelengths (um) with relative weights.

The paper works at one wavelength, 0.5 um (:data:`lenssim.paper.PAPER_SPECTRUM`). A PSF for a
spectrum is the weighted sum of the unit-sum PSFs at each wavelength on the sensor's fixed pixel
grid (each wavelength has its own pupil scale), so its OTF is the weighted sum of the OTFs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Spectrum"]


@dataclass(frozen=True)
class Spectrum:
    """Wavelengths ``wavelengths_um`` (> 0) with weights (>= 0, normalised here to sum 1)."""

    wavelengths_um: tuple[float, ...] = (0.5,)
    weights: tuple[float, ...] = (1.0,)
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
