"""Lens glasses: the refractive index as a function of wavelength.

The paper's glass is non-dispersive, ``n = 1.5`` at every wavelength (:class:`ConstantGlass`).
A dispersive glass is any object with a ``name`` and ``index(wavelength_um) -> float``; the lens,
the aberrations and the PSFs ask for the index at each wavelength of the spectrum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ConstantGlass", "as_glass"]


@dataclass(frozen=True)
class ConstantGlass:
    """A glass of the same refractive index ``refractive_index`` (> 1) at every wavelength."""

    refractive_index: float = 1.5

    def __post_init__(self):
        n = self.refractive_index
        if isinstance(n, bool) or not isinstance(n, (int, float)) or not math.isfinite(n) or not n > 1:
            raise ValueError(f"refractive_index={n!r} is not allowed: a finite number > 1")
        object.__setattr__(self, "refractive_index", float(n))

    @property
    def name(self) -> str:
        return f"n = {self.refractive_index:g}"

    def index(self, wavelength_um: float) -> float:
        """Refractive index at ``wavelength_um`` (the same at every wavelength)."""
        return self.refractive_index


def as_glass(g) -> ConstantGlass:
    """A glass object from a glass or a number (a constant refractive index)."""
    if hasattr(g, "index") and hasattr(g, "name"):
        return g
    return ConstantGlass(g)
