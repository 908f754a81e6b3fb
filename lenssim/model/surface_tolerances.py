"""Manufacturing tolerances per surface of any sequential lens (a :class:`lenssim.model.prescription.Prescription`),
and seeded samples of its manufactured copies (issue 29).

A :class:`SurfaceTolerances` holds one limit per error term (0 switches a term off). As in
:mod:`lenssim.model.tolerances`, a limit "+/- t" is read as :data:`lenssim.model.tolerances.TOLERANCE_SIGMAS`
standard deviations of a normal draw (95% of the parts inside it). Terms:

* ``radius_pct``: the vertex radius of every curved surface (% of its radius; one draw per surface);
* ``thickness_um``: every thickness between surfaces (element centre thicknesses and air gaps alike; one draw per
  gap of nonzero thickness), not the last surface's, which is the image distance;
* ``conic_pct``: every nonzero conic constant (% of its value);
* ``index``: the refractive index of every glass element (absolute; one draw per glass-filled gap, added at every
  wavelength: the catalogue glass keeps its dispersion);
* ``despace_um``: the image plane's residual error (the assembly's focus error);
* ``surface_decentre_um`` and ``surface_tilt_arcmin``: every lens surface (a surface with glass on either side)
  decentred and tilted against its element's axis (the moulding's or the polishing's concentricity and wedge; both
  components drawn, a vector in a random direction; the tilt about the surface's vertex);
* ``element_decentre_um`` and ``element_tilt_arcmin``: every element (a run of surfaces joined by glass: a singlet,
  or a cemented group as one) decentred and tilted in the barrel, as a rigid body, the tilt about its first surface's
  vertex (OpticStudio's element tolerances); a surface's own motion is applied first, then its element's;
* ``focus_compensated`` (default true): each copy's image plane is placed so that its distance from the copy's own
  paraxial focus (primary wavelength) equals the nominal lens's, plus the despace draw, as a camera module is
  focused at assembly; false: the image plane stays at the nominal distance behind the last surface (plus the
  despace draw), and radius, thickness and index errors defocus the copy.

The decentres and tilts make a copy that is not rotationally symmetric: it is traced as such
(:class:`lenssim.optics.sequential.SequentialLens` with ``misalignments``) and evaluated at four image azimuths
(:mod:`lenssim.tolerancing`).

Grades (:data:`SURFACE_GRADES`): ``radius_pct``, ``conic_pct``, ``index`` and ``despace_um`` are the grades of
:data:`lenssim.model.tolerances.GRADES` (the moulded asphere's front-surface radius, conic, index and despace;
sources in ``docs/as-built.md``). The thickness limit per grade (:data:`THICKNESS_UM`) is the centre-thickness
tolerance of Apollo Optical Systems' published "Typical Manufacturing Tolerances" table for injection-moulded
lenses (https://www.apollooptical.com/manufacturing-tolerances): +/-0.025 mm commercial, +/-0.015 mm precision; the
same table's radius tolerances (+/-1% and +/-0.5% of the radius) are the grades' radius values, so the two agree.
The same limit is applied to air gaps (spacer and barrel tolerances of that order; a choice, not from the table).
The surface decentre and tilt per grade are the singlet's ``asphere_decentre_um`` and ``asphere_tilt_arcmin``
(Apollo's concentricity; typical centring classes), the element tilt its ``lens_tilt_arcmin``; the element decentre
(:data:`ELEMENT_DECENTRE_UM`) is an assumption of the same order as the surface decentre (a lens seated in a bore
with a clearance of some 10-25 um), not from a published table.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

import torch

from .misalignment import Misalignment
from .prescription import Prescription
from .tolerances import GRADES, TOLERANCE_SIGMAS, check_limits
from ..torch_utils import HOST
from ..validate import listed, quoted

__all__ = ["SurfaceTolerances", "SurfacePerturbations", "SURFACE_GRADES", "THICKNESS_UM", "ELEMENT_DECENTRE_UM",
           "surface_grade", "perturbed_prescription", "lens_surfaces", "lens_elements", "copy_misalignments"]

THICKNESS_UM = {"none": 0.0, "commercial": 25.0, "precision": 15.0}
"""Thickness limit (um) per grade: Apollo Optical Systems' centre-thickness tolerances for injection-moulded
lenses, commercial and precision (module docstring)."""
ELEMENT_DECENTRE_UM = {"none": 0.0, "commercial": 25.0, "precision": 10.0}
"""Element decentre limit (um) per grade: an assumption (module docstring)."""
ARCMIN_DEG = 1.0 / 60.0


def lens_surfaces(prescription: Prescription) -> tuple[int, ...]:
    """0-based indices of the surfaces with glass on at least one side (the surfaces of the elements)."""
    surfs = prescription.surfaces
    return tuple(i for i in range(len(surfs)) if not surfs[i].is_air or (i > 0 and not surfs[i - 1].is_air))


def lens_elements(prescription: Prescription) -> tuple[tuple[int, int], ...]:
    """The elements ``(first, last)`` (0-based surface indices): runs of surfaces joined by glass (a cemented group is
    one element)."""
    out, start = [], None
    for i, s in enumerate(prescription.surfaces):
        if not s.is_air and start is None:
            start = i
        if s.is_air and start is not None:
            out.append((start, i))
            start = None
    if start is not None:  # glass up to the image (an immersed image): the element ends at the last surface
        out.append((start, len(prescription.surfaces) - 1))
    return tuple(out)



@dataclass(frozen=True, kw_only=True)
class SurfaceTolerances:
    """Limits of the per-surface error terms (module docstring); every term 0 by default (the nominal lens)."""

    radius_pct: float = 0.0
    thickness_um: float = 0.0
    conic_pct: float = 0.0
    index: float = 0.0
    despace_um: float = 0.0
    surface_decentre_um: float = 0.0
    surface_tilt_arcmin: float = 0.0
    element_decentre_um: float = 0.0
    element_tilt_arcmin: float = 0.0
    focus_compensated: bool = True

    def __post_init__(self):
        check_limits(self)

    @classmethod
    def from_dict(cls, d: dict) -> "SurfaceTolerances":
        """From a ``[tolerances]`` table: ``grade = "commercial"`` (or ``"precision"``, ``"none"``) starts from a
        grade, the other keys override it; an unknown key is an error that lists the valid ones."""
        d = dict(d)
        base = surface_grade(d.pop("grade", "none"))
        allowed = [f.name for f in fields(cls)]
        bad = sorted(str(k) for k in set(d) - set(allowed))
        if bad:
            raise ValueError(f"[tolerances]: unknown key(s) {listed(bad)}; valid: {listed(['grade', *allowed], near=bad)}")
        return cls(**{**asdict(base), **d})

    def to_dict(self) -> dict:
        return asdict(self)

    def terms(self) -> tuple[str, ...]:
        """The terms that are on (limit > 0)."""
        return tuple(f.name for f in fields(self) if f.name != "focus_compensated" and getattr(self, f.name) > 0)

    def sample(self, prescription: Prescription, n: int, *, seed: int) -> "SurfacePerturbations":
        """``n`` manufactured copies of ``prescription``, reproducibly from ``seed`` (an explicit
        :class:`torch.Generator`): the terms drawn in a fixed order (radius, thickness, conic, index, despace,
        surface decentre, surface tilt, element decentre, element tilt; a vector term's two components together),
        each for all its surfaces, always (zero where switched off), so that switching a term off leaves the others'
        draws unchanged (common random numbers)."""
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"number of lenses n={n!r} is not allowed: an integer >= 1")
        surfs = prescription.surfaces
        radius_at = tuple(i for i, s in enumerate(surfs) if s.curvature_per_mm != 0)
        thick_at = tuple(i for i, s in enumerate(surfs[:-1]) if s.thickness_mm > 0)
        conic_at = tuple(i for i, s in enumerate(surfs) if s.conic != 0)
        glass_at = tuple(i for i, s in enumerate(surfs[:-1]) if not s.is_air)
        g = torch.Generator().manual_seed(int(seed))
        sd = 1.0 / TOLERANCE_SIGMAS

        def draw(k, limit, *vector):
            return torch.randn((n, k, *vector), generator=g, dtype=torch.float64, device=HOST) * (limit * sd)

        lens_at = lens_surfaces(prescription)
        elements = lens_elements(prescription)
        return SurfacePerturbations(
            radius_rel=draw(len(radius_at), self.radius_pct * 1e-2), radius_at=radius_at,
            thickness_mm=draw(len(thick_at), self.thickness_um * 1e-3), thickness_at=thick_at,
            conic_rel=draw(len(conic_at), self.conic_pct * 1e-2), conic_at=conic_at,
            index=draw(len(glass_at), self.index), index_at=glass_at,
            despace_mm=draw(1, self.despace_um * 1e-3)[:, 0],
            surface_decentre_mm=draw(len(lens_at), self.surface_decentre_um * 1e-3, 2),
            surface_tilt_deg=draw(len(lens_at), self.surface_tilt_arcmin * ARCMIN_DEG, 2), surface_at=lens_at,
            element_decentre_mm=draw(len(elements), self.element_decentre_um * 1e-3, 2),
            element_tilt_deg=draw(len(elements), self.element_tilt_arcmin * ARCMIN_DEG, 2), elements=elements,
            tolerances=self)


SURFACE_GRADES = {name: SurfaceTolerances(radius_pct=t.radius_front_pct, thickness_um=THICKNESS_UM[name],
                                          conic_pct=t.conic_pct, index=t.index, despace_um=t.despace_um,
                                          surface_decentre_um=t.asphere_decentre_um,
                                          surface_tilt_arcmin=t.asphere_tilt_arcmin,
                                          element_decentre_um=ELEMENT_DECENTRE_UM[name],
                                          element_tilt_arcmin=t.lens_tilt_arcmin)
                  for name, t in GRADES.items()}
"""Named grades (``none``, ``commercial``, ``precision``): see the module docstring for the values' sources."""


def surface_grade(name: str) -> SurfaceTolerances:
    """The per-surface tolerances of a named grade; ``ValueError`` listing the grades otherwise."""
    if not isinstance(name, str) or name not in SURFACE_GRADES:
        raise ValueError(f"tolerance grade {quoted(name)} is not known; valid: {', '.join(SURFACE_GRADES)}")
    return SURFACE_GRADES[name]


@dataclass(frozen=True)
class SurfacePerturbations:
    """Sampled errors of ``N`` copies (float64, one column per surface the term applies to; ``*_at`` the 0-based
    surface indices of the columns): relative radius errors, thickness errors (mm) of the gap after the surface,
    relative conic errors, index errors of the glass after the surface, the despace (mm) ``(N,)``; the decentres (mm)
    and tilts (degrees; ``[..., 0]`` about ``x``, ``[..., 1]`` about ``y``, as
    :class:`lenssim.model.misalignment.Misalignment`) ``(N, k, 2)`` of the lens surfaces ``surface_at`` and of the
    elements ``elements`` (``(first, last)`` surface indices)."""

    radius_rel: torch.Tensor
    radius_at: tuple[int, ...]
    thickness_mm: torch.Tensor
    thickness_at: tuple[int, ...]
    conic_rel: torch.Tensor
    conic_at: tuple[int, ...]
    index: torch.Tensor
    index_at: tuple[int, ...]
    despace_mm: torch.Tensor
    surface_decentre_mm: torch.Tensor
    surface_tilt_deg: torch.Tensor
    surface_at: tuple[int, ...]
    element_decentre_mm: torch.Tensor
    element_tilt_deg: torch.Tensor
    elements: tuple[tuple[int, int], ...]
    tolerances: SurfaceTolerances

    def __len__(self) -> int:
        return int(self.despace_mm.shape[0])

    def variables(self) -> dict:
        """The sampled values as named ``(N,)`` columns (surfaces numbered as in the file, 1..N):
        ``name -> (values, units, description)``."""
        out = {}
        for i, k in enumerate(self.radius_at):
            out[f"radius_s{k + 1}_pct"] = (self.radius_rel[:, i] * 100, "%", f"radius error of surface {k + 1}")
        for i, k in enumerate(self.thickness_at):
            out[f"thickness_s{k + 1}_um"] = (self.thickness_mm[:, i] * 1e3, "um",
                                             f"error of the thickness after surface {k + 1}")
        for i, k in enumerate(self.conic_at):
            out[f"conic_s{k + 1}_pct"] = (self.conic_rel[:, i] * 100, "%", f"conic error of surface {k + 1}")
        for i, k in enumerate(self.index_at):
            out[f"index_s{k + 1}"] = (self.index[:, i], "1", f"index error of the glass after surface {k + 1}")
        out["despace_um"] = (self.despace_mm * 1e3, "um", "image-plane residual (despace)")
        for i, k in enumerate(self.surface_at):
            for j, ax in enumerate("xy"):
                out[f"decentre_s{k + 1}_{ax}_um"] = (self.surface_decentre_mm[:, i, j] * 1e3, "um",
                                                     f"decentre of surface {k + 1} along {ax}")
            for j, ax in enumerate("xy"):
                out[f"tilt_s{k + 1}_{ax}_arcmin"] = (self.surface_tilt_deg[:, i, j] * 60, "arcmin",
                                                     f"tilt of surface {k + 1} about {ax}")
        for i, (a, b) in enumerate(self.elements):
            for j, ax in enumerate("xy"):
                out[f"decentre_e{i + 1}_{ax}_um"] = (self.element_decentre_mm[:, i, j] * 1e3, "um",
                                                     f"decentre of element {i + 1} (surfaces {a + 1}-{b + 1}) along {ax}")
            for j, ax in enumerate("xy"):
                out[f"tilt_e{i + 1}_{ax}_arcmin"] = (self.element_tilt_deg[:, i, j] * 60, "arcmin",
                                                     f"tilt of element {i + 1} (surfaces {a + 1}-{b + 1}) about {ax}")
        return out


def perturbed_prescription(prescription: Prescription, pert: SurfacePerturbations, i: int):
    """Copy ``i`` of ``pert`` applied to ``prescription``: the manufactured prescription (radii, thicknesses and
    conics changed; the last thickness, the image distance, left to the caller's focusing) and its index offsets
    ``{surface index: dn}`` (for :class:`lenssim.optics.sequential.SequentialLens`'s ``index_offsets``). A copy whose
    surfaces cross, or whose thickness goes below zero, is a ``ValueError`` naming the copy."""
    surfs = list(prescription.surfaces)
    for j, k in enumerate(pert.radius_at):
        e = float(pert.radius_rel[i, j])
        surfs[k] = replace(surfs[k], curvature_per_mm=surfs[k].curvature_per_mm / (1.0 + e))
    for j, k in enumerate(pert.thickness_at):
        surfs[k] = replace(surfs[k], thickness_mm=surfs[k].thickness_mm + float(pert.thickness_mm[i, j]))
    for j, k in enumerate(pert.conic_at):
        surfs[k] = replace(surfs[k], conic=surfs[k].conic * (1.0 + float(pert.conic_rel[i, j])))
    try:
        p = replace(prescription, surfaces=tuple(surfs))
    except ValueError as exc:
        raise ValueError(f"manufactured copy {i}: {exc} (tolerances too wide for this lens)") from None
    offsets = {k: float(pert.index[i, j]) for j, k in enumerate(pert.index_at) if float(pert.index[i, j]) != 0.0}
    return p, offsets


def copy_misalignments(prescription: Prescription, pert: SurfacePerturbations, i: int) -> dict:
    """Copy ``i``'s decentres and tilts as ``{surface index: (Misalignment, ...)}`` for
    :class:`lenssim.optics.sequential.SequentialLens` (``prescription``: the copy's own, whose vertices pivot the
    element tilts): each lens surface's own motion about its vertex, then its element's about the element's first
    vertex. Empty when every term is zero."""
    motions: dict[int, list] = {}
    z = prescription.vertex_z_mm
    for j, k in enumerate(pert.surface_at):
        d, t = pert.surface_decentre_mm[i, j].tolist(), pert.surface_tilt_deg[i, j].tolist()
        m = Misalignment(decentre_x_mm=d[0], decentre_y_mm=d[1], tilt_x_deg=t[0], tilt_y_deg=t[1])
        if not m.is_zero:
            motions.setdefault(k, []).append(m)
    for j, (a, b) in enumerate(pert.elements):
        d, t = pert.element_decentre_mm[i, j].tolist(), pert.element_tilt_deg[i, j].tolist()
        m = Misalignment(decentre_x_mm=d[0], decentre_y_mm=d[1], tilt_x_deg=t[0], tilt_y_deg=t[1], pivot_z_mm=z[a])
        if not m.is_zero:
            for k in range(a, b + 1):
                motions.setdefault(k, []).append(m)
    return {k: tuple(v) for k, v in motions.items()}
