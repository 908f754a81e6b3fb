"""Industrial cost of the aspheres: RMS slope departure from the best-fitting sphere (Eq. 3).

The cost of a design is the sum of the costs of its aspheric surfaces (those whose conic constant
is a free design parameter, :meth:`lenssim.model.lens.Lens.surfaces`): each asphere is polished and
tested on its own, so their costs add. The paper's lens has one, the back surface. The
posterior conic of curvature ``c = c2`` and conic constant ``Q`` has the exact profile
``z(r) = c r^2 / (1 + sqrt(1 - (1 + Q) c^2 r^2))`` and slope ``z'(r) = c r / sqrt(1 - (1 + Q) c^2 r^2)``
(``tan(alpha_i)`` in the paper's Fig. 2). A sphere of curvature ``k`` has slope
``k r / sqrt(1 - k^2 r^2)`` (``tan(beta_i)``). At ``n`` equally spaced radii
``r_i = y i / (n - 1)``, ``i = 0..n-1`` (centre and rim included), the cost is::

    C_a = min_k sqrt( mean_i (z'(r_i) - k r_i / sqrt(1 - k^2 r_i^2))^2 )

in slope units (dimensionless). ``k`` is found by Gauss-Newton from the third-order optimum
``k0 = c + 3 Q c^3 y^2 / 10``; 12 iterations reach float64 precision on the paper's grid.

Third-order check: for large ``n`` and small apertures ``C_a -> |Q| |c|^3 y^3 / sqrt(175)``.
Sensitivity to ``n`` (paper's lens, s = -0.775, Q = -2.4): see ``docs/reproduction.md``.
"""

from __future__ import annotations

import math

import torch

from ..model.design import Design
from ..model.lens import Lens, LensError
from ..model.numerics import DEFAULT_NUMERICS
from ..torch_utils import as_tensor

__all__ = ["DEFAULT_COST_POINTS", "conic_slope", "sphere_slope", "best_fit_sphere_curvature", "surface_cost",
           "slope_departure_cost", "slope_departure_cost_third_order", "even_asphere_slope", "even_asphere_cost",
           "prescription_costs"]

DEFAULT_COST_POINTS = DEFAULT_NUMERICS.cost_points


def conic_slope(r_mm, c, Q):
    """Slope ``dz/dr`` of a conic of curvature ``c`` (1/mm) and conic constant ``Q`` at radius ``r`` (mm)."""
    return c * r_mm / torch.sqrt(1 - (1 + Q) * c**2 * r_mm**2)


def sphere_slope(r_mm, k):
    """Slope ``dz/dr`` of a sphere of curvature ``k`` (1/mm) at radius ``r`` (mm)."""
    return k * r_mm / torch.sqrt(1 - k**2 * r_mm**2)


def _radii(y, n, like):
    if not (isinstance(n, int) and n >= 2):
        raise ValueError(f"n_points={n!r} is not allowed: an integer >= 2")
    return torch.linspace(0, y, n, dtype=like.dtype, device=like.device)


def best_fit_sphere_curvature(c, Q, y_mm: float, n_points: int = DEFAULT_COST_POINTS, iterations: int = 12):
    """Curvature (1/mm) of the sphere of least RMS slope departure from the conic ``(c, Q)``.

    Gauss-Newton from the third-order optimum, safeguarded: a step is halved until it stays inside
    the sphere's domain (``|k| y < 1``) and does not increase the residual (needed only near the
    conic's limit ``(1 + Q) c^2 y^2 -> 1``, where the rim slope diverges). ``c`` and ``Q`` broadcast
    to ``(*)``; returns ``(*)``. Differentiable (the iterations are unrolled).
    """
    c, Q = torch.broadcast_tensors(as_tensor(c), as_tensor(Q, like=as_tensor(c)))
    r = _radii(y_mm, n_points, c)
    target = conic_slope(r, c[..., None], Q[..., None])
    return _fit_sphere(target, r, c + 0.3 * Q * c**3 * y_mm**2, y_mm, iterations)


def _fit_sphere(target, r, k0, y_mm: float, iterations: int):
    """The sphere curvature ``(*)`` of least RMS departure from the slopes ``target`` ``(*, n)`` at radii ``r``
    ``(n,)``, by Gauss-Newton from ``k0`` (see :func:`best_fit_sphere_curvature`)."""
    k_max = (1 - 1e-12) / y_mm

    def residual(k):
        kk = k[..., None]
        q = 1 - kk**2 * r**2
        return target - kk * r / torch.sqrt(q), q

    k = k0.clamp(-k_max, k_max)
    for _ in range(iterations):
        res, q = residual(k)
        ssr = (res * res).sum(-1)
        jac = r / q**1.5  # d(sphere slope)/dk
        step = (res * jac).sum(-1) / (jac * jac).sum(-1).clamp_min(torch.finfo(target.dtype).tiny)
        ok, t = _backtrack(k.detach(), step.detach(), ssr.detach(), target.detach(), r, k_max)
        k_next = torch.where(ok, k + t * step, k)
        if not k_next.requires_grad and torch.equal(k_next, k):
            break  # a fixed point: every further iteration would compute the same (the result is bit for bit the same)
        k = k_next
    return k


def even_asphere_slope(r_mm, c, Q, coefficients):
    """Slope ``dz/dr`` of an even asphere: the conic ``(c, Q)`` plus ``A4 r^4 + A6 r^6 + ...`` (``coefficients``
    ``A4, A6, ...`` in mm^(1-2j)) at radius ``r`` (mm)."""
    out = conic_slope(r_mm, c, Q)
    for j, a in enumerate(coefficients):
        p = 2 * j + 4
        out = out + p * a * r_mm ** (p - 1)
    return out


def even_asphere_cost(c: float, Q: float, coefficients, y_mm: float, n_points: int = DEFAULT_COST_POINTS,
                      iterations: int = 12) -> float:
    """``C_a`` (slope units) of one even-asphere surface (curvature ``c`` 1/mm, conic ``Q``, ``A4, A6, ...``) over the
    radius ``y_mm``: the paper's Eq. (3) with the even asphere's exact slope (:func:`even_asphere_slope`) at the ``n``
    radii ``r_i = y i / (n - 1)``, the sphere fitted in slope from the third-order start ``k0 = c + 3 (Q c^3 + 8 A4)
    y^2 / 10`` (the ``A4`` term is a conic's fourth-order term ``Q c^3 / 8``). For ``A4 = ... = 0`` it is
    :func:`surface_cost` of the conic; ``NaN`` where the conic is not defined out to ``y``."""
    c64 = torch.tensor(float(c), dtype=torch.float64)
    r = _radii(y_mm, n_points, c64)
    coefficients = tuple(float(a) for a in coefficients)
    target = even_asphere_slope(r, c64, torch.tensor(float(Q), dtype=torch.float64), coefficients)
    a4 = coefficients[0] if coefficients else 0.0
    k0 = c64 + 0.3 * (float(Q) * c64**3 + 8 * a4) * y_mm**2
    k = _fit_sphere(target, r, k0, y_mm, iterations)
    dep = target - sphere_slope(r, k)
    return float(torch.sqrt((dep**2).mean()))


def _backtrack(k, step, ssr, target, r, k_max, halvings: int = 60):
    """The step lengths ``t`` (halved from 1, at most ``halvings`` times) at which each Gauss-Newton step ``k + t step``
    stays in the sphere's domain and does not increase the residual, and whether one was found (``ok``): each element
    is tried on its own (a residual for the elements still searching only), so an element's result does not depend
    on the others'."""
    shape = k.shape
    k, step, ssr = k.reshape(-1), step.reshape(-1), ssr.reshape(-1)
    target = target.reshape(-1, target.shape[-1])
    t = torch.ones_like(k)
    ok = torch.zeros(k.shape, dtype=torch.bool, device=k.device)
    todo = torch.arange(k.numel(), device=k.device)
    for _ in range(halvings):  # backtracking: full steps everywhere but close to the conic's limit
        kt = k[todo]
        cand = kt + t[todo] * step[todo]
        good = cand.abs() < k_max
        kk = torch.where(good, cand, kt)[:, None]
        res_c = target[todo] - kk * r / torch.sqrt(1 - kk**2 * r**2)
        good = good & ((res_c * res_c).sum(-1) <= ssr[todo])
        ok[todo] = good
        todo = todo[~good]
        if not todo.numel():
            break
        t[todo] = 0.5 * t[todo]
    return ok.reshape(shape), t.reshape(shape)


def surface_cost(c, Q, y_mm: float, n_points: int = DEFAULT_COST_POINTS) -> torch.Tensor:
    """``C_a`` (slope units) of one conic surface of curvature ``c`` (1/mm) and conic ``Q`` over radius ``y_mm``."""
    k = best_fit_sphere_curvature(c, Q, y_mm, n_points)
    r = _radii(y_mm, n_points, c)
    dep = conic_slope(r, c[..., None], Q[..., None]) - sphere_slope(r, k[..., None])
    return torch.sqrt((dep**2).mean(-1))


def slope_departure_cost(lens: Lens, design: Design, n_points: int = DEFAULT_COST_POINTS) -> torch.Tensor:
    """``C_a`` (slope units) of a design (parameters broadcast to ``(*)``): the sum over its aspheres.

    Computed in float64 whatever the input dtype, returned in the design's floating dtype.

    References
    ----------
    .. [1] Optics Express 31(10), 16897 (2023), Section 2.2, Eq. (3) and Fig. 2.

    Examples
    --------
    The paper's end-to-end design (s = -0.775, Q = -2.4):

    >>> from lenssim import ConstantGlass, Design, Lens
    >>> lens = Lens(focal_length_mm=25.0, pupil_radius_mm=2.0, glass=ConstantGlass(1.5), field_angles_deg=(0.0,))
    >>> round(float(slope_departure_cost(lens, Design(s=-0.775, Q_back=-2.4))), 7)
    0.000513
    """
    out_dtype = None
    for v in design.values.values():
        out_dtype = v.dtype if out_dtype is None else torch.promote_types(out_dtype, v.dtype)
    d64 = design.to(torch.float64).broadcast()
    lens.check_design(d64)
    total = None
    for surf in lens.surfaces(d64):
        if surf.aspheric:
            c, Q = torch.broadcast_tensors(as_tensor(surf.curvature, dtype=torch.float64),
                                           as_tensor(surf.conic, dtype=torch.float64))
            cost = surface_cost(c, Q, surf.semi_aperture_mm or lens.pupil_radius_mm, n_points)
            if not bool(torch.isfinite(cost).all()):
                bad = int(torch.nonzero(~torch.isfinite(cost.reshape(-1)))[0])
                at = ", ".join(f"{k}={float(torch.broadcast_to(v, cost.shape).reshape(-1)[bad])!r}" for k, v in d64.values.items())
                raise LensError(f"the asphere cost of the design {at} is not finite (the conic {surf.conic_name} is at "
                                "its limit over the aperture)")
            total = cost if total is None else total + cost
    if total is None:
        total = torch.zeros(d64.shape, dtype=torch.float64)
    return total.to(out_dtype or torch.float64)


def slope_departure_cost_third_order(lens: Lens, design: Design) -> torch.Tensor:
    """Continuous third-order estimate ``sum |Q| |c|^3 y^3 / sqrt(175)`` of :func:`slope_departure_cost`."""
    total = 0
    for surf in lens.surfaces(design):
        if surf.aspheric:
            c = as_tensor(surf.curvature)
            y = surf.semi_aperture_mm or lens.pupil_radius_mm
            total = total + as_tensor(surf.conic, like=c).abs() * c.abs() ** 3 * y**3 / 175**0.5
    return total


def prescription_costs(prescription, n_points: int = DEFAULT_COST_POINTS) -> dict[int, dict]:
    """``C_a`` of every aspheric surface of a :class:`lenssim.model.prescription.Prescription` (conic or even-asphere
    terms), by surface number (as in the file): ``{number: {"cost": C_a (slope), "radius_mm": the aperture it is
    taken over}}``. Each surface over its clear semi-diameter, or where the file gives none, over the paraxial beam's
    extent on it (the marginal ray's height plus the chief ray's at the largest field, the largest over the
    wavelengths). The lens's cost is their sum (each asphere is polished and tested on its own)."""
    from .sequential import SequentialLens

    seq = None
    out = {}
    for i, s in enumerate(prescription.surfaces):
        if not s.is_aspheric:
            continue
        y = s.semi_diameter_mm
        if y is None:
            seq = seq or SequentialLens(prescription)
            y = max(seq.paraxial_beam_heights_mm(lam)[i] for lam in prescription.wavelengths_um)
        cost = even_asphere_cost(s.curvature_per_mm, s.conic, s.aspheric_coefficients, y, n_points)
        if not math.isfinite(cost):
            raise LensError(f"surface {i + 1}: its asphere cost is not finite over the radius {y:g} mm (the conic is "
                            "not defined out to there)")
        out[i + 1] = {"cost": cost, "radius_mm": float(y)}
    return out
