"""The standard surface: a sphere or a conic (Zemax's ``STANDARD``).

Sag ``z = c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2))`` (curvature ``c`` 1/mm, conic constant ``k``: 0 a sphere, -1 a
paraboloid), slope ``c r / sqrt(1 - (1 + k) c^2 r^2)``, defined where ``(1 + k) c^2 r^2 < 1``; its ``r^4`` term is
``(1 + k) c^3 / 8``. Rays meet it in closed form (:func:`lenssim.model.surface_kinds.conic_intersection`).
"""

from __future__ import annotations

import torch

from . import SurfaceKind, register

__all__ = ["Standard", "conic_sag", "conic_slope", "STANDARD"]


def conic_sag(rho, c, k):
    """``(z, dz/drho)`` of the conic ``(c, k)`` at ``rho = r^2`` (mm^2); tensors broadcast."""
    root = torch.sqrt(torch.clamp(1 - (1 + k) * c * c * rho, min=0.0))
    z = c * rho / (1 + root)
    dz = c / (2 * root.clamp(min=1e-300))
    return z, dz


def conic_slope(r_mm, c, k):
    """Slope ``dz/dr`` of the conic of curvature ``c`` (1/mm) and conic constant ``k`` at radius ``r`` (mm)."""
    return c * r_mm / torch.sqrt(1 - (1 + k) * c**2 * r_mm**2)


class Standard(SurfaceKind):
    name = "standard"
    label = "sphere or conic"
    zemax_type = "STANDARD"

    def departs(self, s) -> bool:
        return False

    def sag(self, s, rho):
        return conic_sag(rho, s.curvature_per_mm, s.conic)

    def slope(self, s, r):
        return conic_slope(r, s.curvature_per_mm, s.conic)

    def seidel_terms(self, s):
        return s.curvature_per_mm, s.conic, 0.0

    def is_aspheric(self, s) -> bool:
        return s.conic != 0


STANDARD = register(Standard())
