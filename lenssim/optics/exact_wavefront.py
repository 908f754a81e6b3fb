"""How good is third order here? The wavefront of the thin conic lens from an exact ray trace.

The exact wavefront is the optical path difference (OPD) of an exact ray trace through the real surfaces
(:func:`opd`, the general tracer of :mod:`lenssim.optics.sequential` on the singlet's surfaces): the path of each ray from the incident plane wavefront to the reference
sphere centred on the chief ray's image point, minus the chief ray's. It is sampled on a polar pupil grid whose
radii are Gauss-Legendre nodes in ``rho^2`` (so the weighted sum over the grid is the area integral over the
pupil) and represented by its least-squares (area-weighted) projection on the pupil monomials
``rho^2a rho_r^b`` of degree <= 8 of :data:`EXACT_TERMS` (all even in ``rho_t``, as the centred lens's
symmetry requires); :func:`exact_wavefront_fit` reports the RMS residual of that representation (below 1e-4 wave
for the paper's designs at 14 degrees). The chief ray's distortion (its image point's distance from the paraxial
point ``t tan(alpha)``) is added as the tilt that moves the PSF there.

What the PSF then assumes about the oblique beam. The PSF machinery maps the pupil to the image plane with the
on-axis (paraxial) scale: a wavefront slope ``grad W`` lands at ``eps = -(t / y) grad W`` and the pupil is the
paraxial disc of radius ``y`` at distance ``t``. The real oblique beam's reference sphere has radius
``t / cos(alpha)`` and its exit pupil, seen from the image point, is foreshortened by ``cos(alpha)`` in the
meridional direction, so its image-plane blur of the same OPD is wider by ``1 / cos^3(alpha)`` meridionally and
``1 / cos(alpha)`` sagittally (1.095 and 1.031 at 14 degrees). Neither model includes that anamorphic scale:
third order neglects it by order (it is fifth order), and the exact model uses the OPD, the physical wavefront,
with the paraxial scale. The former exact model fitted the image-plane ray errors with the paraxial scale, which
folded that stretch into the wavefront itself (an RMS 6% too large at 14 degrees; issue 19).

The criteria then follow from the same OTF machinery as the third-order ones, in the evaluation layer
(:func:`lenssim.metrics.exact_criteria`; this module, in the optics, does not import it).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

from .aberrations import Term, pupil_monomials
from ..model.camera import Camera
from ..model.design import Design
from .sequential import surfaces_lens, trace_rays, trace_rays_opl
from ..torch_utils import HOST

__all__ = ["EXACT_TERMS", "exact_wavefront_fit", "exact_wavefront_coefficients", "pupil_quadrature", "opd_rms_waves",
           "fit_exact_terms", "lens_exact_coefficients", "opd", "transverse_aberration"]

EXACT_TERMS = tuple(Term(f"E{a}{b}", a, b) for a in range(5) for b in range(9) if 0 < 2 * a + b <= 8)
"""Pupil monomials ``rho^2a rho_r^b`` up to degree 8 (no piston)."""

IMAGE_SIDE_TOLERANCE_MM = 1e-9
"""A batch's chief rays may cross the axis by this (mm) at a field and still count as one side (the axis's own
field images at 0 up to rounding)."""
QUADRATURE_RINGS = 12
"""Gauss-Legendre nodes in ``rho^2`` of the pupil grid: the area integral of a polynomial of degree <= 46 in
``rho`` is exact, so the degree-8 projection is the continuous one."""
QUADRATURE_SPOKES = 48
"""Equally spaced azimuths of the pupil grid (exact for ``cos^b`` products up to b = 47)."""


def _beam(lens, alpha_deg: float, rho_r: torch.Tensor, rho_t: torch.Tensor, pupil_radius_mm: float | None):
    if lens.position_factor != -1.0:
        raise ValueError(f"position_factor={lens.position_factor}: the ray trace supports only p = -1 "
                         "(object at infinity)")
    y = lens.pupil_radius_mm if pupil_radius_mm is None else pupil_radius_mm
    a = math.radians(alpha_deg)
    starts = torch.stack([rho_t * y, rho_r * y, torch.zeros_like(rho_r)], dim=-1)
    return starts, torch.tensor([0.0, math.sin(a), math.cos(a)], dtype=rho_r.dtype, device=rho_r.device)


def transverse_aberration(lens, design: Design, alpha_deg: float, rho_r: torch.Tensor, rho_t: torch.Tensor,
                          pupil_radius_mm: float | None = None, wavelength_um: float | None = None, surfaces=None):
    """Exact transverse ray aberration (mm) in the paraxial image plane of the thin lens ``lens``
    (:class:`lenssim.Lens`).

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
    img = trace_rays(lens.surfaces(design, wavelength_um) if surfaces is None else surfaces, starts, direction, t)
    return img[..., 1] - t * math.tan(math.radians(alpha_deg)), img[..., 0]


def opd(lens, design: Design, alpha_deg: float, rho_r: torch.Tensor, rho_t: torch.Tensor, *,
        wavelength_um: float | None = None, surfaces=None, pupil_radius_mm: float | None = None):
    """Optical path difference (mm, Welford's sign) of the thin lens ``lens`` (:class:`lenssim.Lens`) at field angle
    ``alpha_deg`` at pupil points, traced by :func:`lenssim.optics.sequential.trace_rays_opl`.

    The reference sphere is centred on the chief ray's point in the image plane ``t`` (the lens's image distance
    plus the design's ``focus_shift_um``) and passes through the chief ray's point on the last surface (the exit
    pupil of the thin lens, whose stop is at the lens): its radius is ``t / cos(alpha)`` for the centred lens.
    ``W = OPL(chief) - OPL(ray)``, each path from the incident plane wavefront to the sphere, so a wavefront ahead
    of the sphere at the rim (the image plane beyond the focus) is positive, as the third-order ``W020`` is.
    ``rho_r`` (along +y, the field's direction) and ``rho_t`` are entrance-pupil coordinates normalised to
    ``pupil_radius_mm`` (default the lens's); ``surfaces``: as in :func:`transverse_aberration`. Returns
    ``(W (*), chief image point (3,))`` in mm, float64.
    """
    starts, direction = _beam(lens, alpha_deg, rho_r, rho_t, pupil_radius_mm)
    t_img = lens.image_distance_mm + float(design["focus_shift_um"]) * 1e-3
    seq = surfaces_lens(lens.surfaces(design, wavelength_um) if surfaces is None else surfaces)
    Pc, dc, Lc = trace_rays_opl(seq, torch.zeros(1, 3, dtype=rho_r.dtype, device=rho_r.device), direction)
    Q = Pc[0] + ((t_img - Pc[0, 2]) / dc[0, 2]) * dc[0]  # the chief ray's image point
    R2 = ((Q - Pc[0]) ** 2).sum()
    P, d, L = trace_rays_opl(seq, starts, direction)
    b = ((P - Q) * d).sum(-1)
    c = ((P - Q) ** 2).sum(-1) - R2
    s = c / (-b + torch.sqrt(b * b - c))  # the root near the last surface (stable form): distance to the sphere
    return Lc[0] - (L + s), Q


@lru_cache(maxsize=4)
def pupil_quadrature(n_rings: int = QUADRATURE_RINGS, n_spokes: int = QUADRATURE_SPOKES):
    """Pupil points and area weights of the unit disc: ``(rho_r, rho_t, weight)``, float64 ``(P,)`` each, the
    weights summing to 1 (Gauss-Legendre in ``rho^2`` times the trapezoid rule in azimuth), on :data:`HOST` (cached)."""
    x, w = np.polynomial.legendre.leggauss(n_rings)
    r = torch.tensor(np.sqrt((x + 1) / 2), dtype=torch.float64, device=HOST)
    wr = torch.tensor(w / 2, dtype=torch.float64, device=HOST)
    th = torch.arange(n_spokes, dtype=torch.float64, device=HOST) * (2 * math.pi / n_spokes)
    R, T = torch.meshgrid(r, th, indexing="ij")
    weight = (wr[:, None] / n_spokes).expand_as(R).flatten()
    return (R * torch.cos(T)).flatten(), (R * torch.sin(T)).flatten(), weight


def _opd_waves(camera: Camera, design: Design, alpha_deg: float, lam: float, surfaces=None):
    rr, rt, wt = pupil_quadrature()
    W, Q = opd(camera.lens, design.to(torch.float64), float(alpha_deg), rr, rt, wavelength_um=lam, surfaces=surfaces)
    return rr, rt, wt, W / (lam * 1e-3), Q


def opd_rms_waves(camera: Camera, design: Design, alpha_deg: float, wavelength_um: float | None = None, *,
                  surfaces=None) -> float:
    """RMS (waves) over the pupil of the exact OPD at ``alpha_deg``, piston and tilt removed (area-weighted
    least squares)."""
    lam = camera.spectrum.wavelengths_um[0] if wavelength_um is None else wavelength_um
    rr, rt, wt, W, _ = _opd_waves(camera, design, alpha_deg, lam, surfaces)
    A = torch.stack([torch.ones_like(rr), rr, rt], dim=1) * wt.sqrt()[:, None]
    res = W * wt.sqrt() - A @ torch.linalg.lstsq(A, (W * wt.sqrt())[:, None]).solution[:, 0]
    return float(torch.sqrt((res**2).sum()))


def exact_wavefront_fit(camera: Camera, design: Design, alpha_deg: float, wavelength_um: float | None = None):
    """``(coefficients (T,), residual)``: the exact OPD at field angle ``alpha_deg`` (waves at ``wavelength_um``,
    default the spectrum's first) projected on :data:`EXACT_TERMS`, with the chief ray's distortion as a tilt (see
    the module's note), float64; ``residual`` is the RMS (waves) of the OPD minus the projection."""
    lens = camera.lens
    lam = camera.spectrum.wavelengths_um[0] if wavelength_um is None else wavelength_um
    rr, rt, wt, W, Q = _opd_waves(camera, design, alpha_deg, lam)
    c, residual = fit_exact_terms(rr, rt, wt, W)
    t_img = lens.image_distance_mm + float(design["focus_shift_um"]) * 1e-3
    eps_chief = float(Q[1]) - t_img * math.tan(math.radians(alpha_deg))  # mm, along the field's direction
    tilt = next(i for i, t in enumerate(EXACT_TERMS) if (t.a, t.b) == (0, 1))
    c[tilt] += -(lens.pupil_radius_mm / t_img) * eps_chief / (lam * 1e-3)
    return c, residual


def fit_exact_terms(rr: torch.Tensor, rt: torch.Tensor, wt: torch.Tensor, W: torch.Tensor):
    """``(coefficients (T,), residual)``: the OPD ``W`` (waves) at pupil points ``(rr, rt)`` with area weights ``wt``
    (:func:`pupil_quadrature`) projected on :data:`EXACT_TERMS` (area-weighted least squares); ``residual`` is the
    RMS (waves) of ``W`` minus the projection. The one fit of both lens routes. ``W`` ``(B, P)`` (a batch of
    designs): coefficients ``(B, T)`` and residuals ``(B,)`` as tensors, differentiable in ``W``."""
    basis = pupil_monomials(rr, rt, EXACT_TERMS).T.to(W.device)  # (P, T)
    sw = wt.sqrt().to(W.device)
    if W.dim() == 1:
        c = torch.linalg.lstsq(basis * sw[:, None], (W * sw)[:, None]).solution[:, 0]
        return c, float(torch.sqrt((((W - basis @ c) ** 2) * wt).sum()))
    c = torch.linalg.lstsq(basis * sw[:, None], (W * sw).T).solution.T  # (B, T)
    return c, torch.sqrt((((W - c @ basis.T) ** 2) * wt.to(W.device)).sum(-1))


def lens_exact_coefficients(seq, angles_deg, wavelengths_um) -> torch.Tensor:
    """Coefficients of :data:`EXACT_TERMS` (waves at each wavelength) of the real-ray OPD of the sequential lens
    ``seq`` (:class:`lenssim.optics.sequential.SequentialLens`, object at infinity), ``(A, K, T)`` float64, at field
    angles ``angles_deg`` (deg) and ``wavelengths_um``: rays aimed at the stop (its radius as the prescription's
    ``stop_size`` says) at the points of :func:`pupil_quadrature` (``rho_r`` along the field, toward the image point),
    the surfaces extended beyond their semi-diameters (the pupil is the full disc, as in the third-order route), the
    OPD referred to the sphere about the primary wavelength's real chief ray on the image plane (so the PSFs sit about
    the chief ray, the lateral colour kept as a tilt). Raises ``ValueError`` where a ray cannot be traced.

    A batched lens (:attr:`~lenssim.optics.sequential.SequentialLens.batched`, ``B`` designs): ``(B, A, K, T)`` on its
    device, differentiable in its numbers (every design's image point on one side of the axis at each field)."""
    rr, rt, wt = pupil_quadrature()
    lam0 = seq.primary_wavelength_um
    batch = seq.batched
    dev = seq.device
    zero = torch.zeros(1, dtype=torch.float64, device=dev)
    rr, rt = rr.to(dev), rt.to(dev)
    rows = []
    for a in angles_deg:
        a = float(a)
        chief_y = seq.wavefront(a, zero, zero, lam0).chief_mm[..., 1]
        y0 = chief_y if batch else float(chief_y)
        toward = -1.0 if float(chief_y.detach().reshape(-1)[0]) < 0 else 1.0  # rho_r points from the axis to the image point
        if batch and bool((chief_y * toward < -IMAGE_SIDE_TOLERANCE_MM).any()):
            raise ValueError(f"field {a:g} deg: the designs of the batch image it on both sides of the axis")
        per = []
        for lam in wavelengths_um:
            w = seq.wavefront(a, rt, toward * rr, float(lam), reference_mm=(0.0, y0), vignette=False)
            if not bool(torch.isfinite(w.opd_waves).all()):
                raise ValueError(f"field {a:g} deg, {float(lam):g} um: some rays of the pupil cannot be traced (a "
                                 "surface missed or a total internal reflection): no exact wavefront")
            per.append(fit_exact_terms(rr, rt, wt, w.opd_waves)[0])
        rows.append(torch.stack(per, dim=-2))
    return torch.stack(rows, dim=-3)


def exact_wavefront_coefficients(camera: Camera, design: Design, alpha_deg: float,
                                 wavelength_um: float | None = None) -> torch.Tensor:
    """Coefficients (waves at ``wavelength_um``, default the spectrum's first) of :data:`EXACT_TERMS`: the exact
    OPD at field angle ``alpha_deg`` (:func:`exact_wavefront_fit`); float64 ``(T,)``."""
    return exact_wavefront_fit(camera, design, alpha_deg, wavelength_um)[0]
