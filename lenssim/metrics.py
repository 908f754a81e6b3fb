"""The paper's three design criteria and the industrial cost, for batches of designs.

For each field angle ``alpha`` and noise level ``sigma_w^2 = 10^(-SNR/10)`` (Section 2.3)::

    P_es(f) = sigma_w^2 + |1 - H(f)|^2 P_x(f)                 sensor-image error PSD
    P_er(f) = (|H(f)|^2 / sigma_w^2 + 1 / P_x(f))^-1          Wiener-restored error PSD
    MSE_s/r(alpha) = integral over f in [-1/2, 1/2)^2 of P_es/er  (mean over the N x N DFT grid)
    MSE_S/R = < MSE_s/r(alpha) >_alpha,   RMS_W = sqrt(< RMS_w(alpha)^2 >_alpha)

(``P_es`` is the derivation's ``|1 - H|^2 P_x``; the paper prints ``P_x^-1``, a typo.)
``H`` is the OTF of the pixel-sampled PSF (:func:`lenssim.psf_bank.otf_quarter`), ``P_x`` the image
model of :mod:`lenssim.image_model`. MSE is per pixel, relative to the unit signal variance.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from .aberrations import field_rms_wavefront, rms_wavefront, wavefront_coefficients
from .cost import DEFAULT_COST_POINTS, slope_departure_cost
from .image_model import PAPER_RHO0, PAPER_SNR_DB, image_psd_quarter, noise_variance
from .lens import ThinLens, as_tensor
from .psf_bank import fft_size as choose_fft_size
from .psf_bank import otf_quarter

__all__ = ["mse_from_otf_quarter", "mse_bank", "evaluate"]

_CHUNK_BYTES = 32 * 2**20  # measured fastest on a 2-core CPU (cache-sized chunks)
DEFAULT_FILL = 0.5
DEFAULT_MIN_SIZE = 256
DEFAULT_OVERSAMPLE = 2


def _quarter_weights(n: int, dtype, device) -> torch.Tensor:
    w = torch.full((n // 2 + 1,), 2.0, dtype=dtype, device=device)
    w[0] = 1.0
    w[-1] = 1.0
    return w[:, None] * w[None, :] / float(n * n)


def mse_from_otf_quarter(H: torch.Tensor, psd_quarter: torch.Tensor, sigma2: torch.Tensor):
    """``(MSE_s, MSE_r)`` per OTF, each ``(B, S)`` float64, from quarter-plane OTFs ``(B, n/2+1, n/2+1)``.

    ``psd_quarter`` is ``P_x`` on the same quarter plane; ``sigma2`` ``(S,)`` the noise variances.
    """
    n = 2 * (H.shape[-1] - 1)
    pw = psd_quarter * _quarter_weights(n, psd_quarter.dtype, psd_quarter.device)
    if H.requires_grad:  # differentiable path (no in-place or out= buffers)
        H2 = H.real.square() + H.imag.square()
        blur = ((H2 - 2 * H.real + 1) * pw).sum(dim=(-2, -1))
        mse_s = sigma2.to(blur.dtype)[None, :] + blur[:, None]
        H2psd = H2 * psd_quarter
        mse_r = torch.stack([(pw / (H2psd + s2)).sum(dim=(-2, -1)) * s2 for s2 in sigma2.to(H2.dtype)], dim=-1)
        return mse_s, mse_r
    H2 = H.real.square().add_(H.imag.square())
    E = (H2 - 2 * H.real).add_(1).mul_(pw)  # |1 - H|^2 P_x w
    blur = E.sum(dim=(-2, -1)).to(torch.float64)
    del E
    sig = sigma2.to(torch.float64)
    mse_s = sig[None, :] + blur[:, None]
    H2psd = H2.mul_(psd_quarter)
    tmp = torch.empty_like(H2psd)
    mse_r = torch.stack([torch.div(pw, torch.add(H2psd, s2, out=tmp), out=tmp).sum(dim=(-2, -1)).to(torch.float64)
                         * float(s2) for s2 in sigma2.to(psd_quarter.dtype)], dim=-1)
    return mse_s, mse_r


def mse_bank(lens: ThinLens, coeffs: torch.Tensor, sizes: torch.Tensor, snr_db=PAPER_SNR_DB, *,
             rho0: float = PAPER_RHO0, psd_model: str = "discrete", oversample: int = DEFAULT_OVERSAMPLE,
             chunk_bytes: int = _CHUNK_BYTES, progress: Callable[[int], None] | None = None):
    """``MSE_s`` and ``MSE_r`` ``(P, S)`` (float64) for field-axis coefficient sets ``(P, 4)``.

    PSFs are grouped by FFT size ``sizes`` ``(P,)`` and processed in chunks of at most
    ``chunk_bytes`` of working memory, so memory stays bounded whatever ``P``. The frequency
    integrals use ``oversample`` x finer grids than the FFT (see :func:`lenssim.psf_bank.otf_quarter`):
    the Wiener-error integrand is not band-limited and needs them. ``progress`` is
    called with the number of PSFs finished after each chunk.
    """
    if coeffs.ndim != 2 or coeffs.shape[-1] != 4:
        raise ValueError(f"coeffs has shape {tuple(coeffs.shape)}: expected (P, 4)")
    sigma2 = noise_variance(snr_db).reshape(-1).to(coeffs.device)
    P, S = coeffs.shape[0], sigma2.numel()
    out_s = torch.empty(P, S, dtype=torch.float64, device=coeffs.device)
    out_r = torch.empty_like(out_s)
    sizes = sizes.reshape(-1).cpu()
    for n in torch.unique(sizes).tolist():
        idx = torch.nonzero(sizes == n).flatten().to(coeffs.device)
        m = n * oversample
        psd_q = image_psd_quarter(m, rho0, model=psd_model, dtype=coeffs.dtype, device=coeffs.device)
        per_psf = 6 * max(n, m) * (max(n, m) // 2 + 1) * (2 * coeffs.element_size())
        step = max(1, int(chunk_bytes // per_psf))
        for start in range(0, idx.numel(), step):
            sel = idx[start:start + step]
            H = otf_quarter(lens, coeffs[sel], n, oversample=oversample)
            ms, mr = mse_from_otf_quarter(H, psd_q, sigma2)
            out_s[sel], out_r[sel] = ms, mr
            if progress is not None:
                progress(sel.numel())
    return out_s, out_r


def evaluate(lens: ThinLens, s, Q, snr_db=PAPER_SNR_DB, *, rho0: float = PAPER_RHO0, psd_model: str = "discrete",
             fft_size: int | None = None, fill: float = DEFAULT_FILL, margin_px: int = 16,
             min_size: int = DEFAULT_MIN_SIZE, oversample: int = DEFAULT_OVERSAMPLE,
             cost_points: int = DEFAULT_COST_POINTS, dtype=torch.float32, device=None,
             chunk_bytes: int = _CHUNK_BYTES, progress: Callable[[int], None] | None = None) -> dict:
    """All metrics for designs ``(s, Q)`` broadcast to shape ``(*)``.

    Returns a dict of tensors (float64 for the metrics) with ``A`` field angles and ``S`` SNRs:

    ``rms_w`` ``(*)`` and ``rms_w_alpha`` ``(*, A)`` (waves, no piston removal, as the paper);
    ``rms_w_piston_removed`` ``(*)``; ``mse_s``, ``mse_r`` ``(*, S)`` and ``mse_s_alpha``,
    ``mse_r_alpha`` ``(*, A, S)`` (per pixel, unit signal variance); ``cost`` ``(*)`` (C_a, slope
    units); ``fft_size`` ``(*, A)`` (the FFT size used for each PSF); ``snr_db`` ``(S,)``;
    ``alpha_deg`` ``(A,)``. ``fft_size`` overrides the automatic choice.
    """
    s64, Q64 = torch.broadcast_tensors(as_tensor(s, dtype=torch.float64, device=device),
                                       as_tensor(Q, dtype=torch.float64, device=device))
    lens.check_design(s64, Q64)
    shape = s64.shape
    coeffs64 = wavefront_coefficients(lens, s64, Q64)  # (*, A, 4)
    A = coeffs64.shape[-2]
    flat = coeffs64.reshape(-1, 4)
    if fft_size is None:
        sizes = choose_fft_size(lens, flat, fill=fill, margin_px=margin_px, min_size=min_size)
    else:
        if not (isinstance(fft_size, int) and fft_size >= 16 and fft_size % 2 == 0):
            raise ValueError(f"fft_size={fft_size!r} is not allowed: an even integer >= 16")
        sizes = torch.full((flat.shape[0],), fft_size, dtype=torch.int64)
    snr = torch.as_tensor(snr_db, dtype=torch.float64).reshape(-1)
    ms, mr = mse_bank(lens, flat.to(dtype), sizes, snr, rho0=rho0, psd_model=psd_model,
                      oversample=oversample, chunk_bytes=chunk_bytes, progress=progress)
    S = snr.numel()
    ms = ms.reshape(shape + (A, S))
    mr = mr.reshape(shape + (A, S))
    return {
        "rms_w": field_rms_wavefront(coeffs64),
        "rms_w_alpha": rms_wavefront(coeffs64),
        "rms_w_piston_removed": field_rms_wavefront(coeffs64, piston_removed=True),
        "mse_s": ms.mean(dim=-2),
        "mse_r": mr.mean(dim=-2),
        "mse_s_alpha": ms,
        "mse_r_alpha": mr,
        "cost": slope_departure_cost(lens, s64, Q64, cost_points),
        "fft_size": sizes.reshape(shape + (A,)),
        "snr_db": snr,
        "alpha_deg": lens.field_angles(dtype=torch.float64),
    }
