"""Third-order (Seidel) wavefront aberrations of the thin conic lens over the field.

Implements Eq. (2) of the paper with the thin-lens Seidel sums of Welford (*Aberrations of
Optical Systems*, thin-lens chapter), stop at the lens, ``H = y tan(alpha)``, ``K = 1/f``::

    S_I   = (y^4 K^3 / 4) [ (n/(n-1))^2 + (n+2)/(n(n-1)^2) s^2 + 4(n+1)/(n(n-1)) s p + (3n+2)/n p^2 ]
            + (1 - n) Q c2^3 y^4                      (conic term of the posterior surface)
    S_II  = +(y^2 K^2 H / 2) [ (n+1)/(n(n-1)) s + (2n+1)/n p ]
    S_III = H^2 K,   S_IV = H^2 K / n,   S_V = 0

    W(rho, theta) = S_I/8 rho^4 + S_II/2 rho^3 cos(theta) + S_III/2 rho^2 cos^2(theta)
                    + (S_III + S_IV)/4 rho^2

``rho`` is the normalised pupil radius and ``theta`` is measured from the meridional direction,
which points from the optical axis towards the image point. With that orientation ``S_II`` has
the sign above, which is the sign of Welford's surface-by-surface sum and of an exact ray trace;
NOTES.md prints ``-(...)``, which is the same aberration with the meridional axis pointing away
from the image point (the paper's ``h(alpha) = -f tan(alpha)``). Every metric is unchanged by
that flip; the direction of the coma flare in a PSF is not. ``W`` follows Welford's sign
(positive ``S_I`` = under-corrected), for which the transverse ray aberration in the paraxial
image plane is ``eps = -(f / y) grad_rho W`` (checked against an exact ray trace in the tests).

The four coefficients ``(W040, W131, W222, W220)`` are returned in waves.
"""

from __future__ import annotations

import torch

from .lens import ThinLens, as_tensor

__all__ = [
    "COEFFICIENT_NAMES",
    "seidel_sums",
    "wavefront_coefficients",
    "wavefront",
    "wavefront_gradient",
    "rms_wavefront",
    "field_rms_wavefront",
]

COEFFICIENT_NAMES = ("W040", "W131", "W222", "W220")


def _broadcast(s, Q, alpha_deg, dtype=None, device=None):
    ref = next((t for t in (s, Q, alpha_deg) if isinstance(t, torch.Tensor)), None)
    if dtype is None:
        dtype = ref.dtype if (ref is not None and ref.is_floating_point()) else torch.get_default_dtype()
    device = device if device is not None else (ref.device if ref is not None else None)
    return (as_tensor(v, dtype=dtype, device=device) for v in (s, Q, alpha_deg))


def _seidel_elementwise(lens: ThinLens, s, Q, alpha):
    n, y, p = lens.refractive_index, lens.pupil_radius_mm, lens.position_factor
    K = 1.0 / lens.focal_length_mm
    _, c2 = lens.curvatures(s)
    H = y * torch.tan(torch.deg2rad(alpha))
    bracket = (n / (n - 1)) ** 2 + (n + 2) / (n * (n - 1) ** 2) * s**2 \
        + 4 * (n + 1) / (n * (n - 1)) * s * p + (3 * n + 2) / n * p**2
    S1 = y**4 * K**3 / 4 * bracket + (1 - n) * Q * c2**3 * y**4
    S2 = (y**2 * K**2 * H / 2) * ((n + 1) / (n * (n - 1)) * s + (2 * n + 1) / n * p)
    S3 = H**2 * K
    S4 = H**2 * K / n
    return torch.stack(torch.broadcast_tensors(S1, S2, S3, S4), dim=-1)


def seidel_sums(lens: ThinLens, s, Q, alpha_deg=None, *, elementwise: bool = False) -> torch.Tensor:
    """Seidel sums ``(S_I, S_II, S_III, S_IV)`` in mm.

    Parameters
    ----------
    lens : ThinLens
    s, Q : tensor-like, broadcastable, shape ``(*)``
        Shape factor and conic constant of the posterior surface (dimensionless).
    alpha_deg : tensor-like, shape ``(A,)``, optional
        Field angles in degrees; defaults to ``lens.field_angles_deg``.
    elementwise : bool
        If True, ``alpha_deg`` broadcasts with ``s`` and ``Q`` (one angle per design, e.g. one per
        image point) instead of adding a field axis.

    Returns
    -------
    Tensor of shape ``(*, A, 4)`` (``(*, 4)`` if elementwise) in mm, dtype/device following ``s``/``Q``.
    """
    if alpha_deg is None:
        alpha_deg = lens.field_angles_deg
    s, Q, alpha = _broadcast(s, Q, alpha_deg)
    if elementwise:
        return _seidel_elementwise(lens, s, Q, alpha)
    return _seidel_elementwise(lens, s.unsqueeze(-1), Q.unsqueeze(-1), alpha)


def wavefront_coefficients(lens: ThinLens, s, Q, alpha_deg=None, *, elementwise: bool = False) -> torch.Tensor:
    """Wavefront coefficients ``(W040, W131, W222, W220)`` in waves.

    ``W = W040 rho^4 + W131 rho^3 cos(theta) + W222 rho^2 cos^2(theta) + W220 rho^2`` (Eq. 2 of
    the paper; ``W131`` includes the field height, so the coefficients are per field angle).

    Returns a tensor of shape ``(*, A, 4)``, or ``(*, 4)`` if elementwise (see :func:`seidel_sums`).
    """
    S = seidel_sums(lens, s, Q, alpha_deg, elementwise=elementwise) / lens.wavelength_mm
    S1, S2, S3, S4 = S.unbind(-1)
    return torch.stack([S1 / 8, S2 / 2, S3 / 2, (S3 + S4) / 4], dim=-1)


def _check_coeffs(coeffs: torch.Tensor) -> None:
    if not isinstance(coeffs, torch.Tensor) or coeffs.ndim < 1 or coeffs.shape[-1] != 4:
        shape = tuple(coeffs.shape) if isinstance(coeffs, torch.Tensor) else type(coeffs).__name__
        raise ValueError(f"coeffs has shape {shape}: expected a tensor of shape (*, 4) "
                         "holding (W040, W131, W222, W220) in waves")


def wavefront(coeffs: torch.Tensor, rho_r: torch.Tensor, rho_t: torch.Tensor) -> torch.Tensor:
    """Evaluate ``W`` (waves) at normalised pupil points.

    ``rho_r`` is the pupil coordinate along the meridional (radial-field) direction and ``rho_t``
    the one across it, both normalised to the pupil radius. ``coeffs`` ``(*, 4)`` broadcasts
    against the point arrays: the result has shape ``(*, *P)`` for points of shape ``P``.
    """
    _check_coeffs(coeffs)
    r2 = rho_r**2 + rho_t**2
    c = coeffs.reshape(coeffs.shape[:-1] + (1,) * rho_r.ndim + (4,))
    return c[..., 0] * r2**2 + c[..., 1] * r2 * rho_r + c[..., 2] * rho_r**2 + c[..., 3] * r2


def wavefront_gradient(coeffs: torch.Tensor, rho_r: torch.Tensor, rho_t: torch.Tensor):
    """Gradient ``(dW/drho_r, dW/drho_t)`` in waves per unit normalised pupil radius."""
    _check_coeffs(coeffs)
    r2 = rho_r**2 + rho_t**2
    c = coeffs.reshape(coeffs.shape[:-1] + (1,) * rho_r.ndim + (4,))
    a, b, cc, d = (c[..., i] for i in range(4))
    g_r = 4 * a * r2 * rho_r + b * (r2 + 2 * rho_r**2) + 2 * cc * rho_r + 2 * d * rho_r
    g_t = 4 * a * r2 * rho_t + b * 2 * rho_r * rho_t + 2 * d * rho_t
    return g_r, g_t


def rms_wavefront(coeffs: torch.Tensor, piston_removed: bool = False) -> torch.Tensor:
    """RMS of ``W`` over the unit pupil disc (waves), closed form.

    With ``a, b, c, d = W040, W131, W222, W220``::

        <W^2> = a^2/5 + a c/4 + a d/2 + b^2/8 + c^2/8 + c d/3 + d^2/3
        <W>   = a/3 + c/4 + d/2

    The paper's ``RMS_w`` is ``sqrt(<W^2>)`` (no piston removal); ``piston_removed=True`` gives
    the standard deviation ``sqrt(<W^2> - <W>^2)``. Input ``(*, 4)``, output ``(*)``.
    """
    _check_coeffs(coeffs)
    a, b, c, d = coeffs.unbind(-1)
    m2 = a * a / 5 + a * c / 4 + a * d / 2 + b * b / 8 + c * c / 8 + c * d / 3 + d * d / 3
    if piston_removed:
        m1 = a / 3 + c / 4 + d / 2
        m2 = m2 - m1 * m1
    return torch.sqrt(torch.clamp(m2, min=0))


def field_rms_wavefront(coeffs: torch.Tensor, piston_removed: bool = False) -> torch.Tensor:
    """The paper's ``RMS_W = sqrt(<RMS_w(alpha)^2>_alpha)`` (waves), uniform over the field angles.

    Input ``(*, A, 4)``, output ``(*)``.
    """
    return torch.sqrt((rms_wavefront(coeffs, piston_removed) ** 2).mean(dim=-1))
