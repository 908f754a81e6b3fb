"""A refracting surface: the data an optical system is made of (:meth:`lenssim.Lens.surfaces`).

The model layer's description of a surface; the optics reads it (the paraxial Seidel sums of
:mod:`lenssim.optics.paraxial`, the exact ray trace (:func:`lenssim.optics.sequential.trace_rays_opl`), the cost of
:mod:`lenssim.optics.cost`). ``lenssim.optics.paraxial.Surface`` is the same class.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["Surface"]


@dataclass(frozen=True)
class Surface:
    """A refracting surface.

    curvature : 1/mm; conic : conic constant kappa (0 = sphere);
    n_after : refractive index after the surface; thickness_after_mm : distance to the next one;
    aspheric : the conic is a free design parameter (named ``conic_name``): counted by the
    industrial cost (:mod:`lenssim.optics.cost`); semi_aperture_mm : the clear radius over which the surface is
    used (and made: the cost's aperture); None: the system's pupil radius; decentre_mm : ``(dx, dy)`` mm of the
    vertex off the axis and tilt_deg : ``(tx, ty)`` degrees about the vertex (x axis, then y axis): a displaced
    surface, which only the exact ray trace (:func:`lenssim.optics.sequential.surfaces_lens`) reads; aspheric_coefficients: see below.
    """

    curvature: float | torch.Tensor
    conic: float | torch.Tensor = 0.0
    n_after: float = 1.0
    thickness_after_mm: float = 0.0
    aspheric: bool = False
    conic_name: str | None = None
    semi_aperture_mm: float | None = None
    decentre_mm: tuple[float, float] = (0.0, 0.0)
    tilt_deg: tuple[float, float] = (0.0, 0.0)
    aspheric_coefficients: tuple = ()
    """``(A4, A6, ...)``: even-asphere coefficients of ``r^4, r^6, ...`` (mm^-3, mm^-5, ...) added to the conic's sag;
    the Seidel sums read ``A4`` (its fourth-order term is that of a conic ``8 A4 / c^3``), the exact trace all."""
