"""The even asphere: a conic plus ``A4 r^4 + A6 r^6 + ... + A16 r^16`` (Zemax's ``EVENASPH``).

``aspheric_coefficients`` are ``(A4, A6, ..., A16)`` (mm^-3, mm^-5, ...; trailing zeros may be left out). In a
``.zmx`` file ``PARM 2 .. 8`` are ``A4 .. A16`` in lens units and ``PARM 1`` (an ``r^2`` term) must be 0 (the
curvature gives it). A surface of the standard family with coefficients is this kind.
"""

from __future__ import annotations

from . import ZemaxParmError, register
from .standard import Standard, conic_sag, conic_slope

__all__ = ["EvenAsphere", "MAX_ASPHERE_ORDER", "EVEN_ASPHERE"]

MAX_ASPHERE_ORDER = 16
"""Highest even power of ``r`` of an even asphere (``A4 ... A16``: seven coefficients, ``PARM 2 .. 8`` in Zemax)."""


class EvenAsphere(Standard):
    name = "even_asphere"
    label = "even asphere (a conic plus A4 r^4 ... A16 r^16)"
    zemax_type = "EVENASPH"
    max_coefficients = MAX_ASPHERE_ORDER // 2 - 1
    coefficients_meaning = f"A4 ... A{MAX_ASPHERE_ORDER} of r^4 ... r^{MAX_ASPHERE_ORDER}"

    def coefficient_name(self, i: int) -> str:
        return f"A{2 * i + 4}"

    def departs(self, s) -> bool:
        return bool(s.aspheric_coefficients)

    def sag(self, s, rho):
        z, dz = conic_sag(rho, s.curvature_per_mm, s.conic)
        for i, a in enumerate(s.aspheric_coefficients):
            p = i + 2  # A4 rho^2, A6 rho^3, ...
            z = z + a * rho**p
            dz = dz + p * a * rho ** (p - 1)
        return z, dz

    def slope(self, s, r):
        out = conic_slope(r, s.curvature_per_mm, s.conic)
        for j, a in enumerate(s.aspheric_coefficients):
            p = 2 * j + 4
            out = out + p * a * r ** (p - 1)
        return out

    def seidel_terms(self, s):
        co = s.aspheric_coefficients
        return s.curvature_per_mm, s.conic, co[0] if co else 0.0

    def is_aspheric(self, s) -> bool:
        return s.conic != 0 or any(a != 0 for a in s.aspheric_coefficients)

    def from_zmx(self, parms, scale):
        if parms.get(1, 0.0) != 0:
            raise ZemaxParmError(1, f"PARM 1 = {parms[1]:g} (the r^2 term of the even asphere) is not supported: it "
                                    "must be 0 (the curvature gives the r^2 term)")
        extra = sorted(k for k, v in parms.items() if (k < 1 or k > self.max_coefficients + 1) and v != 0)
        if extra:
            raise ZemaxParmError(extra[0], f"PARM {extra[0]} is not an even-asphere coefficient (PARM 2..8: A4..A16)")
        n = self.max_coefficients + 2
        return {"aspheric_coefficients": tuple(parms.get(k, 0.0) * scale ** (1 - 2 * k) for k in range(2, n))}

    def zmx_lines(self, s):
        return super().zmx_lines(s) + ["PARM 1 0"] + [f"PARM {j + 2} {a!r}"
                                                      for j, a in enumerate(s.aspheric_coefficients)]


EVEN_ASPHERE = register(EvenAsphere())
