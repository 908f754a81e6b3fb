"""Surface-by-surface paraxial ray trace and Seidel sums (Welford's formulation).

This is a general, independent route to the Seidel sums of any centred system of spherical and
conic surfaces; the package uses it to check the thin-lens closed forms of
:mod:`lenssim.optics.aberrations`, and it is the starting point for systems with more surfaces.

Welford, *Aberrations of Optical Systems*, ch. 7 (sign conventions as there): paraxial
refraction ``n'u' - n u = -h c (n' - n)``, transfer ``h_{k+1} = h_k + d_k u'_k``, refraction
invariants ``A = n (h c + u)`` and ``Abar = n (hbar c + ubar)``, Lagrange invariant
``H = n (ubar h - u hbar)`` and, per surface::

    S_I   = -A^2 h D(u/n) + (n' - n) kappa c^3 h^4
    S_II  = -A Abar h D(u/n) + (n' - n) kappa c^3 h^3 hbar
    S_III = -Abar^2 h D(u/n) + (n' - n) kappa c^3 h^2 hbar^2
    S_IV  = -H^2 c D(1/n)
    S_V   = (Abar/A)(S_III + S_IV)   (spherical part; plus the conic's (n'-n) kappa c^3 h hbar^3)

with ``D(x) = x' - x`` across the surface and ``kappa`` the conic constant; an even asphere's ``A4 r^4`` enters as
``kappa c^3 -> kappa c^3 + 8 A4`` (the conic's fourth-order sag is ``kappa c^3 r^4 / 8``; Welford sec. 8.3).
"""

from __future__ import annotations

import torch

from ..model.surface import Surface  # the model's data type, re-exported here
from ..torch_utils import tensor_of

__all__ = ["Surface", "seidel_surface_sums"]


def seidel_surface_sums(surfaces, h, u, hbar, ubar, n_object: float = 1.0) -> torch.Tensor:
    """Seidel sums ``(S_I, S_II, S_III, S_IV, S_V)`` in mm, summed over the surfaces.

    ``h, u`` are the marginal ray's height (mm) and slope at the first surface, ``hbar, ubar``
    the chief ray's. Tensors broadcast; returns shape ``(*, 5)``.
    """
    n = n_object
    H = n * (ubar * h - u * hbar)
    total = None
    for surf in surfaces:
        c, kap, n2 = surf.curvature, surf.conic, surf.n_after
        A = n * (h * c + u)
        Ab = n * (hbar * c + ubar)
        u2 = (n * u - h * c * (n2 - n)) / n2
        ub2 = (n * ubar - hbar * c * (n2 - n)) / n2
        d_un = u2 / n2 - u / n
        a4 = surf.aspheric_coefficients[0] if surf.aspheric_coefficients else 0.0
        asph = (n2 - n) * (kap * c**3 + 8 * a4) if a4 else (n2 - n) * kap * c**3  # A4 r^4 = the conic's (8 A4) c^3 r^4/8
        S1 = -A**2 * h * d_un + asph * h**4
        S2 = -A * Ab * h * d_un + asph * h**3 * hbar
        S3 = -Ab**2 * h * d_un + asph * h**2 * hbar**2
        S4 = -H**2 * c * (1 / n2 - 1 / n)
        S5 = torch.where(tensor_of(A) != 0, Ab / A * (S3 - asph * h**2 * hbar**2 + S4), 0.0)
        S5 = S5 + asph * h * hbar**3
        terms = torch.broadcast_tensors(*(tensor_of(t) for t in (S1, S2, S3, S4, S5)))
        step = torch.stack(terms, dim=-1)
        total = step if total is None else total + step
        h = h + surf.thickness_after_mm * u2
        hbar = hbar + surf.thickness_after_mm * ub2
        u, ubar, n = u2, ub2, n2
    return total
