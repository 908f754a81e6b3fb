"""Best focus: the image-plane position (``focus_shift_um``) that minimises a criterion, by a bounded
1-D search (Brent's method, scipy) over the criterion evaluated by :func:`lenssim.metrics.evaluate`.

For a dispersive lens the paraxial focus of the reference wavelength (the d line) is rarely the
best plane for white light; the search finds, per design, where e.g. MSE_R is smallest.
"""

from __future__ import annotations

from dataclasses import dataclass

from .model.camera import Camera
from .criteria import validate_criterion
from .model.design import Design
from .metrics import evaluate
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .torch_utils import HOST
from .validate import check_real

__all__ = ["FocusResult", "best_focus", "best_focus_batch", "FOCUS_BOUNDS_UM"]

FOCUS_BOUNDS_UM = (-500.0, 500.0)
"""Default search interval of the focus shift (um): the F-C axial colour of a 25 mm singlet in N-SF5 (~0.64 mm)
around its d-line focus, and ~12 depths of focus of the paper's f/6.25 (+-43 um). Measured optima: -58.5 um
(MSE_R, paper's end-to-end design, paper glass), +120.5 um (its RMS_W design); a result on a bound is reported
as such."""


@dataclass(frozen=True)
class FocusResult:
    focus_shift_um: float
    value: float
    criterion: str
    evaluations: int


def best_focus(camera: Camera, design: Design, criterion: str, snr_db: float, *, rho0: float,
               psd_model: str = "discrete", bounds_um=FOCUS_BOUNDS_UM, tol_um: float = 0.5, numerics: Numerics = DEFAULT_NUMERICS) -> FocusResult:
    """The ``focus_shift_um`` of ``design`` (one design) optimising ``criterion`` at ``snr_db`` (its minimum, or its
    maximum for a criterion whose sense is ``"max"``), within ``bounds_um``, to ``tol_um``."""
    from scipy.optimize import minimize_scalar

    crit = validate_criterion(criterion)
    lo = check_real("focus bound", bounds_um[0], unit="um")
    hi = check_real("focus bound", bounds_um[1], lo, unit="um", lo_open=True)
    check_real("tol_um", tol_um, 0.0, lo_open=True, unit="um")
    design.floats()
    count = [0]

    def f(z: float) -> float:
        count[0] += 1
        r = evaluate(camera, design.replace(focus_shift_um=float(z)), [snr_db], rho0=rho0, psd_model=psd_model,
                     numerics=numerics)
        v = r[criterion]
        return crit.sign * (float(v.reshape(-1)[0]) if crit.per_snr else float(v))

    res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": tol_um})
    if min(res.x - lo, hi - res.x) < 2 * tol_um:
        from .validate import warn_model

        warn_model(f"the best focus for {criterion} is at the search bound ({res.x:+.1f} um of [{lo:g}, {hi:g}] um); "
                   "widen the bounds")
    return FocusResult(float(res.x), crit.sign * float(res.fun), criterion, count[0])


def best_focus_batch(camera: Camera, design: Design, criterion: str, snr_db: float, *, rho0: float,
                     bounds_um=FOCUS_BOUNDS_UM, tol_um: float = 1.0, numerics: Numerics = DEFAULT_NUMERICS, **kw):
    """Best focus of every design of a batch at once: golden-section search in lock step (one batched
    :func:`evaluate` per step, ``ceil(log(tol / width) / log(0.618))`` steps).

    Returns ``(focus_shift_um, value)``, tensors of the design's shape (float64); the criterion is minimised, or
    maximised if its sense is ``"max"``. ``kw`` goes to
    :func:`evaluate` (e.g. ``device``, ``rho0``, ``psd_model``).
    """
    import math

    import torch

    crit = validate_criterion(criterion)
    lo = check_real("focus bound", bounds_um[0], unit="um")
    hi = check_real("focus bound", bounds_um[1], lo, unit="um", lo_open=True)
    check_real("tol_um", tol_um, 0.0, lo_open=True, unit="um")
    d = design.to(torch.float64).broadcast()
    shape = d.shape

    def f(z):
        r = evaluate(camera, d.replace(focus_shift_um=z), [snr_db], rho0=rho0, numerics=numerics, **kw)[criterion]
        return crit.sign * (r[..., 0] if crit.per_snr else r).to(torch.float64).cpu()  # minimised

    g = (math.sqrt(5) - 1) / 2
    a, b = (torch.full(shape, v, dtype=torch.float64, device=HOST) for v in (lo, hi))  # as f's values
    c, e = b - g * (b - a), a + g * (b - a)
    fc, fe = f(c), f(e)
    for _ in range(max(1, math.ceil(math.log(tol_um / (hi - lo)) / math.log(g)))):
        left = fc < fe  # the minimum lies in [a, e] (else in [c, b])
        b = torch.where(left, e, b)
        a = torch.where(left, a, c)
        new = torch.where(left, b - g * (b - a), a + g * (b - a))  # the one new point of each interval
        fn = f(new)
        c, fc, e, fe = (torch.where(left, new, e), torch.where(left, fn, fe),
                        torch.where(left, c, new), torch.where(left, fc, fn))
    best = torch.where(fc < fe, c, e)
    return best, crit.sign * torch.minimum(fc, fe)
