"""``mse_s`` and ``mse_r``: the paper's expected image errors, per pixel, unit signal variance.

Per field angle, with ``sigma_w^2 = 10^(-SNR/10)``::

    mse_s:  P_es(f) = sigma_w^2 + |1 - H(f)|^2 P_x(f)             sensor-image error
    mse_r:  P_er(f) = (|H(f)|^2 / sigma_w^2 + 1 / P_x(f))^-1      Wiener-restored error
    mse_r_nominal: |1 - G0 H|^2 P_x + |G0|^2 sigma_w^2,  G0 = conj(H0) P_x / (|H0|^2 P_x + sigma_w^2)
                   the Wiener filter built for a reference (nominal) OTF H0 applied to the lens's OTF H
    MSE = integral over f in [-1/2, 1/2)^2 (mean over the DFT grid)

(``P_es`` is the derivation's ``|1 - H|^2 P_x``; the paper prints ``P_x^-1``, a typo.)

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Section 2.3, Eqs. (4)-(6).
"""

from __future__ import annotations

import torch

from ..torch_utils import abs_square
from . import Criterion, OTFContext, register


def mse_s(ctx: OTFContext) -> torch.Tensor:
    """Sensor-image MSE ``(B, S)``: noise plus the blur's error ``|1 - H|^2 P_x``."""
    blur = ((ctx.H2 - 2 * ctx.H.real + 1) * ctx.pw).sum(dim=(-2, -1)).to(torch.float64)
    return ctx.sigma2.to(torch.float64)[None, :] + blur[:, None]


def mse_r(ctx: OTFContext) -> torch.Tensor:
    """Wiener-restored MSE ``(B, S)``: the mean of ``(|H|^2 / sigma^2 + 1 / P_x)^-1``."""
    H2psd, pw, sigma2 = ctx.H2 * ctx.psd, ctx.pw, ctx.sigma2
    if H2psd.requires_grad:
        return torch.stack([(pw / (H2psd + s2)).sum(dim=(-2, -1)).to(torch.float64) * float(s2)
                            for s2 in sigma2.to(ctx.psd.dtype)], dim=-1)
    tmp = torch.empty_like(H2psd)  # one buffer for every SNR (memory of the sweep's chunks)
    return torch.stack([torch.div(pw, torch.add(H2psd, s2, out=tmp), out=tmp).sum(dim=(-2, -1)).to(torch.float64)
                        * float(s2) for s2 in sigma2.to(ctx.psd.dtype)], dim=-1)


def mse_r_nominal(ctx: OTFContext) -> torch.Tensor:
    """Expected MSE ``(B, S)`` of the Wiener filter designed for the reference OTF ``H0`` (``ctx.reference``, e.g.
    the nominal lens's) applied to an image blurred by ``H`` (an as-built lens) with the same noise: the mean of
    ``|1 - G0 H|^2 P_x + |G0|^2 sigma^2`` with ``G0 = conj(H0) P_x / (|H0|^2 P_x + sigma^2)`` (issue 19). With
    ``H = H0`` (or no reference) it is :func:`mse_r`, the matched filter's error, and it is never below it (the
    matched filter is the minimum-MSE linear filter)."""
    if ctx.reference is None:
        return mse_r(ctx)
    H, H0, P = ctx.H, ctx.reference, ctx.psd
    cross = (H0.real * H.real + H0.imag * H.imag) * P  # Re(conj(H0) H) P_x
    H02P = abs_square(H0).mul_(P)
    out = []
    for s2 in ctx.sigma2.to(P.dtype):
        D = H02P + s2
        dens = P - 2 * cross * P / D + H02P * P * (ctx.H2 * P + s2) / D.square()
        out.append(ctx.integrate(dens))
    return torch.stack(out, dim=-1)


register(Criterion("mse_s", "MSE_S", "sensor-image MSE, field average", "1 (unit signal variance)", True,
                   from_otf=mse_s))
register(Criterion("mse_r", "MSE_R", "MSE after Wiener restoration, field average", "1 (unit signal variance)", True,
                   from_otf=mse_r))
register(Criterion("mse_r_nominal", "MSE_R nominal", "MSE after the Wiener restoration built for the nominal lens, field "
                   "average", "1 (unit signal variance)", True, from_otf=mse_r_nominal, needs_reference=True))
