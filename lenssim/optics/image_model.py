"""Statistical image and noise model of the paper (Section 2.3).

Image: isotropic, unit-variance, autocorrelation ``rho(r) = rho0^|r|`` with ``r`` in pixels and
``rho0 = 0.97``. Its continuous 2-D Fourier transform is (``a = -ln rho0``, ``f`` in cycles/pixel)::

    P_c(f) = 2 pi a / (a^2 + 4 pi^2 |f|^2)^(3/2),      integral over the plane = 1.

Finite pixel grid. A sampled image has the spectrum of the *sampled* correlation, i.e. the
aliased sum ``P_d(f) = sum_k P_c(f + k)`` over integer ``k`` (Poisson summation). On an
``N x N`` DFT grid we compute ``P_d`` exactly: ``rho0^|n|`` is evaluated on the integer lattice
out to ``|n_i| <= L`` with ``rho0^L < 1e-13``, folded modulo ``N`` and transformed with an FFT.
This is the default (``model="discrete"``); its mean over the DFT grid is exactly 1 (the
variance). ``model="continuous"`` samples ``P_c`` on ``[-1/2, 1/2)^2`` instead (no aliasing,
mean slightly below 1): the paper does not say which it used.

Noise: white, ``sigma_w^2 = 10^(-SNR/10)`` relative to the unit signal power (SNR in dB per pixel).
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch

from ..torch_utils import HOST, as_tensor
from ..validate import check_snr_db

__all__ = ["PSD_MODELS", "psd_continuous", "image_psd", "image_psd_quarter", "noise_variance"]

PSD_MODELS = ("discrete", "continuous")


def _check_rho0(rho0: float) -> float:
    if not (isinstance(rho0, (int, float)) and 0 < rho0 < 1):
        raise ValueError(f"rho0={rho0!r} is not allowed: the correlation coefficient must be in (0, 1)")
    return float(rho0)


def psd_continuous(f_cpp: torch.Tensor, rho0: float) -> torch.Tensor:
    """``P_c(|f|)`` for radial frequency ``f`` in cycles/pixel (any shape)."""
    a = -math.log(_check_rho0(rho0))
    return 2 * math.pi * a / (a * a + 4 * math.pi**2 * f_cpp**2) ** 1.5


def _even_dft_quarter(x: torch.Tensor, n: int, dim: int) -> torch.Tensor:
    """DFT (length ``n``) of a sequence even about 0, given on ``0..n/2`` along ``dim``; first ``n/2+1`` outputs."""
    return torch.fft.irfft(x, n=n, dim=dim).narrow(dim, 0, n // 2 + 1) * n


@lru_cache(maxsize=2)
def _lattice_correlation(rho0: float):
    """``rho0^|m|`` on the integer lattice ``|m_i| <= L`` with ``rho0^L < 1e-13`` (float64, CPU), and ``L``."""
    L = int(math.ceil(math.log(1e-13) / math.log(rho0)))
    m = torch.arange(-L, L + 1, dtype=torch.float64, device=HOST)
    return rho0 ** torch.hypot(m[:, None], m[None, :]), L


@lru_cache(maxsize=32)
def _psd_quarter_cached(n: int, rho0: float, model: str) -> torch.Tensor:
    """``P_x`` on the quarter plane ``0..n/2`` x ``0..n/2`` (float64, CPU); memory ``O(n^2 / 4)``."""
    h = n // 2
    if model == "continuous":
        k = torch.arange(h + 1, dtype=torch.float64, device=HOST) / n
        return psd_continuous(torch.hypot(k[:, None], k[None, :]), rho0)
    corr, L = _lattice_correlation(rho0)
    # fold the lattice correlation modulo n (it is even, so the folded one is too) and keep 0..n/2
    r = torch.remainder(torch.arange(-L, L + 1, device=HOST), n)
    keep = r <= h
    idx = r[keep]
    folded = torch.zeros(2 * L + 1, h + 1, dtype=torch.float64, device=HOST).index_add_(1, idx, corr[:, keep])
    folded = torch.zeros(h + 1, h + 1, dtype=torch.float64, device=HOST).index_add_(0, idx, folded[keep])
    if n % 2:
        raise ValueError(f"n={n} is not allowed here: the quarter-plane spectrum needs an even size")
    return _even_dft_quarter(_even_dft_quarter(folded, n, 1), n, 0)


def image_psd_quarter(n: int, rho0: float, *, model: str = "discrete", dtype=torch.float32,
                      device=None) -> torch.Tensor:
    """``P_x`` for ``f = (ky, kx) / n`` with ``ky, kx = 0..n/2`` (``n`` even): shape ``(n/2+1, n/2+1)``.

    The spectrum is even in both axes, so this quarter carries all of it (used by the metrics).
    """
    if model not in PSD_MODELS:
        raise ValueError(f"model={model!r} is not allowed: one of {', '.join(PSD_MODELS)}")
    if not (isinstance(n, int) and n >= 2 and n % 2 == 0):
        raise ValueError(f"n={n!r} is not allowed: an even integer >= 2")
    return _psd_quarter_cached(n, _check_rho0(rho0), model).to(dtype=dtype, device=device)


def image_psd(n: int, rho0: float, *, model: str = "discrete", dtype=torch.float32,
              device=None) -> torch.Tensor:
    """Image power spectrum ``P_x`` on the ``n x n`` DFT grid (DFT order, ``f = k/n`` cycles/pixel).

    Unit-variance normalisation: ``P_x.mean() == 1`` for ``model="discrete"`` once ``n`` exceeds the
    correlation length many times (on small grids the mean is the periodised correlation at lag 0).

    References
    ----------
    .. [1] Optics Express 31(10), 16897 (2023), Section 2.3: the separable ``rho0^|r|`` image model.
    """
    if not (isinstance(n, int) and n >= 2 and n % 2 == 0):
        raise ValueError(f"n={n!r} is not allowed: an even integer >= 2")
    q = image_psd_quarter(n, rho0, model=model, dtype=torch.float64)
    k = torch.arange(n, device=HOST)
    fold = torch.minimum(k, n - k)
    return q[fold][:, fold].to(dtype=dtype, device=device)


def noise_variance(snr_db, *, device=None) -> torch.Tensor:
    """``sigma_w^2 = 10^(-SNR/10)`` for SNR in dB (signal power 1), SNR within :data:`SNR_DB_RANGE`, float64 on
    ``device`` (default: ``snr_db``'s, the CPU for numbers).

    Outside :data:`SNR_DB_VALIDATED` (where the numerics' convergence was checked) a
    :class:`ModelValidityWarning` says so.
    """
    check_snr_db(snr_db)
    return 10 ** (-as_tensor(snr_db, dtype=torch.float64, device=device) / 10)
