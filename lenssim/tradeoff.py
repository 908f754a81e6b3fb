"""Cost-performance trade-off (paper Section 2.4): the best design on each iso-cost curve.

For cost levels ``C`` (paper: 30 levels uniform in [0, 2e-3]) the iso-cost curve ``C_a(s, Q) = C`` is
located *exactly* from the cost model, not from the sweep grid: at fixed ``s`` the cost grows
monotonically with ``|Q|`` (zero at ``Q = 0``), so each ``s`` has at most one solution with
``Q < 0`` and one with ``Q > 0``, found by bisection to 1e-12 in ``Q``. Each criterion (RMS_W,
MSE_S and MSE_R at each SNR) is then interpolated from the sweep grid with bicubic splines along
the curve (sampled every ``ds`` in ``s``), and the minimum is refined by a parabola through the
three best samples. The precision of the interpolated optimum is checked by evaluating the model
directly at the optima (``check_with_model``); see ``docs/reproduction.md``.

The "minimal cost for a given quality" view is the same set of curves read the other way:
:func:`min_cost_for_quality`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import xarray as xr
from scipy.interpolate import RectBivariateSpline

from .cost import slope_departure_cost
from .lens import ThinLens

__all__ = ["PAPER_COST_LEVELS", "iso_cost_curve", "criteria_of", "tradeoff", "min_cost_for_quality", "TradeoffPoint"]

PAPER_COST_LEVELS = np.linspace(0.0, 2e-3, 30)


def iso_cost_curve(lens: ThinLens, level: float, s_values, Q_range=(-10.0, 1.2), *, cost_points: int = 101,
                   iterations: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``(s, Q, branch)`` with ``C_a(s, Q) = level`` inside ``Q_range``.

    ``branch`` is -1 for ``Q < 0`` and +1 for ``Q > 0``. For ``level = 0`` the curve is ``Q = 0`` (and
    the line ``s = 1``, which is returned as the ``s`` values equal to 1 with ``Q`` over the range).
    """
    s = torch.as_tensor(np.asarray(s_values, dtype=np.float64))
    out_s, out_q, out_b = [], [], []
    if level <= 0:
        return s.numpy(), np.zeros(len(s)), np.zeros(len(s), dtype=int)
    for branch, q_end in ((-1, Q_range[0]), (1, Q_range[1])):
        if branch * q_end <= 0:
            continue
        c_end = slope_departure_cost(lens, s, torch.full_like(s, q_end), cost_points)
        ok = c_end >= level
        if not ok.any():
            continue
        lo = torch.zeros_like(s[ok])
        hi = torch.full_like(lo, q_end)
        for _ in range(iterations):  # bisection on |Q|: cost(lo) < level <= cost(hi)
            mid = 0.5 * (lo + hi)
            above = slope_departure_cost(lens, s[ok], mid, cost_points) >= level
            hi = torch.where(above, mid, hi)
            lo = torch.where(above, lo, mid)
        out_s.append(s[ok].numpy())
        out_q.append((0.5 * (lo + hi)).numpy())
        out_b.append(np.full(int(ok.sum()), branch))
    if not out_s:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    return np.concatenate(out_s), np.concatenate(out_q), np.concatenate(out_b)


def criteria_of(ds: xr.Dataset) -> dict[str, xr.DataArray]:
    """The sweep's criteria as 2-D (s, Q) landscapes: ``rms_w``, ``mse_s@SNR``, ``mse_r@SNR``."""
    out = {"rms_w": ds["rms_w"]}
    for k in ("mse_s", "mse_r"):
        for snr in ds["snr"].values:
            out[f"{k}@{snr:g}"] = ds[k].sel(snr=snr)
    return out


@dataclass
class TradeoffPoint:
    criterion: str
    level: float
    s: float
    Q: float
    value: float


def _spline(da: xr.DataArray) -> RectBivariateSpline:
    """Bicubic interpolant of a (s, Q) landscape (lower degree on grids of fewer than 4 points)."""
    s, q = da["s"].values, da["Q"].values
    return RectBivariateSpline(s, q, da.transpose("s", "Q").values, kx=min(3, len(s) - 1), ky=min(3, len(q) - 1))


def tradeoff(ds: xr.Dataset, lens: ThinLens | None = None, levels=PAPER_COST_LEVELS, *, ds_step: float = 0.002,
             cost_points: int | None = None) -> xr.Dataset:
    """Best design of every criterion on every iso-cost level.

    Returns a dataset with dims ``(criterion, level)``: ``s``, ``Q`` (the optimum), ``value`` (the
    criterion there), ``cost`` (C_a recomputed at the optimum), and ``mse_r_ref`` (MSE_R at the
    sweep's middle SNR at that design, for Fig. 6).
    """
    import json

    cfg = json.loads(ds.attrs.get("config", "{}"))
    if lens is None:
        lens = ThinLens(**cfg["lens"]) if "lens" in cfg else ThinLens()
    cost_points = cost_points or cfg.get("cost_points", 101)
    s_grid, q_grid = ds["s"].values, ds["Q"].values
    s_fine = np.arange(s_grid[0], s_grid[-1] + 1e-12, ds_step)
    crits = criteria_of(ds)
    splines = {k: _spline(v) for k, v in crits.items()}
    mid = float(ds["snr"].values[len(ds["snr"]) // 2])
    ref = splines[f"mse_r@{mid:g}"]
    names = list(crits)
    res = {k: np.full((len(names), len(levels)), np.nan) for k in ("s", "Q", "value", "cost", "mse_r_ref")}
    for j, level in enumerate(levels):
        cs, cq, cb = iso_cost_curve(lens, float(level), s_fine, (q_grid[0], q_grid[-1]), cost_points=cost_points)
        if level <= 0:  # zero cost: Q = 0 line, plus the flat-back line s = 1 if on the grid
            cs, cq = np.concatenate([cs, np.full(len(q_grid), 1.0)]), np.concatenate([cq, q_grid])
            inside = cs <= s_grid[-1] + 1e-12
            cs, cq = cs[inside], cq[inside]
            cb = np.zeros(len(cs), dtype=int)
        if len(cs) == 0:
            continue
        for i, name in enumerate(names):
            v = splines[name].ev(cs, cq)
            k = int(np.argmin(v))
            s_opt, q_opt, v_opt = cs[k], cq[k], v[k]
            same = np.nonzero(cb == cb[k])[0]
            pos = np.searchsorted(same, k)
            if 0 < pos < len(same) - 1 and level > 0:  # parabola through the best sample and its neighbours
                i0, i1, i2 = same[pos - 1], same[pos], same[pos + 1]
                y0, y1, y2 = v[i0], v[i1], v[i2]
                den = y0 - 2 * y1 + y2
                if den > 0:
                    t = 0.5 * (y0 - y2) / den  # in units of the s step, within (-1, 1)
                    s_try = cs[i1] + t * (cs[i2] - cs[i1] if t > 0 else cs[i1] - cs[i0])
                    ts, tq, _ = iso_cost_curve(lens, float(level), [s_try], (q_grid[0], q_grid[-1]),
                                               cost_points=cost_points)
                    if len(ts):
                        q_try = tq[np.argmin(np.abs(tq - q_opt))]
                        v_try = float(splines[name].ev(s_try, q_try))
                        if v_try <= v_opt:
                            s_opt, q_opt, v_opt = float(s_try), float(q_try), v_try
            res["s"][i, j], res["Q"][i, j], res["value"][i, j] = s_opt, q_opt, v_opt
            res["cost"][i, j] = float(slope_departure_cost(lens, s_opt, q_opt, cost_points))
            res["mse_r_ref"][i, j] = float(ref.ev(s_opt, q_opt))
    out = xr.Dataset({k: (("criterion", "level"), v) for k, v in res.items()},
                     coords={"criterion": names, "level": np.asarray(levels, dtype=np.float64)})
    out["level"].attrs = {"long_name": "iso-cost level C_a", "units": "1 (slope)"}
    out.attrs = {"reference_snr_db": mid, "method": "exact iso-cost curves (bisection on the cost model), "
                 f"bicubic interpolation of the sweep along them every {ds_step} in s, parabolic refinement"}
    return out


def min_cost_for_quality(trade: xr.Dataset, criterion: str, quality: float) -> float:
    """Smallest iso-cost level whose optimum reaches ``criterion <= quality`` (NaN if none)."""
    v = trade["value"].sel(criterion=criterion).values
    ok = np.nonzero(v <= quality)[0]
    return float(trade["level"].values[ok[0]]) if len(ok) else float("nan")
