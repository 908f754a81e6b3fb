"""Decentre and tilt of a surface or an element (a manufactured or assembled lens's misalignment), as data.

A :class:`Misalignment` moves one surface of a sequential lens rigidly (the lens's frame: axis ``z``, surface 1's
vertex at ``z = 0``, fields along ``+y``, mm): first a tilt, a rotation about an axis in the ``xy`` plane through the
*pivot* ``(0, 0, pivot_z_mm)`` on the optical axis (the surface's own vertex unless given), then a decentre, a
translation ``(decentre_x_mm, decentre_y_mm, 0)`` across the axis. A point ``X`` of the nominal surface goes to
``R (X - pivot) + pivot + decentre``.

Sign and order of the tilt: ``(tilt_x_deg, tilt_y_deg, 0)`` is the tilt's rotation vector (degrees), i.e. one
right-handed rotation by ``sqrt(tilt_x^2 + tilt_y^2)`` about the unit axis ``(tilt_x, tilt_y, 0) / |.|``, so there is
no order between the two: ``tilt_x`` alone is the right-handed rotation about ``+x``, which turns the surface's axis
(its vertex normal, nominally ``+z``) toward ``-y`` (to ``(0, -sin a, cos a)``); ``tilt_y`` alone is the right-handed
rotation about ``+y``, which turns it toward ``+x`` (to ``(sin b, 0, cos b)``). For a tilt about one axis this is the
right-handed rotation of OpticStudio's coordinate breaks and of Optiland's ``rx``/``ry``; with both nonzero those
programs apply ``R_y R_x`` in sequence, which differs from this rotation at second order in the angles (~1e-8 rad for
0.01-degree tilts). The rotation-vector form makes a misalignment turn exactly with the frame
(:meth:`Misalignment.rotated`).

An element's misalignment (OpticStudio's TEDX/TEDY/TETX/TETY) is the same rigid motion of all its surfaces with the
pivot at its first surface's vertex: :func:`element_misalignment`.

Nothing here traces a ray: :class:`lenssim.optics.sequential.SequentialLens` takes ``misalignments``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from .prescription import Prescription

__all__ = ["Misalignment", "element_misalignment", "MAX_TILT_DEG"]

MAX_TILT_DEG = 90.0
"""A surface tilted this much or more (degrees, the rotation's angle) no longer faces the beam: refused."""

_AMOUNTS = ("decentre_x_mm", "decentre_y_mm", "tilt_x_deg", "tilt_y_deg")


def _cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    """``cos`` and ``sin`` of an angle in degrees, exact at multiples of 90 degrees (so a quarter turn of the frame
    maps decentres and tilts onto each other without rounding)."""
    q, r = divmod(angle_deg, 90.0)
    if r == 0.0:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(q) % 4]
    a = math.radians(angle_deg)
    return math.cos(a), math.sin(a)


@dataclass(frozen=True, kw_only=True)
class Misalignment:
    """A rigid motion of one surface (module docstring): decentres in mm across the axis, tilts in degrees (the
    rotation vector's ``x`` and ``y`` components, right-handed), the tilt's pivot on the axis at ``z = pivot_z_mm``
    (mm, the lens's frame: surface 1's vertex at 0; ``None``: the surface's own vertex)."""

    decentre_x_mm: float = 0.0
    decentre_y_mm: float = 0.0
    tilt_x_deg: float = 0.0
    """Right-handed rotation about ``+x`` (degrees): a positive tilt turns the surface's axis toward ``-y``."""
    tilt_y_deg: float = 0.0
    """Right-handed rotation about ``+y`` (degrees): a positive tilt turns the surface's axis toward ``+x``."""
    pivot_z_mm: float | None = None

    def __post_init__(self):
        for name in _AMOUNTS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"misalignment: {name}={v!r} is not allowed: a finite number")
            object.__setattr__(self, name, float(v))
        pz = self.pivot_z_mm
        if pz is not None:
            if isinstance(pz, bool) or not isinstance(pz, (int, float)) or not math.isfinite(pz):
                raise ValueError(f"misalignment: pivot_z_mm={pz!r} is not allowed: a finite number (mm) or None")
            object.__setattr__(self, "pivot_z_mm", float(pz))
        if not self.tilt_deg < MAX_TILT_DEG:
            raise ValueError(f"misalignment: tilt_x_deg={self.tilt_x_deg!r}, tilt_y_deg={self.tilt_y_deg!r} is not "
                             f"allowed: a tilt below {MAX_TILT_DEG:g} degrees in all")

    @property
    def tilt_deg(self) -> float:
        """The tilt's angle (degrees): the length of the rotation vector ``(tilt_x_deg, tilt_y_deg)``."""
        return math.hypot(self.tilt_x_deg, self.tilt_y_deg)

    @property
    def is_zero(self) -> bool:
        """No decentre and no tilt (the pivot then does not matter)."""
        return all(getattr(self, name) == 0.0 for name in _AMOUNTS)

    def rotated(self, azimuth_deg: float) -> "Misalignment":
        """The same misalignment seen in a frame turned about ``z``: the new frame's ``+y`` axis is the direction at
        azimuth ``azimuth_deg`` (degrees, measured from ``+y`` toward ``+x``) of this frame, its ``+x`` axis the
        direction at ``azimuth_deg + 90``. Decentre and tilt vectors ``(x, y)`` become ``(x cos a - y sin a,
        x sin a + y cos a)``; the pivot (on the axis) is kept. E.g. ``rotated(90)`` of a decentre along ``+x`` is a
        decentre along ``+y``."""
        if isinstance(azimuth_deg, bool) or not isinstance(azimuth_deg, (int, float)) or not math.isfinite(azimuth_deg):
            raise ValueError(f"misalignment: azimuth_deg={azimuth_deg!r} is not allowed: a finite number")
        c, s = _cos_sin_deg(float(azimuth_deg))

        def turn(x, y):
            return x * c - y * s, x * s + y * c

        dx, dy = turn(self.decentre_x_mm, self.decentre_y_mm)
        tx, ty = turn(self.tilt_x_deg, self.tilt_y_deg)
        return Misalignment(decentre_x_mm=dx + 0.0, decentre_y_mm=dy + 0.0, tilt_x_deg=tx + 0.0, tilt_y_deg=ty + 0.0,
                            pivot_z_mm=self.pivot_z_mm)

    def rotation_matrix(self) -> tuple[tuple[float, float, float], ...]:
        """The tilt's rotation ``R`` (3 x 3, rows; Rodrigues' formula for the rotation vector ``(tilt_x, tilt_y, 0)``
        in radians): a nominal surface point ``X`` goes to ``R (X - pivot) + pivot + decentre``."""
        a = math.radians(self.tilt_deg)
        if a == 0.0:
            return ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        kx, ky = math.radians(self.tilt_x_deg) / a, math.radians(self.tilt_y_deg) / a
        c, s = math.cos(a), math.sin(a)
        v = 1.0 - c
        return ((c + v * kx * kx, v * kx * ky, s * ky),
                (v * kx * ky, c + v * ky * ky, -s * kx),
                (-s * ky, s * kx, c))

    def to_dict(self) -> dict:
        """The fields by name (units in the names; ``pivot_z_mm`` None: the surface's vertex)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def element_misalignment(prescription: Prescription, first: int, last: int, *, decentre_x_mm: float = 0.0,
                         decentre_y_mm: float = 0.0, tilt_x_deg: float = 0.0,
                         tilt_y_deg: float = 0.0) -> dict[int, Misalignment]:
    """One rigid motion of surfaces ``first..last`` (0-based indices into ``prescription.surfaces``, both included):
    decentres (mm) and tilts (degrees, as :class:`Misalignment`), the tilt's pivot at surface ``first``'s vertex
    (OpticStudio's element tilt and decentre, TEDX/TEDY/TETX/TETY). Returns ``{surface index: Misalignment}`` for
    :class:`lenssim.optics.sequential.SequentialLens`'s ``misalignments``."""
    n = len(prescription.surfaces)
    for name, v in (("first", first), ("last", last)):
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < n:
            raise ValueError(f"element: {name}={v!r} is not allowed: a surface index from 0 to {n - 1}")
    if last < first:
        raise ValueError(f"element: last={last} is not allowed: an index >= first={first}")
    pivot = prescription.vertex_z_mm[first]
    m = Misalignment(decentre_x_mm=decentre_x_mm, decentre_y_mm=decentre_y_mm, tilt_x_deg=tilt_x_deg,
                     tilt_y_deg=tilt_y_deg, pivot_z_mm=pivot)
    return {i: m for i in range(first, last + 1)}
