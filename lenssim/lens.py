"""Thin singlet with a spherical anterior and a conic posterior surface.

The lens of the paper (Optics Express 31(10) 16897, 2023, Section 2.1 and 3.1):
focal length ``f``, stop at the lens with pupil radius ``y``, refractive index ``n``
at wavelength ``lambda``, object at infinity (position factor ``p = -1``).

Conventions (Welford, *Aberrations of Optical Systems*, thin-lens chapter):

* shape factor ``s = (c1 + c2) / (c1 - c2)`` (Welford's bending ``X``),
* position factor ``p = 1 - 2 f / t`` (Welford's conjugate ``Y``; ``t`` lens-to-image distance),
* curvatures ``c1 = (s + 1) / (2 f (n - 1))`` and ``c2 = (s - 1) / (2 f (n - 1))`` in 1/mm,
* the posterior surface has conic constant ``Q`` (``Q = 0`` sphere, ``-1`` paraboloid).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import torch

__all__ = ["LensError", "ThinLens", "PAPER_LENS", "as_tensor"]


class LensError(ValueError):
    """A lens or design parameter outside its physical range."""


def as_tensor(x, *, like: torch.Tensor | None = None, dtype=None, device=None) -> torch.Tensor:
    """Convert ``x`` to a floating tensor, following ``like`` (dtype, device) when given."""
    if like is not None:
        dtype = dtype or like.dtype
        device = device or like.device
    if isinstance(x, torch.Tensor):
        if not x.is_floating_point():
            x = x.to(torch.get_default_dtype())
        return x.to(dtype=dtype or x.dtype, device=device or x.device)
    return torch.as_tensor(x, dtype=dtype or torch.get_default_dtype(), device=device)


def _check(name: str, value: float, ok: bool, allowed: str) -> None:
    if not ok:
        raise LensError(f"{name}={value!r} is not allowed: {allowed}")


@dataclass(frozen=True)
class ThinLens:
    """System parameters shared by every design of the sweep.

    Parameters
    ----------
    focal_length_mm : float
        Paraxial focal length ``f`` in mm, > 0.
    pupil_radius_mm : float
        Entrance-pupil (= lens aperture, stop at the lens) radius ``y`` in mm, 0 < y < f.
    refractive_index : float
        Refractive index ``n`` of the glass at ``wavelength_um``, > 1.
    wavelength_um : float
        Wavelength in micrometres, > 0.
    position_factor : float
        ``p = 1 - 2 f / t``; -1 for an object at infinity. Must be < 1 (real image).
    field_angles_deg : tuple of float
        Half field angles (degrees) at which field-averaged metrics are sampled, each in [0, 90).
    """

    focal_length_mm: float = 25.0
    pupil_radius_mm: float = 2.0
    refractive_index: float = 1.5
    wavelength_um: float = 0.5
    position_factor: float = -1.0
    field_angles_deg: tuple[float, ...] = field(default_factory=lambda: tuple(float(a) for a in range(15)))

    def __post_init__(self) -> None:
        for f_ in fields(self):
            v = getattr(self, f_.name)
            if f_.name == "field_angles_deg":
                try:
                    v = tuple(float(a) for a in v)
                except TypeError as exc:
                    raise LensError(f"field_angles_deg={v!r} is not allowed: a sequence of angles in degrees") from exc
                object.__setattr__(self, "field_angles_deg", v)
                continue
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise LensError(f"{f_.name}={v!r} is not allowed: a finite number")
            object.__setattr__(self, f_.name, float(v))
        _check("focal_length_mm", self.focal_length_mm, self.focal_length_mm > 0, "must be > 0 mm")
        _check("pupil_radius_mm", self.pupil_radius_mm, 0 < self.pupil_radius_mm < self.focal_length_mm,
               f"must be in (0, focal_length_mm={self.focal_length_mm}) mm")
        _check("refractive_index", self.refractive_index, self.refractive_index > 1, "must be > 1")
        _check("wavelength_um", self.wavelength_um, self.wavelength_um > 0, "must be > 0 um")
        _check("position_factor", self.position_factor, self.position_factor < 1,
               "must be < 1 (p = 1 - 2f/t with a real image at t > 0)")
        if len(self.field_angles_deg) == 0:
            raise LensError("field_angles_deg=() is not allowed: give at least one angle in [0, 90) degrees")
        for a in self.field_angles_deg:
            _check("field angle (deg)", a, math.isfinite(a) and 0 <= a < 90, "must be in [0, 90) degrees")

    # ---- derived quantities -------------------------------------------------------------
    @property
    def wavelength_mm(self) -> float:
        return self.wavelength_um * 1e-3

    @property
    def f_number(self) -> float:
        """Working f-number ``f / (2 y)`` (dimensionless)."""
        return self.focal_length_mm / (2 * self.pupil_radius_mm)

    @property
    def image_distance_mm(self) -> float:
        """Lens-to-image distance ``t = 2 f / (1 - p)`` in mm."""
        return 2 * self.focal_length_mm / (1 - self.position_factor)

    @property
    def pixel_pitch_um(self) -> float:
        """Nyquist pixel pitch ``lambda f# / 2`` in um (1.5625 um for the paper's lens)."""
        return self.wavelength_um * self.f_number / 2

    def curvatures(self, s):
        """Surface curvatures ``(c1, c2)`` in 1/mm for shape factor(s) ``s``."""
        k = 2 * self.focal_length_mm * (self.refractive_index - 1)
        return (s + 1) / k, (s - 1) / k

    def field_angles(self, *, dtype=None, device=None) -> torch.Tensor:
        """Field angles as a tensor of shape ``(A,)`` in degrees."""
        return torch.tensor(self.field_angles_deg, dtype=dtype or torch.get_default_dtype(), device=device)

    def image_height_mm(self, alpha_deg):
        """Paraxial image height ``f tan(alpha)`` in mm (magnitude; the image is inverted)."""
        alpha = as_tensor(alpha_deg)
        return self.focal_length_mm * torch.tan(torch.deg2rad(alpha))

    def field_angle_deg(self, x_mm, y_mm):
        """Field angle (deg) of the image point ``(x, y)`` (mm from the optical axis)."""
        r = torch.hypot(as_tensor(x_mm), as_tensor(y_mm))
        return torch.rad2deg(torch.atan(r / self.focal_length_mm))

    def check_design(self, s, Q) -> None:
        """Raise :class:`LensError` if a design ``(s, Q)`` is not a physical lens.

        The shape factor must be finite; the conic must be defined over the whole aperture,
        ``(1 + Q) c2^2 y^2 < 1``; the spherical front must not be a hemisphere smaller than
        the aperture, ``c1^2 y^2 < 1``.
        """
        s_t = as_tensor(s, dtype=torch.float64)
        q_t = as_tensor(Q, dtype=torch.float64)
        for name, t in (("s", s_t), ("Q", q_t)):
            bad = ~torch.isfinite(t)
            if bad.any():
                raise LensError(f"{name}={t[bad].flatten()[0].item()!r} is not allowed: a finite number")
        c1, c2 = self.curvatures(s_t)
        y2 = self.pupil_radius_mm**2
        arg = torch.broadcast_to(1 - (1 + q_t) * c2**2 * y2, torch.broadcast_shapes(s_t.shape, q_t.shape))
        if (arg <= 0).any():
            i = int(torch.nonzero((arg <= 0).flatten())[0])
            sb = torch.broadcast_to(s_t, arg.shape).flatten()[i].item()
            qb = torch.broadcast_to(q_t, arg.shape).flatten()[i].item()
            lim = 1 / (self.curvatures(sb)[1] ** 2 * y2) - 1
            raise LensError(
                f"Q={qb!r} with s={sb!r} is not allowed: the conic back surface is undefined over the "
                f"{self.pupil_radius_mm} mm aperture; Q must be < {lim:.6g} for this s"
            )
        if (c1**2 * y2 >= 1).any():
            sb = s_t.flatten()[int(torch.nonzero((c1**2 * y2 >= 1).flatten())[0])].item()
            raise LensError(f"s={sb!r} is not allowed: the front sphere is smaller than the aperture")


PAPER_LENS = ThinLens()
"""The paper's lens: f = 25 mm, y = 2 mm, n = 1.5, lambda = 0.5 um, p = -1, alpha = 0..14 deg."""
