"""Exact (real) ray trace through centred conic surfaces, for checking the third-order model.

Each surface is ``c (x^2 + y^2) + c (1 + kappa) z^2 - 2 z = 0`` about its vertex; rays are refracted
with the vector form of Snell's law. Vertex separations may be zero (the thin-lens limit): a
ray may then travel a (signed) negative distance between the surfaces, which is the analytic
continuation the thin-lens formulas assume. Units: mm. Computations in the dtype of the input
(use float64 for checks).
"""

from __future__ import annotations

import math

import torch

from ..model.design import Design
from ..model.lens import Lens
from .paraxial import Surface

__all__ = ["trace_rays", "transverse_aberration"]


def _intersect(P, d, c, kappa, z_vertex):
    z = P[..., 2] - z_vertex
    k1 = c * (1 + kappa)
    A = c * (d[..., 0] ** 2 + d[..., 1] ** 2) + k1 * d[..., 2] ** 2
    Bh = c * (P[..., 0] * d[..., 0] + P[..., 1] * d[..., 1]) + k1 * z * d[..., 2] - d[..., 2]
    C = c * (P[..., 0] ** 2 + P[..., 1] ** 2) + k1 * z**2 - 2 * z
    disc = Bh**2 - A * C
    if (disc < 0).any():
        raise ValueError("a ray misses a surface (discriminant < 0); reduce the aperture or field")
    # root continuous with the vertex-plane intersection (stable for c -> 0)
    t = -C / (Bh + torch.sign(Bh) * torch.sqrt(disc))
    X = P + t.unsqueeze(-1) * d
    zl = X[..., 2] - z_vertex
    N = torch.stack([c * X[..., 0], c * X[..., 1], k1 * zl - 1], dim=-1)
    N = N / torch.linalg.norm(N, dim=-1, keepdim=True)
    return X, N


def _refract(d, N, n1, n2):
    cos_i = (d * N).sum(-1, keepdim=True)
    N = torch.where(cos_i < 0, -N, N)
    cos_i = cos_i.abs()
    mu = n1 / n2
    k = 1 - mu**2 * (1 - cos_i**2)
    if (k < 0).any():
        raise ValueError("total internal reflection in the ray trace")
    return mu * d + (torch.sqrt(k) - mu * cos_i) * N


def trace_rays(surfaces: list[Surface], starts: torch.Tensor, direction: torch.Tensor, z_image_mm: float,
               n_object: float = 1.0) -> torch.Tensor:
    """Trace rays from ``starts`` ``(*, 3)`` along ``direction`` ``(3,)`` or ``(*, 3)`` to ``z = z_image``.

    The first surface vertex is at ``z = 0``. Returns the image-plane points ``(*, 3)`` in mm.
    """
    P = starts
    d = direction.expand_as(P)
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
    n = n_object
    z_v = 0.0
    for surf in surfaces:
        c = torch.as_tensor(surf.curvature, dtype=P.dtype, device=P.device)
        kap = torch.as_tensor(surf.conic, dtype=P.dtype, device=P.device)
        P, N = _intersect(P, d, c, kap, z_v)
        d = _refract(d, N, n, surf.n_after)
        n = surf.n_after
        z_v += surf.thickness_after_mm
    t = (z_image_mm - P[..., 2]) / d[..., 2]
    return P + t.unsqueeze(-1) * d


def transverse_aberration(lens: Lens, design: Design, alpha_deg: float, rho_r: torch.Tensor,
                          rho_t: torch.Tensor, pupil_radius_mm: float | None = None, wavelength_um: float | None = None):
    """Exact transverse ray aberration (mm) in the paraxial image plane of the thin lens.

    Object at infinity (``p = -1`` only), field angle ``alpha_deg`` in the y-z plane, stop at the
    lens. ``rho_r`` (meridional, along +y) and ``rho_t`` are pupil coordinates normalised to
    ``pupil_radius_mm`` (default ``lens.pupil_radius_mm``). Returns ``(eps_r, eps_t)`` relative to
    the paraxial image point ``(0, t tan(alpha))``, along the same axes, in the image plane ``t`` (the
    lens's image distance plus the design's ``focus_shift_um``), at ``wavelength_um`` (default: the
    reference index).
    """
    if lens.position_factor != -1.0:
        raise ValueError(f"position_factor={lens.position_factor}: the ray trace supports only p = -1 "
                         "(object at infinity)")
    y = lens.pupil_radius_mm if pupil_radius_mm is None else pupil_radius_mm
    dt = rho_r.dtype
    a = math.radians(alpha_deg)
    starts = torch.stack([rho_t * y, rho_r * y, torch.zeros_like(rho_r)], dim=-1)
    direction = torch.tensor([0.0, math.sin(a), math.cos(a)], dtype=dt)
    t = lens.image_distance_mm + float(design["focus_shift_um"]) * 1e-3
    img = trace_rays(lens.surfaces(design, wavelength_um), starts, direction, t)
    return img[..., 1] - t * math.tan(a), img[..., 0]
