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
* ``focus_compensated`` (default true): each copy's image plane is placed so that its distance from the copy's own
  paraxial focus (primary wavelength) equals the nominal lens's, plus the despace draw, as a camera module is
  focused at assembly; false: the image plane stays at the nominal distance behind the last surface (plus the
  despace draw), and radius, thickness and index errors defocus the copy.

Decentre and tilt of a surface or element need a ray tracer without rotational symmetry, which lenssim does not
have: such keys are refused (:data:`NOT_SUPPORTED`).

Grades (:data:`SURFACE_GRADES`): ``radius_pct``, ``conic_pct``, ``index`` and ``despace_um`` are the grades of
:data:`lenssim.model.tolerances.GRADES` (the moulded asphere's front-surface radius, conic, index and despace;
sources in ``docs/as-built.md``). The thickness limit per grade (:data:`THICKNESS_UM`) is the centre-thickness
tolerance of Apollo Optical Systems' published "Typical Manufacturing Tolerances" table for injection-moulded
lenses (https://www.apollooptical.com/manufacturing-tolerances): +/-0.025 mm commercial, +/-0.015 mm precision; the
same table's radius tolerances (+/-1% and +/-0.5% of the radius) are the grades' radius values, so the two agree.
The same limit is applied to air gaps (spacer and barrel tolerances of that order; a choice, not from the table).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import torch

from .prescription import Prescription
from .tolerances import GRADES, TOLERANCE_SIGMAS

__all__ = ["SurfaceTolerances", "SurfacePerturbations", "SURFACE_GRADES", "THICKNESS_UM", "NOT_SUPPORTED",
           "surface_grade", "perturbed_prescription"]

NOT_SUPPORTED = "decentre and tilt need a tracer without rotational symmetry: not supported for --lens yet"
"""The one line that refuses a decentre or tilt tolerance of any lens."""
_REFUSED_WORDS = ("decentre", "decenter", "tilt", "wedge", "concentricity")

THICKNESS_UM = {"none": 0.0, "commercial": 25.0, "precision": 15.0}
"""Thickness limit (um) per grade: Apollo Optical Systems' centre-thickness tolerances for injection-moulded
lenses, commercial and precision (module docstring)."""


@dataclass(frozen=True, kw_only=True)
class SurfaceTolerances:
    """Limits of the per-surface error terms (module docstring); every term 0 by default (the nominal lens)."""

    radius_pct: float = 0.0
    thickness_um: float = 0.0
    conic_pct: float = 0.0
    index: float = 0.0
    despace_um: float = 0.0
    focus_compensated: bool = True

    def __post_init__(self):
        if not isinstance(self.focus_compensated, bool):
            raise ValueError(f"tolerances: focus_compensated={self.focus_compensated!r} is not allowed: true or false")
        for f in fields(self):
            if f.name == "focus_compensated":
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"tolerances: {f.name}={v!r} is not allowed: a finite number >= 0")
            object.__setattr__(self, f.name, float(v))

    @classmethod
    def from_dict(cls, d: dict) -> "SurfaceTolerances":
        """From a ``[tolerances]`` table: ``grade = "commercial"`` (or ``"precision"``, ``"none"``) starts from a
        grade, the other keys override it; a decentre or tilt key is refused (:data:`NOT_SUPPORTED`), an unknown key
        is an error that lists the valid ones."""
        d = dict(d)
        if any(w in str(k).lower() for k in d for w in _REFUSED_WORDS):
            raise ValueError(NOT_SUPPORTED)
        base = surface_grade(d.pop("grade", "none"))
        allowed = [f.name for f in fields(cls)]
        bad = sorted(str(k) for k in set(d) - set(allowed))
        if bad:
            raise ValueError(f"[tolerances]: unknown key(s) {bad}; valid: grade, {', '.join(allowed)}")
        return cls(**{**asdict(base), **d})

    def to_dict(self) -> dict:
        return asdict(self)

    def terms(self) -> tuple[str, ...]:
        """The terms that are on (limit > 0)."""
        return tuple(f.name for f in fields(self) if f.name != "focus_compensated" and getattr(self, f.name) > 0)

    def sample(self, prescription: Prescription, n: int, *, seed: int) -> "SurfacePerturbations":
        """``n`` manufactured copies of ``prescription``, reproducibly from ``seed`` (an explicit
        :class:`torch.Generator`): the terms drawn in a fixed order (radius, thickness, conic, index, despace), each
        for all its surfaces, always (zero where switched off), so that switching a term off leaves the others'
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

        def draw(k, limit):
            return torch.randn((n, k), generator=g, dtype=torch.float64) * (limit * sd)

        return SurfacePerturbations(
            radius_rel=draw(len(radius_at), self.radius_pct * 1e-2), radius_at=radius_at,
            thickness_mm=draw(len(thick_at), self.thickness_um * 1e-3), thickness_at=thick_at,
            conic_rel=draw(len(conic_at), self.conic_pct * 1e-2), conic_at=conic_at,
            index=draw(len(glass_at), self.index), index_at=glass_at,
            despace_mm=draw(1, self.despace_um * 1e-3)[:, 0], tolerances=self)


SURFACE_GRADES = {name: SurfaceTolerances(radius_pct=t.radius_front_pct, thickness_um=THICKNESS_UM[name],
                                          conic_pct=t.conic_pct, index=t.index, despace_um=t.despace_um)
                  for name, t in GRADES.items()}
"""Named grades (``none``, ``commercial``, ``precision``): see the module docstring for the values' sources."""


def surface_grade(name: str) -> SurfaceTolerances:
    """The per-surface tolerances of a named grade; ``ValueError`` listing the grades otherwise."""
    if name not in SURFACE_GRADES:
        raise ValueError(f"tolerance grade {name!r} is not known; valid: {', '.join(SURFACE_GRADES)}")
    return SURFACE_GRADES[name]


@dataclass(frozen=True)
class SurfacePerturbations:
    """Sampled errors of ``N`` copies (float64, one column per surface the term applies to; ``*_at`` the 0-based
    surface indices of the columns): relative radius errors, thickness errors (mm) of the gap after the surface,
    relative conic errors, index errors of the glass after the surface, and the despace (mm) ``(N,)``."""

    radius_rel: torch.Tensor
    radius_at: tuple[int, ...]
    thickness_mm: torch.Tensor
    thickness_at: tuple[int, ...]
    conic_rel: torch.Tensor
    conic_at: tuple[int, ...]
    index: torch.Tensor
    index_at: tuple[int, ...]
    despace_mm: torch.Tensor
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
