"""How good is third order here? The wavefront of the thin conic lens from an exact ray trace.

The transverse ray aberrations of an exact trace through the real surfaces
(:func:`lenssim.raytrace.transverse_aberration`) relate to the wavefront by
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
from .camera import Camera
from .criteria import CRITERIA, quarter_weights
from .design import Design
from .image_model import image_psd_quarter, noise_variance
from .numerics import DEFAULT_NUMERICS, Numerics
from .paper import PAPER_RHO0, PAPER_SNR_DB
from .psf_bank import _polar_probe, nice_fft_size, otf_quarter
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


def _fft_size(camera: Camera, coeffs: torch.Tensor, lam: float, numerics: Numerics) -> int:
    rr, rt = _polar_probe()
    gr, gt = monomial_gradients(rr, rt, EXACT_TERMS)
    G = float(torch.sqrt((coeffs @ gr) ** 2 + (coeffs @ gt) ** 2).max())
    n_phase = G / (0.5 * numerics.fill) / camera.pupil_radius_px(1, lam)
    n_psf = 2 * camera.geometric_radius_px(G, lam) / numerics.fill + numerics.margin_px
    return nice_fft_size(int(math.ceil(max(n_phase, n_psf, numerics.min_size))))


def exact_criteria(camera: Camera, design: Design, snr_db=PAPER_SNR_DB, *, rho0: float = PAPER_RHO0,
                   numerics: Numerics = DEFAULT_NUMERICS) -> dict:
    """The OTF criteria (``mse_s``, ``mse_r``; field averages, ``(S,)`` float64) of one design with the exact
    (ray-traced, fitted) wavefront at each field angle, one wavelength (the spectrum's first); also
    ``NAME_alpha`` ``(A, S)`` and ``fft_size`` ``(A,)``."""
    if len(camera.spectrum) != 1 or camera.channels:
        raise ValueError("exact_criteria takes a one-wavelength camera")
    lam = camera.spectrum.wavelengths_um[0]
    sigma2 = noise_variance(snr_db).reshape(-1)
    names = [k for k, c in CRITERIA.items() if c.from_otf is not None]
    per = {k: [] for k in names}
    sizes = []
    for a in camera.lens.field_angles_deg:
        c = exact_wavefront_coefficients(camera, design, a, lam)
        n = _fft_size(camera, c, lam, numerics)
        sizes.append(n)
        m = n * numerics.oversample
        H = otf_quarter(c[None].to(torch.float32), n, pupil_radius_px=camera.pupil_radius_px(n, lam),
                        oversample=numerics.oversample, supersample=numerics.supersample, terms=EXACT_TERMS)
        psd = image_psd_quarter(m, rho0, dtype=torch.float32)
        pw = psd * quarter_weights(m, psd.dtype, psd.device)
        H2 = H.real.square() + H.imag.square()
        for k in names:
            per[k].append(CRITERIA[k].from_otf(H, H2, psd, pw, sigma2)[0])
    out = {}
    for k in names:
        v = torch.stack(per[k])
        out[k], out[f"{k}_alpha"] = v.mean(dim=0), v
    out["fft_size"] = torch.tensor(sizes)
    return out
