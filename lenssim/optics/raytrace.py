"""Exact (real) ray trace through conic surfaces, centred or displaced, with optical path lengths.

Each surface is ``c (x^2 + y^2) + c (1 + kappa) z^2 - 2 z = 0`` in its own frame, whose origin is the
vertex; rays are refracted with the vector form of Snell's law. A surface may be decentred (``decentre_mm``:
its vertex moved by ``(dx, dy)`` mm off the axis) and tilted (``tilt_deg``: rotated by ``(tx, ty)`` degrees
about its vertex, first about the x axis, then about the y axis; a positive ``tx`` turns the surface's normal
towards -y, i.e. its axis into the y-z plane), as a manufacturing or assembly error (issue 19). Vertex
separations may be zero (the thin-lens limit): a ray may then travel a (signed) negative distance between the
surfaces, which is the analytic continuation the thin-lens formulas assume, and its optical path counts that
distance with its sign. Units: mm. Computations in the dtype of the input (use float64 for checks).
"""

from __future__ import annotations

import math

import torch

from ..model.design import Design
from ..model.lens import Lens
from ..model.surface import Surface
from ..model.surface_kinds import conic_intersection, refract, sag_normal
from ..model.surface_kinds.standard import conic_sag
from ..torch_utils import HOST

__all__ = ["trace_rays", "trace_rays_opl", "transverse_aberration", "surface_frame", "opd"]


def _intersect(P, d, c, kappa):
    """Intersection with the conic in its own frame (vertex at the origin): points, unit normals, distances (the
    standard surface kind's closed form and normal, :mod:`lenssim.model.surface_kinds.standard`)."""
    t, ok = conic_intersection(P, d, c, kappa)
    if not bool(ok.all()):
        raise ValueError("a ray misses a surface (discriminant < 0); reduce the aperture or field")
    X = P + t.unsqueeze(-1) * d
    return X, sag_normal(X, conic_sag(X[..., 0] ** 2 + X[..., 1] ** 2, c, kappa)[1]), t


def surface_frame(surf: Surface, z_vertex_mm: float, dtype=torch.float64, device=None):
    """``(origin (3,), R (3, 3))`` of a surface's own frame: a point ``X`` of the system is ``R^T (X - origin)``
    in the surface's frame. ``origin`` is the nominal vertex ``(0, 0, z)`` plus the decentre; ``R`` the tilt
    (about x by ``tx``, then about y by ``ty``); on ``device`` (default :data:`lenssim.torch_utils.HOST`)."""
    dx, dy = surf.decentre_mm
    tx, ty = (math.radians(v) for v in surf.tilt_deg)
    device = device or HOST
    rx = torch.tensor([[1, 0, 0], [0, math.cos(tx), -math.sin(tx)], [0, math.sin(tx), math.cos(tx)]], dtype=dtype,
                      device=device)
    ry = torch.tensor([[math.cos(ty), 0, math.sin(ty)], [0, 1, 0], [-math.sin(ty), 0, math.cos(ty)]], dtype=dtype,
                      device=device)
    return torch.tensor([dx, dy, z_vertex_mm], dtype=dtype, device=device), ry @ rx


def trace_rays_opl(surfaces: list[Surface], starts: torch.Tensor, direction: torch.Tensor, n_object: float = 1.0):
    """Trace rays from ``starts`` ``(*, 3)`` along ``direction`` ``(3,)`` or ``(*, 3)`` through ``surfaces``.

    The first surface's nominal vertex is at ``z = 0``. Returns ``(points, directions, opl)``: each ray's point on
    the last surface ``(*, 3)`` (mm), its unit direction after it ``(*, 3)``, and its optical path (mm) from the
    plane through the origin normal to its incoming direction (a plane wavefront of the object at infinity) to that
    point, distances signed (see the module's note on zero separations).
    """
    P = starts
    d = direction.expand_as(P)
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
    n = n_object
    opl = n * (P * d).sum(-1)
    z_v = 0.0
    for surf in surfaces:
        c = torch.as_tensor(surf.curvature, dtype=P.dtype, device=P.device)
        kap = torch.as_tensor(surf.conic, dtype=P.dtype, device=P.device)
        o, R = surface_frame(surf, z_v, P.dtype, P.device)
        Pl, dl = (P - o) @ R, d @ R  # into the surface's frame (rows times R = R^T applied)
        Xl, Nl, t = _intersect(Pl, dl, c, kap)
        dl, ok = refract(dl, Nl, n, surf.n_after)
        if not bool(ok.all()):
            raise ValueError("total internal reflection in the ray trace")
        opl = opl + n * t
        P, d = Xl @ R.T + o, dl @ R.T
        n = surf.n_after
        z_v += surf.thickness_after_mm
    return P, d, opl


def trace_rays(surfaces: list[Surface], starts: torch.Tensor, direction: torch.Tensor, z_image_mm: float,
               n_object: float = 1.0) -> torch.Tensor:
    """Trace rays from ``starts`` ``(*, 3)`` along ``direction`` ``(3,)`` or ``(*, 3)`` to ``z = z_image``.

    The first surface vertex is at ``z = 0``. Returns the image-plane points ``(*, 3)`` in mm.
    """
    P, d, _ = trace_rays_opl(surfaces, starts, direction, n_object)
    t = (z_image_mm - P[..., 2]) / d[..., 2]
    return P + t.unsqueeze(-1) * d


def _beam(lens: Lens, alpha_deg: float, rho_r: torch.Tensor, rho_t: torch.Tensor, pupil_radius_mm: float | None):
    if lens.position_factor != -1.0:
        raise ValueError(f"position_factor={lens.position_factor}: the ray trace supports only p = -1 "
                         "(object at infinity)")
    y = lens.pupil_radius_mm if pupil_radius_mm is None else pupil_radius_mm
    a = math.radians(alpha_deg)
    starts = torch.stack([rho_t * y, rho_r * y, torch.zeros_like(rho_r)], dim=-1)
    return starts, torch.tensor([0.0, math.sin(a), math.cos(a)], dtype=rho_r.dtype, device=rho_r.device)


def transverse_aberration(lens: Lens, design: Design, alpha_deg: float, rho_r: torch.Tensor,
                          rho_t: torch.Tensor, pupil_radius_mm: float | None = None, wavelength_um: float | None = None,
                          surfaces: list[Surface] | None = None):
    """Exact transverse ray aberration (mm) in the paraxial image plane of the thin lens.

    Object at infinity (``p = -1`` only), field angle ``alpha_deg`` in the y-z plane, stop at the
    lens. ``rho_r`` (meridional, along +y) and ``rho_t`` are pupil coordinates normalised to
    ``pupil_radius_mm`` (default ``lens.pupil_radius_mm``). Returns ``(eps_r, eps_t)`` relative to
    the paraxial image point ``(0, t tan(alpha))``, along the same axes, in the image plane ``t`` (the
    lens's image distance plus the design's ``focus_shift_um``), at ``wavelength_um`` (default: the
    reference index). ``surfaces``: the lens's surfaces (default ``lens.surfaces(design, wavelength_um)``; e.g.
    displaced ones).
    """
    starts, direction = _beam(lens, alpha_deg, rho_r, rho_t, pupil_radius_mm)
    t = lens.image_distance_mm + float(design["focus_shift_um"]) * 1e-3
    surfs = lens.surfaces(design, wavelength_um) if surfaces is None else surfaces
    img = trace_rays(surfs, starts, direction, t)
    return img[..., 1] - t * math.tan(math.radians(alpha_deg)), img[..., 0]


def opd(lens: Lens, design: Design, alpha_deg: float, rho_r: torch.Tensor, rho_t: torch.Tensor, *,
        wavelength_um: float | None = None, surfaces: list[Surface] | None = None,
        pupil_radius_mm: float | None = None):
    """Optical path difference (mm, Welford's sign) of the beam at field angle ``alpha_deg`` at pupil points.

    The reference sphere is centred on the chief ray's point in the image plane ``t`` (the lens's image distance
    plus the design's ``focus_shift_um``) and passes through the chief ray's point on the last surface (the exit
    pupil of the thin lens, whose stop is at the lens): its radius is ``t / cos(alpha)`` for the centred lens.
    ``W = OPL(chief) - OPL(ray)``, each path from the incident plane wavefront to the sphere, so a wavefront ahead
    of the sphere at the rim (the image plane beyond the focus) is positive, as the third-order ``W020`` is.
    ``rho_r`` (along +y, the field's direction) and ``rho_t`` are entrance-pupil coordinates normalised to
    ``pupil_radius_mm`` (default the lens's). Returns ``(W (*), chief image point (3,))`` in mm.
    """
    starts, direction = _beam(lens, alpha_deg, rho_r, rho_t, pupil_radius_mm)
    t_img = lens.image_distance_mm + float(design["focus_shift_um"]) * 1e-3
    surfs = lens.surfaces(design, wavelength_um) if surfaces is None else surfaces
    zero = torch.zeros(1, 3, dtype=rho_r.dtype, device=rho_r.device)
    Pc, dc, Lc = trace_rays_opl(surfs, zero, direction)
    Q = Pc[0] + ((t_img - Pc[0, 2]) / dc[0, 2]) * dc[0]  # the chief ray's image point
    R2 = ((Q - Pc[0]) ** 2).sum()
    P, d, L = trace_rays_opl(surfs, starts, direction)
    b = ((P - Q) * d).sum(-1)
    c = ((P - Q) ** 2).sum(-1) - R2
    s = c / (-b + torch.sqrt(b * b - c))  # the root near the last surface (stable form): distance to the sphere
    return Lc[0] - (L + s), Q
