"""Surface kinds: one class per kind of rotationally symmetric refracting surface, registered by name.

A :class:`lenssim.model.prescription.PrescriptionSurface` holds a surface's numbers (``curvature_per_mm``,
``conic``, ``aspheric_coefficients``, its kind's own ``shape_parameters``); its kind (:attr:`PrescriptionSurface.
surface_kind`, a :class:`SurfaceKind` of :data:`SURFACE_KINDS`) says what they mean. The kind owns:

* the shape, as torch functions of tensors (a later batch of designs, autograd through them): :meth:`SurfaceKind.sag`
  (mm, and ``d sag / d rho``, ``rho = r^2``), :meth:`SurfaceKind.slope` (``d sag / d r``), the ray intersection
  :meth:`SurfaceKind.intersect` (the base conic's closed form, then Newton's method on the full sag) and its normal;
* first and third order: :meth:`SurfaceKind.paraxial_curvature` and :meth:`SurfaceKind.seidel_terms` (the conic and
  ``A4`` of the even asphere with the same ``r^2`` and ``r^4`` terms: what the Seidel sums read);
* the asphere cost's input: :meth:`SurfaceKind.slope` and :meth:`SurfaceKind.is_aspheric`;
* its checks (:meth:`SurfaceKind.check`) and its files: TOML through :attr:`SurfaceKind.shape_parameters` and
  ``kind = NAME``, ``.zmx`` through :attr:`SurfaceKind.zemax_type`, :meth:`SurfaceKind.from_zmx` and
  :meth:`SurfaceKind.zmx_lines`.

Adding a kind is one module in this package that defines a subclass and calls :func:`register` (every module here
is imported when the package is: ``standard`` and ``even_asphere`` first, then the others by name), plus its test;
docs/architecture.md walks through ``qbfs.py``. The standard surface (a sphere or conic) and the even asphere are one
family in the files: a surface of that family is an even asphere when it has ``A4 ...`` terms, else standard.
"""

from __future__ import annotations

import math

import torch

from ...registry import Registry, import_plugins
from ...torch_utils import HOST

__all__ = ["SurfaceKind", "SURFACE_KINDS", "register", "ZemaxParmError", "sag_normal", "conic_intersection", "refract",
           "NEWTON_ITERATIONS", "INTERSECTION_TOLERANCE_MM", "finite_number"]

NEWTON_ITERATIONS = 12
"""Newton steps refining an aspheric intersection from its base conic's (quadratic convergence: ample)."""

INTERSECTION_TOLERANCE_MM = 1e-10
"""A ray meets an aspheric surface if the sag equation holds to this (mm) after the Newton steps."""

SURFACE_KINDS = Registry("surface kind")
"""Every surface kind by its name (the TOML ``kind``), filled by the modules of this package."""


class ZemaxParmError(ValueError):
    """A ``.zmx`` ``PARM`` its kind does not allow; ``parm``: its number (the reader names its line)."""

    def __init__(self, parm: int, message: str):
        super().__init__(message)
        self.parm = parm


def finite_number(name: str, v, allowed: str = "a finite number") -> float:
    """``v`` as a float, or ``ValueError`` naming ``name`` and what is ``allowed``."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{name} = {v!r} is not allowed: {allowed}")
    return float(v)


def conic_intersection(P, d, c, k, valid=None):
    """``(t, ok)``: the distance along unit ``d`` from ``P`` (``(*, 3)``, vertex at the origin) to the conic ``c (x^2
    + y^2) + c (1 + k) z^2 - 2 z = 0``, the root continuous with the vertex plane's (stable as ``c -> 0``), and the
    rays (of ``valid``) with a real root. Tensors broadcast."""
    k1 = c * (1 + k)
    A = c * (d[..., 0] ** 2 + d[..., 1] ** 2) + k1 * d[..., 2] ** 2
    Bh = c * (P[..., 0] * d[..., 0] + P[..., 1] * d[..., 1]) + k1 * P[..., 2] * d[..., 2] - d[..., 2]
    C = c * (P[..., 0] ** 2 + P[..., 1] ** 2) + k1 * P[..., 2] ** 2 - 2 * P[..., 2]
    disc = Bh**2 - A * C
    ok = disc >= 0 if valid is None else valid & (disc >= 0)
    disc = torch.where(ok, disc, torch.zeros_like(disc))
    den = Bh + torch.where(Bh >= 0, 1.0, -1.0) * torch.sqrt(disc)
    den = torch.where(den == 0, torch.ones_like(den), den)
    return -C / den, ok


def sag_normal(X, dz):
    """Unit normals (towards ``-z``) at points ``X`` ``(*, 3)`` where ``d sag / d rho`` is ``dz``: ``(2 x dz, 2 y dz,
    -1)`` normalised."""
    N = torch.stack([2 * X[..., 0] * dz, 2 * X[..., 1] * dz, -torch.ones_like(dz)], dim=-1)
    return N / torch.linalg.norm(N, dim=-1, keepdim=True)


def refract(d, N, n1, n2, valid=None):
    """``(d', ok)``: unit directions ``d`` ``(*, 3)`` refracted at unit normals ``N`` (either orientation) from index
    ``n1`` into ``n2`` by the vector form of Snell's law, and the rays (of ``valid``) not totally internally reflected
    (``d'`` is then meaningless): the refraction of every ray trace, whatever the surface's kind."""
    cos_i = (d * N).sum(-1, keepdim=True)
    N = torch.where(cos_i < 0, -N, N)
    cos_i = cos_i.abs()
    mu = n1 / n2
    k = 1 - mu**2 * (1 - cos_i**2)
    ok = k[..., 0] >= 0 if valid is None else valid & (k[..., 0] >= 0)
    k = torch.where(ok.unsqueeze(-1), k, torch.ones_like(k))
    return mu * d + (torch.sqrt(k) - mu * cos_i) * N, ok


class SurfaceKind:
    """A kind of surface (the module docstring); a subclass sets the attributes and the shape's methods. Every method
    takes the surface ``s`` (a :class:`~lenssim.model.prescription.PrescriptionSurface`); the shape's take tensors and
    return tensors of their dtype and device."""

    name = ""  # the registry key and the TOML ``kind``
    label = ""  # what it is, in words
    zemax_type: str | None = None  # its ``.zmx`` TYPE; None: not read from or written to .zmx files
    shape_parameters: tuple[str, ...] = ()  # its own numbers (TOML keys, units in the names), each required
    max_coefficients = 0  # most ``aspheric_coefficients``
    coefficients_meaning = "none"  # what they are, in words
    has_conic = True  # ``conic`` is one of its numbers (else it must be 0)

    def check(self, s) -> dict:
        """Fields to replace (coefficients as floats without trailing zeros, ``shape_parameters`` a sorted tuple of
        pairs); ``ValueError`` naming the number that is not allowed."""
        coeffs = tuple(s.aspheric_coefficients)
        if len(coeffs) > self.max_coefficients:
            raise ValueError(f"{len(coeffs)} aspheric coefficients given; at most {self.max_coefficients} "
                             f"({self.coefficients_meaning})")
        coeffs = tuple(finite_number(self.coefficient_name(i), a) for i, a in enumerate(coeffs))
        while coeffs and coeffs[-1] == 0:
            coeffs = coeffs[:-1]
        if not self.has_conic and s.conic != 0:
            raise ValueError(f"conic = {s.conic!r} is not allowed on a {self.name} surface: 0 (its base is a sphere)")
        given = dict(s.shape_parameters)
        for n in sorted(set(given) - set(self.shape_parameters)):
            raise ValueError(f"shape parameter {n!r} is not one of a {self.name} surface's "
                             f"({', '.join(self.shape_parameters) or 'none'})")
        for n in self.shape_parameters:
            if n not in given:
                raise ValueError(f"a {self.name} surface needs {n}")
        return {"aspheric_coefficients": coeffs,
                "shape_parameters": tuple(sorted((n, finite_number(n, v)) for n, v in given.items()))}

    def coefficient_name(self, i: int) -> str:
        return f"coefficient {i}"

    # -- the shape (torch) -----------------------------------------------------------------------------------------
    def base_conic(self, s) -> tuple:
        """``(c, k)``: the conic whose closed-form intersection seeds Newton's method and whose domain
        ``(1 + k) c^2 r^2 < 1`` bounds the surface's."""
        return s.curvature_per_mm, s.conic

    def departs(self, s) -> bool:
        """Whether the sag departs from :meth:`base_conic`'s (intersections are then refined by Newton's method)."""
        return bool(s.aspheric_coefficients)

    def sag(self, s, rho: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(z, dz/drho)``: the sag (mm, from the vertex along the axis) and its derivative in ``rho = r^2``."""
        raise NotImplementedError

    def slope(self, s, r: torch.Tensor) -> torch.Tensor:
        """``dz/dr`` at radii ``r`` (mm)."""
        return 2 * r * self.sag(s, r * r)[1]

    def sag_mm(self, s, r_mm: float) -> float:
        """The sag (mm) at one height (float64: the prescription's own checks)."""
        return float(self.sag(s, torch.tensor(float(r_mm) ** 2, dtype=torch.float64, device=HOST))[0])

    def intersect(self, s, P, d, valid):
        """Rays from ``P`` along unit ``d`` (``(R, 3)``, the vertex at the origin) onto the surface: ``(X, N, t, ok,
        rho)``: points, unit normals (towards ``-z``), distances, the rays of ``valid`` that meet it (within the base
        conic's domain) and ``x^2 + y^2`` there."""
        c, k = self.base_conic(s)
        t, ok = conic_intersection(P, d, c, k, valid)
        if self.departs(s):
            for _ in range(NEWTON_ITERATIONS):
                X = P + t.unsqueeze(-1) * d
                rho = X[..., 0] ** 2 + X[..., 1] ** 2
                z, dz = self.sag(s, rho)
                g = z - X[..., 2]
                dg = dz * 2 * (X[..., 0] * d[..., 0] + X[..., 1] * d[..., 1]) - d[..., 2]
                dg = torch.where(dg == 0, torch.ones_like(dg), dg)
                t = t - torch.where(ok, g / dg, torch.zeros_like(g))
            X = P + t.unsqueeze(-1) * d
            z, _ = self.sag(s, X[..., 0] ** 2 + X[..., 1] ** 2)
            ok = ok & ((z - X[..., 2]).abs() < INTERSECTION_TOLERANCE_MM) & torch.isfinite(t)
            t = torch.where(ok, t, torch.zeros_like(t))
        X = P + t.unsqueeze(-1) * d
        rho = X[..., 0] ** 2 + X[..., 1] ** 2
        _, dz = self.sag(s, rho)
        ok = ok & ((1 - (1 + k) * c * c * rho > 0) | (c == 0))  # the conic's slope diverges at its rim
        return X, sag_normal(X, dz), t, ok, rho

    # -- first and third order, the cost ---------------------------------------------------------------------------
    def paraxial_curvature(self, s):
        """The curvature (1/mm) of the sphere osculating the surface at its vertex (the paraxial trace's)."""
        return s.curvature_per_mm

    def seidel_terms(self, s) -> tuple:
        """``(c, k, A4)`` of the even asphere with the same ``r^2`` and ``r^4`` sag terms (``c r^2 / 2 + ((1 + k) c^3
        / 8 + A4) r^4``): what the Seidel sums read."""
        raise NotImplementedError

    def is_aspheric(self, s) -> bool:
        """Not a sphere (the industrial cost counts it; its input is :meth:`slope`)."""
        raise NotImplementedError

    # -- .zmx files (TOML: ``kind`` and :attr:`shape_parameters`) --------------------------------------------------
    def from_zmx(self, parms: dict[int, float], scale: float) -> dict:
        """Fields from a ``.zmx`` surface's ``PARM`` values (lens units, ``scale`` mm each); :class:`ZemaxParmError`
        for one not allowed (here: any nonzero)."""
        for n, v in sorted(parms.items()):
            if v != 0:
                raise ZemaxParmError(n, f"PARM {n} = {v:g} on a {self.zemax_type} surface is not supported")
        return {}

    def zmx_lines(self, s) -> list[str]:
        """The ``.zmx`` lines of the shape (lens unit mm)."""
        return [f"TYPE {self.zemax_type}", f"CURV {s.curvature_per_mm!r}", f"CONI {s.conic!r}"]


register = SURFACE_KINDS.register
"""Add a kind (an instance) under its ``name``; returns it."""

import_plugins(__name__, __path__, first=("standard", "even_asphere"))
