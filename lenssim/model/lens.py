"""The thin singlet: a spherical front surface and a conic back surface, stop at the lens.

The lens of the paper (Optics Express 31(10) 16897, 2023, Section 2.1 and 3.1): focal length
``f``, stop at the lens with pupil radius ``y``, a glass of refractive index ``n``, object at
infinity (position factor ``p = -1``), field angles 0..14 degrees. The free parameters of a
design (:class:`lenssim.model.design.Design`) set the surfaces (:meth:`Lens.surfaces`).

Conventions (Welford, *Aberrations of Optical Systems*, thin-lens chapter):

* shape factor ``s = (c1 + c2) / (c1 - c2)`` (Welford's bending ``X``),
* position factor ``p = 1 - 2 f / t`` (Welford's conjugate ``Y``; ``t`` lens-to-image distance),
* curvatures ``c1 = (s + 1) / (2 f (n - 1))`` and ``c2 = (s - 1) / (2 f (n - 1))`` in 1/mm,
* the back surface has conic constant ``Q_back`` (``0`` sphere, ``-1`` paraboloid).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

from .design import Design
from .glass import ConstantGlass, as_glass
from .surface import Surface
from ..torch_utils import HOST, as_tensor, broadcast_shape
from ..validate import listed, quoted, warn_model

THIRD_ORDER_LIMIT = 0.25
"""Largest ``(1 + conic) c^2 y^2`` of a surface for which the third-order model is taken as valid (the paper's
grid reaches 0.13); beyond it a warning (the surface itself is defined up to 1)."""

__all__ = ["LensError", "Lens", "as_tensor"]


class LensError(ValueError):
    """A lens or design parameter outside its physical range."""


def _check(name: str, value: float, ok: bool, allowed: str) -> None:
    if not ok:
        raise LensError(f"{name}={value!r} is not allowed: {allowed}")


@dataclass(frozen=True, kw_only=True)
class Lens:
    """The physical singlet shared by every design of a sweep.

    Parameters
    ----------
    focal_length_mm : float
        Paraxial focal length ``f`` in mm, > 0.
    pupil_radius_mm : float
        Entrance-pupil (= lens aperture, stop at the lens) radius ``y`` in mm, 0 < y < f.
    glass : glass object or float
        The glass (:mod:`lenssim.model.glass`); a number is a constant refractive index (> 1).
    position_factor : float
        ``p = 1 - 2 f / t``; -1 for an object at infinity. Must be < 1 (real image).
    field_angles_deg : tuple of float
        Half field angles (degrees) at which field-averaged metrics are sampled, each in [0, 90).
    """

    focal_length_mm: float
    pupil_radius_mm: float
    glass: ConstantGlass
    field_angles_deg: tuple[float, ...]
    position_factor: float = -1.0

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "glass", as_glass(self.glass))
        except ValueError as exc:
            raise LensError(str(exc)) from None
        for f_ in fields(self):
            v = getattr(self, f_.name)
            if f_.name == "glass":
                continue
            if f_.name == "field_angles_deg":
                try:
                    v = tuple(float(a) for a in v)
                except (TypeError, ValueError) as exc:
                    raise LensError(f"field_angles_deg={v!r} is not allowed: a sequence of angles in degrees") from exc
                object.__setattr__(self, "field_angles_deg", v)
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise LensError(f"{f_.name}={v!r} is not allowed: a finite number")
            object.__setattr__(self, f_.name, float(v))
        _check("focal_length_mm", self.focal_length_mm, self.focal_length_mm > 0, "must be > 0 mm")
        _check("pupil_radius_mm", self.pupil_radius_mm, 0 < self.pupil_radius_mm < self.focal_length_mm,
               f"must be in (0, focal_length_mm={self.focal_length_mm}) mm")
        _check("position_factor", self.position_factor, self.position_factor < 1,
               "must be < 1 (p = 1 - 2f/t with a real image at t > 0)")
        if len(self.field_angles_deg) == 0:
            raise LensError("field_angles_deg=() is not allowed: give at least one angle in [0, 90) degrees")
        for a in self.field_angles_deg:
            _check("field angle (deg)", a, math.isfinite(a) and 0 <= a < 90, "must be in [0, 90) degrees")

    @classmethod
    def from_dict(cls, d: dict) -> "Lens":
        """From a config table: ``refractive_index`` (a constant glass) is accepted for ``glass``."""
        d = dict(d)
        if d.get("refractive_index", 0) is None:
            d.pop("refractive_index")
        if "refractive_index" in d:
            if "glass" in d:
                raise LensError("give either glass or refractive_index, not both")
            n = d.pop("refractive_index")
            if isinstance(n, bool) or not isinstance(n, (int, float)):
                raise LensError(f"refractive_index={quoted(n)} is not allowed: a finite number > 1 (or name a glass)")
            d["glass"] = n  # a number: a constant glass
        allowed = {f.name for f in fields(cls)}
        bad = sorted(set(d) - allowed)
        if bad:
            raise LensError(f"unknown lens key(s) {listed(bad)}; allowed: {listed(sorted(allowed | {'refractive_index'}), near=bad)}")
        return cls(**d)

    def to_dict(self) -> dict:
        glass = {"glass": self.glass.name} if getattr(self.glass, "dispersive", False) else \
            {"refractive_index": self.refractive_index}
        return {"focal_length_mm": self.focal_length_mm, "pupil_radius_mm": self.pupil_radius_mm, **glass,
                "position_factor": self.position_factor, "field_angles_deg": list(self.field_angles_deg)}

    # ---- derived quantities -------------------------------------------------------------
    @property
    def refractive_index(self) -> float:
        """Refractive index of the glass that sets the curvatures (a constant glass's only index)."""
        return self.glass.refractive_index

    @property
    def f_number(self) -> float:
        """Working f-number ``f / (2 y)`` (dimensionless)."""
        return self.focal_length_mm / (2 * self.pupil_radius_mm)

    @property
    def image_distance_mm(self) -> float:
        """Lens-to-image distance ``t = 2 f / (1 - p)`` in mm."""
        return 2 * self.focal_length_mm / (1 - self.position_factor)

    def nyquist_pitch_um(self, wavelength_um: float) -> float:
        """The pixel pitch ``lambda f# / 2`` (um) at which the OTF's cut-off is the Nyquist frequency."""
        return wavelength_um * self.f_number / 2

    def curvatures(self, s):
        """Surface curvatures ``(c1, c2)`` in 1/mm for shape factor(s) ``s``."""
        k = 2 * self.focal_length_mm * (self.refractive_index - 1)
        return (s + 1) / k, (s - 1) / k

    def surfaces(self, design: Design, wavelength_um: float | None = None) -> list[Surface]:
        """The two surfaces (zero separation) for ``design``: the front (a sphere unless the design gives
        ``Q_front``) and the conic back, with the glass's index at ``wavelength_um`` (default: the reference).

        A surface whose conic constant is a free design parameter is ``aspheric``; its curvature
        and conic are tensors broadcasting like the design. The curvatures are fixed by the design
        at the reference index, whatever the wavelength.
        """
        c1, c2 = self.curvatures(design["s"])
        n = self.refractive_index if wavelength_um is None else self.glass.index(wavelength_um)
        y = self.pupil_radius_mm  # thin lens, stop at the lens: both surfaces are used over the pupil
        front = (Surface(c1, design["Q_front"], n, 0.0, aspheric=True, conic_name="Q_front", semi_aperture_mm=y)
                 if "Q_front" in design else Surface(c1, 0.0, n, 0.0, aspheric=False, semi_aperture_mm=y))
        return [front, Surface(c2, design["Q_back"], 1.0, 0.0, aspheric=True, conic_name="Q_back", semi_aperture_mm=y)]

    @property
    def stop_index(self) -> int:
        """The aperture stop is at the lens: its first surface (zero thickness)."""
        return 0

    def prescription(self, design: Design, wavelengths_um, *, name: str = ""):
        """The singlet at one ``design`` as a :class:`lenssim.model.prescription.Prescription` (the one lens model
        every ``--lens`` route reads): two surfaces 0 mm apart, the stop at surface 1, the entrance pupil ``2 y``,
        the semi-diameters ``y``, the image plane at ``t`` plus the design's focus shift, the glass (a constant one as
        the model glass ``(n, 0)``), the field angles, ``wavelengths_um`` (the first the primary). Its free parameters
        ``E1.bending``, ``S2.conic``, ``S1.conic`` are the design's ``s``, ``Q_back``, ``Q_front``
        (:attr:`lenssim.model.design.Parameter.lens_name`); its ``focus_um`` moves the image plane from where the
        design's ``focus_shift_um`` put it (the same number about the prescription of a design without a shift)."""
        from .prescription import Prescription, PrescriptionSurface

        if design.shape.numel() != 1:
            raise ValueError(f"a prescription is one lens: the design holds {design.shape.numel()} designs")
        c1, c2 = (float(c) for c in self.curvatures(design["s"].double()))
        material = self.glass.name if getattr(self.glass, "dispersive", False) else (self.refractive_index, 0.0)
        y = self.pupil_radius_mm
        front = PrescriptionSurface(c1, 0.0, material, conic=float(design["Q_front"]), semi_diameter_mm=y,
                                    comment="front" + (" (conic Q_front)" if "Q_front" in design else ""))
        back = PrescriptionSurface(c2, self.image_distance_mm + float(design["focus_shift_um"]) * 1e-3, "air",
                                   conic=float(design["Q_back"]), semi_diameter_mm=y, comment="back (conic Q_back)")
        lams = tuple(float(w) for w in wavelengths_um)
        return Prescription((front, back), 1, 2 * y, fields=self.field_angles_deg, wavelengths_um=lams,
                            primary_wavelength_um=lams[0], name=name or design.name)

    def seidel_sums(self, design: Design, alpha, wavelength_um: float | None = None) -> torch.Tensor:
        """``(S_I, S_II, S_III, S_IV)`` (mm) by the thin lens's closed forms (Welford ch. 8): the fast path of the
        :class:`lenssim.optics.optical_system.OpticalSystem` protocol, equal to the general surface-by-surface sums
        (:func:`lenssim.optics.optical_system.surface_seidel_sums`; tested). ``alpha`` (deg) broadcasts with the design."""
        n = self.refractive_index if wavelength_um is None else self.glass.index(wavelength_um)
        y, p = self.pupil_radius_mm, self.position_factor_at(wavelength_um)
        K = self.power(wavelength_um)
        s = design["s"]
        H = y * torch.tan(torch.deg2rad(alpha))
        bracket = (n / (n - 1)) ** 2 + (n + 2) / (n * (n - 1) ** 2) * s**2 \
            + 4 * (n + 1) / (n * (n - 1)) * s * p + (3 * n + 2) / n * p**2
        S1 = y**4 * K**3 / 4 * bracket
        n_before = 1.0
        for surf in self.surfaces(design, wavelength_um):  # conic contributions (zero for spheres)
            if surf.aspheric:
                S1 = S1 + (surf.n_after - n_before) * surf.conic * surf.curvature**3 * y**4
            n_before = surf.n_after
        S2 = (y**2 * K**2 * H / 2) * ((n + 1) / (n * (n - 1)) * s + (2 * n + 1) / n * p)
        S3 = H**2 * K
        S4 = H**2 * K / n
        return torch.stack(torch.broadcast_tensors(S1, S2, S3, S4), dim=-1)

    def power(self, wavelength_um: float | None = None) -> float:
        """Paraxial power ``K = (n(lambda) - 1)(c1 - c2)`` (1/mm); ``1 / focal_length_mm`` at the reference index."""
        if wavelength_um is None:
            return 1.0 / self.focal_length_mm
        n = self.glass.index(wavelength_um)
        if n == self.refractive_index:
            return 1.0 / self.focal_length_mm
        return (n - 1) / ((self.refractive_index - 1) * self.focal_length_mm)

    def focus_distance_mm(self, wavelength_um: float | None = None) -> float:
        """Lens-to-focus distance (mm) at ``wavelength_um`` for the lens's object distance (axial colour)."""
        if wavelength_um is None or self.glass.index(wavelength_um) == self.refractive_index:
            return self.image_distance_mm
        vergence = -(1 + self.position_factor) / (2 * self.focal_length_mm)  # object side, from the reference conjugates
        return 1.0 / (self.power(wavelength_um) + vergence)

    def position_factor_at(self, wavelength_um: float | None = None) -> float:
        """Position factor ``p = 1 - 2 / (K t)`` at ``wavelength_um`` (-1 for an object at infinity at every wavelength)."""
        if wavelength_um is None or self.glass.index(wavelength_um) == self.refractive_index:
            return self.position_factor
        return 1 - 2 / (self.power(wavelength_um) * self.focus_distance_mm(wavelength_um))

    def field_angles(self, *, dtype=None, device=None) -> torch.Tensor:
        """Field angles as a tensor of shape ``(A,)`` in degrees (on ``device``, default :data:`HOST`)."""
        return torch.tensor(self.field_angles_deg, dtype=dtype or torch.get_default_dtype(), device=device or HOST)

    def check_design(self, design: Design) -> None:
        """Raise :class:`LensError` if a design is not a physical lens.

        Every parameter must be finite, and every surface (curvature ``c``, conic ``kappa``) must
        be defined over the whole aperture: ``(1 + kappa) c^2 y^2 < 1`` (for the spherical front,
        not a hemisphere smaller than the aperture); the image plane must lie within a focal length of
        the focus (``|focus_shift_um| < 1000 f``: beyond, it would sit on or in front of the lens).
        """
        design = design.to(torch.float64)
        for name, t in design.values.items():
            bad = ~torch.isfinite(t)
            if bad.any():
                raise LensError(f"{name}={t[bad].flatten()[0].item()!r} is not allowed: a finite number")
        if "focus_shift_um" in design.values:  # the image plane stays behind the lens: |shift| < f
            dz = design.values["focus_shift_um"]
            if bool((dz.abs() >= 1e3 * self.focal_length_mm).any()):
                v = dz[dz.abs() >= 1e3 * self.focal_length_mm].flatten()[0].item()
                raise LensError(f"focus_shift_um={v!r} is not allowed: the image plane must stay within the lens's "
                                f"focal length of the focus, |focus_shift_um| < {1e3 * self.focal_length_mm:g} um")
        y2 = self.pupil_radius_mm**2
        shape, device = design.shape, design["s"].device
        for i, surf in enumerate(self.surfaces(design)):
            c = torch.as_tensor(surf.curvature, dtype=torch.float64, device=device)
            kappa = torch.as_tensor(surf.conic, dtype=torch.float64, device=device)
            arg = torch.broadcast_to(1 - (1 + kappa) * c**2 * y2, broadcast_shape(shape, c.shape, kappa.shape))
            if (arg <= 0).any():
                j = int(torch.nonzero((arg <= 0).flatten())[0])
                at = {k: torch.broadcast_to(v, arg.shape).flatten()[j].item() for k, v in design.values.items()}
                where = ", ".join(f"{k}={v!r}" for k, v in at.items())
                if surf.conic_name is None:
                    raise LensError(f"{where} is not allowed: surface {i + 1} (spherical) is smaller than the "
                                    f"{self.pupil_radius_mm} mm aperture")
                cj = torch.broadcast_to(c, arg.shape).flatten()[j].item()
                lim = 1 / (cj**2 * y2) - 1
                raise LensError(f"{where} is not allowed: the conic surface {i + 1} is undefined over the "
                                f"{self.pupil_radius_mm} mm aperture; {surf.conic_name} must be < {lim:.6g} here")
            if bool((arg < 1 - THIRD_ORDER_LIMIT).any()):
                warn_model(f"surface {i + 1}: (1 + conic) c^2 y^2 exceeds {THIRD_ORDER_LIMIT:g} for some designs; the "
                           "third-order (Seidel) model is far outside its validated range there")
        self._check_blur(design)

    def _check_blur(self, design: Design) -> None:
        """Raise :class:`LensError` if a design's third-order transverse blur at the largest field angle, bounded by
        ``(|S_I| + |S_II| + |S_III| + |S_IV|) / u'`` (mm, ``u' = y / t`` the image-space marginal ray angle), is not
        finite or reaches the focal length: no lens (a conic of -1e308 overflows the wavefront and its PSF)."""
        alpha = torch.tensor(max(self.field_angles_deg), dtype=torch.float64, device=design["s"].device)
        sums = self.seidel_sums(design, alpha)
        blur = sums.abs().sum(dim=-1) / (self.pupil_radius_mm / self.image_distance_mm)
        bad = ~(blur < self.focal_length_mm)  # NaN and inf included
        if bool(bad.any()):
            j = int(torch.nonzero(bad.flatten())[0])
            at = {k: torch.broadcast_to(v, blur.shape).flatten()[j].item() for k, v in design.values.items()}
            where = ", ".join(f"{k}={v!r}" for k, v in at.items())
            size = f"{blur.flatten()[j].item():.3g} mm" if torch.isfinite(blur.flatten()[j]) else "not finite"
            raise LensError(f"{where} is not allowed at the field angle {float(alpha):g} deg: its third-order blur is "
                            f"{size}, not smaller than the focal length {self.focal_length_mm:g} mm (no image forms)")

