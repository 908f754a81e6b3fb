"""Cost-performance trade-off (paper Section 2.4): the best design on each iso-cost curve.

For cost levels ``C`` (paper: 30 levels uniform in [0, 2e-3]) the iso-cost curve ``C_a(s, Q) = C`` is
located *exactly* from the cost model, not from the sweep grid. The sweep's two design dimensions
are read from the dataset: the curve runs along the first (``s``) and is solved for in the second,
a conic constant (``Q_back``): at fixed ``s`` the cost grows monotonically with ``|Q|`` (zero at
``Q = 0``), so each ``s`` has at most one solution with ``Q < 0`` and one with ``Q > 0``, found by
bisection to 1e-12 in ``Q``. Each criterion (RMS_W,
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

from lenssim.optics.cost import DEFAULT_COST_POINTS, slope_departure_cost
from lenssim.criteria import CRITERIA, lens_criteria, quality_criteria, validate_criterion
from lenssim.model.design import Design
from lenssim.model.lens import Lens
from .paper import PAPER_COST_LEVELS, REFERENCE_SNR_DB
from .sweep import SweepConfig, design_dims
from lenssim_studies.paper import PAPER_LENS

__all__ = ["PAPER_COST_LEVELS", "iso_cost_curve", "iso_cost_curves", "criteria_of", "tradeoff", "min_cost_for_quality", "TradeoffPoint",
           "find_optimum"]


def iso_cost_curve(lens: Lens, level: float, s_values, Q_range=(-10.0, 1.2), *, cost_points: int = DEFAULT_COST_POINTS,
                   iterations: int = 60, dims: tuple[str, str] = ("s", "Q_back")) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``(s, Q, branch)`` with ``C_a(s, Q) = level`` inside ``Q_range``.

    ``dims`` names the two design parameters: the one the curve runs along (given values
    ``s_values``) and the conic constant solved for. ``branch`` is -1 for ``Q < 0`` and +1 for
    ``Q > 0``. For ``level = 0`` the curve is ``Q = 0`` (and the line ``s = 1``, which is returned
    as the ``s`` values equal to 1 with ``Q`` over the range).
    """
    s = np.asarray(s_values, dtype=np.float64).reshape(-1)
    return iso_cost_curves(lens, [level], s, Q_range, cost_points=cost_points, iterations=iterations, dims=dims)[0]


def iso_cost_curves(lens: Lens, levels, s_values, Q_range=(-10.0, 1.2), *, cost_points: int = DEFAULT_COST_POINTS,
                    iterations: int = 60, dims: tuple[str, str] = ("s", "Q_back"), pairs: bool = False) -> list:
    """:func:`iso_cost_curve` for every level of ``levels`` (a list of its results, one per level), solved together:
    each bisection step evaluates the cost of every level's points in one batch (each point's arithmetic is its own,
    so the result is the same as one level at a time). ``pairs``: ``s_values[i]`` belongs to ``levels[i]`` alone
    (one point per level) instead of every level running along all of ``s_values``."""
    cost = lambda a, b: slope_departure_cost(lens, Design({dims[0]: a, dims[1]: b}), cost_points)  # noqa: E731
    s_in = torch.as_tensor(np.asarray(s_values, dtype=np.float64)).reshape(-1)
    lv_in = np.asarray(levels, dtype=np.float64).reshape(-1)
    if pairs:
        if len(lv_in) != len(s_in):
            raise ValueError(f"pairs: {len(lv_in)} levels for {len(s_in)} points")
        s, lv, owner = s_in, torch.as_tensor(lv_in), torch.arange(len(lv_in))
    else:
        s = s_in.repeat(len(lv_in))
        lv = torch.as_tensor(lv_in).repeat_interleave(len(s_in))
        owner = torch.arange(len(lv_in)).repeat_interleave(len(s_in))
    found = {}  # (branch) -> (mask over the points, Q)
    live = lv > 0
    for branch, q_end in ((-1, Q_range[0]), (1, Q_range[1])):
        if branch * q_end <= 0 or not bool(live.any()):
            continue
        idx = torch.nonzero(live).flatten()
        c_end = cost(s[idx], torch.full_like(s[idx], q_end))
        ok = c_end >= lv[idx]
        idx = idx[ok]
        if not idx.numel():
            continue
        lo = torch.zeros_like(s[idx])
        hi = torch.full_like(lo, q_end)
        for _ in range(iterations):  # bisection on |Q|: cost(lo) < level <= cost(hi)
            mid = 0.5 * (lo + hi)
            above = cost(s[idx], mid) >= lv[idx]
            hi = torch.where(above, mid, hi)
            lo = torch.where(above, lo, mid)
        found[branch] = (idx, 0.5 * (lo + hi))
    out = []
    for j, level in enumerate(lv_in):
        mine = torch.nonzero(owner == j).flatten()
        if level <= 0:
            out.append((s[mine].numpy(), np.zeros(len(mine)), np.zeros(len(mine), dtype=int)))
            continue
        out_s, out_q, out_b = [], [], []
        for branch, (idx, q) in found.items():
            sel = owner[idx] == j
            out_s.append(s[idx[sel]].numpy())
            out_q.append(q[sel].numpy())
            out_b.append(np.full(int(sel.sum()), branch))
        if not out_s or not sum(len(v) for v in out_s):
            out.append((np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)))
        else:
            out.append((np.concatenate(out_s), np.concatenate(out_q), np.concatenate(out_b)))
    return out


def criteria_of(ds: xr.Dataset, criteria=None) -> dict[str, xr.DataArray]:
    """The sweep's quality criteria as design-space landscapes, ``NAME`` or ``NAME@SNR`` (e.g. ``rms_w``,
    ``mse_s@27.6``): ``criteria`` (names, in that order), default every registered criterion whose role is
    quality and that the sweep holds."""
    names = [k for k in quality_criteria() if k in ds] if criteria is None else list(criteria)
    out = {}
    for name in names:
        c = validate_criterion(name)
        if c.role != "quality":
            raise ValueError(f"criterion {name!r} is a {c.role}, not an image-quality criterion: the trade-off "
                             "weighs quality against the cost")
        if name not in ds:
            raise ValueError(f"criterion {name!r} is not in this sweep; it holds {', '.join(k for k in CRITERIA if k in ds)}")
        if c.per_snr:
            for snr in ds["snr"].values:
                out[f"{name}@{snr:g}"] = ds[name].sel(snr=snr)
        else:
            out[name] = ds[name]
    return out


def _sense(key: str) -> float:
    """+1 or -1: the sign that makes the landscape ``key`` (``NAME`` or ``NAME@SNR``) one to minimise."""
    return CRITERIA[key.split("@")[0]].sign


@dataclass
class TradeoffPoint:
    criterion: str
    level: float
    s: float
    Q: float
    value: float


def _spline(da: xr.DataArray, dims) -> RectBivariateSpline:
    """Bicubic interpolant of a 2-D design landscape (lower degree on grids of fewer than 4 points)."""
    s, q = da[dims[0]].values, da[dims[1]].values
    return RectBivariateSpline(s, q, da.transpose(*dims).values, kx=min(3, len(s) - 1), ky=min(3, len(q) - 1))


def _two_dims(ds: xr.Dataset) -> tuple[str, str]:
    dims = design_dims(ds)
    if len(dims) != 2:
        raise ValueError(f"the trade-off needs a sweep over two design parameters (along, conic); this one has "
                         f"{list(dims)}")
    return dims


def tradeoff(ds: xr.Dataset, lens: Lens | None = None, levels=PAPER_COST_LEVELS, *, ds_step: float = 0.002,
             cost_points: int | None = None, criteria=None, reference: str = "mse_r") -> xr.Dataset:
    """Best design of every quality criterion on every iso-cost level (minimum or maximum, by its sense).

    ``criteria``: names (default: every quality criterion the sweep holds, :func:`criteria_of`). Returns a
    dataset with dims ``(criterion, level)``: one variable per design dimension (the optimum, e.g. ``s`` and
    ``Q_back``), ``value`` (the criterion there), ``cost`` (C_a recomputed at the optimum), and
    ``REFERENCE_ref`` (the ``reference`` criterion at the sweep's middle SNR at that design, for Fig. 6).
    """
    import json

    dims = _two_dims(ds)
    cfg = SweepConfig.from_dict(json.loads(ds.attrs["config"])) if "config" in ds.attrs else None
    if lens is None:
        lens = cfg.lens if cfg is not None else PAPER_LENS
    cost_points = cost_points or (cfg.numerics.cost_points if cfg is not None else DEFAULT_COST_POINTS)
    if cfg is not None and set(cfg.fixed) - {"focus_shift_um"}:
        raise ValueError(f"the trade-off's iso-cost curves are those of the two gridded parameters alone; this sweep "
                         f"also fixes {sorted(set(cfg.fixed) - {'focus_shift_um'})}, which may add cost")
    s_grid, q_grid = ds[dims[0]].values, ds[dims[1]].values
    s_fine = np.arange(s_grid[0], s_grid[-1] + 1e-12, ds_step)
    crits = criteria_of(ds, criteria)
    splines = {k: _spline(v, dims) for k, v in crits.items()}
    mid = float(ds["snr"].values[len(ds["snr"]) // 2])
    ref_crit = validate_criterion(reference)
    ref = _spline(ds[reference].sel(snr=mid) if ref_crit.per_snr else ds[reference], dims)
    ref_key = f"{reference}_ref"
    names = list(crits)
    res = {k: np.full((len(names), len(levels)), np.nan) for k in dims + ("value", "cost", ref_key)}
    curves = iso_cost_curves(lens, [float(v) for v in levels], s_fine, (q_grid[0], q_grid[-1]), cost_points=cost_points,
                             dims=dims)
    refine = []  # (i, j, s_try, q_opt, sign, s_opt, q_opt, v_opt): solved together below
    for j, level in enumerate(levels):
        cs, cq, cb = curves[j]
        if level <= 0:  # zero cost: Q = 0 line, plus the flat-back line s = 1 if on the grid
            cs, cq = np.concatenate([cs, np.full(len(q_grid), 1.0)]), np.concatenate([cq, q_grid])
            inside = cs <= s_grid[-1] + 1e-12
            cs, cq = cs[inside], cq[inside]
            cb = np.zeros(len(cs), dtype=int)
        if len(cs) == 0:
            continue
        for i, name in enumerate(names):
            sign = _sense(name)
            v = sign * splines[name].ev(cs, cq)  # minimised whatever the criterion's sense
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
                    refine.append((i, j, float(s_try), float(level)))
            res[dims[0]][i, j], res[dims[1]][i, j], res["value"][i, j] = s_opt, q_opt, sign * v_opt
    if refine:  # each refined point's iso-cost Q, every one in one batch
        tried = iso_cost_curves(lens, [r[3] for r in refine], [r[2] for r in refine], (q_grid[0], q_grid[-1]),
                                cost_points=cost_points, dims=dims, pairs=True)
        for (i, j, s_try, _), (ts, tq, _) in zip(refine, tried):
            if len(ts):
                name, sign = names[i], _sense(names[i])
                q_opt, v_opt = res[dims[1]][i, j], sign * res["value"][i, j]
                q_try = tq[np.argmin(np.abs(tq - q_opt))]
                v_try = sign * float(splines[name].ev(s_try, q_try))
                if v_try <= v_opt:
                    res[dims[0]][i, j], res[dims[1]][i, j], res["value"][i, j] = s_try, float(q_try), sign * v_try
    done = np.isfinite(res["value"])
    if done.any():  # the cost recomputed at every optimum, in one batch
        ii, jj = np.nonzero(done)
        res["cost"][ii, jj] = slope_departure_cost(lens, Design({dims[0]: torch.as_tensor(res[dims[0]][ii, jj]),
                                                                 dims[1]: torch.as_tensor(res[dims[1]][ii, jj])}),
                                                   cost_points).numpy()
        res[ref_key][ii, jj] = ref.ev(res[dims[0]][ii, jj], res[dims[1]][ii, jj])
    out = xr.Dataset({k: (("criterion", "level"), v) for k, v in res.items()},
                     coords={"criterion": names, "level": np.asarray(levels, dtype=np.float64)})
    out["level"].attrs = {"long_name": "iso-cost level C_a", "units": "1 (slope)"}
    out.attrs = {"reference_snr_db": mid, "design_parameters": " ".join(dims), "method": "exact iso-cost curves (bisection on the cost model), "
                 f"bicubic interpolation of the sweep along them every {ds_step} in s, parabolic refinement"}
    return out


def min_cost_for_quality(trade: xr.Dataset, criterion: str, quality: float) -> float:
    """Smallest iso-cost level whose optimum reaches ``quality`` (``criterion`` ``NAME`` or ``NAME@SNR``: at most
    ``quality`` for a criterion to minimise, at least for one to maximise; NaN if none)."""
    sign = _sense(criterion)
    v = trade["value"].sel(criterion=criterion).values
    ok = np.nonzero(sign * v <= sign * quality)[0]
    return float(trade["level"].values[ok[0]]) if len(ok) else float("nan")


def find_optimum(ds: xr.Dataset, criterion: str, snr: float | None = None) -> dict:
    """Grid optimum of a registered ``criterion`` in a sweep dataset: its minimum, or its maximum for a
    criterion whose sense is ``"max"`` (``snr`` in dB picks the noise level).

    Returns ``criterion``, ``snr_db``, ``design`` (``{parameter: value}``), ``value``, every criterion the sweep
    holds at that design by name (a number, or ``{"SNR": number}`` for one that depends on the SNR) and
    ``on_grid_boundary``.
    """
    crit = validate_criterion(criterion)
    if criterion not in ds:
        raise ValueError(f"criterion {criterion!r} is not in this sweep; it holds {', '.join(k for k in CRITERIA if k in ds)}")
    dims = design_dims(ds)
    da = ds[criterion]
    if "snr" in da.dims:
        if snr is None:
            snr = REFERENCE_SNR_DB if REFERENCE_SNR_DB in ds["snr"].values else float(ds["snr"].values[len(ds["snr"]) // 2])
        if not np.any(np.isclose(ds["snr"].values, snr)):
            raise ValueError(f"SNR {snr!r} dB is not in the sweep; available: {[float(v) for v in ds['snr'].values]}")
        da = da.sel(snr=snr, method="nearest")
    da = da.transpose(*dims)
    idx = np.unravel_index(int(np.nanargmin(crit.sign * da.values)), da.shape)
    at = dict(zip(dims, idx))
    design = {d: float(ds[d].values[i]) for d, i in at.items()}
    out = {"criterion": criterion, "snr_db": snr, "design": design, "value": float(da.values[idx])}
    for k, c in lens_criteria().items():
        if k in ds:
            v = ds[k][at]
            out[k] = {f"{s:g}": float(v.sel(snr=s)) for s in ds["snr"].values} if "snr" in v.dims else float(v)
    out["on_grid_boundary"] = bool(any(i in (0, ds.sizes[d] - 1) for d, i in at.items()))
    return out
