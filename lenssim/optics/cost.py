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

in slope units (dimensionless), the minimum over every sphere that exists over the aperture
(``|k| y < 1``). ``k`` is found in the sphere's rim slope ``T = k y / sqrt(1 - k^2 y^2)`` (any real
number, so no sphere is out of reach) by safeguarded Newton steps from the best of a scan of spheres,
the sphere of the surface's own rim slope and the third-order optimum ``k0 = c + 3 Q c^3 y^2 / 10``.
That start alone is not enough: for a phone lens's strongly hyperbolic last surface with large
``A4`` it lies beyond the hemisphere (``|k0| y`` of 1.7-25), and iterations in ``k`` held at the
hemisphere's edge priced such a surface at ~100 instead of ~0.2 (issue 43).

Third-order check: for large ``n`` and small apertures ``C_a -> |Q| |c|^3 y^3 / sqrt(175)``.
Sensitivity to ``n`` (paper's lens, s = -0.775, Q = -2.4): see ``docs/reproduction.md``.
"""

from __future__ import annotations

import math

import torch

from ..model.design import Design
from ..model.lens import Lens, LensError
from ..model.numerics import DEFAULT_NUMERICS
from ..model.surface_kinds.standard import conic_slope
from ..torch_utils import HOST, as_tensor

__all__ = ["DEFAULT_COST_POINTS", "conic_slope", "sphere_slope", "best_fit_sphere_curvature", "surface_cost",
           "slope_departure_cost", "slope_departure_cost_third_order", "asphere_cost", "prescription_costs",
           "lens_cost"]

DEFAULT_COST_POINTS = DEFAULT_NUMERICS.cost_points


def sphere_slope(r_mm, k):
    """Slope ``dz/dr`` of a sphere of curvature ``k`` (1/mm) at radius ``r`` (mm): the conic's with conic 0."""
    return conic_slope(r_mm, k, 0.0)


def _radii(y, n, like):
    if not (isinstance(n, int) and n >= 2):
        raise ValueError(f"n_points={n!r} is not allowed: an integer >= 2")
    return torch.linspace(0, y, n, dtype=like.dtype, device=like.device)


SPHERE_SCAN_POINTS = 64
"""Spheres tried before the Newton iterations of the best-fit sphere start from the best of them: rim slopes
``T = tan(theta)``, ``theta`` at the centres of 64 equal steps of (-90, 90) deg (``|T|`` up to 41). A third-order
start alone can lie far from the optimum, even beyond the hemisphere (a phone lens's strongly hyperbolic last
surface with large A4: ``|k0| y`` of 1.7-25); the scan puts the iterations in the basin of the least RMS departure
(only a basin narrower than 1/64 of the rim-slope angle can be missed: none was in 3000 random even aspheres,
24 of them with two local minima, each checked against a dense search)."""

SPHERE_FIT_ITERATIONS = 40
"""Most safeguarded Newton iterations of the best-fit sphere: from the best scanned sphere they reach a fixed point in
2-6 on every surface tried (the paper's grid, phone-lens aspheres, oblate and near-flat ones); one that has not
converged after this many returns ``NaN`` rather than a wrong sphere."""

SPHERE_FIT_STEP_TOL = 1e-12
"""Convergence of the best-fit sphere: the last Newton step in the rim slope ``T`` at most this times ``1 + |T|`` (the
step is taken: Newton's quadratic convergence leaves ``T`` at float64's resolution)."""

SPHERE_FIT_SMALL_STEP = 1e-8
"""Newton steps in ``T`` at most this times ``1 + |T|`` are taken without comparing the departures: near the minimum
the sum of squared departures changes by less than its rounding (``~ step^2``: ``sqrt`` of float64's epsilon), so the
comparison would stall the iterations ~1e-13 short of the minimum (measured: 2e-14 relative in ``k``)."""

_HALVINGS = 60
"""Most halvings of a Newton step that would increase the departure (2^-60: below float64's resolution of ``T``)."""


def best_fit_sphere_curvature(c, Q, y_mm: float, n_points: int = DEFAULT_COST_POINTS):
    """Curvature (1/mm) of the sphere of least RMS slope departure from the conic ``(c, Q)``.

    The sphere is sought over every sphere that exists over the aperture (``|k| y < 1``; see :func:`_fit_sphere`),
    starting from the best of the third-order optimum ``k0 = c + 3 Q c^3 y^2 / 10`` and a scan. ``c`` and ``Q``
    broadcast to ``(*)``; returns ``(*)``. Differentiable (one Newton step at the converged sphere carries the
    implicit-function gradient).
    """
    c, Q = torch.broadcast_tensors(as_tensor(c), as_tensor(Q, like=as_tensor(c)))
    r = _radii(y_mm, n_points, c)
    target = conic_slope(r, c[..., None], Q[..., None])
    return _fit_sphere(target, r, y_mm, c + 0.3 * Q * c**3 * y_mm**2)


def _sphere_in_rim_slope(T, rho):
    """Slope ``(*, n)`` at the relative radii ``rho = r / y`` ``(n,)`` of the sphere whose slope at the rim is ``T``
    ``(*, 1)``: ``g = T rho / sqrt(1 + T^2 (1 - rho^2))``, :func:`sphere_slope` with ``k = T / (y sqrt(1 + T^2))``.
    Every real ``T`` is a sphere that exists over the aperture (``|k| y < 1``) and ``dg/dT = rho w^-1.5`` (``w = 1 +
    T^2 (1 - rho^2)``) is at most 1: the fit needs no domain bound and cannot stall where the derivative in the
    curvature diverges (``|k| y -> 1``)."""
    return T * rho / torch.sqrt(1 + (1 - rho * rho) * T * T)


def _newton_step(T, target, rho):
    """The Newton step in ``T`` ``(*)`` towards the least sum of squared departures of the spheres
    (:func:`_sphere_in_rim_slope`) from ``target`` ``(*, n)`` (the Gauss-Newton step where that sum's curvature is not
    positive: a descent direction either way), and that sum ``(*)``."""
    a = 1 - rho * rho
    w = 1 + a * T[..., None] ** 2
    res = target - T[..., None] * rho / torch.sqrt(w)
    g_t = rho / w**1.5  # dg/dT
    g_tt = -3 * a * T[..., None] * rho / w**2.5
    grad = (res * g_t).sum(-1)
    gn = (g_t * g_t).sum(-1)  # >= 1: the rim term alone gives 1
    hess = gn - (res * g_tt).sum(-1)
    return grad / torch.where(hess > 0, hess, gn), (res * res).sum(-1)


def _ssr(T, target, rho):
    """Sum of squared slope departures ``(*)`` of the spheres of rim slope ``T`` ``(*)`` from ``target`` ``(*, n)``."""
    res = target - _sphere_in_rim_slope(T[..., None], rho)
    return (res * res).sum(-1)


def _fit_sphere(target, r, y_mm: float, k0=None):
    """The sphere curvature ``(*)`` of least RMS departure from the slopes ``target`` ``(*, n)`` at radii ``r`` ``(n,)``
    (``r[-1] = y_mm``), among all spheres that exist over the aperture.

    Parametrised by the sphere's rim slope ``T`` (:func:`_sphere_in_rim_slope`: no domain, bounded derivative). The
    start is the best of :data:`SPHERE_SCAN_POINTS` scanned spheres, the sphere of the target's own rim slope and
    ``k0`` where given and inside the aperture; safeguarded Newton steps (halved until the departure does not grow)
    then run to a fixed point, without a graph. Where an input requires a gradient one Newton step more is taken at
    the converged sphere with the graph: at a minimum it leaves the value where it is and its derivative is the exact
    implicit-function derivative. ``NaN`` where the target is not finite or the iterations did not converge."""
    rho, n = r / y_mm, r.shape[-1]
    with torch.no_grad():
        tgt = target.detach()
        theta = (torch.arange(SPHERE_SCAN_POINTS, dtype=r.dtype, device=r.device) + 0.5) / SPHERE_SCAN_POINTS - 0.5
        scan = torch.tan(math.pi * theta)
        g = _sphere_in_rim_slope(scan[:, None], rho)  # (G, n): the same spheres for every element
        ssr_scan = (g * g).sum(-1) - 2 * tgt @ g.T  # + sum(tgt^2), the same for every sphere: enough to rank them
        candidates = [scan[ssr_scan.nan_to_num(math.inf).argmin(-1)], tgt[..., -1]]
        if k0 is not None:
            ky = torch.broadcast_to(k0.detach() * y_mm, tgt.shape[:-1])
            candidates.append(torch.where(ky.abs() < 1, ky / torch.sqrt((1 - ky * ky).clamp_min(0)), tgt[..., -1]))
        T, best = candidates[0], _ssr(candidates[0], tgt, rho)
        for cand in candidates[1:]:
            ssr = _ssr(cand, tgt, rho)
            better = ssr < best
            T, best = torch.where(better, cand, T), torch.where(better, ssr, best)
        active = torch.isfinite(best)  # each element iterates until its own fixed point, then is left alone
        for _ in range(SPHERE_FIT_ITERATIONS):
            if not bool(active.any()):
                break
            step, ssr = _newton_step(T, tgt, rho)
            T_next, todo = T.clone(), torch.nonzero(active.reshape(-1))[:, 0]
            T_flat, step, ssr, tgt_flat = T.reshape(-1), step.reshape(-1), ssr.reshape(-1), tgt.reshape(-1, n)
            for _ in range(_HALVINGS):  # halve each element's step until the departure does not grow (those only)
                cand = T_flat[todo] + step[todo]
                small = step[todo].abs() <= SPHERE_FIT_SMALL_STEP * (1 + T_flat[todo].abs())
                ok = small | (_ssr(cand, tgt_flat[todo], rho) <= ssr[todo])
                T_next.view(-1)[todo[ok]] = cand[ok]
                todo = todo[~ok]
                if not todo.numel():
                    break
                step[todo] = 0.5 * step[todo]
            active = active & ((T_next - T).abs() > SPHERE_FIT_STEP_TOL * (1 + T.abs()))
            T = T_next
        T = torch.where(active | ~torch.isfinite(best), torch.full_like(T, math.nan), T)
    if target.requires_grad:
        T = T + _newton_step(T, target, rho)[0]  # zero at the minimum; carries d T / d(parameters)
    k = T / (y_mm * torch.sqrt(1 + T * T))
    if k0 is None:
        return k
    with torch.no_grad():  # k0 where it is as good: exactly the sphere itself for a sphere (k0 = c), cost exactly 0
        k0 = torch.broadcast_to(k0, k.shape)
        inside = k0.detach().abs() * y_mm < 1
        ssr0 = ((tgt - sphere_slope(r, torch.where(inside, k0.detach(), 0)[..., None])) ** 2).sum(-1)
        use_k0 = inside & (ssr0 <= ((tgt - sphere_slope(r, k.detach()[..., None])) ** 2).sum(-1))
    return torch.where(use_k0, k0, k)


def asphere_cost(surface, y_mm: float, n_points: int = DEFAULT_COST_POINTS) -> float:
    """``C_a`` (slope units) of one surface of a prescription (a
    :class:`lenssim.model.prescription.PrescriptionSurface` of any kind) over the radius ``y_mm``: the paper's Eq. (3)
    with the exact slope its kind gives (:meth:`lenssim.model.surface_kinds.SurfaceKind.slope`) at the ``n`` radii
    ``r_i = y i / (n - 1)``, the sphere of least RMS departure among all that exist over the aperture
    (:func:`_fit_sphere`; its third-order start ``k0 = c + 3 (Q c^3 + 8 A4) y^2 / 10`` from the kind's
    :meth:`~lenssim.model.surface_kinds.SurfaceKind.seidel_terms` is one of the candidates, the ``A4`` term being a
    conic's fourth-order term ``Q c^3 / 8``). For a conic it is :func:`surface_cost`; ``NaN`` where the surface is not
    defined out to ``y``."""
    kind = surface.surface_kind
    c, Q, a4 = (torch.tensor(float(v), dtype=torch.float64, device=HOST) for v in kind.seidel_terms(surface))
    return float(_slope_departure(kind, surface, y_mm, n_points, c, Q, a4))


def _slope_departure(kind, surface, y_mm: float, n_points: int, c, Q, a4) -> torch.Tensor:
    """The RMS slope departure of ``surface`` (its ``kind``) from its best-fit sphere over ``y_mm``, its third-order
    terms ``c, Q, a4`` (tensors ``()`` or ``(B,)``) seeding the fit; ``(B,)`` or ``()``. A sphere's departure is
    exactly 0, a kink: its derivative there is taken as 0 (the central differences' value)."""
    r = _radii(y_mm, n_points, c)
    target = kind.slope(surface, r)
    k = _fit_sphere(target, r, y_mm, c + 0.3 * (Q * c**3 + 8 * a4) * y_mm**2)
    ms = ((target - sphere_slope(r, k[..., None])) ** 2).mean(-1)
    return torch.where(ms == 0, 0.0, torch.sqrt(torch.where(ms == 0, 1.0, ms)))  # NaN stays NaN (a fit that failed)


def lens_cost(seq, n_points: int = DEFAULT_COST_POINTS) -> torch.Tensor:
    """``C_a`` of a batch of designs (a :attr:`lenssim.optics.sequential.SequentialLens.batched` lens), ``(B,)``,
    differentiable in its numbers: :func:`asphere_cost` of every surface that is aspheric in the file or whose conic
    or coefficients the batch moves, summed (a sphere's is 0), each over its clear semi-diameter, which every such
    surface must have (:func:`prescription_costs` takes the design's own paraxial beam where the file gives none: a
    radius that moves with the design, not taken here). ``ValueError`` naming a surface without one."""
    total = 0.0
    for i, (s, q) in enumerate(zip(seq.numbers, seq.prescription.surfaces)):
        free = any(torch.is_tensor(v) for v in (s.curvature_per_mm, s.conic, *s.aspheric_coefficients))
        if not (q.is_aspheric or any(torch.is_tensor(v) for v in (s.conic, *s.aspheric_coefficients))):
            continue
        y = q.semi_diameter_mm
        if y is None:
            raise ValueError(f"surface {i + 1}: a batch's asphere cost needs the surface's semi-diameter (the file "
                             "gives none)")
        if not free:  # the file's surface: the same for every design
            total = total + asphere_cost(q, y, n_points)
            continue
        kind = s.surface_kind
        c, Q, a4 = (torch.as_tensor(v, dtype=torch.float64, device=seq.device).reshape(-1)
                    for v in kind.seidel_terms(s))
        cost = _slope_departure(kind, s, y, n_points, c, Q, a4)
        if not bool(torch.isfinite(cost).all()):
            raise LensError(f"surface {i + 1}: its asphere cost is not finite over the radius {y:g} mm for a design "
                            "of the batch (the conic at its limit, or a best-fit sphere that did not converge)")
        total = total + cost
    return torch.zeros(seq.batch_size, dtype=torch.float64, device=seq.device) + total


def _why_not_finite(c: float, Q: float, y_mm: float, conic: str) -> str:
    """Why a cost came out ``NaN``: the conic not defined out to ``y_mm`` (``(1 + Q) c^2 y^2 >= 1``), else the best-fit
    sphere's iterations did not converge (:data:`SPHERE_FIT_ITERATIONS`)."""
    if (1 + Q) * c * c * y_mm * y_mm >= 1:
        return f"{conic} is at its limit over the aperture: (1 + conic) c^2 y^2 >= 1"
    return f"its best-fit sphere did not converge within {SPHERE_FIT_ITERATIONS} Newton iterations"


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
    total, device = None, d64["s"].device
    for surf in lens.surfaces(d64):
        if surf.aspheric:
            c, Q = torch.broadcast_tensors(as_tensor(surf.curvature, dtype=torch.float64, device=device),
                                           as_tensor(surf.conic, dtype=torch.float64, device=device))
            cost = surface_cost(c, Q, surf.semi_aperture_mm or lens.pupil_radius_mm, n_points)
            if not bool(torch.isfinite(cost).all()):
                bad = int(torch.nonzero(~torch.isfinite(cost.reshape(-1)))[0])
                at = ", ".join(f"{k}={float(torch.broadcast_to(v, cost.shape).reshape(-1)[bad])!r}" for k, v in d64.values.items())
                cb, Qb = float(c.reshape(-1)[bad]), float(Q.reshape(-1)[bad])
                raise LensError(f"the asphere cost of the design {at} is not finite ("
                                + _why_not_finite(cb, Qb, surf.semi_aperture_mm or lens.pupil_radius_mm,
                                                  f"the conic {surf.conic_name}") + ")")
            total = cost if total is None else total + cost
    if total is None:
        total = torch.zeros(d64.shape, dtype=torch.float64, device=device)
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
    """``C_a`` of every aspheric surface of a :class:`lenssim.model.prescription.Prescription` (any kind:
    :func:`asphere_cost`), by surface number (as in the file): ``{number: {"cost": C_a (slope), "radius_mm": the aperture it is
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
        cost = asphere_cost(s, y, n_points)
        if not math.isfinite(cost):
            raise LensError(f"surface {i + 1}: its asphere cost is not finite over the radius {y:g} mm ("
                            + _why_not_finite(*s.surface_kind.base_conic(s), y, "the conic") + ")")
        out[i + 1] = {"cost": cost, "radius_mm": float(y)}
    return out
