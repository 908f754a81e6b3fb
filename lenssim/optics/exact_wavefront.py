"""How good is third order here? The wavefront of the thin conic lens from an exact ray trace.

The transverse ray aberrations of an exact trace through the real surfaces
(:func:`lenssim.optics.raytrace.transverse_aberration`) relate to the wavefront by
``eps = -(t / y) grad_rho W`` (``t`` the image distance): the relation the third-order model itself
uses, exact to first order in the aberration (``(y / t)^2 ~ 0.6%`` at f/6.25). ``W`` is fitted to
the rays of a polar pupil grid by least squares as a polynomial of degree <= 8 in the pupil: the
monomials ``rho^2a rho_r^b`` of :data:`EXACT_TERMS` (all even in ``rho_t``, as the lens's symmetry
requires; the tilt ``rho_r`` carries the real distortion that third order lacks). The criteria
then follow from the same OTF machinery as the third-order ones (:func:`exact_criteria`).
"""

from __future__ import annotations

import math

import torch

from .aberrations import Term, monomial_gradients
from ..model.camera import Camera
from ..model.design import Design
from ..metrics import otf_criteria_bank
from ..model.numerics import DEFAULT_NUMERICS, Numerics
from .psf_bank import fft_size
from .raytrace import transverse_aberration

__all__ = ["EXACT_TERMS", "exact_wavefront_coefficients", "exact_criteria"]

EXACT_TERMS = tuple(Term(f"E{a}{b}", a, b) for a in range(5) for b in range(9) if 0 < 2 * a + b <= 8)
"""Pupil monomials ``rho^2a rho_r^b`` up to degree 8 (no piston)."""


def exact_wavefront_coefficients(camera: Camera, design: Design, alpha_deg: float, wavelength_um: float | None = None,
                                 *, n_r: int = 24, n_t: int = 48) -> torch.Tensor:
    """Coefficients (waves at ``wavelength_um``, default the spectrum's first) of :data:`EXACT_TERMS` fitted to
    an exact ray trace at field angle ``alpha_deg``; float64 ``(T,)``."""
    lens = camera.lens
    lam = camera.spectrum.wavelengths_um[0] if wavelength_um is None else wavelength_um
    d = design.to(torch.float64)
    r = torch.linspace(1.0 / n_r, 1.0, n_r, dtype=torch.float64)
    t = torch.arange(n_t, dtype=torch.float64) * (2 * math.pi / n_t)
    R, T = torch.meshgrid(r, t, indexing="ij")
    rho_r, rho_t = (R * torch.cos(T)).flatten(), (R * torch.sin(T)).flatten()
    eps_r, eps_t = transverse_aberration(lens, d, float(alpha_deg), rho_r, rho_t, wavelength_um=lam)
    gr, gt = monomial_gradients(rho_r, rho_t, EXACT_TERMS)
    t_img = lens.image_distance_mm + float(d["focus_shift_um"]) * 1e-3
    k = -t_img / lens.pupil_radius_mm
    A = torch.cat([k * gr.T, k * gt.T])  # (2P, T): mm of ray aberration per mm of wavefront coefficient
    b = torch.cat([eps_r, eps_t])[:, None]
    c_mm = torch.linalg.lstsq(A, b).solution[:, 0]
    return c_mm / (lam * 1e-3)


def exact_criteria(camera: Camera, design: Design, snr_db, *, rho0: float,
                   numerics: Numerics = DEFAULT_NUMERICS) -> dict:
    """Every registered OTF criterion (field averages, ``(S,)`` float64, ``()`` for one that does not depend on the
    SNR) of one design with the exact (ray-traced, fitted) wavefront at each field angle, one wavelength (the
    spectrum's first); also ``NAME_alpha`` ``(A, S)`` (``(A,)``) and ``fft_size`` ``(A,)``."""
    if len(camera.spectrum) != 1 or camera.channels:
        raise ValueError("exact_criteria takes a one-wavelength camera")
    lam = camera.spectrum.wavelengths_um[0]
    c = torch.stack([exact_wavefront_coefficients(camera, design, a, lam) for a in camera.lens.field_angles_deg])
    sizes = fft_size(camera, c[:, None], numerics, terms=EXACT_TERMS)
    per = otf_criteria_bank(camera, c[:, None].to(torch.float32), sizes, snr_db, rho0=rho0, numerics=numerics,
                            terms=EXACT_TERMS)
    out = {}
    for k, v in per.items():
        out[k], out[f"{k}_alpha"] = v.mean(dim=0), v
    out["fft_size"] = sizes
    return out
