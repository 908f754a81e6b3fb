"""Adaptive local Wiener restoration in the windows of the blur (paper Section 3.3).

In every window (same scheme as :mod:`pipeline.blur`: local PSF at the window centre, cores
blended linearly) and for every channel:

* ``mu`` and ``var_y``: mean and variance of the observed image over the central ``stats`` x ``stats``
  pixels of the window (the local statistics);
* noise variance, signal dependent (Poisson): ``sigma_n^2 = mu / e + read_var``, where ``e`` is the
  number of electrons per unit of the linear image (``full_well / peak`` in the simulation);
* signal variance of the *unblurred* image: ``sigma_x^2 = max(var_y - sigma_n^2, floor) / <|H|^2 P>``
  (blur scales the variance of a signal with spectrum ``P`` by the mean of ``|H|^2 P``);
* Wiener filter with the paper's image model ``P`` (``rho0^|r|``, unit variance, the same spectrum
  as :func:`lenssim.image_psd`) scaled by ``sigma_x^2``:
  ``G = conj(H) sigma_x^2 P / (|H|^2 sigma_x^2 P + sigma_n^2)`` applied to ``y - mu``, then ``+ mu``.

With no blur (``H = 1``) and no noise (``e = inf``) this is the identity.
"""

from __future__ import annotations

import math

import torch

from lenssim import PAPER_RHO0, ThinLens, image_psd

from .blur import PAPER_SCHEME, WindowScheme, apply_windowed

__all__ = ["wiener_windowed", "richardson_lucy_windowed"]


def wiener_windowed(observed: torch.Tensor, lens: ThinLens, s: float, Q: float, *, electrons_per_unit: float,
                    read_noise_var: float = 0.0, rho0: float = PAPER_RHO0, stats: int = 128,
                    scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int | None = None,
                    progress=None, psf_fn=None, floor: float = 1e-10) -> torch.Tensor:
    """Restore a linear sensor image ``(B, C, H, W)`` blurred by the lens ``(s, Q)`` with Poisson noise.

    ``electrons_per_unit`` may be ``math.inf`` (no photon noise). Returns the same shape.
    """
    if not electrons_per_unit > 0:
        raise ValueError(f"electrons_per_unit={electrons_per_unit!r} is not allowed: must be > 0 (inf: no noise)")
    if not (isinstance(stats, int) and 2 <= stats <= scheme.window):
        raise ValueError(f"stats={stats!r} is not allowed: an integer in [2, window={scheme.window}]")
    win, half = scheme.window, scheme.window // 2
    P = image_psd(win, rho0, dtype=observed.dtype, device=observed.device)[:, : half + 1]
    P = P / P.mean()
    inv_e = 0.0 if math.isinf(electrons_per_unit) else 1.0 / electrons_per_unit
    w = torch.full((half + 1,), 2.0, dtype=P.dtype, device=P.device)
    w[0] = w[-1] = 1
    tiny = torch.finfo(observed.dtype).eps ** 2  # guards the noise-free inverse filter (|H| = 0) against 0 / 0

    def restore(patches, otf):
        centre = patches[..., half - stats // 2: half + stats // 2, half - stats // 2: half + stats // 2]
        mu = centre.mean(dim=(-2, -1), keepdim=True)
        var_y = centre.var(dim=(-2, -1), correction=0, keepdim=True)
        noise = mu.clamp_min(0) * inv_e + read_noise_var
        H = otf[:, None, None]  # (k, 1, 1, win, win/2+1)
        HP = (H.real.square() + H.imag.square()) * P
        # <|H|^2 P> over the full grid from the half-plane (rfft layout: inner columns count twice)
        gain = (HP * w).sum(dim=(-2, -1), keepdim=True) / (win * win)
        sx = (var_y - noise).clamp_min(floor) / gain
        # G = conj(H) sx P / (|H|^2 sx P + noise) = conj(H) P / (|H|^2 P + noise / sx), built in place
        G = HP + noise / sx
        torch.div(P, G.clamp_min_(tiny), out=G)
        out = torch.fft.rfft2(patches)
        dc = mu[..., 0, 0] * (win * win)  # the local mean's DC term: filter y - mu, then add mu back
        out[..., 0, 0] -= dc
        out.mul_(H.conj()).mul_(G)
        out[..., 0, 0] += dc
        return out  # spectrum: apply_windowed inverse transforms only the core

    return apply_windowed(observed, lens, s, Q, restore, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress, psf_fn=psf_fn)


def richardson_lucy_windowed(observed: torch.Tensor, lens: ThinLens, s: float, Q: float, *, iterations: int = 30,
                             scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int = 4,
                             progress=None, psf_fn=None, eps: float = 1e-12) -> torch.Tensor:
    """Richardson-Lucy deconvolution (the non-linear, train-free comparison) in the blur's windows.

    Per window, with the local PSF ``h`` (circular convolution over the window, as the blur)::

        u_{k+1} = u_k * ( h~ conv ( y / (h conv u_k) ) ),   u_0 = 0.5,   h~ the mirrored PSF

    the same iteration as ``skimage.restoration.richardson_lucy`` (which the tests compare against).
    Non-negative input required; no regularisation (stop early with ``iterations``).
    """
    if not (isinstance(iterations, int) and iterations >= 1):
        raise ValueError(f"iterations={iterations!r} is not allowed: an integer >= 1")
    if (observed < 0).any():
        raise ValueError("observed image has negative values: Richardson-Lucy needs y >= 0")
    win = scheme.window

    def rl(patches, otf):
        H = otf[:, None, None]
        conv = lambda x, F: torch.fft.irfft2(torch.fft.rfft2(x) * F, s=(win, win))  # noqa: E731
        u = torch.full_like(patches, 0.5)  # scikit-image's starting point
        for _ in range(iterations):
            ratio = patches / conv(u, H).clamp_min(eps)
            u = u * conv(ratio, H.conj())
        return u

    return apply_windowed(observed, lens, s, Q, rl, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress, psf_fn=psf_fn)
