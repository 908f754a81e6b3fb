"""The optical-system protocol: what the optics code (Seidel sums, PSFs, cost, exact ray trace) reads of a lens.

An optical system, for a design (:class:`lenssim.Design`), is a centred sequence of refracting surfaces
(:class:`lenssim.model.surface.Surface`: curvature in 1/mm, conic constant, index after it per wavelength, thickness
after it in mm, semi-aperture in mm, whether its conic is a free design parameter), with the aperture stop at
surface :attr:`OpticalSystem.stop_index`, an object at infinity or at a finite conjugate, a focal length, an
entrance-pupil radius and an image plane. Today's thin singlet, :class:`lenssim.Lens`, is one implementation;
a doublet or a lens from a prescription is another: it implements :meth:`OpticalSystem.surfaces` and the
quantities below, and may leave the Seidel sums to :func:`surface_seidel_sums` (the general surface-by-surface
route); the thin lens keeps its closed form as a fast path, checked against that route in the tests.

References
----------
.. [1] W. T. Welford, *Aberrations of Optical Systems* (Adam Hilger, 1986), chapters 7-8 (Seidel sums surface
   by surface; thin-lens closed forms).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch

from .paraxial import seidel_surface_sums
from ..torch_utils import tensor_of

__all__ = ["OpticalSystem", "surface_seidel_sums"]


@runtime_checkable
class OpticalSystem(Protocol):
    """What every optics routine of the package reads of a lens (units in the names)."""

    focal_length_mm: float
    """Paraxial focal length (mm) at the reference wavelength."""
    pupil_radius_mm: float
    """Entrance-pupil radius (mm)."""
    field_angles_deg: tuple[float, ...]
    """Half field angles (deg) at which field averages are sampled."""

    @property
    def stop_index(self) -> int:
        """Index of the aperture-stop surface in :meth:`surfaces`."""

    @property
    def image_distance_mm(self) -> float:
        """Distance (mm) from the last surface to the paraxial image plane at the reference wavelength."""

    @property
    def f_number(self) -> float:
        """Working f-number ``f / (2 y)``."""

    def surfaces(self, design, wavelength_um: float | None = None) -> list:
        """The surfaces for ``design`` (tensors broadcasting like the design), with indices at ``wavelength_um``."""

    def check_design(self, design) -> None:
        """Raise :class:`lenssim.LensError` naming a design the system cannot take."""

    def seidel_sums(self, design, alpha, wavelength_um: float | None = None) -> torch.Tensor:
        """Seidel sums ``(S_I, S_II, S_III, S_IV)`` (mm) for ``design`` and field angles ``alpha`` (deg, broadcasting
        with the design): ``(*, 4)``."""

    def focus_distance_mm(self, wavelength_um: float | None = None) -> float:
        """Distance (mm) from the last surface to the focus at ``wavelength_um`` (axial colour)."""


def surface_seidel_sums(system: OpticalSystem, design, alpha, wavelength_um: float | None = None,
                        object_vergence_per_mm: float = 0.0) -> torch.Tensor:
    """``(S_I, S_II, S_III, S_IV)`` (mm) of any centred system by the surface-by-surface route
    (:func:`lenssim.optics.paraxial.seidel_surface_sums`), with the stop at the first surface: the marginal ray at the
    pupil's edge with slope ``-y * object_vergence`` (0: object at infinity), the chief ray through the stop's
    centre at ``tan(alpha)``. ``alpha`` (deg) broadcasts with the design; returns ``(*, 4)``."""
    if system.stop_index != 0:
        raise ValueError("surface_seidel_sums puts the stop at the first surface; this system's stop is at surface "
                         f"{system.stop_index}")
    alpha = tensor_of(alpha, torch.float64)
    y = system.pupil_radius_mm
    u = torch.full_like(alpha, -y * object_vergence_per_mm)
    s = seidel_surface_sums(system.surfaces(design, wavelength_um), torch.full_like(alpha, y), u,
                            torch.zeros_like(alpha), torch.tan(torch.deg2rad(alpha)))
    return s[..., :4]
