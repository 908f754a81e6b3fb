"""The third-order wavefront of an as-built thin lens: perturbed surfaces, displaced surfaces, figure error.

Derivation (surface-by-surface Seidel sums with displaced surfaces; Welford, *Aberrations of Optical Systems*,
ch. 7, and the nodal-aberration picture of Thompson, JOSA A 22, 1389 (2005), for surfaces at the stop). Both
surfaces of the thin lens lie at its stop, where the nominal chief ray has height 0. The marginal ray (height
``h = y``) is the centred one's, with the perturbed curvatures ``c_j`` and index ``n``. A surface decentred by
``delta`` (its vertex moved to ``delta``) and tilted by ``tau`` (its axis tipped towards ``(tau, 1)``) sees the
chief ray, in its own frame, at height ``hbar = -delta`` and angle ``theta = ubar - tau``; its refraction invariant
is the vector ``Abar = n (c hbar + theta)`` (``n``: the index before it). Its Seidel contributions are the centred
surface's with that vector (``k = -h D(u/n)``, ``a = (n' - n) kappa c^3`` the conic's)::

    S_I        = A^2 k + a h^4
    S_II (vec) = A k Abar + a h^3 hbar                    -> 1/2 (S_II . rho) rho^2
    S_III (dyad)= k Abar Abar^T + a h^2 hbar hbar^T        -> 1/2 rho^T S_III rho + 1/4 tr(S_III) rho^2
    S_IV       = -H^2 c D(1/n)                             -> 1/4 S_IV rho^2

with ``H = h theta_1``, the Lagrange invariant, the same at both surfaces (the chief ray against the lens's axis,
i.e. the front surface's). The front surface's tilt deviates the chief ray inside the glass (``theta' = theta / n``
in its frame), which the back surface sees. (Evaluating the Petzval term with each surface's own ``Abar``, or adding
an image tilt for the prism deviation of a wedged lens, both miss the ray trace by 12-27%: tested alternatives.) For the centred lens these are the
thin-lens closed forms (tested); to first order in the errors they add the field-constant coma and the
field-linear astigmatism of nodal aberration theory (the aberration field of each surface centred on its own
axis), the asphere's decentre adding the conic's coma ``a h^3 (-delta)``. A tilt of the whole lens also tilts the
image plane seen from the lens: the image point ``r`` (mm) lies ``tau . r`` closer to the lens (sign from the ray
trace), a defocus linear in the field. Radius, conic and index errors enter through ``c``, ``kappa`` and ``n``; the
defocus is ``W020 = (t_img - t_f) y^2 / (2 t_f t_img)`` with the perturbed focus ``t_f`` and the image plane at
the nominal distance plus the despace. The figure error of the asphere adds ``(n' - n) dz`` (six Zernike terms,
:data:`lenssim.model.tolerances.FIGURE_TERMS`, their tilts and piston left out).

What is left out, as geometry rather than blur: the image's displacement (boresight) and scale (focal-length)
errors; every PSF is centred on its as-built chief ray, as the nominal PSFs are on theirs. Tested against the exact
ray trace with the perturbed and displaced surfaces (:func:`as_built_surfaces`, ``tests/lenssim/test_as_built.py``).

Coefficients are in the frame of each field point (``rho_r`` towards the image point at azimuth ``phi`` from +x,
``rho_t`` 90 degrees counter-clockwise from it, as :func:`lenssim.optics.psf_bank.psf` rotates its pupils), on the
monomials of :data:`AS_BUILT_TERMS`.
"""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache

import torch

from .aberrations import Term
from ..model.camera import Camera
from ..model.design import Design
from ..model.tolerances import Perturbations
from .cost import slope_departure_cost
from ..torch_utils import HOST, tensor_of

__all__ = ["AS_BUILT_TERMS", "as_built_coefficients", "as_built_surfaces", "nominal_as_built_coefficients",
           "field_points", "figure_heights_mm"]

AS_BUILT_TERMS = (Term("rho4", 2, 0), Term("rho2_r", 1, 1), Term("rho2_t", 1, 0, 1), Term("r2", 0, 2),
                  Term("rt", 0, 1, 1), Term("t2", 0, 0, 2))
"""``rho^4``, ``rho^2 rho_r``, ``rho^2 rho_t``, ``rho_r^2``, ``rho_r rho_t``, ``rho_t^2``: the third-order wavefront of
any field point of a displaced lens (defocus is ``rho_r^2 + rho_t^2``)."""

_SQ3, _SQ5, _SQ6, _SQ8 = math.sqrt(3), math.sqrt(5), math.sqrt(6), math.sqrt(8)


def field_points(alpha_deg, azimuths_deg=(0.0, 90.0, 180.0, 270.0)):
    """Field points ``(alpha (F,), azimuth (F,))`` in degrees: each angle at each azimuth, the axis once."""
    al, az = [], []
    for a in alpha_deg:
        for p in (azimuths_deg if float(a) != 0 else azimuths_deg[:1]):
            al.append(float(a))
            az.append(float(p))
    return torch.tensor(al, dtype=torch.float64, device=HOST), torch.tensor(az, dtype=torch.float64, device=HOST)


def _rot(v: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Lens-frame vectors ``(N, 2)`` into the frames of field points at azimuths ``phi`` (rad, ``(F,)``): ``(N, F, 2)``."""
    c, s = torch.cos(phi), torch.sin(phi)
    x, y = v[:, None, 0], v[:, None, 1]
    return torch.stack([x * c + y * s, -x * s + y * c], dim=-1)


@lru_cache(maxsize=1)
def _figure_gradient_norm() -> float:
    """Mean over the unit disc of ``|grad Z|^2`` of the figure's Zernike terms, averaged over the terms."""
    from .exact_wavefront import pupil_quadrature

    x, y, w = pupil_quadrature(16, 64)
    r2 = x**2 + y**2
    grads = [(4 * _SQ3 * x, 4 * _SQ3 * y), (2 * _SQ6 * x, -2 * _SQ6 * y), (2 * _SQ6 * y, 2 * _SQ6 * x),
             (_SQ8 * (3 * r2 - 2 + 6 * x**2), _SQ8 * 6 * x * y), (_SQ8 * 6 * x * y, _SQ8 * (3 * r2 - 2 + 6 * y**2)),
             (_SQ5 * (24 * r2 - 12) * x, _SQ5 * (24 * r2 - 12) * y)]
    return float(sum(((gx**2 + gy**2) * w).sum() for gx, gy in grads) / len(grads))


def figure_heights_mm(camera: Camera, design: Design, pert: Perturbations) -> torch.Tensor:
    """The asphere's figure error of each lens: coefficients (mm of surface height) of the Noll-normalised Zernike
    terms of :data:`lenssim.model.tolerances.FIGURE_TERMS` over its clear aperture, ``(N, 6)``: the sampled weights
    scaled so that the expected mean square of the surface's slope (rad) over the aperture is
    ``tolerances.figure_slope_rad(C_a)^2`` (``E[w^T G w] = tr(G) / 6`` for independent weights of variance 1/6,
    ``G`` the Zernikes' gradient products, :func:`_figure_gradient_norm` its mean diagonal)."""
    cost = slope_departure_cost(camera.lens, design.to(torch.float64))
    scale = pert.tolerances.figure_slope_rad(cost) * camera.lens.pupil_radius_mm / math.sqrt(_figure_gradient_norm())
    return pert.figure * scale


def _perturbed(camera: Camera, design: Design, pert: Perturbations, wavelength_um: float):
    lens = camera.lens
    if lens.position_factor != -1.0:
        raise ValueError(f"position_factor={lens.position_factor}: the as-built model supports only p = -1 "
                         "(object at infinity)")
    d = design.to(torch.float64)
    c1, c2 = (tensor_of(c, torch.float64).reshape(()) for c in lens.curvatures(d["s"]))
    c1 = c1 / (1 + pert.radius_front)
    c2 = c2 / (1 + pert.radius_back)
    n = lens.glass.index(wavelength_um) + pert.index
    k1 = d["Q_front"].reshape(()) * (1 + pert.conic) if "Q_front" in d else torch.zeros_like(c1)
    k2 = d["Q_back"].reshape(()) * (1 + pert.conic)
    return c1, c2, n, k1, k2


def as_built_surfaces(camera: Camera, design: Design, pert: Perturbations, i: int = 0,
                      wavelength_um: float | None = None):
    """The surfaces of as-built lens ``i`` for the exact ray trace (:func:`lenssim.optics.exact_wavefront.opd`): perturbed
    curvatures, conics and index, the asphere decentred and tilted against the front, the whole lens tilted. (The
    figure error is not a surface of the trace.) The despace goes into the design's ``focus_shift_um``
    (:func:`as_built_design`)."""
    lam = camera.spectrum.wavelengths_um[0] if wavelength_um is None else wavelength_um
    c1, c2, n, k1, k2 = _perturbed(camera, design, pert[i], lam)
    front, back = camera.lens.surfaces(design.to(torch.float64), lam)
    lt = pert.lens_tilt_rad[i]
    at = pert.asphere_tilt_rad[i] + lt

    def tilt_deg(t):  # an axis tipped towards (tx, ty, 1) is a rotation of -ty about x, then tx about y
        return (-math.degrees(float(t[1])), math.degrees(float(t[0])))

    dec = pert.asphere_decentre_mm[i]
    front = dataclasses.replace(front, curvature=float(c1[0]), conic=float(k1[0]), n_after=float(n[0]),
                                tilt_deg=tilt_deg(lt))
    back = dataclasses.replace(back, curvature=float(c2[0]), conic=float(k2[0]), tilt_deg=tilt_deg(at),
                               decentre_mm=(float(dec[0]), float(dec[1])))
    return [front, back]


def image_plane_mm(camera: Camera, design: Design, pert: Perturbations) -> torch.Tensor:
    """The image plane's distance (mm) from each as-built lens, ``(N,)``: the nominal image distance, or with
    ``focus_compensated`` the lens's own paraxial focus at the spectrum's reference wavelength, plus the design's
    focus shift and the despace."""
    lens = camera.lens
    d = design.to(torch.float64)
    base = torch.full_like(pert.despace_mm, lens.image_distance_mm)
    if pert.tolerances.focus_compensated:
        c1, c2, n, _, _ = _perturbed(camera, d, pert, camera.spectrum.reference_um)
        base = 1 / ((n - 1) * (c1 - c2))
    return base + float(d["focus_shift_um"]) * 1e-3 + pert.despace_mm


def as_built_design(camera: Camera, design: Design, pert: Perturbations, i: int = 0) -> Design:
    """``design`` with the ``focus_shift_um`` that puts the ray trace's image plane where lens ``i``'s is
    (:func:`image_plane_mm`)."""
    d = design.to(torch.float64)
    t = float(image_plane_mm(camera, d, pert[i])[0])
    return d.replace(focus_shift_um=(t - camera.lens.image_distance_mm) * 1e3)


IMAGE_TILT_SIGN = 1.0
"""A lens whose axis is tipped towards ``(tau, 1)`` focuses the image point ``r`` (mm) ``tau . r`` closer than the
sensor: the sensor lies ``IMAGE_TILT_SIGN * tau . r`` beyond its focus (the geometry of a tipped plane; tested
against the ray trace)."""


def as_built_coefficients(camera: Camera, design: Design, pert: Perturbations, alpha_deg, azimuth_deg, *,
                          wavelength_um: float | None = None) -> torch.Tensor:
    """Wavefront coefficients (waves at ``wavelength_um``, default every wavelength of the camera's spectrum) of
    :data:`AS_BUILT_TERMS` for ``N`` as-built lenses at field points ``(alpha_deg, azimuth_deg)`` ``(F,)``:
    float64 ``(N, F, K, 6)`` (``K`` = 1 with ``wavelength_um``)."""
    lens = camera.lens
    lams = camera.spectrum.wavelengths_um if wavelength_um is None else (wavelength_um,)
    alpha = tensor_of(alpha_deg, torch.float64).reshape(-1)
    phi = torch.deg2rad(tensor_of(azimuth_deg, torch.float64).reshape(-1))
    d = design.to(torch.float64)
    y = lens.pupil_radius_mm
    N, F = len(pert), alpha.numel()
    ubar = torch.stack([torch.tan(torch.deg2rad(alpha)), torch.zeros_like(alpha)], dim=-1)[None]  # (1, F, 2)
    lt = _rot(pert.lens_tilt_rad, phi)
    at = _rot(pert.asphere_tilt_rad, phi) + lt
    dec = _rot(pert.asphere_decentre_mm, phi)
    # the image plane: nominal distance + design focus shift + despace, tilted with the lens
    r_img = lens.image_distance_mm * torch.tan(torch.deg2rad(alpha))  # (F,) mm, along the point's r axis
    t_img0 = image_plane_mm(camera, d, pert)[:, None]  # (N, 1)
    fig = figure_heights_mm(camera, d, pert)  # (N, 6): power, astig_0, astig_45, coma_x, coma_y, spherical
    out = []
    for lam in lams:
        c1, c2, n, k1, k2 = _perturbed(camera, d, pert, lam)
        c1, c2, n, k1, k2 = (v[:, None] for v in (c1, c2, n, k1, k2))  # (N, 1)
        h = y
        u1 = -h * c1 * (n - 1) / n
        A = (h * c1, n * (h * c2 + u1))
        k = (-h * (u1 / n), -h * ((n * u1 - h * c2 * (1 - n)) - u1 / n))
        asph = ((n - 1) * k1 * c1**3, (1 - n) * k2 * c2**3)
        dinv = (1 / n - 1, 1 - 1 / n)
        theta1 = ubar - lt  # (N, F, 2) the chief ray in the front surface's frame (height 0)
        hb = (torch.zeros_like(dec), -dec)
        Abar1 = theta1
        ug = theta1 / n[..., None] + lt  # inside the glass, in the lens's frame
        Abar2 = n[..., None] * (c2[..., None] * hb[1] + ug - at)
        S1 = sum(A[j] ** 2 * k[j] + asph[j] * h**4 for j in range(2))  # (N, 1)
        S2 = sum((A[j] * k[j])[..., None] * Ab + (asph[j] * h**3)[..., None] * hb[j]
                 for j, Ab in enumerate((Abar1, Abar2)))  # (N, F, 2)
        dyad = sum(k[j][..., None, None] * Ab[..., :, None] * Ab[..., None, :]
                   + (asph[j] * h**2)[..., None, None] * hb[j][..., :, None] * hb[j][..., None, :]
                   for j, Ab in enumerate((Abar1, Abar2)))  # (N, F, 2, 2)
        # Petzval: the Lagrange invariant is the same at both surfaces, h theta1 (the chief ray against the lens's axis)
        S4 = -(h**2) * (theta1**2).sum(-1) * (c1 * dinv[0] + c2 * dinv[1])  # (N, F)
        t_f = 1 / ((n - 1) * (c1 - c2))  # (N, 1) the perturbed focus (object at infinity)
        t_img = t_img0 + IMAGE_TILT_SIGN * lt[..., 0] * r_img[None]  # (N, F): the sensor tilted against the lens
        w020 = (t_img - t_f) * y**2 / (2 * t_f * t_img)
        q = 0.25 * (dyad[..., 0, 0] + dyad[..., 1, 1] + S4) + w020
        # the figure error of the back surface: W = (1 - n) dz, in each field point's frame
        g = (1 - n)  # (N, 1)
        p_fig = g * (2 * _SQ3 * fig[:, 0:1] - 6 * _SQ5 * fig[:, 5:6])  # rho^2
        s_fig = g * 6 * _SQ5 * fig[:, 5:6]  # rho^4
        M = torch.stack([torch.stack([fig[:, 1], fig[:, 2]], -1), torch.stack([fig[:, 2], -fig[:, 1]], -1)], -2) * _SQ6
        cph, sph = torch.cos(phi), torch.sin(phi)
        R = torch.stack([torch.stack([cph, -sph], -1), torch.stack([sph, cph], -1)], -2)  # (F, 2, 2): point -> lens
        Mp = R.transpose(-1, -2)[None] @ M[:, None] @ R[None]  # (N, F, 2, 2)
        cp = _rot(fig[:, 3:5], phi) * 3 * _SQ8  # (N, F, 2)
        coef = torch.stack([
            (S1 / 8 + s_fig).expand(N, F),
            S2[..., 0] / 2 + g * cp[..., 0],
            S2[..., 1] / 2 + g * cp[..., 1],
            dyad[..., 0, 0] / 2 + q + p_fig + g * Mp[..., 0, 0],
            dyad[..., 0, 1] + 2 * g * Mp[..., 0, 1],
            dyad[..., 1, 1] / 2 + q + p_fig + g * Mp[..., 1, 1],
        ], dim=-1)
        out.append(coef / (lam * 1e-3))
    return torch.stack(out, dim=-2)


def nominal_as_built_coefficients(camera: Camera, design: Design, alpha_deg, azimuth_deg, *,
                                  wavelength_um: float | None = None) -> torch.Tensor:
    """:func:`as_built_coefficients` of the nominal lens (every error zero): ``(1, F, K, 6)``."""
    from ..model.tolerances import Tolerances

    return as_built_coefficients(camera, design, Tolerances().sample(1, seed=0), alpha_deg, azimuth_deg,
                                 wavelength_um=wavelength_um)
