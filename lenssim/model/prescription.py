"""A sequential lens prescription: what a designer's file (Zemax ``.zmx``, our TOML) says, as data.

A centred, rotationally symmetric system of refracting surfaces, numbered as in the file: the object is surface 0,
the refracting surfaces (and flat dummies such as a stop) are 1..N, the image plane is N + 1 and lies
``surfaces[-1].thickness_mm`` behind the last surface (the prescription's own image distance).

Each surface: its kind (:mod:`lenssim.model.surface_kinds`: ``""`` the standard family, a sphere or conic and, with
coefficients, an even asphere ``c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2)) + A4 r^4 + ... + A16 r^16``; or another
registered kind, e.g. ``"qbfs"``), curvature (1/mm; 0 flat), conic constant, aspheric coefficients (their meaning is
the kind's: ``A4, A6, ...`` in mm^(1-2k) for the even asphere), the kind's own shape parameters, the thickness after
it (mm), the material after it (``"air"``, a catalogue glass name, or a model glass ``(n_d, V_d)``) and its clear
semi-diameter (mm; None: unlimited, the beam decides). One surface is the aperture stop.
The object is at infinity (field angles, degrees) or at a finite distance (``object_distance_mm`` before surface 1;
fields are then object heights, mm). The aperture is the entrance-pupil diameter (mm).

Nothing here traces a ray: :mod:`lenssim.optics.sequential` does. Readers and writers are in :mod:`lenssim.io`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from ..validate import quoted
from .surface_kinds import SURFACE_KINDS, finite_number
from .surface_kinds.even_asphere import EVEN_ASPHERE, MAX_ASPHERE_ORDER
from .surface_kinds.standard import STANDARD

__all__ = ["PrescriptionError", "PrescriptionSurface", "Prescription", "MAX_ASPHERE_ORDER", "AIR", "STOP_SIZES"]

AIR = "air"
"""The material name of air (index 1 at every wavelength, as the optical-design programs take it)."""

STOP_SIZES = ("paraxial", "real")
"""How the entrance-pupil diameter sizes the stop that real rays are aimed at (``[aperture] stop_size``):
``"paraxial"``: the paraxial marginal ray's height at the stop (Zemax's "paraxial" ray aiming, its default, and the
default here); ``"real"``: the height at the stop of the real axial ray entering at the entrance pupil's rim (Zemax's
"aberrated" ray aiming; Optiland's real aiming), so the axial beam is exactly the entrance-pupil diameter wide. The
two differ by the pupil's spherical aberration, when lenses stand before the stop: 1.5% of the stop radius for the
Cooke triplet of ``tests/data/lenses/cooke_stop_inside.toml``, 2.7% of its RMS OPD at 20 deg."""

EDGE_TOLERANCE_MM = 1e-6
"""Two surfaces cross when the gap between them at the smaller semi-diameter is below minus this (mm): a contact
(a cemented or touching edge, gap 0) is allowed."""


class PrescriptionError(ValueError):
    """A prescription that is not a lens this tool can trace: the message names the surface and the quantity."""


def _finite(where: str, name: str, v, allowed: str = "a finite number") -> float:
    try:
        return finite_number(name, v, allowed)
    except ValueError as exc:
        raise PrescriptionError(f"{where}: {exc}") from None


@dataclass(frozen=True)
class PrescriptionSurface:
    """One refracting surface (units in the names). ``material``: after the surface; a ``str`` (``"air"`` or a
    catalogue glass) or a tuple ``(n_d, V_d)`` (a model glass; ``V_d = 0``: no dispersion)."""

    curvature_per_mm: float = 0.0
    thickness_mm: float = 0.0
    material: str | tuple[float, float] = AIR
    conic: float = 0.0
    aspheric_coefficients: tuple[float, ...] = ()
    """The kind's coefficients (even asphere: ``(A4, A6, ..., A16)`` of ``r^4, r^6, ...``, mm^-3, mm^-5, ...);
    trailing zeros may be left out."""
    semi_diameter_mm: float | None = None
    comment: str = ""
    kind: str = ""
    """A name of :data:`lenssim.model.surface_kinds.SURFACE_KINDS`; ``""`` (or ``"standard"``, ``"even_asphere"``):
    the standard family, an even asphere if it has coefficients, else standard."""
    shape_parameters: tuple = ()
    """The kind's own numbers, ``((name, value), ...)`` (a dict is taken), e.g. Qbfs's ``normalization_radius_mm``."""

    @property
    def surface_kind(self):
        """The :class:`lenssim.model.surface_kinds.SurfaceKind` that says what this surface's numbers mean."""
        if self.kind in ("", STANDARD.name, EVEN_ASPHERE.name):
            return EVEN_ASPHERE if self.aspheric_coefficients else STANDARD
        return SURFACE_KINDS[self.kind]

    @property
    def paraxial_curvature_per_mm(self) -> float:
        """The curvature (1/mm) of the sphere osculating the surface at its vertex (the paraxial trace's)."""
        return self.surface_kind.paraxial_curvature(self)

    @property
    def radius_mm(self) -> float:
        """Radius of curvature (mm; ``inf`` for a flat surface)."""
        return math.inf if self.curvature_per_mm == 0 else 1.0 / self.curvature_per_mm

    @property
    def is_air(self) -> bool:
        return isinstance(self.material, str) and self.material.lower() == AIR

    @property
    def is_aspheric(self) -> bool:
        """Not a sphere (a conic, an even-asphere term, ...: the surfaces the industrial cost counts)."""
        return self.surface_kind.is_aspheric(self)

    def sag_mm(self, r_mm: float) -> float:
        """The surface's sag (mm, along the axis from its vertex) at height ``r_mm``."""
        return self.surface_kind.sag_mm(self, r_mm)

    def check(self, number: int) -> "PrescriptionSurface":
        """This surface with its numbers as floats; :class:`PrescriptionError` naming surface ``number`` otherwise."""
        where = f"surface {number}"
        c = _finite(where, "curvature (1/mm)", self.curvature_per_mm)
        t = _finite(where, "thickness (mm)", self.thickness_mm)
        k = _finite(where, "conic", self.conic)
        kind = self.kind if self.kind not in (STANDARD.name, EVEN_ASPHERE.name) else ""
        params = self.shape_parameters
        try:
            if not isinstance(kind, str):
                raise ValueError(f"kind {quoted(kind)} is not a name")
            if kind:
                SURFACE_KINDS.validate(kind)
            params = tuple(params.items()) if isinstance(params, dict) else tuple(tuple(p) for p in params)
            same = replace(self, curvature_per_mm=c, conic=k, kind=kind, shape_parameters=params)
            fields = same.surface_kind.check(same)
        except (ValueError, TypeError) as exc:
            raise PrescriptionError(f"{where}: {exc}") from None
        same = replace(same, **fields)
        c0, k0 = same.surface_kind.base_conic(same)
        sd = self.semi_diameter_mm
        if sd is not None:
            sd = _finite(where, "semi-diameter (mm)", sd, "a finite number > 0")
            if not sd > 0:
                raise PrescriptionError(f"{where}: semi-diameter (mm) = {sd!r} is not allowed: a number > 0")
            if c0 != 0 and (1 + k0) * c0 * c0 * sd * sd >= 1:
                raise PrescriptionError(f"{where}: the conic surface (radius {1 / c0:g} mm, conic {k0:g}) is not "
                                        f"defined out to its semi-diameter {sd:g} mm")
        mat = self.material
        if isinstance(mat, str):
            if not mat.strip():
                raise PrescriptionError(f"{where}: material '' is not allowed: 'air', a glass name or (n_d, V_d)")
            mat = mat.strip()
        else:
            try:
                nd, vd = mat
            except (TypeError, ValueError):
                raise PrescriptionError(f"{where}: material {quoted(mat)} is not allowed: 'air', a glass name or "
                                        "(n_d, V_d)") from None
            nd = _finite(where, "n_d", nd, "a refractive index >= 1")
            vd = _finite(where, "V_d", vd, "an Abbe number >= 0 (0: no dispersion)")
            if nd < 1 or vd < 0:
                raise PrescriptionError(f"{where}: model glass (n_d={nd:g}, V_d={vd:g}) is not allowed: n_d >= 1, "
                                        "V_d >= 0")
            mat = (nd, vd)
        return replace(same, thickness_mm=t, semi_diameter_mm=sd, material=mat)

    def to_dict(self) -> dict:
        d = {"kind": self.kind} if self.kind else {}
        d.update({"radius_mm": "inf" if self.curvature_per_mm == 0 else 1.0 / self.curvature_per_mm,
                  "thickness_mm": self.thickness_mm})
        d["material"] = list(self.material) if isinstance(self.material, tuple) else self.material
        d.update(self.shape_parameters)
        if self.conic:
            d["conic"] = self.conic
        if self.aspheric_coefficients:
            d["aspheric_coefficients"] = list(self.aspheric_coefficients)
        if self.semi_diameter_mm is not None:
            d["semi_diameter_mm"] = self.semi_diameter_mm
        if self.comment:
            d["comment"] = self.comment
        return d


@dataclass(frozen=True)
class Prescription:
    """A sequential lens (see the module docstring). ``stop_surface`` is the stop's number (1..N, as in the file);
    ``fields`` are field angles (deg, object at infinity) or object heights (mm, finite object);
    ``wavelengths_um`` with ``primary_wavelength_um`` among them."""

    surfaces: tuple[PrescriptionSurface, ...]
    stop_surface: int
    entrance_pupil_diameter_mm: float
    fields: tuple[float, ...] = (0.0,)
    wavelengths_um: tuple[float, ...] = (0.5875618,)
    primary_wavelength_um: float = 0.5875618
    object_distance_mm: float = math.inf
    name: str = ""
    source: str = ""
    notes: str = ""
    stop_size: str = "paraxial"
    """How the entrance pupil sizes the stop real rays are aimed at: one of :data:`STOP_SIZES`."""
    extra: dict = field(default_factory=dict, compare=False)
    """What a reader kept beside the lens (e.g. the published figures a shipped lens is checked against)."""

    def __post_init__(self):
        surfs = tuple(self.surfaces)
        if not surfs:
            raise PrescriptionError("the prescription has no surfaces")
        surfs = tuple(s.check(i + 1) for i, s in enumerate(surfs))
        object.__setattr__(self, "surfaces", surfs)
        n = len(surfs)
        stop = self.stop_surface
        if isinstance(stop, bool) or not isinstance(stop, int) or not 1 <= stop <= n:
            raise PrescriptionError(f"stop surface {stop!r} is not allowed: a surface number from 1 to {n}")
        epd = _finite("aperture", "entrance-pupil diameter (mm)", self.entrance_pupil_diameter_mm, "a number > 0")
        if not epd > 0:
            raise PrescriptionError(f"aperture: entrance-pupil diameter (mm) = {epd!r} is not allowed: a number > 0")
        object.__setattr__(self, "entrance_pupil_diameter_mm", epd)
        if self.stop_size not in STOP_SIZES:
            raise PrescriptionError(f"aperture: stop_size = {quoted(self.stop_size)} is not allowed: one of "
                                    f"{', '.join(STOP_SIZES)}")
        od = self.object_distance_mm
        if isinstance(od, bool) or not isinstance(od, (int, float)) or math.isnan(od) or not od > 0:
            raise PrescriptionError(f"object distance (mm) = {od!r} is not allowed: a number > 0 or infinity")
        object.__setattr__(self, "object_distance_mm", float(od))
        infinite = math.isinf(od)
        flds = tuple(_finite("fields", "field", f) for f in self.fields)
        if not flds:
            raise PrescriptionError("fields: give at least one field (0 is the axis)")
        for f in flds:
            if f < 0 or (infinite and f >= 90):
                raise PrescriptionError(f"fields: {f:g} is not allowed: " + (
                    "field angles from 0 to below 90 degrees" if infinite else "object heights >= 0 mm"))
        object.__setattr__(self, "fields", flds)
        lams = tuple(_finite("wavelengths", "wavelength (um)", w) for w in self.wavelengths_um)
        if not lams or any(not 0.2 <= w <= 20 for w in lams):
            raise PrescriptionError(f"wavelengths (um) = {lams} are not allowed: 0.2 to 20 um each, at least one")
        object.__setattr__(self, "wavelengths_um", lams)
        p = _finite("wavelengths", "primary wavelength (um)", self.primary_wavelength_um)
        if not any(abs(p - w) < 1e-9 for w in lams):
            raise PrescriptionError(f"primary wavelength {p:g} um is not one of the wavelengths {lams}")
        object.__setattr__(self, "primary_wavelength_um", p)
        if not surfs[-1].thickness_mm > 0:
            raise PrescriptionError(f"surface {n}: the image distance (its thickness) must be > 0 mm, not "
                                    f"{surfs[-1].thickness_mm:g}")
        for i, s in enumerate(surfs[:-1]):
            if s.thickness_mm < 0:
                raise PrescriptionError(f"surface {i + 1}: thickness (mm) = {s.thickness_mm:g} is not allowed: >= 0 "
                                        "(a sequential lens's surfaces follow each other)")
            nxt = surfs[i + 1]
            if s.semi_diameter_mm is not None and nxt.semi_diameter_mm is not None and s.thickness_mm > 0:
                r = min(s.semi_diameter_mm, nxt.semi_diameter_mm)
                edge = s.thickness_mm + nxt.sag_mm(r) - s.sag_mm(r)
                if edge < -EDGE_TOLERANCE_MM:
                    raise PrescriptionError(f"surface {i + 2} crosses surface {i + 1} within their semi-diameters: the "
                                            f"gap between them is {edge:.4g} mm at a height of {r:g} mm")

    @property
    def object_at_infinity(self) -> bool:
        return math.isinf(self.object_distance_mm)

    @property
    def stop_index(self) -> int:
        """Index (0-based) of the stop in :attr:`surfaces`."""
        return self.stop_surface - 1

    @property
    def vertex_z_mm(self) -> tuple[float, ...]:
        """Each surface's vertex on the axis (mm), surface 1 at 0."""
        z, out = 0.0, []
        for s in self.surfaces:
            out.append(z)
            z += s.thickness_mm
        return tuple(out)

    @property
    def image_z_mm(self) -> float:
        """The image plane on the axis (mm, surface 1 at 0): the last surface's thickness behind it."""
        return self.vertex_z_mm[-1] + self.surfaces[-1].thickness_mm

    def with_image_distance(self, distance_mm: float) -> "Prescription":
        """The same lens with the image plane ``distance_mm`` behind the last surface (refocused)."""
        last = replace(self.surfaces[-1], thickness_mm=distance_mm)
        return replace(self, surfaces=self.surfaces[:-1] + (last,))

    def to_dict(self) -> dict:
        d = {"name": self.name, "source": self.source}
        if self.notes:
            d["notes"] = self.notes
        d["aperture"] = {"entrance_pupil_diameter_mm": self.entrance_pupil_diameter_mm}
        if self.stop_size != STOP_SIZES[0]:
            d["aperture"]["stop_size"] = self.stop_size
        d["object"] = {"distance_mm": "inf" if self.object_at_infinity else self.object_distance_mm}
        d["fields"] = {"angles_deg" if self.object_at_infinity else "heights_mm": list(self.fields)}
        d["wavelengths"] = {"um": list(self.wavelengths_um), "primary_um": self.primary_wavelength_um}
        d["stop_surface"] = self.stop_surface
        d["surfaces"] = [s.to_dict() for s in self.surfaces]
        d.update(self.extra)
        return d
