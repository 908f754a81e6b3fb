"""Forbes's Q-type asphere ``Qbfs``: a best-fit sphere and an orthogonal departure from it.

Sag (G. W. Forbes, "Shape specification for axially symmetric optical surfaces", Opt. Express 15, 5218 (2007))::

    z = c r^2 / (1 + sqrt(1 - c^2 r^2)) + u^2 (1 - u^2) / sqrt(1 - c^2 r^2) * sum_m a_m Q_m(u^2),   u = r / r_n

``curvature_per_mm`` is the best-fit sphere's ``c`` (1/mm; ``conic`` must be 0), the shape parameter
``normalization_radius_mm`` is ``r_n`` (mm; usually the clear semi-aperture), ``aspheric_coefficients`` are ``a_0,
a_1, ...`` (mm). To first order the bracket is the departure along the sphere's normal, and Forbes's ``Q_m`` make
the slopes of its terms orthonormal: the mean square of the departure's slope ``d/du`` over the aperture, weighted
by ``1 / sqrt(1 - u^2)``, is ``sum a_m^2`` (mm^2 per unit ``u``): the coefficients measure slope departure, the
quantity the industrial asphere cost prices. ``Q_m`` by Forbes's recurrence (his appendix)::

    P_0 = 2,  P_1 = 6 - 8x,  P_m = (2 - 4x) P_{m-1} - P_{m-2}
    f_0 = 2,  g_0 = -1/2,  h_{m-2} = -m (m - 1) / (2 f_{m-2}),  g_{m-1} = -(1 + g_{m-2} h_{m-2}) / f_{m-1},
    f_m = sqrt(m (m + 1) + 3 - g_{m-1}^2 - h_{m-2}^2)
    Q_m = (P_m - g_{m-1} Q_{m-1} - h_{m-2} Q_{m-2}) / f_m      (Q_0 = 1, Q_1 = (13 - 16x) / sqrt(19), ...)

Its paraxial curvature is ``c + 2 S(0) / r_n^2`` and its ``r^4`` term ``c^3 / 8 + (S'(0) - S(0)) / r_n^4 + c^2 S(0)
/ (2 r_n^2)`` (``S = sum a_m Q_m``): the Seidel sums read these. TOML only: ``kind = "qbfs"``. OpticStudio has a
Q-type asphere, but its ``.zmx`` keyword and parameter layout are not documented where this tool could check them,
so a ``qbfs`` surface is refused when a ``.zmx`` file is written, and none is read from one.
"""

from __future__ import annotations

import math
from functools import lru_cache

from . import SurfaceKind, register
from .standard import conic_sag

__all__ = ["Qbfs", "QBFS", "QBFS_MAX_TERMS", "qbfs_polynomials", "qbfs_series"]

QBFS_MAX_TERMS = 20
"""Most Qbfs coefficients a surface takes (``a_0 .. a_19``): a bound on the work per ray (one step of the recurrence
per term), within which the recurrence is checked (the 20 terms' slopes orthonormal to 6e-15 by quadrature)."""


@lru_cache(maxsize=None)
def _recurrence(m: int) -> tuple[tuple[float, float, float], ...]:
    """Forbes's constants ``(f_j, g_{j-1}, h_{j-2})`` for ``j = 0 .. m - 1`` (numbers, not parameters: cached)."""
    f, g, h = {0: 2.0}, {-1: 0.0, 0: -0.5}, {-2: 0.0, -1: 0.0}
    for j in range(1, m):
        h[j - 2] = -j * (j - 1) / (2 * f[j - 2]) if j >= 2 else 0.0
        g[j - 1] = -(1 + g[j - 2] * h[j - 2]) / f[j - 1]
        f[j] = math.sqrt(j * (j + 1) + 3 - g[j - 1] ** 2 - h[j - 2] ** 2)
    return tuple((f[j], g[j - 1], h[j - 2]) for j in range(m))


def qbfs_polynomials(x, m: int):
    """``[(Q_j(x), Q_j'(x)) for j = 0 .. m - 1]`` at ``x = u^2`` (a tensor or a number), by the recurrence."""
    out = []
    for j, (f, g, h) in enumerate(_recurrence(m)):
        if j == 0:
            p, dp = 2 + 0 * x, 0 * x
            q, dq = p / f, dp / f
        else:
            if j == 1:
                p, dp, p_prev, dp_prev = 6 - 8 * x, -8 + 0 * x, p, dp
            else:
                p, dp, p_prev, dp_prev = ((2 - 4 * x) * p - p_prev, -4 * p + (2 - 4 * x) * dp - dp_prev, p, dp)
            q1, dq1 = out[j - 1]
            q2, dq2 = out[j - 2] if j >= 2 else (0 * x, 0 * x)
            q, dq = (p - g * q1 - h * q2) / f, (dp - g * dq1 - h * dq2) / f
        out.append((q, dq))
    return out


def qbfs_series(x, coefficients):
    """``(S, dS/dx)`` of ``S(x) = sum_m a_m Q_m(x)`` (``coefficients`` ``a_m``)."""
    s, ds = 0 * x, 0 * x
    for a, (q, dq) in zip(coefficients, qbfs_polynomials(x, len(coefficients))):
        s, ds = s + a * q, ds + a * dq
    return s, ds


class Qbfs(SurfaceKind):
    name = "qbfs"
    label = "Forbes Q-type asphere (Qbfs: a best-fit sphere plus slope-orthogonal terms)"
    shape_parameters = ("normalization_radius_mm",)
    max_coefficients = QBFS_MAX_TERMS
    coefficients_meaning = "a_0, a_1, ... (mm) of Forbes's Qbfs polynomials"
    has_conic = False

    def check(self, s) -> dict:
        out = super().check(s)
        rn = dict(out["shape_parameters"])["normalization_radius_mm"]
        if not rn > 0:
            raise ValueError(f"normalization_radius_mm = {rn!r} is not allowed: a radius > 0 (mm)")
        return out

    def coefficient_name(self, i: int) -> str:
        return f"a{i}"

    @staticmethod
    def _rn(s):
        return dict(s.shape_parameters)["normalization_radius_mm"]

    def base_conic(self, s):
        return s.curvature_per_mm, 0.0

    def sag(self, s, rho):
        c, rn2 = s.curvature_per_mm, self._rn(s) ** 2
        z, dz = conic_sag(rho, c, 0.0)
        if not s.aspheric_coefficients:
            return z, dz
        x = rho / rn2
        S, dS = qbfs_series(x, s.aspheric_coefficients)
        D, dD = x * (1 - x) * S, (1 - 2 * x) * S + x * (1 - x) * dS  # the departure's bracket and d/dx
        inv = 1 / (1 - c * c * rho).clamp(min=1e-300).sqrt()
        return z + D * inv, dz + dD / rn2 * inv + D * c * c * inv**3 / 2

    def paraxial_curvature(self, s):
        S0, _ = qbfs_series(0.0, s.aspheric_coefficients)
        return s.curvature_per_mm + 2 * S0 / self._rn(s) ** 2

    def seidel_terms(self, s):
        c, rn2 = s.curvature_per_mm, self._rn(s) ** 2
        S0, dS0 = qbfs_series(0.0, s.aspheric_coefficients)
        c0 = c + 2 * S0 / rn2
        r4 = c**3 / 8 + (dS0 - S0) / rn2**2 + c * c * S0 / (2 * rn2)  # the sag's r^4 term
        return c0, 0.0, r4 - c0**3 / 8

    def is_aspheric(self, s) -> bool:
        return any(a != 0 for a in s.aspheric_coefficients)


QBFS = register(Qbfs())
