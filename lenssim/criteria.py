"""The design criteria, as a registry: name -> how it is computed, its label and its unit.

Two kinds (Section 2.3 of the paper):

* **OTF criteria**, computed per field angle from the quarter-plane OTF ``H`` of each PSF and the
  image model ``P_x``, then averaged over the field (``sigma_w^2 = 10^(-SNR/10)`` per SNR)::

      mse_s:  P_es(f) = sigma_w^2 + |1 - H(f)|^2 P_x(f)             sensor-image error
      mse_r:  P_er(f) = (|H(f)|^2 / sigma_w^2 + 1 / P_x(f))^-1      Wiener-restored error
      MSE = integral over f in [-1/2, 1/2)^2 (mean over the DFT grid), per pixel, unit signal variance

  (``P_es`` is the derivation's ``|1 - H|^2 P_x``; the paper prints ``P_x^-1``, a typo.)
* **design criteria**, computed from the design and its wavefront coefficients directly:
  ``rms_w`` (the paper's ``RMS_W = sqrt(<RMS_w(alpha)^2>_alpha)``, no piston removal) and
  ``cost`` (``C_a``, :mod:`lenssim.cost`).

A new criterion is one entry in :data:`CRITERIA` and its function here; :func:`lenssim.metrics.evaluate`,
sweeps, optima, the trade-off, figures and the command line read the registry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from .aberrations import rms_wavefront
from .cost import slope_departure_cost

__all__ = ["Criterion", "CRITERIA", "validate_criterion", "otf_criteria", "quarter_weights", "wavefront_rms_per_field"]


@dataclass(frozen=True)
class Criterion:
    """A design criterion (smaller is better).

    ``from_otf(H, H2, psd, pw, sigma2) -> (B, S)`` (float64) for OTF criteria: ``H`` quarter-plane
    OTFs ``(B, m/2+1, m/2+1)``, ``H2 = |H|^2``, ``psd`` the image model on the same grid, ``pw`` it
    times the quarter-plane integration weights, ``sigma2`` ``(S,)`` noise variances.
    ``from_design(camera, design, coeffs, numerics) -> (*)`` for design criteria (``coeffs``
    ``(*, A, K, T)`` in waves, design in float64).
    """

    name: str
    label: str
    description: str
    units: str
    per_snr: bool
    from_otf: Callable | None = None
    from_design: Callable | None = None


def quarter_weights(n: int, dtype, device) -> torch.Tensor:
    """Weights ``(n/2+1, n/2+1)`` that turn a quarter-plane sum into the mean over the ``n x n`` DFT grid
    of a function even in both axes."""
    w = torch.full((n // 2 + 1,), 2.0, dtype=dtype, device=device)
    w[0] = 1.0
    w[-1] = 1.0
    return w[:, None] * w[None, :] / float(n * n)


def _mse_s(H, H2, psd, pw, sigma2):
    blur = ((H2 - 2 * H.real + 1) * pw).sum(dim=(-2, -1)).to(torch.float64)  # |1 - H|^2 P_x
    return sigma2.to(torch.float64)[None, :] + blur[:, None]


def _mse_r(H, H2, psd, pw, sigma2):
    H2psd = H2 * psd
    if H2psd.requires_grad:
        return torch.stack([(pw / (H2psd + s2)).sum(dim=(-2, -1)).to(torch.float64) * float(s2)
                            for s2 in sigma2.to(psd.dtype)], dim=-1)
    tmp = torch.empty_like(H2psd)  # one buffer for every SNR (memory of the sweep's chunks)
    return torch.stack([torch.div(pw, torch.add(H2psd, s2, out=tmp), out=tmp).sum(dim=(-2, -1)).to(torch.float64)
                        * float(s2) for s2 in sigma2.to(psd.dtype)], dim=-1)


def wavefront_rms_per_field(camera, coeffs: torch.Tensor, piston_removed: bool = False) -> torch.Tensor:
    """``RMS_w(alpha)`` ``(*, A)`` in waves at the spectrum's reference wavelength, from ``(*, A, K, T)``.

    Over a spectrum: the weighted mean square over the wavelengths (``W_k lambda_k / lambda_ref`` in
    reference waves).
    """
    spec = camera.spectrum
    if len(spec) == 1:
        return rms_wavefront(coeffs[..., 0, :], piston_removed)
    ms = sum(w * rms_wavefront(coeffs[..., k, :] * (lam / spec.reference_um), piston_removed) ** 2
             for k, (lam, w) in enumerate(zip(spec.wavelengths_um, spec.weights)))
    return torch.sqrt(ms)


def _rms_w(camera, design, coeffs, numerics):
    return torch.sqrt((wavefront_rms_per_field(camera, coeffs) ** 2).mean(dim=-1))


def _cost(camera, design, coeffs, numerics):
    return slope_departure_cost(camera.lens, design, numerics.cost_points)


CRITERIA: dict[str, Criterion] = {c.name: c for c in (
    Criterion("rms_w", "RMS_W", "field RMS of the wavefront error (no piston removal)", "waves", False,
              from_design=_rms_w),
    Criterion("mse_s", "MSE_S", "sensor-image MSE, field average", "1 (unit signal variance)", True,
              from_otf=_mse_s),
    Criterion("mse_r", "MSE_R", "MSE after Wiener restoration, field average", "1 (unit signal variance)", True,
              from_otf=_mse_r),
    Criterion("cost", "C_a", "industrial cost: RMS slope departure of the aspheres", "1 (slope)", False,
              from_design=_cost),
)}


def validate_criterion(name: str) -> Criterion:
    """The registered criterion ``name``; ``ValueError`` listing the valid names otherwise."""
    if name not in CRITERIA:
        raise ValueError(f"criterion {name!r} is not known; valid: {', '.join(CRITERIA)}")
    return CRITERIA[name]


def otf_criteria() -> tuple[str, ...]:
    return tuple(k for k, c in CRITERIA.items() if c.from_otf is not None)
