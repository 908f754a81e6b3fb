"""Manufacturing and assembly tolerances, and seeded samples of as-built lenses, for both lens kinds: the thin conic
singlet (:class:`Tolerances`) and any sequential lens, per surface (:class:`SurfaceTolerances`, of a
:class:`lenssim.model.prescription.Prescription`; issue 29).

Either holds one limit per error term (0 switches a term off), checked by one :func:`check_limits`, with one grade
table mechanism (``Tolerances.grade(name)`` from :data:`GRADES`, ``SurfaceTolerances.grade(name)`` from
:data:`SURFACE_GRADES`). A sampled lens draws each term
from a normal distribution whose ``TOLERANCE_SIGMAS`` standard deviations reach the limit (the usual reading of a
tolerance "+/- t" in a Monte Carlo tolerance analysis: 95% of the parts inside it), from one seeded generator
(:class:`_Draws`); a vector term (decentre, tilt) draws both components so, in a random direction.

The singlet's terms (the figure error is the exception: its limit is not a tolerance but a model, below; what each
term does to the wavefront is :mod:`lenssim.optics.as_built`):

* ``radius_front_pct``, ``radius_back_pct``: vertex-radius error of each surface (% of the radius);
* ``conic_pct``: error of the asphere's conic constant (% of the design's value);
* ``index``: refractive-index error of the glass (absolute);
* ``asphere_decentre_um`` and ``asphere_tilt_arcmin``: the aspheric back surface displaced against the front
  (the lens's wedge or moulding "concentricity");
* ``lens_tilt_arcmin``: the whole lens tilted in its mount (assembly). A decentre of the whole lens, whose stop is
  its own rim, only moves the image (a boresight error, not blur) and is left out;
* ``despace_um``: the image plane's distance from the lens (the assembly's focus error). With
  ``focus_compensated`` (default) the module is focused at assembly, as camera modules are: the image plane is
  placed at the as-built lens's own paraxial focus (at the spectrum's reference wavelength, plus the design's
  focus shift) and the despace is the residual error of that focusing; without it the image plane stays at the
  nominal distance, and radius and index errors defocus the lens (1% of radius is 250 um at f = 25 mm, against
  a depth of focus of about +/-40 um at f/6.25);
* the figure (surface-form) error of the asphere, six low-order Zernike terms (power, astigmatism x 2, coma x 2,
  spherical) with random coefficients whose RMS slope has the expected value
  ``figure_floor + figure_per_cost * (C_a / COST_SCALE)^figure_exponent`` (slopes in rad, ``C_a`` the design's
  slope-departure cost): the paper's premise that the discrepancy between nominal and as-built aspheres grows with
  their slope departure (Section 1, refs. [2, 6]), with the law's parameters settings.

The thin lens has no centre thickness, so its thickness error has no term here.

Grades (:data:`GRADES`), for a moulded or polished small asphere; sources in ``docs/as-built.md``.

Any lens's terms (each for every surface it applies to):

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
:data:`GRADES` (the moulded asphere's front-surface radius, conic, index and despace; sources in
``docs/as-built.md``). The thickness limit per grade (:data:`THICKNESS_UM`) is the centre-thickness
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

import math
from dataclasses import asdict, dataclass, fields, replace

import torch

from ..torch_utils import HOST, tensor_of
from ..validate import listed, quoted
from .misalignment import Misalignment
from .prescription import Prescription

__all__ = ["Tolerances", "Perturbations", "GRADES", "TOLERANCE_SIGMAS", "COST_SCALE", "FIGURE_TERMS",
           "SurfaceTolerances", "SurfacePerturbations", "SURFACE_GRADES", "THICKNESS_UM", "ELEMENT_DECENTRE_UM",
           "perturbed_prescription", "lens_surfaces", "lens_elements", "copy_misalignments"]

TOLERANCE_SIGMAS = 2.0
"""A tolerance limit is this many standard deviations of the sampled error."""
COST_SCALE = 1e-3
"""The slope-departure cost at which ``figure_per_cost`` applies (the middle of the paper's 0..2e-3 range)."""
FIGURE_TERMS = ("power", "astig_0", "astig_45", "coma_x", "coma_y", "spherical")
"""The figure error's Zernike terms (Noll 4, 6, 5, 8, 7, 11), over the asphere's clear aperture."""
ARCMIN_RAD = math.pi / (180 * 60)
"""One arcminute in radians (the singlet's tilts, drawn in rad)."""
ARCMIN_DEG = 1.0 / 60.0
"""One arcminute in degrees (any lens's tilts, drawn in degrees as :class:`Misalignment` takes them)."""
THICKNESS_UM = {"none": 0.0, "commercial": 25.0, "precision": 15.0}
"""Thickness limit (um) per grade: Apollo Optical Systems' centre-thickness tolerances for injection-moulded
lenses, commercial and precision (module docstring)."""
ELEMENT_DECENTRE_UM = {"none": 0.0, "commercial": 25.0, "precision": 10.0}
"""Element decentre limit (um) per grade: an assumption (module docstring)."""


def check_limits(t) -> None:
    """A tolerances dataclass's fields, in place: ``focus_compensated`` a bool, every other field a finite number
    >= 0 (made a float); one-line ``ValueError`` naming the field otherwise."""
    if not isinstance(t.focus_compensated, bool):
        raise ValueError(f"tolerances: focus_compensated={t.focus_compensated!r} is not allowed: true or false")
    for f in fields(t):
        if f.name == "focus_compensated":
            continue
        v = getattr(t, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ValueError(f"tolerances: {f.name}={v!r} is not allowed: a finite number >= 0")
        object.__setattr__(t, f.name, float(v))


class _Draws:
    """The seeded draws of ``n`` lenses, both kinds: one explicit :class:`torch.Generator` from ``seed``, every draw
    float64 on the host (the generator's device), in the caller's fixed order, so that a term switched off (drawn
    anyway, scaled by zero) leaves the others' draws unchanged (common random numbers)."""

    def __init__(self, n: int, seed: int):
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"number of lenses n={n!r} is not allowed: an integer >= 1")
        self.n = n
        self.g = torch.Generator().manual_seed(int(seed))

    def normal(self, *shape) -> torch.Tensor:
        """Standard-normal draws ``(n, *shape)``."""
        return torch.randn((self.n, *shape), generator=self.g, dtype=torch.float64, device=HOST)

    def within(self, limit: float, *shape) -> torch.Tensor:
        """Errors ``(n, *shape)`` of a term whose tolerance is ``limit`` (``TOLERANCE_SIGMAS`` standard deviations)."""
        return self.normal(*shape) * (limit * (1.0 / TOLERANCE_SIGMAS))


class _Limits:
    """What both kinds of tolerances share: checked limits, a named grade, a ``[tolerances]`` table (the grade table
    ``_grades``, set on each subclass below its table)."""

    _grades: dict

    def __post_init__(self):
        check_limits(self)

    @classmethod
    def grade(cls, name: str):
        """The tolerances of a named grade; ``ValueError`` listing the grades otherwise."""
        table = cls._grades
        if not isinstance(name, str) or name not in table:
            raise ValueError(f"tolerance grade {quoted(name)} is not known; valid: {', '.join(table)}")
        return table[name]

    @classmethod
    def from_dict(cls, d: dict):
        """From a ``[tolerances]`` table: ``grade = "commercial"`` (or ``"precision"``, ``"none"``) starts from a
        grade, the other keys override it; an unknown key is an error that lists the valid ones."""
        d = dict(d)
        base = cls.grade(d.pop("grade", "none"))
        allowed = [f.name for f in fields(cls)]
        bad = sorted(str(k) for k in set(d) - set(allowed))
        if bad:
            raise ValueError(f"[tolerances]: unknown key(s) {listed(bad)}; valid: {listed(['grade', *allowed], near=bad)}")
        return cls(**{**asdict(base), **d})

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, kw_only=True)
class Tolerances(_Limits):
    """Limits of the singlet's error terms (module docstring); every term 0 by default (a perfect lens)."""

    radius_front_pct: float = 0.0
    radius_back_pct: float = 0.0
    conic_pct: float = 0.0
    index: float = 0.0
    asphere_decentre_um: float = 0.0
    asphere_tilt_arcmin: float = 0.0
    lens_tilt_arcmin: float = 0.0
    despace_um: float = 0.0
    figure_floor: float = 0.0
    figure_per_cost: float = 0.0
    figure_exponent: float = 1.0
    focus_compensated: bool = True

    def __post_init__(self):
        super().__post_init__()
        if self.figure_exponent <= 0:
            raise ValueError(f"tolerances: figure_exponent={self.figure_exponent!r} is not allowed: > 0")

    def only(self, name: str) -> "Tolerances":
        """These tolerances with every term but ``name`` switched off (``"figure"``: the three figure settings)."""
        keep = {"figure_floor", "figure_per_cost", "figure_exponent"} if name == "figure" else {name}
        if not keep & {f.name for f in fields(self)}:
            raise ValueError(f"tolerance term {name!r} is not known; valid: {', '.join(self.terms())}")
        return Tolerances(**{k: (v if k in keep or k in ("figure_exponent", "focus_compensated") else 0.0)
                             for k, v in asdict(self).items()})

    def terms(self) -> tuple[str, ...]:
        """The switchable terms that are on (``"figure"`` for the figure error)."""
        out = [f.name for f in fields(self) if not f.name.startswith(("figure", "focus")) and getattr(self, f.name) > 0]
        if self.figure_floor > 0 or self.figure_per_cost > 0:
            out.append("figure")
        return tuple(out)

    def figure_slope_rad(self, cost):
        """Expected RMS slope (rad) of the asphere's figure error for slope-departure cost(s) ``cost``."""
        c = tensor_of(cost, torch.float64)
        return self.figure_floor + self.figure_per_cost * (c.clamp(min=0) / COST_SCALE) ** self.figure_exponent

    def sample(self, n: int, *, seed: int) -> "Perturbations":
        """``n`` as-built lenses, reproducibly from ``seed`` (:class:`_Draws`): every term drawn (zero where switched
        off) in a fixed order, the figure weights last."""
        d = _Draws(n, seed)
        return Perturbations(
            radius_front=d.within(self.radius_front_pct * 1e-2),
            radius_back=d.within(self.radius_back_pct * 1e-2),
            conic=d.within(self.conic_pct * 1e-2),
            index=d.within(self.index),
            asphere_decentre_mm=d.within(self.asphere_decentre_um * 1e-3, 2),
            asphere_tilt_rad=d.within(self.asphere_tilt_arcmin * ARCMIN_RAD, 2),
            lens_tilt_rad=d.within(self.lens_tilt_arcmin * ARCMIN_RAD, 2),
            despace_mm=d.within(self.despace_um * 1e-3),
            figure=d.normal(len(FIGURE_TERMS)) / math.sqrt(len(FIGURE_TERMS)),
            tolerances=self,
        )


@dataclass(frozen=True)
class Perturbations:
    """Sampled errors of ``N`` lenses (float64): relative radius errors ``(N,)``, relative conic error ``(N,)``,
    index error ``(N,)``, decentre (mm) and tilts (rad) ``(N, 2)`` as ``(x, y)`` vectors in the image plane's axes
    (a tilt ``(tx, ty)`` tips the surface's axis towards ``(tx, ty, 1)``), despace (mm) ``(N,)``, and the figure
    error's standard-normal Zernike weights ``(N, 6)`` scaled by ``1/sqrt(6)`` (scaled to the design's figure
    slope by :func:`lenssim.optics.as_built.as_built_coefficients`)."""

    radius_front: torch.Tensor
    radius_back: torch.Tensor
    conic: torch.Tensor
    index: torch.Tensor
    asphere_decentre_mm: torch.Tensor
    asphere_tilt_rad: torch.Tensor
    lens_tilt_rad: torch.Tensor
    despace_mm: torch.Tensor
    figure: torch.Tensor
    tolerances: Tolerances

    def __len__(self) -> int:
        return int(self.radius_front.shape[0])

    @property
    def rotationally_symmetric(self) -> bool:
        """True if every lens is rotationally symmetric: no decentre, no tilt, and no astigmatic or comatic figure
        error (then one azimuth per field angle and the mirror-symmetric OTF path serve)."""
        fig = self.figure[:, [FIGURE_TERMS.index(t) for t in ("astig_0", "astig_45", "coma_x", "coma_y")]]
        if "figure" not in self.tolerances.terms():  # the weights are drawn always, scaled by a zero slope here
            fig = fig[:0]
        return not any(bool(v.abs().max() > 0) for v in (self.asphere_decentre_mm, self.asphere_tilt_rad,
                                                          self.lens_tilt_rad, fig) if v.numel())

    def __getitem__(self, idx) -> "Perturbations":
        sel = slice(idx, idx + 1) if isinstance(idx, int) else idx
        return Perturbations(**{f.name: (getattr(self, f.name)[sel] if f.name != "tolerances" else self.tolerances)
                                for f in fields(self)})

    def variables(self) -> dict:
        """The sampled values as named ``(N,)`` columns with units (for a dataset): ``name -> (values, units)``."""
        out = {"radius_front_pct": (self.radius_front * 100, "%"), "radius_back_pct": (self.radius_back * 100, "%"),
               "conic_pct": (self.conic * 100, "%"), "index_error": (self.index, "1"),
               "despace_um": (self.despace_mm * 1e3, "um")}
        for name, v, k, unit in (("asphere_decentre", self.asphere_decentre_mm, 1e3, "um"),
                                 ("asphere_tilt", self.asphere_tilt_rad, 1 / ARCMIN_RAD, "arcmin"),
                                 ("lens_tilt", self.lens_tilt_rad, 1 / ARCMIN_RAD, "arcmin")):
            out[f"{name}_x_{unit}"] = (v[:, 0] * k, unit)
            out[f"{name}_y_{unit}"] = (v[:, 1] * k, unit)
        for i, t in enumerate(FIGURE_TERMS):
            out[f"figure_{t}"] = (self.figure[:, i], "1 (weight of the unit-slope figure error)")
        return out


GRADES = {
    "none": Tolerances(),
    # a moulded asphere, commercial class (docs/as-built.md gives the sources)
    "commercial": Tolerances(radius_front_pct=1.0, radius_back_pct=1.0, conic_pct=2.0, index=1e-3,
                             asphere_decentre_um=25.0, asphere_tilt_arcmin=3.0, lens_tilt_arcmin=5.0, despace_um=10.0,
                             figure_floor=5e-5, figure_per_cost=1e-4),
    # a precision moulded or polished asphere
    "precision": Tolerances(radius_front_pct=0.5, radius_back_pct=0.5, conic_pct=0.5, index=5e-4,
                            asphere_decentre_um=10.0, asphere_tilt_arcmin=1.0, lens_tilt_arcmin=2.0, despace_um=3.0,
                            figure_floor=2e-5, figure_per_cost=4e-5),
}
"""Named tolerance grades: ``none`` (the nominal lens), ``commercial``, ``precision``."""
Tolerances._grades = GRADES


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
class SurfaceTolerances(_Limits):
    """Limits of any lens's per-surface error terms (module docstring); every term 0 by default (the nominal lens)."""

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

    def terms(self) -> tuple[str, ...]:
        """The terms that are on (limit > 0)."""
        return tuple(f.name for f in fields(self) if f.name != "focus_compensated" and getattr(self, f.name) > 0)

    def sample(self, prescription: Prescription, n: int, *, seed: int) -> "SurfacePerturbations":
        """``n`` manufactured copies of ``prescription``, reproducibly from ``seed`` (an explicit
        :class:`torch.Generator`, :class:`_Draws`): the terms drawn in a fixed order (radius, thickness, conic, index, despace,
        surface decentre, surface tilt, element decentre, element tilt; a vector term's two components together),
        each for all its surfaces, always (zero where switched off), so that switching a term off leaves the others'
        draws unchanged (common random numbers)."""
        surfs = prescription.surfaces
        radius_at = tuple(i for i, s in enumerate(surfs) if s.curvature_per_mm != 0)
        thick_at = tuple(i for i, s in enumerate(surfs[:-1]) if s.thickness_mm > 0)
        conic_at = tuple(i for i, s in enumerate(surfs) if s.conic != 0)
        glass_at = tuple(i for i, s in enumerate(surfs[:-1]) if not s.is_air)
        d = _Draws(n, seed)
        lens_at = lens_surfaces(prescription)
        elements = lens_elements(prescription)
        return SurfacePerturbations(
            radius_rel=d.within(self.radius_pct * 1e-2, len(radius_at)), radius_at=radius_at,
            thickness_mm=d.within(self.thickness_um * 1e-3, len(thick_at)), thickness_at=thick_at,
            conic_rel=d.within(self.conic_pct * 1e-2, len(conic_at)), conic_at=conic_at,
            index=d.within(self.index, len(glass_at)), index_at=glass_at,
            despace_mm=d.within(self.despace_um * 1e-3, 1)[:, 0],
            surface_decentre_mm=d.within(self.surface_decentre_um * 1e-3, len(lens_at), 2),
            surface_tilt_deg=d.within(self.surface_tilt_arcmin * ARCMIN_DEG, len(lens_at), 2), surface_at=lens_at,
            element_decentre_mm=d.within(self.element_decentre_um * 1e-3, len(elements), 2),
            element_tilt_deg=d.within(self.element_tilt_arcmin * ARCMIN_DEG, len(elements), 2), elements=elements,
            tolerances=self)


SURFACE_GRADES = {name: SurfaceTolerances(radius_pct=t.radius_front_pct, thickness_um=THICKNESS_UM[name],
                                          conic_pct=t.conic_pct, index=t.index, despace_um=t.despace_um,
                                          surface_decentre_um=t.asphere_decentre_um,
                                          surface_tilt_arcmin=t.asphere_tilt_arcmin,
                                          element_decentre_um=ELEMENT_DECENTRE_UM[name],
                                          element_tilt_arcmin=t.lens_tilt_arcmin)
                  for name, t in GRADES.items()}
"""Named grades (``none``, ``commercial``, ``precision``): see the module docstring for the values' sources."""
SurfaceTolerances._grades = SURFACE_GRADES


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
