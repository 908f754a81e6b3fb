"""Free parameters of any prescription, by name (issue 30, item 1).

A designer names the numbers of their lens that may move; each name resolves against the
:class:`lenssim.model.prescription.Prescription` (surfaces numbered as in the file, 1..N; elements numbered from the
object side, 1..E, as :func:`lenssim.model.tolerances.lens_elements` finds them: a run of surfaces joined by
glass, a cemented group being one element):

=================  ========  ======================================================================================
name               unit      what moves
=================  ========  ======================================================================================
``S5.curvature``   1/mm      surface 5's vertex curvature (0: flat)
``S5.radius``      mm        surface 5's vertex radius (the same number as ``1 / curvature``; not both)
``S5.conic``       1         surface 5's conic constant (any standard surface has one)
``S5.A4`` .. A16   mm^(1-k)  the even asphere's coefficient of ``r^k``; only on a surface that is an even asphere in the
                             file, unless the surface is made one (``aspherize``: every coefficient up to the named one
                             starting at 0); not on another kind's surface (a ``qbfs``'s coefficients are not ``A4..``)
``S2.thickness``   mm        the thickness after surface 2 (a centre thickness or an air gap; after the last surface:
                             the image distance)
``E1.bending``     1         element 1's bending: its shape factor ``(c_first + c_last) / (c_first - c_last)`` (the
                             paper's ``s``), every curvature of the element shifted by the same amount, which holds
                             each component's thin-lens power (for a singlet: ``c1 - c2``)
``focus_um``       um        the image plane's shift from the file's (positive: away from the lens)
=================  ========  ======================================================================================

:func:`apply_parameters` gives the prescription at given values (one design; batches are evaluated one design at a
time by the callers), or a :class:`lenssim.model.prescription.PrescriptionError` saying why the design is invalid
(crossing surfaces, a negative thickness...). Names are case-sensitive as printed above, except the ``S``/``E``
prefix and the keyword (``s5.Conic`` is ``S5.conic``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import torch

from .prescription import Prescription
from .surface_kinds.standard import Standard
from .tolerances import lens_elements

__all__ = ["LensParameter", "lens_parameters", "parse_parameter", "apply_parameters", "parameter_numbers",
           "parameter_values",
           "ASPHERIC_ORDERS", "FOCUS_PARAMETER"]

ASPHERIC_ORDERS = (4, 6, 8, 10, 12, 14, 16)
"""The even asphere's powers of ``r``, as :class:`lenssim.model.prescription.PrescriptionSurface` holds them."""
FOCUS_PARAMETER = "focus_um"
_SURFACE_KEYS = ("curvature", "radius", "conic", "thickness") + tuple(f"A{k}" for k in ASPHERIC_ORDERS)
_PATTERN = re.compile(r"^([SsEe])(\d+)\.(\w+)$")


@dataclass(frozen=True)
class LensParameter:
    """One free parameter: its canonical ``name``, ``kind`` (``curvature``, ``radius``, ``conic``, ``A4``..,
    ``thickness``, ``bending`` or ``focus``), the 0-based surface index (or element ``(first, last)`` indices), its
    unit and a description in words."""

    name: str
    kind: str
    index: int | tuple[int, int] | None
    unit: str
    description: str


def _elements(p: Prescription) -> tuple[tuple[int, int], ...]:
    return lens_elements(p)


def lens_parameters(p: Prescription, *, aspherize=()) -> dict[str, LensParameter]:
    """Every parameter name of the lens ``p`` (in order: surfaces, elements, focus). ``aspherize``: 1-based surface
    numbers made even aspheres (their ``A4..A16`` become free)."""
    make = {int(k) for k in aspherize}
    out: dict[str, LensParameter] = {}
    for i, s in enumerate(p.surfaces):
        k = i + 1
        out[f"S{k}.curvature"] = LensParameter(f"S{k}.curvature", "curvature", i, "1/mm", f"curvature of surface {k}")
        out[f"S{k}.radius"] = LensParameter(f"S{k}.radius", "radius", i, "mm", f"radius of surface {k}")
        out[f"S{k}.conic"] = LensParameter(f"S{k}.conic", "conic", i, "1", f"conic constant of surface {k}")
        if isinstance(s.surface_kind, Standard) and (s.is_aspheric or k in make):  # the even-asphere family
            for j, order in enumerate(ASPHERIC_ORDERS):
                out[f"S{k}.A{order}"] = LensParameter(f"S{k}.A{order}", f"A{order}", i, f"mm^{1 - order}",
                                                      f"even-asphere coefficient of r^{order} of surface {k}")
        after = "the image distance" if k == len(p.surfaces) else f"the thickness after surface {k}"
        out[f"S{k}.thickness"] = LensParameter(f"S{k}.thickness", "thickness", i, "mm", after)
    for j, (a, b) in enumerate(_elements(p)):
        out[f"E{j + 1}.bending"] = LensParameter(f"E{j + 1}.bending", "bending", (a, b), "1",
                                                 f"bending (shape factor) of element {j + 1}, surfaces {a + 1}-{b + 1}")
    out[FOCUS_PARAMETER] = LensParameter(FOCUS_PARAMETER, "focus", None, "um", "image-plane shift from the file's")
    return out


def _canonical(name: str) -> str:
    m = _PATTERN.match(name.strip())
    if not m:
        return name.strip()
    key = m.group(3)
    low = key.lower()
    key = low if low in ("curvature", "radius", "conic", "thickness", "bending") else key.upper()
    return f"{m.group(1).upper()}{int(m.group(2))}.{key}"


def parse_parameter(p: Prescription, name: str, *, aspherize=()) -> LensParameter:
    """The parameter ``name`` of the lens ``p``; a one-line ``ValueError`` listing the lens's valid names otherwise
    (and, for ``A4``.. on a surface that is not an even asphere, how to make it one)."""
    params = lens_parameters(p, aspherize=aspherize)
    c = _canonical(str(name))
    if c in params:
        return params[c]
    m = _PATTERN.match(c)
    n, e = len(p.surfaces), len(_elements(p))
    valid = (f"S1..S{n}.curvature|radius|conic|thickness, A4..A16 on the aspheric surfaces "
             f"({', '.join(str(i + 1) for i, s in enumerate(p.surfaces) if s.is_aspheric) or 'none'}), "
             f"E1..E{e}.bending, {FOCUS_PARAMETER}")
    if m and m.group(1) == "S" and 1 <= int(m.group(2)) <= n and m.group(3) in {f"A{k}" for k in ASPHERIC_ORDERS}:
        raise ValueError(f"parameter {name!r} is not allowed: surface {m.group(2)} is not an even asphere in the file "
                         f"(make it one by naming it among the aspherized surfaces); valid: {valid}")
    raise ValueError(f"parameter {name!r} is not a parameter of this lens; valid: {valid}")


def parameter_values(p: Prescription, params) -> dict[str, float]:
    """The values the lens ``p`` has for ``params`` (:class:`LensParameter` s): the design as the file gives it."""
    out = {}
    for q in params:
        if q.kind == "focus":
            out[q.name] = 0.0
        elif q.kind == "bending":
            a, b = q.index
            c1, c2 = p.surfaces[a].curvature_per_mm, p.surfaces[b].curvature_per_mm
            out[q.name] = (c1 + c2) / (c1 - c2) if c1 != c2 else math.inf
        else:
            s = p.surfaces[q.index]
            if q.kind == "curvature":
                out[q.name] = s.curvature_per_mm
            elif q.kind == "radius":
                out[q.name] = s.radius_mm
            elif q.kind == "conic":
                out[q.name] = s.conic
            elif q.kind == "thickness":
                out[q.name] = s.thickness_mm
            else:
                j = ASPHERIC_ORDERS.index(int(q.kind[1:]))
                co = s.aspheric_coefficients
                out[q.name] = co[j] if j < len(co) else 0.0
    return out


def apply_parameters(p: Prescription, values: dict) -> tuple[Prescription, float]:
    """The prescription with ``values`` (``{LensParameter or name: value}``; names resolved with the surfaces that
    are even aspheres in ``p`` or made so) and the image shift (mm) ``focus_um`` asks for. Bending is applied after
    the surfaces' own curvatures (``E1.bending`` with ``S1.curvature`` moves both). Errors: ``ValueError`` for a
    bad value (not finite, a bending of 1 or -1 on a flat-flat element...), :class:`PrescriptionError` for an invalid
    lens (the prescription's own checks: crossing surfaces, negative thickness...)."""
    items = []
    for q, v in values.items():
        q = q if isinstance(q, LensParameter) else parse_parameter(p, q)
        v = float(v)
        if not math.isfinite(v):
            raise ValueError(f"{q.name} = {v!r} is not allowed: a finite number")
        items.append((q, v))
    surfs, shift_mm = _applied(p, items)
    return replace(p, surfaces=tuple(surfs)), shift_mm


def parameter_numbers(p: Prescription, params, x):
    """A batch of designs of the lens ``p`` as tensors, differentiable in ``x``: the free ``params``
    (:class:`LensParameter` s) at the values ``x`` (a float64 tensor ``(B, P)``, or ``(P,)`` for one design, in each
    parameter's unit). Returns ``(surfaces, image_shift_mm)``: ``p``'s surfaces with every number the parameters move
    a tensor ``(B, 1)`` (the others as in the file), for :class:`lenssim.optics.sequential.SequentialLens`'s
    ``numbers``, and the image shift (mm, ``(B, 1)``, or ``0.0`` without ``focus_um``). The same arithmetic as
    :func:`apply_parameters`, which stays the route that checks a design (crossing surfaces...): check the batch's
    designs there before trusting its rays."""
    params = tuple(params)
    x = x.reshape(-1, len(params)) if x.dim() < 2 else x
    if x.dtype != torch.float64 or x.shape[-1] != len(params):
        raise ValueError(f"x must be float64 (B, {len(params)}): one value per free parameter, not {x.dtype} "
                         f"{tuple(x.shape)}")
    return _applied(p, [(q, x[:, j:j + 1]) for j, q in enumerate(params)])


def _any(condition) -> bool:
    return bool(condition.any()) if hasattr(condition, "any") else bool(condition)


def _applied(p: Prescription, items) -> tuple[list, float]:
    """``p``'s surfaces with the ``(parameter, value)`` items applied (floats, or tensors of one batch shape) and the
    image shift (mm): the one arithmetic of :func:`apply_parameters` and :func:`parameter_numbers`."""
    surfs = [s for s in p.surfaces]
    shift_mm = 0.0
    kinds = {}
    for q, v in items:
        kinds.setdefault(q.index if q.kind not in ("focus", "bending") else q.name, []).append(q.kind)
        if q.kind == "focus":
            shift_mm = v * 1e-3
        elif q.kind == "bending":
            continue
        else:
            s = surfs[q.index]
            if q.kind == "curvature":
                s = replace(s, curvature_per_mm=v)
            elif q.kind == "radius":
                if _any(v == 0):
                    raise ValueError(f"{q.name} = 0 is not allowed: a radius (mm), or inf for a flat surface")
                s = replace(s, curvature_per_mm=1.0 / v)
            elif q.kind == "conic":
                s = replace(s, conic=v)
            elif q.kind == "thickness":
                s = replace(s, thickness_mm=v)
            else:
                j = ASPHERIC_ORDERS.index(int(q.kind[1:]))
                co = list(s.aspheric_coefficients) + [0.0] * max(0, j + 1 - len(s.aspheric_coefficients))
                co[j] = v
                s = replace(s, aspheric_coefficients=tuple(co))
            surfs[q.index] = s
    for key, ks in kinds.items():
        if "curvature" in ks and "radius" in ks:
            raise ValueError(f"surface {key + 1}: curvature and radius name the same number; free one of them")
    for q, v in items:
        if q.kind != "bending":
            continue
        a, b = q.index
        c1, c2 = surfs[a].curvature_per_mm, surfs[b].curvature_per_mm
        if _any(c1 == c2):
            raise ValueError(f"{q.name}: element {q.name[1:q.name.index('.')]} has equal outer curvatures (no power): "
                             "its bending is not defined")
        delta = (v * (c1 - c2) - (c1 + c2)) / 2
        for k in range(a, b + 1):
            surfs[k] = replace(surfs[k], curvature_per_mm=surfs[k].curvature_per_mm + delta)
    return surfs, shift_mm
