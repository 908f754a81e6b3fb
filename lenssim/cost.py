"""Industrial cost of the asphere: RMS slope departure from the best-fitting sphere (Eq. 3).

The posterior conic of curvature ``c = c2`` and conic constant ``Q`` has the exact profile
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

import torch

from .lens import ThinLens, as_tensor

__all__ = ["DEFAULT_COST_POINTS", "conic_slope", "sphere_slope", "best_fit_sphere_curvature",
           "slope_departure_cost", "slope_departure_cost_third_order"]

DEFAULT_COST_POINTS = 101


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

    ``c`` and ``Q`` broadcast to ``(*)``; returns ``(*)``.
    """
    c, Q = torch.broadcast_tensors(as_tensor(c), as_tensor(Q, like=as_tensor(c)))
    r = _radii(y_mm, n_points, c)
    target = conic_slope(r, c[..., None], Q[..., None])
    k = c + 0.3 * Q * c**3 * y_mm**2
    for _ in range(iterations):
        kk = k[..., None]
        q = 1 - kk**2 * r**2
        res = target - kk * r / torch.sqrt(q)
        jac = r / q**1.5  # d(sphere slope)/dk
        k = k + (res * jac).sum(-1) / (jac * jac).sum(-1).clamp_min(torch.finfo(c.dtype).tiny)
    return k


def slope_departure_cost(lens: ThinLens, s, Q, n_points: int = DEFAULT_COST_POINTS) -> torch.Tensor:
    """``C_a`` (slope units) of the posterior conic for designs ``(s, Q)`` broadcast to ``(*)``.

    Computed in float64 whatever the input dtype, returned in the input's floating dtype.
    """
    s_t, Q_t = as_tensor(s), as_tensor(Q)
    out_dtype = torch.promote_types(s_t.dtype, Q_t.dtype)
    s64, Q64 = torch.broadcast_tensors(s_t.to(torch.float64), Q_t.to(torch.float64))
    lens.check_design(s64, Q64)
    _, c = lens.curvatures(s64)
    y = lens.pupil_radius_mm
    k = best_fit_sphere_curvature(c, Q64, y, n_points)
    r = _radii(y, n_points, c)
    dep = conic_slope(r, c[..., None], Q64[..., None]) - sphere_slope(r, k[..., None])
    return torch.sqrt((dep**2).mean(-1)).to(out_dtype)


def slope_departure_cost_third_order(lens: ThinLens, s, Q) -> torch.Tensor:
    """Continuous third-order estimate ``|Q| |c2|^3 y^3 / sqrt(175)`` of :func:`slope_departure_cost`."""
    _, c = lens.curvatures(as_tensor(s))
    return as_tensor(Q, like=c).abs() * c.abs() ** 3 * lens.pupil_radius_mm**3 / 175**0.5
