"""Gradient-based trade-off without a grid (paper Section 5): optimise quality along an iso-cost curve.

The whole chain ``(s, Q) -> W -> pupil -> PSF -> OTF -> MSE`` is differentiable torch code, and so
is the cost ``C_a`` (the best-fit-sphere Gauss-Newton iterations are unrolled). At each step the
quality gradient is projected on the subspace orthogonal to the cost gradient, a backtracking
step is taken along it, and the point is pulled back onto ``C_a = level`` by Newton steps along
the cost gradient. FFT sizes are fixed per field angle at the start (piecewise-constant in the
design, so they carry no gradient). Coordinates are scaled by the paper's grid steps
(0.025 in s, 0.1 in Q) so both parameters move comparably.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from .aberrations import wavefront_coefficients
from .cost import slope_departure_cost
from .image_model import image_psd_quarter, noise_variance
from .lens import ThinLens
from .metrics import DEFAULT_FILL, DEFAULT_MIN_SIZE, mse_from_otf_quarter
from .psf_bank import fft_size, otf_quarter

__all__ = ["DifferentiableMSE", "IsoCostResult", "optimise_on_iso_cost"]

SCALE = torch.tensor([0.025, 0.1], dtype=torch.float64)  # grid steps of s and Q


class DifferentiableMSE:
    """``MSE_R`` (or ``MSE_S``) field average at one SNR as a differentiable function of ``x = (s, Q)``."""

    def __init__(self, lens: ThinLens, snr_db: float = 27.6, criterion: str = "mse_r", *, fill: float = DEFAULT_FILL,
                 min_size: int = DEFAULT_MIN_SIZE, oversample: int = 1, dtype=torch.float64):
        if criterion not in ("mse_r", "mse_s"):
            raise ValueError(f"criterion={criterion!r} is not allowed: 'mse_r' or 'mse_s'")
        self.lens, self.criterion, self.fill, self.min_size, self.oversample, self.dtype = \
            lens, criterion, fill, min_size, oversample, dtype
        self.sigma2 = noise_variance([snr_db]).to(dtype)
        self.sizes: list[int] | None = None
        self.evaluations = 0

    def fix_sizes(self, x: torch.Tensor) -> None:
        """Choose the FFT size per field angle at design ``x`` (with a 25% margin for the way ahead)."""
        c = wavefront_coefficients(self.lens, x[0].detach(), x[1].detach()).to(torch.float64)
        self.sizes = [int(v) for v in fft_size(self.lens, c * 1.25, fill=self.fill, min_size=self.min_size)]

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if self.sizes is None:
            self.fix_sizes(x)
        self.evaluations += 1
        coeffs = wavefront_coefficients(self.lens, x[0], x[1]).to(self.dtype)  # (A, 4)
        total = 0
        for a, n in enumerate(self.sizes):
            m = n * self.oversample
            H = otf_quarter(self.lens, coeffs[a:a + 1], n, oversample=self.oversample)
            ms, mr = mse_from_otf_quarter(H, image_psd_quarter(m, dtype=self.dtype), self.sigma2)
            total = total + (mr if self.criterion == "mse_r" else ms)[0, 0]
        return total / len(self.sizes)


@dataclass
class IsoCostResult:
    s: float
    Q: float
    value: float
    cost: float
    level: float
    iterations: int
    evaluations: int
    history: list = field(default_factory=list)


def _cost(lens, x, points):
    return slope_departure_cost(lens, x[0], x[1], points)


def _project_to_level(lens, x, level, points, iters=6):
    """Newton steps along the cost gradient back onto ``C_a = level``."""
    for _ in range(iters):
        xx = x.detach().requires_grad_(True)
        c = _cost(lens, xx, points)
        (g,) = torch.autograd.grad(c, xx)
        err = c.item() - level
        if abs(err) <= 1e-10 * max(level, 1e-12):
            break
        x = x.detach() - err * g / g.dot(g)
    return x.detach()


def optimise_on_iso_cost(lens: ThinLens, quality: DifferentiableMSE, x0, level: float, *, steps: int = 30,
                         step0: float = 2.0, tol: float = 1e-7, cost_points: int = 101,
                         Q_bounds=(-10.0, 1.2), s_bounds=(-2.0, 1.025)) -> IsoCostResult:
    """Minimise ``quality`` along ``C_a = level`` from ``x0 = (s, Q)`` by projected gradient descent.

    ``step0`` is the first trial step in grid steps; steps are halved until the quality decreases.
    Stops when the tangential gradient (per grid step) is below ``tol`` relative to the value, or
    after ``steps`` accepted steps. Designs are kept inside the bounds (the paper's |Q| <= 10).
    """
    x = torch.as_tensor(x0, dtype=torch.float64).clone()
    x = _project_to_level(lens, x, level, cost_points)
    quality.fix_sizes(x)
    lo = torch.tensor([s_bounds[0], Q_bounds[0]], dtype=torch.float64)
    hi = torch.tensor([s_bounds[1], Q_bounds[1]], dtype=torch.float64)
    step = step0
    history = []
    it = 0
    for it in range(1, steps + 1):
        xx = x.clone().requires_grad_(True)
        q = quality(xx)
        (gq,) = torch.autograd.grad(q, xx)
        xc = x.clone().requires_grad_(True)
        (gc,) = torch.autograd.grad(_cost(lens, xc, cost_points), xc)
        gq_u, gc_u = gq * SCALE, gc * SCALE  # gradients per grid step
        nrm = gc_u / gc_u.norm()
        tangent = gq_u - gq_u.dot(nrm) * nrm
        qv = q.item()
        history.append((float(x[0]), float(x[1]), qv))
        if tangent.norm() <= tol * abs(qv):
            break
        direction = -tangent / tangent.norm() * SCALE  # in (s, Q) units, one grid step long
        accepted = False
        while step >= 1e-3:
            trial = torch.maximum(torch.minimum(x + step * direction, hi), lo)
            trial = _project_to_level(lens, trial, level, cost_points)
            trial = torch.maximum(torch.minimum(trial, hi), lo)
            with torch.no_grad():
                qt = quality(trial)
            if qt.item() < qv:
                x, accepted = trial, True
                step *= 1.5
                break
            step *= 0.5
        if not accepted:
            break
    with torch.no_grad():
        v = float(quality(x))
    return IsoCostResult(float(x[0]), float(x[1]), v, _cost(lens, x, cost_points).item(), level, it,
                         quality.evaluations, history)
