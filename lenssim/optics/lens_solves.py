"""Solves that hold what a designer holds fixed while free parameters move (issue 30, item 2).

:func:`solve_design` applies a design's free parameters (:mod:`lenssim.model.lens_parameters`) to a prescription,
then restores, in order:

* ``efl``: the paraxial focal length (primary wavelength) of the file, by the curvature of one surface (default the
  last curved surface). The system's power is affine in any one surface's curvature (the ``y-nu`` trace: the marginal
  ray's height at that surface does not depend on its curvature, its slope after it is affine in it, and every later
  refraction and transfer is linear), so two paraxial traces give the exact curvature; the result is checked by a
  third (relative error below :data:`SOLVE_TOLERANCE`), and a design whose power does not depend on that surface (the
  marginal ray at its vertex height 0) cannot be solved;
* ``fnum``: the F-number (focal length / entrance-pupil diameter) of the file, by the entrance-pupil diameter;
* the image plane (``image``): where the file puts it (``"file"``: the last thickness as the design leaves it, plus
  ``focus_um``), at the design's paraxial focus (``"paraxial"``, plus ``focus_um``), or at its best focus (``"best"``:
  the least RMS wavefront averaged over the file's fields, :func:`best_focus_shift`, plus ``focus_um``).

A design no solve can satisfy is a :class:`SolveError` saying which and why (the callers mark it invalid with that
reason; never a silent fallback).
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from ..model.lens_parameters import LensParameter, apply_parameters, parameter_numbers
from ..model.prescription import Prescription
from .sequential import SequentialLens

__all__ = ["solve_design", "solve_numbers", "check_solves", "best_focus_shift", "SolveError", "HOLDS", "IMAGE_PLANES", "SOLVE_TOLERANCE", "default_solve_surface"]

HOLDS = ("efl", "fnum")
"""What a design may hold: the focal length (by a surface's curvature) and the F-number (by the entrance pupil)."""
IMAGE_PLANES = ("file", "paraxial", "best")
BEST_FOCUS_PUPIL_GRID = 24
"""Pupil samples across the diameter of the best focus's RMS wavefront (per field)."""
BEST_FOCUS_RANGE_DEPTHS = 10
"""The best focus is searched within this many focal depths (``4 lambda N_w^2``) of the paraxial focus first."""
BEST_FOCUS_EXPANSIONS = 8
"""Where the least lies at the search range's edge, the search is repeated about it, twice as wide, this many times
at most (a lens with strong spherical aberration focuses best far from its paraxial focus)."""
BEST_FOCUS_EDGE_MM = 1e-5
"""A best focus closer than this (mm) to the search range's edge is taken as lying beyond it."""
SOLVE_TOLERANCE = 1e-9
"""Relative error of a held focal length after its solve."""


class SolveError(ValueError):
    """A design whose solve cannot hold what is asked (one line: which solve and why)."""


def default_solve_surface(p: Prescription) -> int:
    """The 0-based index of the last curved surface (the focal length's solve by default)."""
    curved = [i for i, s in enumerate(p.surfaces) if s.curvature_per_mm != 0]
    if not curved:
        raise SolveError("the focal length cannot be held: the lens has no curved surface")
    return curved[-1]


def check_solves(p: Prescription, params, *, hold=(), solve_surface: int | None = None) -> int | None:
    """Before any design: the surface (0-based) whose curvature holds the focal length (None without ``efl`` in
    ``hold``), whose curvature none of the free ``params`` (:class:`LensParameter` s) may move (its curvature or
    radius, or an element's bending that includes it; its conic and asphere do not change the power); one-line
    ``ValueError``."""
    for h in hold:
        if h not in HOLDS:
            raise ValueError(f"hold {h!r} is not allowed: one of {', '.join(HOLDS)}")
    if "efl" not in hold:
        return solve_surface
    k = default_solve_surface(p) if solve_surface is None else solve_surface
    moved = {q.index for q in params if isinstance(q, LensParameter) and q.kind in ("curvature", "radius")}
    bends = [q.index for q in params if isinstance(q, LensParameter) and q.kind == "bending"]
    if k in moved or any(a <= k <= b for a, b in bends):
        raise ValueError(f"surface {k + 1} holds the focal length: it cannot also be a free parameter (choose "
                         "another solve surface)")
    return k


def best_focus_shift(p: Prescription, fields=None) -> float:
    """The image plane's shift (mm) from ``p``'s own that minimises the RMS wavefront (primary wavelength) averaged
    over ``fields`` (default the file's): a bounded scalar search within :data:`BEST_FOCUS_RANGE_DEPTHS` focal depths
    of the paraxial focus (to 1e-6 mm), widened about its edge while the least lies there
    (:data:`BEST_FOCUS_EXPANSIONS`); :class:`SolveError` if it never settles."""
    from scipy.optimize import minimize_scalar

    from .sequential import pupil_grid

    fields = tuple(p.fields if fields is None else fields)
    seq = SequentialLens(p)
    par = seq.paraxial()
    depth = BEST_FOCUS_RANGE_DEPTHS * 4 * (seq.primary_wavelength_um * 1e-3) * par.working_f_number**2
    start = par.image_z_mm - p.image_z_mm
    px, py = pupil_grid(BEST_FOCUS_PUPIL_GRID)
    maps = [seq.through_focus(f, px, py) for f in fields]  # each field traced once: a plane moves its sphere only

    def mean_rms(shift):
        return sum(at(float(shift)).rms_waves() for at in maps) / len(fields)

    for _ in range(BEST_FOCUS_EXPANSIONS + 1):
        lo, hi = start - depth, start + depth
        x = float(minimize_scalar(mean_rms, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6}).x)
        if min(x - lo, hi - x) > BEST_FOCUS_EDGE_MM:
            return x
        start, depth = x, 2 * depth  # the least lies beyond the range: search again about the edge, twice as wide
    raise SolveError(f"no best focus within {depth / 2:.4g} mm of {start:.6g} mm from the file's image plane: the mean "
                     "RMS wavefront keeps falling")


def _efl(p: Prescription) -> float:
    return SequentialLens(p).paraxial().efl_mm


def _any(condition) -> bool:
    return bool(condition.any()) if torch.is_tensor(condition) else bool(condition)


def _efl_curvature(efl_at, c0, target: float, k: int):
    """The curvature of surface ``k`` (0-based) that gives the focal length ``target`` (mm), ``efl_at(c)`` the
    design's focal length at curvature ``c`` (floats, or tensors of a batch: differentiable): the power is affine in
    ``c`` (module docstring), so one secant from ``c0`` is exact; :class:`SolveError` if the power does not depend on
    it or the result misses the target by more than :data:`SOLVE_TOLERANCE`."""
    step = max(abs(float(c0)), 1.0 / abs(target)) * 1e-2
    phi0, phi1 = 1.0 / efl_at(c0), 1.0 / efl_at(c0 + step)
    slope = (phi1 - phi0) / step
    bad = ~torch.isfinite(slope) | (slope.abs() * abs(target) < 1e-12) if torch.is_tensor(slope) else (
        not math.isfinite(slope) or abs(slope) * abs(target) < 1e-12)
    if _any(bad):
        raise SolveError(f"the focal length cannot be held by surface {k + 1}'s curvature: the system's power does "
                         "not depend on it")
    c = c0 + (1.0 / target - phi0) / slope
    got = efl_at(c)
    miss = ~torch.isfinite(got) | ((got / target - 1).abs() > SOLVE_TOLERANCE) if torch.is_tensor(got) else not (
        math.isfinite(got) and abs(got / target - 1) <= SOLVE_TOLERANCE)
    if _any(miss):
        worst = float(got.reshape(-1)[0]) if torch.is_tensor(got) else got
        raise SolveError(f"the focal length cannot be held by surface {k + 1}'s curvature: {worst:.6g} mm instead "
                         f"of {target:.6g} mm")
    return c


def solve_numbers(p: Prescription, params, x, *, hold=(), solve_surface: int | None = None, image: str = "file"):
    """:func:`solve_design` for a batch of designs as tensors (:func:`lenssim.model.lens_parameters.parameter_numbers`,
    differentiable in ``x`` through the solves): the free ``params`` at ``x`` ``(B, P)`` or ``(P,)``, then the
    ``efl`` solve (the same secant, in tensors) and the ``image`` plane (``file`` or ``paraxial``). Returns the
    :class:`SequentialLens` of the batch (its :attr:`~SequentialLens.numbers` tensors ``(B, 1)``). ``fnum`` would move
    the entrance pupil, which a batch shares, and ``best`` focus is a search: both are refused (``ValueError``)."""
    hold = tuple(hold)
    if "fnum" in hold or image not in ("file", "paraxial"):
        raise ValueError("a batch of designs holds the entrance pupil and takes the image plane file or paraxial: "
                         f"hold {', '.join(hold) or 'nothing'}, image {image!r} is not allowed")
    params = tuple(params)
    k = check_solves(p, params, hold=hold, solve_surface=solve_surface)
    surfs, shift = parameter_numbers(p, params, x)
    if "efl" in hold:

        def at(c):
            out = list(surfs)
            out[k] = replace(out[k], curvature_per_mm=c)
            return out

        def efl_at(c):
            if not torch.is_tensor(c):
                c = torch.full_like(x.reshape(-1, len(params))[:, :1], c)
            return SequentialLens(p, numbers=at(c)).paraxial().efl_mm

        surfs = at(_efl_curvature(efl_at, surfs[k].curvature_per_mm, SequentialLens(p).paraxial().efl_mm, k))
    seq = SequentialLens(p, numbers=surfs, image_shift_mm=shift)
    if image == "paraxial":
        seq = SequentialLens(p, numbers=surfs, image_shift_mm=shift + seq.paraxial().image_z_mm - seq.image_z_mm)
    return seq


def solve_design(p: Prescription, values: dict, *, hold=(), solve_surface: int | None = None,
                 image: str = "file") -> tuple[Prescription, float]:
    """The prescription of the design ``values`` (``{LensParameter or name: value}``) on the lens ``p`` with the
    ``hold`` solves (:data:`HOLDS`) and the image plane ``image`` (:data:`IMAGE_PLANES`): ``(prescription,
    image_shift_mm)`` (the shift from the returned prescription's own image distance). ``solve_surface``: the
    0-based surface whose curvature holds the focal length (default :func:`default_solve_surface`); it must not be a
    free parameter. Errors: :class:`SolveError` (a solve that cannot hold), ``ValueError`` / ``PrescriptionError``
    (an invalid design)."""
    hold = tuple(hold)
    if image not in IMAGE_PLANES:
        raise ValueError(f"image plane {image!r} is not allowed: one of {', '.join(IMAGE_PLANES)}")
    k = check_solves(p, values, hold=hold, solve_surface=solve_surface)
    q, shift = apply_parameters(p, values)
    par0 = SequentialLens(p).paraxial()
    if "efl" in hold:

        def at(c):
            surfs = list(q.surfaces)
            surfs[k] = replace(surfs[k], curvature_per_mm=c)
            return replace(q, surfaces=tuple(surfs))

        q = at(_efl_curvature(lambda c: _efl(at(c)), q.surfaces[k].curvature_per_mm, par0.efl_mm, k))
    if "fnum" in hold:
        efl = SequentialLens(q).paraxial().efl_mm
        epd = abs(efl) / par0.f_number
        if not (math.isfinite(epd) and epd > 0):
            raise SolveError(f"the F-number cannot be held: focal length {efl:.6g} mm")
        q = replace(q, entrance_pupil_diameter_mm=epd)
    if image == "paraxial":
        shift += SequentialLens(q).paraxial().image_z_mm - q.image_z_mm
    elif image == "best":
        shift += best_focus_shift(q)
    return q, shift
