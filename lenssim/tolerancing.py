"""The criteria of as-built lenses: every OTF criterion over the field, restored with their own PSFs (calibrated) and
with the nominal lens's (``mse_r_nominal``), in bounded-memory chunks (issue 19).

An as-built lens has no rotational symmetry, so its field is sampled at every field angle of the lens and at the
azimuths :data:`AZIMUTHS_DEG` (the axis once): a field average is the mean over each angle's azimuths, then over the
angles, as the nominal lens's is over its angles. Its OTFs come from the general (non-symmetric) path,
:func:`lenssim.optics.psf_bank.otf_quarter_pair`, and a criterion's full-plane mean is the mean of its two quarter
planes. The nominal lens's OTF at the same field point and FFT size is the reference of criteria that need one.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from .criteria import CRITERIA, OTFContext, otf_criteria, quarter_weights
from .model.camera import Camera
from .model.design import Design
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .model.tolerances import Perturbations, Tolerances
from .optics.as_built import AS_BUILT_TERMS, as_built_coefficients, field_points
from .optics.cost import slope_departure_cost
from .optics.exact_wavefront import pupil_quadrature
from .optics.image_model import image_psd_quarter, noise_variance
from .optics.psf_bank import fft_size, otf_quarter_pair, otf_quarter_spectrum
from .optics.aberrations import pupil_monomials
from .torch_utils import HOST, chunk_budget_bytes, tensor_of
from .validate import NumericalError, check_memory

__all__ = ["AZIMUTHS_DEG", "as_built_criteria", "AS_BUILT_CRITERIA"]

AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)
"""Azimuths (deg) at which an as-built lens's field is sampled, at each field angle."""


def AS_BUILT_CRITERIA() -> tuple[str, ...]:
    """The criteria an as-built evaluation reports: every OTF criterion (those comparing with the nominal lens
    included), ``rms_w`` and ``cost``."""
    return otf_criteria(reference=True) + ("rms_w", "cost")


def _field_mean(v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Mean over field points ``(..., F)``: over each angle's azimuths, then over the angles."""
    out = []
    for a in torch.unique(alpha):
        out.append(v[..., alpha == a].mean(dim=-1))
    return torch.stack(out, dim=-1).mean(dim=-1)


def _otf(camera, coeffs, n, oversample, numerics, symmetric):
    """The two quarter planes ``(B, 2, m/2+1, m/2+1)``: of the general path, or for mirror-symmetric wavefronts the
    fast quarter bank twice (the two quarters are equal)."""
    if symmetric:
        H = otf_quarter_spectrum(camera, coeffs, n, oversample=oversample, numerics=numerics, terms=AS_BUILT_TERMS)
        return torch.stack([H, H], dim=1)
    return otf_quarter_pair(camera, coeffs, n, oversample=oversample, numerics=numerics, terms=AS_BUILT_TERMS)


def as_built_criteria(camera: Camera, design: Design, pert: Perturbations, snr_db, *, rho0: float,
                      psd_model: str = "discrete", numerics: Numerics = DEFAULT_NUMERICS, alpha_deg=None,
                      azimuths_deg=AZIMUTHS_DEG, dtype=torch.float32, device=None,
                      progress: Callable[[int], None] | None = None) -> dict:
    """Criteria of ``N`` as-built lenses of one design: ``{name: (N, S)}`` (``(N,)`` for a criterion that does not
    depend on the SNR) for the names of :func:`AS_BUILT_CRITERIA`, float64, field averages; ``mse_r`` is the lens
    restored with its own PSFs (calibrated), ``mse_r_nominal`` with the nominal lens's. Also ``snr_db`` ``(S,)``,
    ``alpha_deg`` and ``azimuth_deg`` ``(F,)`` (the field points) and ``fft_size`` ``(N, F)``.

    ``alpha_deg``: field angles (default the lens's). Rotationally symmetric lenses (no decentre, tilt or
    non-symmetric figure error: :attr:`Perturbations.rotationally_symmetric`) take one azimuth per angle and the
    mirror-symmetric OTF bank, chosen automatically. A colour camera is evaluated channel by channel and averaged,
    as :func:`lenssim.metrics.evaluate` does. ``progress(k)`` after each chunk of ``k`` OTFs.
    """
    if camera.channels:
        parts = [as_built_criteria(c, design, pert, snr_db, rho0=rho0, psd_model=psd_model, numerics=numerics,
                                   alpha_deg=alpha_deg, azimuths_deg=azimuths_deg, dtype=dtype, device=device,
                                   progress=progress)
                 for c in camera.with_quadrature(numerics.spectral_tol).channel_cameras()]
        out = dict(parts[0])
        for k in AS_BUILT_CRITERIA():
            out[k] = torch.stack([p[k] for p in parts]).mean(dim=0)
        out["fft_size"] = torch.stack([p["fft_size"] for p in parts]).amax(dim=0)
        return out
    d64 = design.to(torch.float64)
    d64.floats()  # one design
    camera.lens.check_design(d64)
    symmetric = pert.rotationally_symmetric  # the mirror-symmetric fast path, one azimuth per angle
    al, az = field_points(camera.lens.field_angles_deg if alpha_deg is None else alpha_deg,
                          azimuths_deg[:1] if symmetric else azimuths_deg)
    N, F, K = len(pert), al.numel(), len(camera.spectrum)
    c = as_built_coefficients(camera, d64, pert, al, az)  # (N, F, K, 6)
    c0 = as_built_coefficients(camera, d64, Tolerances().sample(1, seed=0), al, az)[0]  # (F, K, 6) the nominal
    if not bool(torch.isfinite(c).all()):
        raise NumericalError("an as-built wavefront is not finite; no result is reported")
    flat = c.reshape(N * F, K, len(AS_BUILT_TERMS))
    n_lens = fft_size(camera, flat, numerics, terms=AS_BUILT_TERMS).reshape(N, F)
    n_nom = fft_size(camera, c0, numerics, terms=AS_BUILT_TERMS)  # (F,)
    sizes = torch.maximum(n_lens, n_nom[None])  # the lens and its reference on one grid
    snr = tensor_of(snr_db, torch.float64).reshape(-1)
    sigma2 = noise_variance(snr).reshape(-1)
    S = snr.numel()
    names = otf_criteria(reference=True)
    per = {k: torch.empty((N, F, S) if CRITERIA[k].per_snr else (N, F), dtype=torch.float64, device=HOST)
           for k in names}
    oversample = numerics.oversample
    flat_sizes = sizes.reshape(-1)
    point = torch.arange(F, device=HOST).repeat(N)
    for n in torch.unique(flat_sizes).tolist():
        idx = torch.nonzero(flat_sizes == n).flatten()
        m = n * oversample
        psd_q = image_psd_quarter(m, rho0, model=psd_model, dtype=dtype, device=device)
        weights = quarter_weights(m, psd_q.dtype, psd_q.device)
        pw = psd_q * weights
        per_psf = 2 * 4 * m * m * (2 * dtype.itemsize)  # lens + reference, 2 quarters
        check_memory(per_psf, f"one as-built OTF of {m} x {m} samples", setting="max_fft_size")
        step = max(1, int(chunk_budget_bytes(device or HOST, numerics.chunk_bytes) // per_psf))
        nominal = {}
        for start in range(0, idx.numel(), step):
            sel = idx[start:start + step]
            H = _otf(camera, flat[sel].to(dtype=dtype, device=device), n, oversample, numerics, symmetric)
            pts = point[sel]
            need = sorted(set(pts.tolist()) - set(nominal))
            if need:
                H0 = _otf(camera, c0[need].to(dtype=dtype, device=device), n, oversample, numerics, symmetric)
                nominal.update({f: H0[i] for i, f in enumerate(need)})
            ref = torch.stack([nominal[f] for f in pts.tolist()])
            B = sel.numel()
            Hf, Rf = H.reshape(2 * B, *H.shape[-2:]), ref.reshape(2 * B, *H.shape[-2:])
            ctx = OTFContext(Hf, Hf.real.square() + Hf.imag.square(), psd_q, weights, pw, sigma2.to(psd_q.device), n,
                             camera, numerics, reference=Rf)
            for k in names:
                v = CRITERIA[k].from_otf(ctx).cpu()
                v = v.reshape(B, 2, *v.shape[1:]).mean(dim=1)
                per[k].reshape(N * F, *per[k].shape[2:])[sel] = v
            if progress is not None:
                progress(B)
    out = {}
    for k in names:
        v = per[k].movedim(1, -1) if CRITERIA[k].per_snr else per[k]  # (N, S, F) or (N, F)
        out[k] = _field_mean(v, al)
    # RMS_W as the paper's (no piston removed): sqrt of the field mean of the pupil mean of W^2, per wavelength
    rr, rt, w = pupil_quadrature()
    basis = pupil_monomials(rr, rt, AS_BUILT_TERMS)  # (6, P)
    spec = camera.spectrum
    ms = sum(wk * ((((c[..., k, :] * (lam / spec.reference_um)) @ basis) ** 2) * w).sum(-1)
             for k, (lam, wk) in enumerate(zip(spec.wavelengths_um, spec.weights)))  # (N, F) waves^2
    out["rms_w"] = torch.sqrt(_field_mean(ms, al))
    out["cost"] = slope_departure_cost(camera.lens, d64).reshape(()).expand(N).clone()
    out["snr_db"], out["alpha_deg"], out["azimuth_deg"], out["fft_size"] = snr, al, az, sizes
    for k in AS_BUILT_CRITERIA():
        if not bool(torch.isfinite(out[k]).all()):
            raise NumericalError(f"as-built criterion {k} is not finite (numerical breakdown); no result is reported")
    return out
