"""Manufacturing and assembly tolerances of the thin conic singlet, and seeded samples of as-built lenses.

A :class:`Tolerances` holds one limit per error term (0 switches a term off). A sampled lens draws each term from
a normal distribution whose ``TOLERANCE_SIGMAS`` standard deviations reach the limit (the usual reading of a
tolerance "+/- t" in a Monte Carlo tolerance analysis: 95% of the parts inside it); a vector term (decentre,
tilt) draws both components so, in a random direction. The figure error is the exception: its limit is not a
tolerance but a model (below). What each term does to the wavefront is :mod:`lenssim.optics.as_built`.

Terms:

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
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch

from ..torch_utils import HOST, tensor_of
from ..validate import listed, quoted

__all__ = ["Tolerances", "Perturbations", "GRADES", "TOLERANCE_SIGMAS", "COST_SCALE", "FIGURE_TERMS", "grade"]

TOLERANCE_SIGMAS = 2.0
"""A tolerance limit is this many standard deviations of the sampled error."""
COST_SCALE = 1e-3
"""The slope-departure cost at which ``figure_per_cost`` applies (the middle of the paper's 0..2e-3 range)."""
FIGURE_TERMS = ("power", "astig_0", "astig_45", "coma_x", "coma_y", "spherical")
"""The figure error's Zernike terms (Noll 4, 6, 5, 8, 7, 11), over the asphere's clear aperture."""
ARCMIN_RAD = math.pi / (180 * 60)


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


@dataclass(frozen=True, kw_only=True)
class Tolerances:
    """Limits of the error terms (module docstring); every term 0 by default (a perfect lens)."""

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
        check_limits(self)
        if self.figure_exponent <= 0:
            raise ValueError(f"tolerances: figure_exponent={self.figure_exponent!r} is not allowed: > 0")

    @classmethod
    def from_dict(cls, d: dict) -> "Tolerances":
        """From a ``[tolerances]`` table: ``grade = "commercial"`` (or ``"precision"``, ``"none"``) starts from a
        grade, the other keys override it; an unknown key is an error that lists the valid ones."""
        d = dict(d)
        base = grade(d.pop("grade", "none"))
        allowed = [f.name for f in fields(cls)]
        bad = sorted(set(d) - set(allowed))
        if bad:
            raise ValueError(f"[tolerances]: unknown key(s) {listed(bad)}; valid: {listed(['grade', *allowed], near=bad)}")
        return cls(**{**asdict(base), **d})

    def to_dict(self) -> dict:
        return asdict(self)

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
        """``n`` as-built lenses, reproducibly from ``seed``: every term drawn (zero where switched off) in a fixed
        order, so that switching a term off leaves the others' draws unchanged (common random numbers)."""
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"number of lenses n={n!r} is not allowed: an integer >= 1")
        g = torch.Generator().manual_seed(int(seed))
        s = 1.0 / TOLERANCE_SIGMAS

        def draw(shape, limit):
            z = torch.randn(shape, generator=g, dtype=torch.float64, device=HOST)  # the generator's device
            return z * (limit * s)

        return Perturbations(
            radius_front=draw((n,), self.radius_front_pct * 1e-2),
            radius_back=draw((n,), self.radius_back_pct * 1e-2),
            conic=draw((n,), self.conic_pct * 1e-2),
            index=draw((n,), self.index),
            asphere_decentre_mm=draw((n, 2), self.asphere_decentre_um * 1e-3),
            asphere_tilt_rad=draw((n, 2), self.asphere_tilt_arcmin * ARCMIN_RAD),
            lens_tilt_rad=draw((n, 2), self.lens_tilt_arcmin * ARCMIN_RAD),
            despace_mm=draw((n,), self.despace_um * 1e-3),
            figure=torch.randn((n, len(FIGURE_TERMS)), generator=g, dtype=torch.float64, device=HOST)
            / math.sqrt(len(FIGURE_TERMS)),
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


def grade(name: str) -> Tolerances:
    """The tolerances of a named grade; ``ValueError`` listing the grades otherwise."""
    if not isinstance(name, str) or name not in GRADES:
        raise ValueError(f"tolerance grade {quoted(name)} is not known; valid: {', '.join(GRADES)}")
    return GRADES[name]
