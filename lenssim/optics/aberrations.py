"""Third-order (Seidel) wavefront aberrations of the thin conic lens over the field.

Implements Eq. (2) of the paper with the thin-lens Seidel sums of Welford (*Aberrations of
Optical Systems*, thin-lens chapter), stop at the lens, ``H = y tan(alpha)``, ``K = 1/f``::

    S_I   = (y^4 K^3 / 4) [ (n/(n-1))^2 + (n+2)/(n(n-1)^2) s^2 + 4(n+1)/(n(n-1)) s p + (3n+2)/n p^2 ]
            + sum over surfaces of (n' - n) kappa c^3 y^4       (conic terms; the paper: the back surface)
    S_II  = +(y^2 K^2 H / 2) [ (n+1)/(n(n-1)) s + (2n+1)/n p ]
    S_III = H^2 K,   S_IV = H^2 K / n,   S_V = 0

    W(rho, theta) = S_I/8 rho^4 + S_II/2 rho^3 cos(theta) + S_III/2 rho^2 cos^2(theta)
                    + (S_III + S_IV)/4 rho^2

At the stop (chief-ray height 0) a conic surface adds to ``S_I`` only. ``rho`` is the normalised
pupil radius and ``theta`` is measured from the meridional direction, which points from the
optical axis towards the image point. With that orientation ``S_II`` has the sign above, which is
the sign of Welford's surface-by-surface sum and of an exact ray trace; NOTES.md prints ``-(...)``,
which is the same aberration with the meridional axis pointing away from the image point (the
paper's ``h(alpha) = -f tan(alpha)``). Every metric is unchanged by that flip; the direction of
the coma flare in a PSF is not. ``W`` follows Welford's sign (positive ``S_I`` = under-corrected),
for which the transverse ray aberration in the paraxial image plane is ``eps = -(f / y) grad_rho W``.

The wavefront is a sum of the pupil monomials of :data:`TERMS` (``rho^2a rho_r^b``, with ``rho_r =
rho cos(theta)``) times coefficients in waves; everything that evaluates, differentiates or
integrates ``W`` reads that table, so a new term is a new row there and its coefficient in
:func:`wavefront_coefficients`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch

from ..checks import check_shape
from ..model.design import Design
from ..model.lens import Lens
from ..torch_utils import HOST, as_tensor
from ..validate import check_finite

__all__ = [
    "Term",
    "TERMS",
    "COEFFICIENT_NAMES",
    "N_TERMS",
    "seidel_sums",
    "defocus_mm",
    "wavefront_coefficients",
    "pupil_monomials",
    "monomial_gradients",
    "wavefront",
    "wavefront_rotated",
    "wavefront_gradient",
    "rms_wavefront",
    "field_rms_wavefront",
]


@dataclass(frozen=True)
class Term:
    """Pupil monomial ``(rho_r^2 + rho_t^2)^a rho_r^b rho_t^c`` (= ``rho^(2a+b+c) cos^b(theta) sin^c(theta)``) named
    ``name``. ``c = 0`` (even in ``rho_t``) for every wavefront of a centred lens; odd ``c`` for the non-symmetric
    wavefronts of decentred or tilted lenses (:mod:`lenssim.optics.as_built`)."""

    name: str
    a: int
    b: int
    c: int = 0

    @property
    def symmetric(self) -> bool:
        """Even in ``rho_t`` (mirror-symmetric about the meridional plane)."""
        return self.c % 2 == 0

    def __call__(self, r2: torch.Tensor, rho_r: torch.Tensor, rho_t: torch.Tensor | None = None) -> torch.Tensor:
        out = self._even(r2, rho_r)
        return out if not self.c else out * rho_t**self.c

    def _even(self, r2, rho_r):
        if self.b == 0:
            return r2**self.a
        if self.a == 0:
            return rho_r**self.b
        return r2**self.a * rho_r**self.b

    def weighted(self, coeff: torch.Tensor, r2: torch.Tensor, rho_r: torch.Tensor,
                 rho_t: torch.Tensor | None = None) -> torch.Tensor:
        """``coeff r2^a rho_r^b rho_t^c``, multiplied left to right (the rounding of the original four-term formula)."""
        out = coeff * r2**self.a if self.a else coeff
        out = out * rho_r**self.b if self.b else out * torch.ones_like(r2)
        return out * rho_t**self.c if self.c else out


TERMS = (Term("W040", 2, 0), Term("W131", 1, 1), Term("W222", 0, 2), Term("W220", 1, 0))
"""Spherical aberration, coma, astigmatism, field curvature (+ half the astigmatism): Eq. (2)."""
COEFFICIENT_NAMES = tuple(t.name for t in TERMS)
N_TERMS = len(TERMS)


def _check_coeffs(coeffs) -> None:
    check_shape(coeffs, f"* {N_TERMS}", f"coeffs ({', '.join(COEFFICIENT_NAMES)} in waves)")
    check_finite("coeffs", coeffs.detach())


def _design_and_angles(design: Design, alpha_deg):
    ref = next((t for t in design.values.values()), None)
    if isinstance(alpha_deg, torch.Tensor) and alpha_deg.is_floating_point():
        ref = alpha_deg if ref is None else ref
    dtype = ref.dtype if ref is not None else torch.get_default_dtype()
    device = ref.device if ref is not None else None
    return design.to(dtype=dtype, device=device), as_tensor(alpha_deg, dtype=dtype, device=device)


def seidel_sums(lens: Lens, design: Design, alpha_deg=None, *, elementwise: bool = False,
                wavelength_um: float | None = None) -> torch.Tensor:
    """Seidel sums ``(S_I, S_II, S_III, S_IV)`` in mm.

    Parameters
    ----------
    lens : Lens
    design : Design, parameters broadcasting to shape ``(*)``
    alpha_deg : tensor-like, shape ``(A,)``, optional
        Field angles in degrees; defaults to ``lens.field_angles_deg``.
    elementwise : bool
        If True, ``alpha_deg`` broadcasts with the design (one angle per design, e.g. one per
        image point) instead of adding a field axis.
    wavelength_um : float, optional
        With a dispersive glass: the index, power and position factor at this wavelength (the
        curvatures stay those of the design); default the reference index.

    Returns
    -------
    Tensor of shape ``(*, A, 4)`` (``(*, 4)`` if elementwise) in mm, dtype/device following the design.
    """
    if alpha_deg is None:
        alpha_deg = lens.field_angles_deg
    design, alpha = _design_and_angles(design, alpha_deg)
    if elementwise:
        return lens.seidel_sums(design, alpha, wavelength_um)
    return lens.seidel_sums(design.unsqueeze(-1), alpha, wavelength_um)


def defocus_mm(lens: Lens, design: Design, wavelength_um: float | None = None) -> torch.Tensor:
    """Defocus ``W020`` (mm of wavefront, coefficient of ``rho^2``) at ``wavelength_um``:
    ``delta y^2 / (2 t_f t_img)``.

    ``t_img`` is the image plane's distance from the lens (the paraxial image distance plus the design's
    ``focus_shift_um``), ``t_f`` the focus distance at this wavelength and ``delta = t_img - t_f`` (axial colour
    plus the focus shift). A ray at pupil height ``y rho`` aimed at the focus ``t_f`` crosses the image plane at
    ``-y rho delta / t_f``; the PSF reads a wavefront ``W`` through the image-plane scale
    ``eps = -(t_img / y) dW/drho`` (the reference sphere centred on the image plane, radius ``t_img``), which
    gives this ``W020``. The former ``delta y^2 / (2 t_f^2)`` is off by ``t_img / t_f`` (1.1% for the F line of
    the end-to-end design in N-BK7; issue 19).
    """
    t = lens.focus_distance_mm(wavelength_um)
    t_img = lens.image_distance_mm + design["focus_shift_um"] * 1e-3
    delta = t_img - t
    return delta * lens.pupil_radius_mm**2 / (2 * t * t_img)


def wavefront_coefficients(lens: Lens, design: Design, alpha_deg=None, *, wavelength_um: float,
                           elementwise: bool = False) -> torch.Tensor:
    """Wavefront coefficients of :data:`TERMS` in waves at ``wavelength_um``.

    ``W = W040 rho^4 + W131 rho^3 cos(theta) + W222 rho^2 cos^2(theta) + W220 rho^2`` (Eq. 2 of
    the paper; ``W131`` includes the field height, so the coefficients are per field angle).

    Returns a tensor of shape ``(*, A, T)``, or ``(*, T)`` if elementwise (see :func:`seidel_sums`).
    """
    lam_mm = wavelength_um * 1e-3
    S = seidel_sums(lens, design, alpha_deg, elementwise=elementwise, wavelength_um=wavelength_um) / lam_mm
    S1, S2, S3, S4 = S.unbind(-1)
    d = design.to(dtype=S.dtype, device=S.device)
    w020 = defocus_mm(lens, d if elementwise else d.unsqueeze(-1), wavelength_um) / lam_mm
    return torch.stack(torch.broadcast_tensors(S1 / 8, S2 / 2, S3 / 2, (S3 + S4) / 4 + w020), dim=-1)


def pupil_monomials(rho_r: torch.Tensor, rho_t: torch.Tensor, terms=TERMS) -> torch.Tensor:
    """The monomials of ``terms`` (default :data:`TERMS`) at pupil points, stacked: ``(T, *P)``."""
    r2 = rho_r**2 + rho_t**2
    return torch.stack(torch.broadcast_tensors(*(t(r2, rho_r, rho_t) for t in terms)))


def monomial_gradients(rho_r: torch.Tensor, rho_t: torch.Tensor, terms=TERMS):
    """``(d/drho_r, d/drho_t)`` of each monomial of ``terms``, each stacked ``(T, *P)``."""
    r2 = rho_r**2 + rho_t**2
    gr, gt = [], []
    for t in terms:
        g_r = torch.zeros_like(r2)
        g_t = torch.zeros_like(r2)
        tc = rho_t**t.c if t.c else 1.0
        if t.a:
            common = 2 * t.a * r2 ** (t.a - 1) * rho_r**t.b * tc
            g_r = g_r + common * rho_r
            g_t = g_t + common * rho_t
        if t.b:
            g_r = g_r + t.b * r2**t.a * rho_r ** (t.b - 1) * tc
        if t.c:
            g_t = g_t + t.c * r2**t.a * rho_r**t.b * rho_t ** (t.c - 1)
        gr.append(g_r)
        gt.append(g_t)
    return torch.stack(gr), torch.stack(gt)


def wavefront(coeffs: torch.Tensor, rho_r: torch.Tensor, rho_t: torch.Tensor) -> torch.Tensor:
    """Evaluate ``W`` (waves) at normalised pupil points.

    ``rho_r`` is the pupil coordinate along the meridional (radial-field) direction and ``rho_t``
    the one across it, both normalised to the pupil radius. ``coeffs`` ``(*, T)`` broadcasts
    against the point arrays: the result has shape ``(*, *P)`` for points of shape ``P``.
    """
    _check_coeffs(coeffs)
    r2 = rho_r**2 + rho_t**2
    c = coeffs.reshape(coeffs.shape[:-1] + (1,) * rho_r.ndim + (N_TERMS,))
    return sum(t.weighted(c[..., k], r2, rho_r) for k, t in enumerate(TERMS))


def wavefront_rotated(coeffs: torch.Tensor, rho_r: torch.Tensor, rho_t: torch.Tensor, terms=TERMS) -> torch.Tensor:
    """``W`` (waves) for coefficients ``(B, T)`` of ``terms`` and per-row pupil points ``(B or 1, *P)``: ``(B, *P)``."""
    r2 = rho_r**2 + rho_t**2
    extra = (None,) * (rho_r.ndim - 1)
    return sum(t.weighted(coeffs[(slice(None), k) + extra], r2, rho_r, rho_t) for k, t in enumerate(terms))


def wavefront_gradient(coeffs: torch.Tensor, rho_r: torch.Tensor, rho_t: torch.Tensor):
    """Gradient ``(dW/drho_r, dW/drho_t)`` in waves per unit normalised pupil radius.

    ``d/drho_r [r2^a rho_r^b] = 2a r2^(a-1) rho_r^(b+1) + b r2^a rho_r^(b-1)``,
    ``d/drho_t [r2^a rho_r^b] = 2a r2^(a-1) rho_r^b rho_t``.
    """
    _check_coeffs(coeffs)
    r2 = rho_r**2 + rho_t**2
    c = coeffs.reshape(coeffs.shape[:-1] + (1,) * rho_r.ndim + (N_TERMS,))
    g_r = g_t = 0
    for k, t in enumerate(TERMS):
        ck = c[..., k]
        if t.a:
            common = 2 * t.a * r2 ** (t.a - 1) * rho_r**t.b
            g_r = g_r + ck * common * rho_r
            g_t = g_t + ck * common * rho_t
        if t.b:
            g_r = g_r + ck * t.b * r2**t.a * rho_r ** (t.b - 1)
    return g_r, g_t


def _disc_mean(a: int, b: int) -> float:
    """Mean of ``rho^(2a+b) cos^b(theta)`` over the unit disc: ``2 / (2a + b + 2) (b-1)!!/b!!`` (0 for odd b)."""
    if b % 2:
        return 0.0
    ratio = math.prod(range(b - 1, 0, -2)) / math.prod(range(b, 0, -2)) if b else 1.0
    return 2.0 / (2 * a + b + 2) * ratio


_MOMENTS = torch.tensor([[_disc_mean(ti.a + tj.a, ti.b + tj.b) for tj in TERMS] for ti in TERMS], dtype=torch.float64,
                        device=HOST)
_MEANS = torch.tensor([_disc_mean(t.a, t.b) for t in TERMS], dtype=torch.float64, device=HOST)


@lru_cache(maxsize=8)
def _moments(terms: tuple) -> tuple[torch.Tensor, torch.Tensor]:
    """Disc means of the products of ``terms``' monomials and of each monomial (even in ``rho_t``)."""
    if any(t.c for t in terms):
        raise ValueError("rms_wavefront takes monomials even in rho_t (c = 0)")
    M = torch.tensor([[_disc_mean(ti.a + tj.a, ti.b + tj.b) for tj in terms] for ti in terms], dtype=torch.float64,
                     device=HOST)
    return M, torch.tensor([_disc_mean(t.a, t.b) for t in terms], dtype=torch.float64, device=HOST)


def rms_wavefront(coeffs: torch.Tensor, piston_removed: bool = False, terms=None) -> torch.Tensor:
    """RMS of ``W`` over the unit pupil disc (waves), closed form.

    ``<W^2> = c^T M c`` with ``M_ij`` the disc mean of the product of monomials ``i`` and ``j``
    (:func:`_disc_mean`); for the paper's four terms ``a, b, c, d = W040, W131, W222, W220``::

        <W^2> = a^2/5 + a c/4 + a d/2 + b^2/8 + c^2/8 + c d/3 + d^2/3
        <W>   = a/3 + c/4 + d/2

    The paper's ``RMS_w`` is ``sqrt(<W^2>)`` (no piston removal); ``piston_removed=True`` gives
    the standard deviation ``sqrt(<W^2> - <W>^2)``. Input ``(*, T)``, output ``(*)``. ``terms``: the coefficients'
    monomial table (default :data:`TERMS`; monomials even in ``rho_t``).
    """
    if terms is None:
        _check_coeffs(coeffs)
        M, means = _MOMENTS, _MEANS
    else:
        check_shape(coeffs, f"* {len(terms)}", "coeffs (waves)")
        check_finite("coeffs", coeffs.detach())
        M, means = _moments(tuple(terms))
    M = M.to(dtype=coeffs.dtype, device=coeffs.device)
    m2 = torch.einsum("...i,ij,...j->...", coeffs, M, coeffs)
    if piston_removed:
        m1 = coeffs @ means.to(dtype=coeffs.dtype, device=coeffs.device)
        m2 = m2 - m1 * m1
    return torch.sqrt(torch.clamp(m2, min=0))


def field_rms_wavefront(coeffs: torch.Tensor, piston_removed: bool = False) -> torch.Tensor:
    """The paper's ``RMS_W = sqrt(<RMS_w(alpha)^2>_alpha)`` (waves), uniform over the field angles.

    Input ``(*, A, T)``, output ``(*)``.
    """
    return torch.sqrt((rms_wavefront(coeffs, piston_removed) ** 2).mean(dim=-1))
