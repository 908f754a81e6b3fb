"""The cost-performance trade-off (paper Section 2.4) of either kind of lens: the best design on each iso-cost level.

**The paper's singlet** (a sweep dataset of :mod:`lenssim_studies.sweep`; its fast path, :func:`tradeoff`): for cost
levels ``C`` (paper: 30 levels uniform in [0, 2e-3]) the iso-cost curve ``C_a(s, Q) = C`` is located *exactly* from
the cost model, not from the sweep grid. The sweep's two design dimensions are read from the dataset: the curve runs
along the first (``s``) and is solved for in the second, a conic constant (``Q_back``): at fixed ``s`` the cost grows
monotonically with ``|Q|`` (zero at ``Q = 0``), so each ``s`` has at most one solution with ``Q < 0`` and one with
``Q > 0``, found by bisection to 1e-12 in ``Q``. Each criterion (RMS_W, MSE_S and MSE_R at each SNR) is then
interpolated from the sweep grid with bicubic splines along the curve (sampled every ``ds`` in ``s``), and the minimum
is refined by a parabola through the three best samples (see ``docs/reproduction.md``). The "minimal cost for a given
quality" view is the same set of curves read the other way: :func:`min_cost_for_quality`.

**Any lens** (issue 30, item 4; ``lenssim tradeoff --lens``): a :class:`LensTradeoffRun` scores every design of a
grid of a prescription's free parameters (:func:`_evaluate`: real rays or third order) and prices it
(:func:`lenssim.optics.cost.prescription_costs`); a design that cannot be made is kept invalid, with the reason.
Its optima per cost level (:func:`front`) are the best valid designs costing at most each level (the paper's iso-cost
optimum to the grid's resolution). For more free parameters than a grid holds, a :class:`LensGradientRun`
(``--optimise``) runs the paper's iso-cost descent (:func:`lenssim.design_opt.optimise_on_iso_cost`) per level from
several starts. Both runs resume from checksummed chunks (:func:`lenssim_studies.chunks.run_resumable`).
:func:`find_lens_optimum` reads a trade-off back (``lenssim optimum``). Ties go to the first design in the grid's order
(C order), everywhere, so the unconstrained optimum is the one ``tradeoff.json`` lists and ``designs/NAME.toml`` holds.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import xarray as xr
from scipy.interpolate import RectBivariateSpline

from lenssim import __version__
from lenssim.criteria import CRITERIA, lens_criteria, quality_criteria, validate_criterion
from lenssim.model.design import Design
from lenssim.model.lens import Lens
from lenssim.model.lens_parameters import LensParameter, parameter_values, parse_parameter
from lenssim.model.numerics import DEFAULT_NUMERICS, Numerics
from lenssim.model.prescription import Prescription
from lenssim.model.spectrum import Spectrum
from lenssim.optics.cost import DEFAULT_COST_POINTS, slope_departure_cost
from lenssim.optics.lens_solves import solve_design
from lenssim.optics.sequential import SequentialLens
from lenssim.optics.psf_bank import TABLE_INITIAL_NODES, TABLE_MAX_NODES
from lenssim.optics.psf_provider import SequentialPSF
from lenssim.metrics import evaluate_sequential, evaluate_third_order, evaluation_angles
from lenssim.validate import ModelValidityWarning, check_distinct, check_snr_db

from .chunks import read_stamped_chunk, result_mismatch, resume_chunks, run_resumable, write_stamped_chunk
from .paper import PAPER_CAMERA, PAPER_COST_LEVELS, PAPER_LENS, REFERENCE_SNR_DB
from .sweep import SweepConfig, design_dims

__all__ = [
    # the singlet's sweep
    "PAPER_COST_LEVELS", "iso_cost_curve", "iso_cost_curves", "criteria_of", "tradeoff", "min_cost_for_quality",
    "find_optimum",
    # any lens: the grid, its front, reading it back
    "LensTradeoffRun", "run_lens_tradeoff", "front", "end_to_end_gain", "tradeoff_json",
    "design_prescription", "write_design_files", "TRADEOFF_CRITERIA", "tradeoff_mismatch", "check_psf_sampling",
    "sequential_provider", "photo_field", "PhotoFieldError", "MAX_GRID_PARAMETERS", "MAX_GRID_DESIGNS",
    "CHUNK_DESIGNS", "TRADEOFF_ANGLES", "WAVEFRONTS", "TRADEOFF_TITLE", "TRADEOFF_FILE", "OPTIMUM_CRITERIA",
    "COST_TOLERANCE", "is_lens_tradeoff", "check_lens_tradeoff", "verify_lens_tradeoff", "check_design_file",
    "check_max_cost", "resolve_criterion", "find_lens_optimum", "design_file_name", "tradeoff_run_from_dict",
    "rebuild_run", "write_optimum_lens",
    # any lens: the gradient route
    "LensGradientRun", "run_lens_gradient", "gradient_json", "score_optima", "STOP_REASONS",
    "MAX_STARTS", "MAX_STEPS", "TYPICAL_STEPS",
]


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


def criteria_of(ds: xr.Dataset, criteria=None, *, first_bare: bool = False) -> dict[str, xr.DataArray]:
    """The sweep's quality criteria as design-space landscapes, ``NAME`` or ``NAME@SNR`` (e.g. ``rms_w``,
    ``mse_s@27.6``): ``criteria`` (names, in that order), default every registered criterion whose role is
    quality and that the sweep holds. ``first_bare``: a per-SNR criterion at the first SNR is named ``NAME`` (as
    ``tradeoff.json`` and ``lenssim optimum`` name a trade-off's of any lens)."""
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
            for j, snr in enumerate(ds["snr"].values):
                out[name if first_bare and j == 0 else f"{name}@{snr:g}"] = ds[name].sel(snr=snr)
        else:
            out[name] = ds[name]
    return out


def _sense(key: str) -> float:
    """+1 or -1: the sign that makes the landscape ``key`` (``NAME`` or ``NAME@SNR``) one to minimise."""
    return CRITERIA[key.split("@")[0]].sign


def _sense_name(key: str) -> str:
    """``min`` or ``max``: the sense of the landscape ``key`` (``NAME`` or ``NAME@SNR``)."""
    return CRITERIA[key.split("@")[0]].sense


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


def find_optimum(ds: xr.Dataset, criterion: str, snr: float | None = None, max_cost: float | None = None) -> dict:
    """Grid optimum of a registered ``criterion`` in a sweep dataset: its minimum, or its maximum for a
    criterion whose sense is ``"max"`` (``snr`` in dB picks the noise level), among the designs whose cost is at most
    ``max_cost`` if given (as :func:`find_lens_optimum` takes a cost limit: a one-line ``ValueError`` naming the
    cheapest cost if no design is within it).

    Returns ``criterion``, ``snr_db``, ``design`` (``{parameter: value}``), ``value``, every criterion the sweep
    holds at that design by name (a number, or ``{"SNR": number}`` for one that depends on the SNR) and
    ``on_grid_boundary``.
    """
    max_cost = check_max_cost(max_cost)
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
    if max_cost is not None:
        if "cost" not in ds:
            raise ValueError("--max-cost: this sweep holds no cost")
        cost = ds["cost"]
        finite = np.isfinite(cost.values)
        if not finite.any():
            raise ValueError("--max-cost: this sweep's costs are not finite")
        within = cost.copy(data=_within(cost.values, max_cost) & finite)
        if not within.values.any():
            raise ValueError(f"--max-cost {max_cost:g} is below every design's cost: the cheapest design costs "
                             f"{float(cost.values[finite].min())!r}")
        da = da.where(within)
        if not np.isfinite(da.values).any():
            raise ValueError(f"--max-cost {max_cost:g}: no design within this cost has a finite {criterion}")
    da = da.transpose(*dims)
    idx = np.unravel_index(int(np.nanargmin(crit.sign * da.values)), da.shape)
    at = dict(zip(dims, idx))
    design = {d: float(ds[d].values[i]) for d, i in at.items()}
    out = {"criterion": criterion, "snr_db": snr, "design": design, "value": float(da.values[idx])}
    out |= _criteria_at(ds, at, [k for k in lens_criteria() if k in ds])
    out["on_grid_boundary"] = bool(any(i in (0, ds.sizes[d] - 1) for d, i in at.items()))
    return out


# -- optima at most a cost, of either kind ------------------------------------------------------------------------
COST_TOLERANCE = (1e-12, 1e-15)
"""``cost <= C * (1 + rel) + abs``: a design at the level ``C`` counts (the grid's front, its end-to-end gain and
``lenssim optimum --max-cost``)."""
GRADIENT_COST_TOLERANCE = (1e-9, 0.0)
"""The same for a descent's end point: its projection onto its level stops within 1e-10 of it, relative."""


def check_max_cost(max_cost) -> float | None:
    if max_cost is None:
        return None
    if isinstance(max_cost, bool) or not isinstance(max_cost, (int, float)) or not math.isfinite(max_cost):
        raise ValueError(f"--max-cost {max_cost!r} is not allowed: a finite asphere cost C_a")
    return float(max_cost)


def _within(cost, limit: float, tolerance=COST_TOLERANCE):
    rel, tol = tolerance
    return cost <= limit * (1 + rel) + tol


def _criteria_at(ds: xr.Dataset, at: dict, names) -> dict:
    """Each criterion of ``names`` at the grid point ``at`` (``{dim: index}``): a number, or ``{"SNR": number}``."""
    out = {}
    for k in names:
        v = ds[k].isel(at)
        out[k] = {f"{float(s):g}": float(v.sel(snr=s)) for s in ds["snr"].values} if "snr" in v.dims else float(v)
    return out


def _first_best(score: np.ndarray, mask: np.ndarray) -> int:
    """The first index (the grid's order) of the least ``score`` among ``mask``."""
    return int(np.flatnonzero(mask)[np.argmin(score[mask])])


# -- any lens: its PSFs on the paper's sensor ---------------------------------------------------------------------
TRADEOFF_CRITERIA = ("rms_w", "mse_s", "mse_r", "strehl", "mtf50")
"""What each design is scored on (field averages; ``mse_s`` and ``mse_r`` per SNR)."""
MAX_GRID_PARAMETERS = 3
"""A grid sweep's most free parameters (more: a grid's size grows as the power)."""
MAX_GRID_DESIGNS = 20_000
"""A grid's most designs (each traces its own wavefronts: seconds a design)."""
CHUNK_DESIGNS = 8
"""Designs per chunk file."""
TRADEOFF_ANGLES = 5
"""Field angles of each design's field average (the exact route), from the axis to the lens's largest, evenly."""
WAVEFRONTS = ("exact", "third_order")
"""How each design's wavefront is obtained (:attr:`LensTradeoffRun.wavefront`)."""
TRADEOFF_TITLE = "lenssim trade-off of any lens"
"""The ``title`` attribute of a trade-off file (:func:`run_lens_tradeoff`)."""
TRADEOFF_FILE = "tradeoff.nc"
"""The trade-off's data file in its output folder."""
OPTIMUM_CRITERIA = TRADEOFF_CRITERIA + ("cost",)
"""What a trade-off's optimum may be of (``cost``: the cheapest valid design)."""


def sequential_provider(p: Prescription, seq: SequentialLens, *, pitch_um: float, sampling: str,
                        max_field_deg: float, numerics: Numerics = DEFAULT_NUMERICS, coarse: bool = False,
                        width_px: int = 1, height_px: int = 1, colour_channels=()) -> SequentialPSF:
    """The PSFs of ``seq`` on the paper's sensor (its noise and full wells) with ``width_px`` x ``height_px`` pixels of
    ``pitch_um``, in the lens's own wavelengths (equal weights) or in ``colour_channels`` (each a
    :class:`lenssim.Spectrum`), traced out to ``max_field_deg``; ``coarse``: the wavefront table at its initial field
    nodes only."""
    sensor = replace(PAPER_CAMERA.sensor, pixel_pitch_um=pitch_um, width_px=width_px, height_px=height_px)
    light = Spectrum(p.wavelengths_um, (1.0,) * len(p.wavelengths_um),
                     name=f"the lens's {len(p.wavelengths_um)} wavelength(s)")
    return SequentialPSF(seq, sensor, light, tuple(colour_channels), max_field_deg=max_field_deg, sampling=sampling,
                         numerics=numerics, table_max_nodes=TABLE_INITIAL_NODES if coarse else TABLE_MAX_NODES)


def photo_field(p: Prescription, seq: SequentialLens, shape, *, pitch_um: float | None = None,
                margin_px: float = 0.0) -> tuple[float, float]:
    """The pixel pitch (um) and the largest field angle (deg) of a photo of ``shape`` ``(..., H, W)`` taken through
    ``seq``, where the angle reaches ``margin_px`` past the photo's corners (the blur's windows reach past the frame's
    edges by up to half a core on each axis: their PSFs too). By default the pitch puts that reach at the lens's
    largest field, so the photo spans the lens's field and every PSF asked for lies within it; ``pitch_um``: the given
    pitch, refused (:class:`PhotoFieldError`, with the pitch that would fit) where the lens's chief ray does not pass
    at the reach it gives."""
    from lenssim.optics.psf_bank import image_scale_mm

    H, W = shape[-2:]
    reach_px = math.hypot(H - 1, W - 1) / 2 + margin_px
    scale = image_scale_mm(seq)
    amax = max(p.fields)
    fit_um = scale * math.tan(math.radians(amax)) / reach_px * 1e3 if amax > 0 else None
    if pitch_um is None:
        if fit_um is None:
            raise ValueError("the lens has only the axial field: give a pixel pitch (um) for the sensor")
        return float(fit_um), float(amax)
    reach = math.degrees(math.atan(reach_px * pitch_um * 1e-3 / scale))
    if reach > amax:
        from lenssim.optics.sequential import RayTraceError
        from lenssim.optics.psf_bank import chief_point_mm

        try:
            for lam in p.wavelengths_um:
                chief_point_mm(seq, reach, lam)
        except RayTraceError as exc:
            where = f"{reach:.4g} deg at the photo's corners" + (f" and the blur's {margin_px:g} px margin beyond them"
                                                                 if margin_px else "")
            hint = (f"a pitch of at most {fit_um:.4g} um keeps the photo within the lens's {amax:g} deg field"
                    if fit_um is not None else "the lens gives no field to fit the photo in")
            raise PhotoFieldError(f"a pixel pitch of {pitch_um:g} um puts {where}, where this lens forms no image "
                                  f"({exc}); {hint}", fit_um) from None
    return float(pitch_um), reach


class PhotoFieldError(ValueError):
    """A pixel pitch that puts a photo's corners beyond the field a lens images; ``fit_um`` the pitch that fits."""

    def __init__(self, message: str, fit_um: float | None):
        super().__init__(message)
        self.fit_um = fit_um


def check_psf_sampling(psf: SequentialPSF, numerics: Numerics) -> None:
    """Refuse the pixels of ``psf`` if an aberration-free PSF on them (its diffraction alone) needs more than
    ``numerics.max_fft_size``: its pixel grid, or the finer grid an area sample is computed on (a
    :class:`lenssim.validate.ResourceLimitError`; cheap: no ray is traced)."""
    from lenssim.metrics import _grid_size
    from lenssim.validate import ResourceLimitError

    n = _grid_size(psf, psf.margin_px(), numerics)
    if psf.fft_size(n) > numerics.max_fft_size:
        raise ResourceLimitError(f"a PSF sampled over the pixels' area needs an FFT of {psf.fft_size(n)} samples "
                                 f"({psf.oversample()} per pixel); the limit is max_fft_size = {numerics.max_fft_size}",
                                 "max_fft_size")


# -- any lens: what a run of either route shares ------------------------------------------------------------------
class _LensRun:
    """A trade-off run of the lens ``prescription`` (grid or gradient): its free parameters by name, its designs as
    lenses (the solves applied), how they are scored (its ``sampling`` and ``coarse``: see :func:`_evaluate`), its
    digest."""

    def parameter(self, name: str) -> LensParameter:
        return parse_parameter(self.prescription, name, aspherize=self.aspherize)

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]

    @property
    def max_field_deg(self) -> float:
        return max(self.prescription.fields)

    @property
    def evaluation_angles(self) -> tuple[float, ...]:
        """The field angles (deg) each design's criteria average over: the prescription's own (the paper's sampling)."""
        return tuple(float(a) for a in self.prescription.fields)

    def solve(self, design: dict) -> tuple[Prescription, float]:
        """The prescription of the design ``{name: value}`` and its image shift (mm): its solves applied."""
        return solve_design(self.prescription, {self.parameter(k): v for k, v in design.items()}, hold=self.hold,
                            image=self.image)

    def lens_at(self, design: dict) -> SequentialLens:
        """The lens of the design ``{name: value}``, its solves applied."""
        q, shift = self.solve(design)
        return SequentialLens(q, image_shift_mm=shift)

    def _check_names(self, given) -> None:
        names = [self.parameter(n).name for n in given]
        if len(set(names)) != len(names):
            raise ValueError(f"a free parameter is named twice: {', '.join(names)}")


def _evaluate(run: _LensRun, seq: SequentialLens) -> dict:
    """Every criterion of :data:`OPTIMUM_CRITERIA` of the lens ``seq`` as ``run`` scores its designs (its SNRs, pixels,
    image model, numerics and evaluation angles): the third-order wavefront
    (:func:`lenssim.metrics.evaluate_third_order`) or the real rays'
    (:func:`lenssim.metrics.evaluate_sequential`)."""
    if run.wavefront == "third_order":
        return evaluate_third_order(seq, run.snr_db, pitch_um=run.pitch_um, rho0=run.rho0,
                                    angles_deg=run.evaluation_angles, numerics=run.numerics, criteria=OPTIMUM_CRITERIA)
    psf = sequential_provider(seq.prescription, seq, pitch_um=run.pitch_um, sampling=run.sampling,
                              max_field_deg=run.max_field_deg, numerics=run.numerics, coarse=run.coarse)
    return evaluate_sequential(psf, run.snr_db, rho0=run.rho0, numerics=run.numerics, angles_deg=run.evaluation_angles,
                               criteria=OPTIMUM_CRITERIA)


def design_prescription(run: _LensRun, design: dict) -> Prescription:
    """The prescription of one design of ``run`` (``{name: value}``), its solves applied and its image shift folded
    into the last thickness (a file that stands alone: ``--lens`` on every command)."""
    q, shift = run.solve(design)
    surfs = list(q.surfaces)
    surfs[-1] = replace(surfs[-1], thickness_mm=surfs[-1].thickness_mm + shift)
    label = ", ".join(f"{k} = {v:.6g}" for k, v in design.items())
    return replace(q, surfaces=tuple(surfs), name=f"{q.name or run.lens} ({label})",
                   notes=(q.notes + " " if q.notes else "") + f"lenssim tradeoff design: {label}; holds "
                   f"{', '.join(run.hold) or 'none'}; image plane {run.image}.")


def design_file_name(name: str) -> str:
    """The file ``designs/NAME.toml`` of an optimum named as ``tradeoff.json`` names it (``@`` written ``_at_``)."""
    return name.replace("@", "_at_") + ".toml"


def write_design_files(run: _LensRun, res: dict, folder: Path) -> dict[str, str]:
    """Each optimum of ``res`` (``tradeoff.json`` of either route) as a TOML prescription in ``folder``
    (:func:`design_prescription`): the grid's each criterion's unconstrained optimum as ``NAME.toml`` (``{criterion:
    file name}``); the gradient route's each level's optimum as ``CRITERION_level_KK.toml`` (from 01) and the
    unconstrained one as ``CRITERION.toml`` (``{"level_KK" or "unconstrained": file name}``)."""
    from lenssim.io.prescription_file import write_prescription_toml

    if res.get("method") == "gradient":
        c = res["criterion"]
        entries = [(f"level_{k + 1:02d}", f"{c}_level_{k + 1:02d}", o) for k, o in enumerate(res["optima"][c])]
        entries.append(("unconstrained", c, res["unconstrained"][c]))
    else:
        entries = [(name, name, u) for name, u in res["unconstrained"].items()]
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for key, name, o in entries:
        if o is not None:
            fname = design_file_name(name)
            write_prescription_toml(design_prescription(run, o["design"]), folder / fname)
            out[key] = f"{folder.name}/{fname}"
    return out


# -- any lens: the grid -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LensTradeoffRun(_LensRun):
    """A trade-off of the lens ``prescription`` (as read from ``lens``): ``vary`` ``((name, values), ...)`` the free
    parameters and their grid values (names as :func:`lenssim.model.lens_parameters.parse_parameter` reads them),
    ``hold`` and ``image`` the solves, ``aspherize`` surfaces (1-based) made even aspheres, the SNRs (dB), the image
    model's correlation, the pixel pitch (um; the same sensor for every design) and sampling, the numerics, whether
    the wavefront tables are coarse, and the number of cost levels."""

    prescription: Prescription
    lens: str
    vary: tuple[tuple[str, tuple[float, ...]], ...]
    snr_db: tuple[float, ...]
    rho0: float
    pitch_um: float
    sampling: str
    numerics: Numerics
    hold: tuple[str, ...] = ()
    image: str = "file"
    aspherize: tuple[int, ...] = ()
    coarse: bool = True
    levels: int = 30
    angles: int = TRADEOFF_ANGLES
    wavefront: str = "exact"
    """``exact`` (real-ray OPD, :func:`lenssim.metrics.evaluate_sequential`, at :attr:`angles` field angles
    evenly) or ``third_order`` (the Seidel wavefront, :func:`lenssim.metrics.evaluate_third_order`, at
    the prescription's own field angles, point samples: the paper's route)."""

    def __post_init__(self):
        if not 1 <= len(self.vary) <= MAX_GRID_PARAMETERS:
            raise ValueError(f"{len(self.vary)} free parameters are not allowed in a grid sweep: 1 to "
                             f"{MAX_GRID_PARAMETERS}")
        self._check_names(n for n, _ in self.vary)
        for n, v in self.vary:
            if not v or not all(math.isfinite(x) for x in v):
                raise ValueError(f"--vary {n}: its values must be finite numbers, at least one")
        if self.size > MAX_GRID_DESIGNS:
            raise ValueError(f"a grid of {self.size} designs is not allowed: at most {MAX_GRID_DESIGNS} (fewer values "
                             "per parameter)")
        from lenssim.optics.lens_solves import IMAGE_PLANES, check_solves

        check_solves(self.prescription, [self.parameter(n) for n, _ in self.vary], hold=self.hold)
        if self.image not in IMAGE_PLANES:
            raise ValueError(f"image plane {self.image!r} is not allowed: one of {', '.join(IMAGE_PLANES)}")
        if self.levels < 2:
            raise ValueError(f"levels={self.levels} is not allowed: at least 2 cost levels")
        check_snr_db(self.snr_db, "snr_db", warn=False)  # the criteria's rule, before the grid (it warns there)
        check_distinct("snr_db", self.snr_db, as_written=True)
        if self.wavefront not in WAVEFRONTS:
            raise ValueError(f"wavefront {self.wavefront!r} is not allowed: one of {', '.join(WAVEFRONTS)}")
        if self.wavefront == "third_order":
            from lenssim.optics.seidel_wavefront import check_third_order_parameters

            check_third_order_parameters([self.parameter(n) for n, _ in self.vary])
            if self.sampling != "point":
                raise ValueError("the third-order route samples the PSF at points (the paper's image model): "
                                 f"sampling {self.sampling!r} is not allowed with it")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.parameter(n).name for n, _ in self.vary)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for _, v in self.vary)

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    def design(self, i: int) -> dict[str, float]:
        """Design ``i`` of the grid (C order: the last parameter fastest) as ``{name: value}``."""
        idx = np.unravel_index(i, self.shape)
        return {name: float(v[j]) for name, (_, v), j in zip(self.names, self.vary, idx)}

    def to_dict(self) -> dict:
        out = {"prescription": self.prescription.to_dict(), "lens": self.lens,
               "vary": [[n, list(v)] for n, v in zip(self.names, (v for _, v in self.vary))],
               "snr_db": list(self.snr_db), "rho0": self.rho0, "pitch_um": self.pitch_um, "sampling": self.sampling,
               "numerics": self.numerics.to_dict(), "hold": list(self.hold), "image": self.image,
               "aspherize": list(self.aspherize), "coarse": self.coarse, "levels": self.levels,
               "angles": self.angles, "lenssim_version": __version__}
        if self.wavefront != "exact":  # the exact route's digests as before this option
            out["wavefront"] = self.wavefront
        return out

    def chunks(self) -> list[tuple[int, int]]:
        return [(k, min(k + CHUNK_DESIGNS, self.size)) for k in range(0, self.size, CHUNK_DESIGNS)]

    @property
    def evaluation_angles(self) -> tuple[float, ...]:
        """The field angles (deg) each design's criteria average over: the prescription's own for ``third_order`` (the
        paper's sampling), :attr:`angles` evenly from the axis to the largest for ``exact``."""
        if self.wavefront == "third_order":
            return _LensRun.evaluation_angles.fget(self)
        return evaluation_angles(self.max_field_deg, self.angles)

    def check_sampling(self) -> None:
        """Before any design is scored: pixels on which no design can be, refused (one line). The pixel pitch against
        the lens's diffraction alone (an aberration-free PSF of the file's lens and working F-number): the third-order
        route's point samples need a pitch below ``lambda N_w``; the PSF grid, and an area sample's finer grid, must
        fit ``numerics.max_fft_size``. A design's own aberrations may need more: it is then kept invalid, with the
        reason."""
        from lenssim.optics.aberrations import TERMS
        from lenssim.optics.psf_bank import fft_size
        from lenssim.metrics import third_order_camera
        from lenssim.validate import ResourceLimitError

        seq = SequentialLens(self.prescription)
        what = f"pixels of {self.pitch_um:g} um ({self.sampling} samples) on {self.lens}"
        try:
            if self.wavefront == "third_order":
                camera = third_order_camera(seq, self.pitch_um, self.evaluation_angles)
                fft_size(camera, torch.zeros(len(self.evaluation_angles), len(camera.spectrum), len(TERMS),
                                             dtype=torch.float64), self.numerics, terms=TERMS)
                return
            check_psf_sampling(sequential_provider(self.prescription, seq, pitch_um=self.pitch_um,
                                                   sampling=self.sampling, max_field_deg=self.max_field_deg,
                                                   numerics=self.numerics, coarse=self.coarse), self.numerics)
        except ResourceLimitError as exc:
            raise ResourceLimitError(f"{what}: even an aberration-free design: {exc}", exc.setting) from None
        except ValueError as exc:
            raise ValueError(f"{what}: {exc}") from None


def _score(run: LensTradeoffRun, i: int) -> dict:
    """Design ``i``: its criteria, cost and validity (``reason``: '' if valid)."""
    S = len(run.snr_db)
    nan = {"rms_w": math.nan, "mse_s": [math.nan] * S, "mse_r": [math.nan] * S, "strehl": math.nan,
           "mtf50": math.nan, "cost": math.nan, "efl_mm": math.nan}
    try:
        seq = run.lens_at(run.design(i))
        seq.check_aperture()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ModelValidityWarning)
            r = _evaluate(run, seq)
    except ValueError as exc:  # PrescriptionError, SolveError, RayTraceError, ...: the design is invalid
        return nan | {"reason": str(exc).splitlines()[0][:300], "mtf50_capped": False}
    capped = False
    for w in caught:  # the MTF50 lower bound is recorded per design (mtf50_capped); the SNRs are the run's, said
        # once before the grid (run_lens_tradeoff); anything else is passed on
        if issubclass(w.category, ModelValidityWarning) and str(w.message).startswith("MTF50"):
            capped = True
        elif not (issubclass(w.category, ModelValidityWarning) and str(w.message).startswith("SNR [")):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    out = {k: torch.as_tensor(r[k], dtype=torch.float64).tolist() for k in TRADEOFF_CRITERIA}
    out["cost"] = float(r["cost"])  # prescription_costs over each aspheric surface's clear aperture
    out["efl_mm"] = seq.paraxial().efl_mm
    bad = [k for k in OPTIMUM_CRITERIA if not np.isfinite(np.asarray(out[k])).all()]
    if bad:
        return nan | {"reason": f"not finite: {', '.join(bad)}", "mtf50_capped": False}
    return out | {"reason": "", "mtf50_capped": capped}


_KEYS = OPTIMUM_CRITERIA + ("efl_mm", "mtf50_capped")


def _compute_chunk(run: LensTradeoffRun, i: int, progress) -> dict:
    k0, k1 = run.chunks()[i]
    rows = []
    for k in range(k0, k1):
        rows.append(_score(run, k))
        progress(1)
    chunk = {key: np.asarray([r[key] for r in rows], dtype=np.float64) for key in _KEYS}
    chunk["reason"] = np.asarray([r["reason"] for r in rows], dtype=np.str_)
    return chunk


def _write_chunk(path: Path, chunk: dict, run: LensTradeoffRun, i: int) -> None:
    write_stamped_chunk(path, chunk, run.digest(), i)


def _read_chunk(path: Path, run: LensTradeoffRun, i: int):
    """The chunk's arrays if ``path`` holds chunk ``i`` of this run intact, else the reason it does not."""
    k0, k1 = run.chunks()[i]
    return read_stamped_chunk(path, _KEYS + ("reason",), run.digest(), i, run="trade-off run", rows_key="cost",
                              rows=k1 - k0, what="designs")


def _dataset(run: LensTradeoffRun, chunks: list[dict]) -> xr.Dataset:
    shape = run.shape
    dims = tuple(run.names)
    coords = {n: np.asarray(v, dtype=np.float64) for n, (_, v) in zip(run.names, run.vary)}
    coords["snr"] = np.asarray(run.snr_db, dtype=np.float64)
    data = {}
    for k in _KEYS:
        v = np.concatenate([c[k] for c in chunks])
        if k == "mtf50_capped":
            data[k] = xr.Variable(dims, v.reshape(shape).astype(np.int8),
                                  {"long_name": "1: the design's MTF50 stays above 0.5 up to Nyquist at some field "
                                                "angle, counted there (a lower bound)"})
            continue
        per_snr = v.ndim == 2
        data[k] = xr.Variable(dims + (("snr",) if per_snr else ()), v.reshape(shape + v.shape[1:]),
                              {"units": CRITERIA[k].units if k in CRITERIA else ("mm" if k == "efl_mm" else "1"),
                               "long_name": CRITERIA[k].description if k in CRITERIA else
                               ("paraxial focal length" if k == "efl_mm" else
                                "asphere cost C_a: sum of the aspheric surfaces' RMS slope departure")})
    reason = np.concatenate([c["reason"] for c in chunks]).reshape(shape)
    data["valid"] = xr.Variable(dims, reason == "", {"long_name": "the design could be made and scored"})
    data["reason"] = xr.Variable(dims, reason.astype(str), {"long_name": "why a design is invalid ('' if valid)"})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs = {"title": TRADEOFF_TITLE, "lens": run.lens}
    return ds


def run_lens_tradeoff(run: LensTradeoffRun, out, *, show_progress: bool = True,
                      max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) the grid sweep and write ``out`` (NetCDF); ``None`` if ``max_chunks`` stopped it early."""

    def prepare():
        run.check_sampling()
        check_snr_db(run.snr_db)  # outside where the criteria were validated: said once, here

    def build(part):
        ranges = run.chunks()
        paths = [part / f"chunk_{i:05d}.npz" for i in range(len(ranges))]
        chunks = resume_chunks(paths, kind="trade-off", read=lambda p, i: _read_chunk(p, run, i),
                               write=lambda p, chunk, i: _write_chunk(p, chunk, run, i),
                               compute=lambda i, progress: _compute_chunk(run, i, progress),
                               weight=lambda i: ranges[i][1] - ranges[i][0], desc="designs", unit="design",
                               show_progress=show_progress, max_chunks=max_chunks)
        return None if chunks is None else _dataset(run, chunks)

    return run_resumable(run, out, output="trade-off output", kind="trade-off", check=tradeoff_mismatch,
                         refusal="chunks of a different trade-off", build=build, prepare=prepare)


def tradeoff_mismatch(ds: xr.Dataset) -> str | None:
    """Why the trade-off ``ds`` makes no sense for the run its ``config`` records, or None: its grid (each parameter's
    coordinate and the variables' dimensions) and SNRs are the run's, ``valid`` says what ``reason`` says, every
    criterion, the cost and the focal length of a valid design are finite (the criteria and the cost >= 0), an invalid
    design's are NaN, and ``mtf50_capped`` is 0 or 1 (0 where invalid)."""
    try:
        d = json.loads(ds.attrs["config"])
        vary = {str(n): np.asarray(v, dtype=np.float64) for n, v in d["vary"]}
        snr = np.asarray(d["snr_db"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return "it carries no readable run record (config)"
    names = tuple(vary)
    missing = [k for k in _KEYS + ("valid", "reason") if k not in ds]
    if missing:
        return f"it holds no {', '.join(missing)}"
    for k in _KEYS + ("valid", "reason"):
        want = names + (("snr",) if k in ("mse_s", "mse_r") else ())
        if tuple(ds[k].dims) != want:
            return f"its {k} is not over the run's grid ({', '.join(want)})"
    why = result_mismatch(ds, {**vary, "snr": snr})
    if why:
        return why
    valid = np.asarray(ds["valid"].values)
    reason = np.asarray(ds["reason"].values).astype(str)
    if valid.dtype != bool or not np.array_equal(valid, reason == ""):
        return "its valid flags are not what its reasons say (valid where no reason is given)"
    for k in OPTIMUM_CRITERIA + ("efl_mm",):
        v = np.asarray(ds[k].values, dtype=np.float64)
        made, unmade = v[valid], v[~valid]
        if not np.isfinite(made).all() or (k != "efl_mm" and (made < 0).any()):
            return f"its {k} of a valid design is not a finite number" + ("" if k == "efl_mm" else " >= 0")
        if not np.isnan(unmade).all():
            return f"its {k} of an invalid design is a number (an invalid design is never scored)"
    capped = np.asarray(ds["mtf50_capped"].values)
    if not np.isin(capped, (0, 1)).all() or capped[~valid].any():
        return "its mtf50_capped is not 0 or 1 (0 for an invalid design)"
    return None


# -- any lens: the grid's front, its JSON and figure --------------------------------------------------------------
def _criteria_columns(ds: xr.Dataset) -> dict[str, tuple[np.ndarray, str]]:
    """``{name: (values over the grid, flattened; sense)}``: ``rms_w``, ``mse_s`` and ``mse_r`` at each SNR (named
    ``mse_r@27.6`` beyond the first SNR, as ``lenssim optimum`` names them), ``strehl``, ``mtf50``."""
    return {k: (v.values.reshape(-1), _sense_name(k)) for k, v in criteria_of(ds, TRADEOFF_CRITERIA, first_bare=True).items()}


def _grid_designs(ds: xr.Dataset):
    """``(names, design)``: the grid's free parameters and ``design(i)``, design ``i`` (C order) as ``{name: value}``."""
    names = list(ds["valid"].dims)
    grids = [g.reshape(-1) for g in np.meshgrid(*(ds[n].values for n in names), indexing="ij")]
    return names, lambda i: {n: float(g[i]) for n, g in zip(names, grids)}


def front(ds: xr.Dataset, levels: int) -> dict:
    """The optima per cost level and unconstrained, per criterion (see the module docstring): ``{"levels": [...],
    "optima": {criterion: [{"cost", "value", "design"} or None per level]}, "unconstrained": {criterion: {...}}}``;
    a level no valid design reaches is None."""
    valid = ds["valid"].values.reshape(-1)
    cost = ds["cost"].values.reshape(-1)
    names, design = _grid_designs(ds)
    top = float(cost[valid].max()) if valid.any() else 0.0
    lv = [float(v) for v in np.linspace(0.0, top, levels)]
    res = {"parameters": names, "levels": lv, "optima": {}, "unconstrained": {}}

    def entry(i, v):
        return {"cost": float(cost[i]), "design": design(i), "value": float(v[i])}

    for name, (v, sense) in _criteria_columns(ds).items():
        score = v if sense == "min" else -v
        ok = valid & np.isfinite(score)
        if not ok.any():
            res["optima"][name] = [None] * len(lv)
            res["unconstrained"][name] = None
            continue
        res["unconstrained"][name] = entry(_first_best(score, ok), v)
        masks = [ok & _within(cost, c) for c in lv]
        res["optima"][name] = [entry(_first_best(score, m), v) if m.any() else None for m in masks]
    res["invalid"] = int((~valid).sum())
    res["designs"] = int(valid.size)
    return res


def end_to_end_gain(ds: xr.Dataset) -> dict:
    """The paper's comparison on this grid, per SNR (``mse_r``, ``mse_r@33.6``, ...): the RMS_W optimum (the
    sequential design) against the designs chosen for the restored image. ``equal_cost``: the best ``mse_r`` among
    valid designs costing at most the RMS_W optimum (``mse_r_ratio``: its ``mse_r`` over the RMS_W optimum's, < 1 when
    designing for the restored image pays); ``equal_quality``: the cheapest valid design restoring at least as well as
    the RMS_W optimum (``cost_saving``: ``1 - its cost / the RMS_W optimum's``). Ties: the first in the grid's order.
    Empty if no design is valid."""
    valid = ds["valid"].values.reshape(-1)
    cols = _criteria_columns(ds)
    rms, _ = cols["rms_w"]
    ok = valid & np.isfinite(rms)
    if not ok.any():
        return {}
    cost = ds["cost"].values.reshape(-1)
    _, design = _grid_designs(ds)
    w = _first_best(rms, ok)
    out = {}
    for name, (v, _) in cols.items():
        if name.split("@")[0] != "mse_r":
            continue
        good = valid & np.isfinite(v)
        e = _first_best(v, good & _within(cost, cost[w]))
        q = _first_best(cost, good & (v <= v[w]))
        out[name] = {"rms_w_optimum": {"design": design(w), "cost": float(cost[w]), "mse_r": float(v[w])},
                     "equal_cost": {"design": design(e), "cost": float(cost[e]), "mse_r": float(v[e])},
                     "mse_r_ratio": float(v[e] / v[w]),
                     "equal_quality": {"design": design(q), "cost": float(cost[q]), "mse_r": float(v[q])},
                     "cost_saving": float(1 - cost[q] / cost[w]) if cost[w] > 0 else 0.0}
    return out


def tradeoff_json(ds: xr.Dataset, levels: int) -> dict:
    """``tradeoff.json``: :func:`front`, :func:`end_to_end_gain` (``end_to_end_vs_rms_w``) and every invalid design
    with its reason."""
    res = front(ds, levels)
    res["end_to_end_vs_rms_w"] = end_to_end_gain(ds)
    _, design = _grid_designs(ds)
    reasons = ds["reason"].values.reshape(-1)
    res["invalid_designs"] = [{"design": design(i), "reason": str(reasons[i])} for i in np.flatnonzero(reasons != "")]
    return res


# -- any lens: reading a trade-off file back ----------------------------------------------------------------------
def is_lens_tradeoff(ds: xr.Dataset) -> bool:
    """Whether ``ds`` is a trade-off of any lens (by its title)."""
    return ds.attrs.get("title") == TRADEOFF_TITLE


def check_lens_tradeoff(ds: xr.Dataset, where: str = "the file") -> None:
    """A one-line ``ValueError`` unless ``ds`` holds what a trade-off file holds (its variables over its grid)."""
    need = OPTIMUM_CRITERIA + ("valid",)
    missing = [k for k in need if k not in ds]
    if missing or "snr" not in ds.coords:
        raise ValueError(f"{where} is titled a lenssim trade-off but is incomplete (no {', '.join(missing) or 'snr'}); "
                         "run `lenssim tradeoff` again")
    dims = ds["valid"].dims
    for k in OPTIMUM_CRITERIA:
        extra = set(ds[k].dims) - set(dims) - {"snr"}
        if set(dims) - set(ds[k].dims) or extra:
            raise ValueError(f"{where} is titled a lenssim trade-off but its {k} is not over the grid {list(dims)}")


def verify_lens_tradeoff(ds: xr.Dataset, path) -> None:
    """Refuse a trade-off file read back whose numbers are not the ones its run wrote (its checksum,
    :func:`lenssim_studies.chunks.verify_result`) or that make no sense for its run record (:func:`tradeoff_mismatch`):
    one-line ``ValueError`` naming the file."""
    from .chunks import verify_result

    again = "run `lenssim tradeoff` again"
    verify_result(ds, path, "trade-off", again)
    why = tradeoff_mismatch(ds)
    if why:
        raise ValueError(f"{str(path)!r} makes no sense for its run record: {why}; {again}")


def check_design_file(ds: xr.Dataset, design: dict, path: Path) -> bool:
    """Whether the lens file ``path`` (a trade-off's ``designs/NAME.toml``) holds the design ``design`` of the trade-off
    ``ds`` (its solves applied, as :func:`write_design_files` wrote it): False if the run cannot be rebuilt here
    (another version of lenssim: the file cannot be vouched for); a one-line ``ValueError`` if the file holds anything
    else (changed after the trade-off wrote it)."""
    from lenssim.io.prescription_file import read_lens

    try:
        want = design_prescription(rebuild_run(ds), design).to_dict()
    except ValueError:
        return False
    bad = f"{str(path)!r} does not hold the design it is named for (changed after the trade-off wrote it)"
    try:
        got = read_lens(str(path)).to_dict()
    except (OSError, ValueError) as exc:
        raise ValueError(f"{bad}: {' '.join(str(exc).split())[:200]}; remove it or run `lenssim tradeoff` again") \
            from None
    if not _same(got, want):
        raise ValueError(f"{bad}; remove it or run `lenssim tradeoff` again")
    return True


DESIGN_FILE_RTOL = 1e-12
"""Relative difference of two numbers of a design file that still hold the same design: a curvature rebuilt from its
recorded radius may come back 1 ulp away (:func:`tradeoff_run_from_dict`), and the solves follow it."""


def _same(a, b) -> bool:
    """``a`` and ``b`` (a prescription's ``to_dict``) equal, numbers to :data:`DESIGN_FILE_RTOL`."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return a == b or math.isclose(a, b, rel_tol=DESIGN_FILE_RTOL, abs_tol=0.0)
    return a == b


def resolve_criterion(ds: xr.Dataset, criterion: str, snr_db: float | None = None) -> tuple[str, float | None, str]:
    """``(criterion, SNR or None, name)``: the trade-off criterion ``criterion`` (``NAME`` or ``NAME@SNR``) at the
    SNR ``snr_db`` (per-SNR criteria only; default the run's first), and its name as ``tradeoff.json`` names it
    (``mse_r`` at the first SNR, ``mse_r@33.6`` at another)."""
    text = str(criterion).strip()
    base, at, snr_text = text.partition("@")
    base = base.strip()
    snrs = [float(v) for v in ds["snr"].values]
    listed = ", ".join(f"{s:g}" for s in snrs)
    if base not in OPTIMUM_CRITERIA:
        raise ValueError(f"criterion {text!r} is not in this trade-off; it holds {', '.join(OPTIMUM_CRITERIA)} "
                         f"(mse_s and mse_r at --snr: {listed} dB)")
    per_snr = "snr" in ds[base].dims
    if at:
        if not per_snr:
            raise ValueError(f"criterion {text!r}: {base} does not depend on the SNR (give {base})")
        try:
            s = float(snr_text)
        except ValueError:
            raise ValueError(f"criterion {text!r}: {snr_text.strip()!r} is not an SNR in dB") from None
        if snr_db is not None and not math.isclose(s, snr_db, rel_tol=1e-9, abs_tol=1e-9):
            raise ValueError(f"criterion {text!r} and --snr {snr_db:g} name different SNRs; give one")
        snr_db = s
    if not per_snr:
        if snr_db is not None:
            raise ValueError(f"--snr applies to mse_s and mse_r; {base} does not depend on the SNR")
        return base, None, base
    if snr_db is None:
        j = 0
    else:
        if isinstance(snr_db, bool) or not math.isfinite(float(snr_db)):
            raise ValueError(f"--snr {snr_db!r} is not allowed: an SNR in dB of this trade-off ({listed} dB)")
        hits = [j for j, s in enumerate(snrs) if math.isclose(s, float(snr_db), rel_tol=1e-9, abs_tol=1e-9)]
        if not hits:
            raise ValueError(f"SNR {float(snr_db):g} dB is not in this trade-off; it holds {listed} dB")
        j = hits[0]
    return base, snrs[j], base if j == 0 else f"{base}@{snrs[j]:g}"


def _column(ds: xr.Dataset, base: str, snr: float | None, dims) -> np.ndarray:
    da = ds[base]
    if snr is not None:
        da = da.isel(snr=[float(v) for v in ds["snr"].values].index(snr))
    return np.asarray(da.transpose(*dims).values, dtype=np.float64)


def find_lens_optimum(ds: xr.Dataset, criterion: str, snr_db: float | None = None, max_cost: float | None = None, *,
                      folder: str | Path | None = None) -> dict:
    """The best valid design of the trade-off ``ds`` for ``criterion`` (its minimum, or its maximum for ``strehl`` and
    ``mtf50``), at most ``max_cost`` if given (see the module docstring).

    Returns ``criterion`` (the name without the SNR), ``snr_db`` (None for a criterion without one), ``name`` (as
    ``tradeoff.json`` names it), ``value``, ``cost``, ``design`` (``{parameter: value}``), every criterion at that
    design (``mse_s`` and ``mse_r`` as ``{"SNR": value}``), ``max_cost``, ``on_grid_boundary`` (a parameter at its
    grid's first or last value; a parameter with one value is fixed, never on a boundary), ``boundary_parameters``,
    ``mtf50_capped``, ``efl_mm``, ``valid_designs``, ``designs`` and ``lens_file``: ``folder/designs/NAME.toml`` if
    ``folder`` (the trade-off's output folder) holds it and the chosen design is the unconstrained optimum it was
    written for, else None. One-line ``ValueError``: an unknown criterion, an SNR not in the file, no valid design, a
    ``max_cost`` below every valid design's cost."""
    check_lens_tradeoff(ds)
    max_cost = check_max_cost(max_cost)
    base, snr, name = resolve_criterion(ds, criterion, snr_db)
    dims = ds["valid"].dims
    valid = np.asarray(ds["valid"].values).astype(bool)
    value = _column(ds, base, snr, dims)
    cost = _column(ds, "cost", None, dims)
    score = value if CRITERIA[base].sense == "min" else -value
    ok = (valid & np.isfinite(score) & np.isfinite(cost)).reshape(-1)
    if not ok.any():
        reasons = [str(r) for r in np.asarray(ds["reason"].values).reshape(-1) if str(r)] if "reason" in ds else []
        raise ValueError(f"no valid design in this trade-off ({valid.size} designs"
                         + (f"; the first is invalid: {reasons[0]}" if reasons else "") + ")")
    flat_score, flat_cost = score.reshape(-1), cost.reshape(-1)
    unconstrained = _first_best(flat_score, ok)
    if max_cost is None:
        i = unconstrained
    else:
        within = ok & _within(flat_cost, max_cost)
        if not within.any():
            raise ValueError(f"--max-cost {max_cost:g} is below every valid design's cost: the cheapest valid design "
                             f"costs {float(flat_cost[ok].min())!r}")
        i = _first_best(flat_score, within)
    idx = np.unravel_index(i, valid.shape)
    at = dict(zip(dims, (int(k) for k in idx)))
    design = {d: float(ds[d].values[k]) for d, k in at.items()}
    out = {"criterion": base, "snr_db": snr, "name": name, "value": float(value.reshape(-1)[i]),
           "cost": float(flat_cost[i]), "design": design, "max_cost": max_cost}
    out |= _criteria_at(ds, at, OPTIMUM_CRITERIA)
    edge = [d for d, k in at.items() if ds.sizes[d] > 1 and k in (0, ds.sizes[d] - 1)]
    out["on_grid_boundary"] = bool(edge)
    out["boundary_parameters"] = edge
    if "mtf50_capped" in ds:
        out["mtf50_capped"] = bool(ds["mtf50_capped"].isel(at))
    if "efl_mm" in ds:
        out["efl_mm"] = float(ds["efl_mm"].isel(at))
    out["valid_designs"] = int(ok.sum())
    out["designs"] = int(valid.size)
    lens_file = None
    if folder is not None and i == unconstrained:
        f = Path(folder) / "designs" / design_file_name(name)
        if f.is_file() and check_design_file(ds, design, f):
            lens_file = str(f)
    out["lens_file"] = lens_file
    return out


def tradeoff_run_from_dict(d: dict) -> LensTradeoffRun:
    """The run of :meth:`LensTradeoffRun.to_dict` ``d`` (its inverse: the rebuilt run's ``to_dict``, hence its digest,
    equals ``d`` when ``d`` was written by this version of lenssim). Every key is a field of the run (a field
    ``to_dict`` leaves out takes its default) but ``lenssim_version``; lists are read as tuples. ``to_dict`` records
    each surface's radius, not its curvature: a curvature whose reciprocal's reciprocal is not itself comes back as
    the one 1 ulp away with the same radius. Errors: ``KeyError``, ``TypeError``, ``ValueError``."""
    from lenssim.io.prescription_file import prescription_from_dict

    if not isinstance(d, dict):
        raise TypeError(f"a run config is a JSON object, not {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(LensTradeoffRun)}
    unknown = sorted(set(d) - names - {"lenssim_version"})
    if unknown:
        raise KeyError(f"unknown run field(s) {', '.join(unknown)}")
    kw = {}
    for k, v in d.items():
        if k == "lenssim_version":
            continue
        if k == "prescription":  # radii: a curvature 1 ulp from the run's may come back, with the same to_dict
            kw[k] = prescription_from_dict(v)
        elif k == "vary":
            kw[k] = tuple((str(n), tuple(float(x) for x in values)) for n, values in v)
        elif k == "numerics":
            kw[k] = Numerics(**v)
        elif isinstance(v, list):
            kw[k] = tuple(v)
        else:
            kw[k] = v
    return LensTradeoffRun(**kw)


def rebuild_run(ds: xr.Dataset, where: str = "the trade-off file") -> LensTradeoffRun:
    """The run that wrote the trade-off ``ds`` (its ``config``), its digest checked against ``config_digest``; a
    one-line ``ValueError`` if it cannot be rebuilt (another version of lenssim, or a file edited by hand)."""
    try:
        d = json.loads(ds.attrs["config"])
        digest = str(ds.attrs["config_digest"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{where} carries no readable run config; run `lenssim tradeoff` again") from None
    version = d.get("lenssim_version") if isinstance(d, dict) else None
    if version != __version__:
        raise ValueError(f"{where} was written by lenssim {version}, not by this version ({__version__}): its designs "
                         "cannot be rebuilt exactly; run `lenssim tradeoff` again")
    try:
        run = tradeoff_run_from_dict(d)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        msg = " ".join(str(exc).split())
        raise ValueError(f"{where} was written by a different version or config of lenssim: its run cannot be "
                         f"rebuilt ({type(exc).__name__}: {msg})") from None
    if run.digest() != digest:
        raise ValueError(f"{where} was written by a different version or config of lenssim: its run rebuilds to "
                         f"digest {run.digest()}, not its config_digest {digest}")
    return run


def write_optimum_lens(ds: xr.Dataset, design: dict, path, *, where: str = "the trade-off file") -> Path:
    """Write the design ``design`` (``{parameter: value}``) of the trade-off ``ds`` as a stand-alone TOML
    prescription ``path`` (:func:`design_prescription`), atomically; returns the path. The caller refuses an existing
    file."""
    from lenssim.io.prescription_file import write_prescription_toml

    return write_prescription_toml(design_prescription(rebuild_run(ds, where), design), path)


# -- any lens: the gradient route ---------------------------------------------------------------------------------
STOP_REASONS = ("gradient", "step", "steps", "invalid")
"""Why a descent stopped (:class:`lenssim.design_opt.IsoCostResult`), and ``invalid``: its start could not be made."""
MAX_STARTS = 64
MAX_STEPS = 500
TYPICAL_STEPS = 20
"""Each parameter's typical step (the optimiser's scale) is its bounds' width over this."""
_DESCENT_KEYS = ("design", "start_design", "value", "cost", "iterations", "evaluations", "stopped", "gradient")


@dataclass(frozen=True)
class LensGradientRun(_LensRun):
    """The gradient route's settings: ``bounds`` ``((name, lo, hi), ...)``, ``criterion`` optimised at ``snr_db[0]``
    (dB), the image model ``rho0``, pixels ``pitch_um`` (um, point samples), ``numerics`` (the FFTs; its
    ``cost_points`` the cost's radii), the solves ``hold``/``image``, ``aspherize`` (1-based surfaces made even
    aspheres), ``levels`` cost levels, ``starts`` starts (seed ``seed``), at most ``steps`` steps a descent.

    For each cost level ``C`` (``C_u k / levels`` for ``k = 1 .. levels``, ``C_u`` the cost of the unconstrained
    optimum: :func:`cost_levels`) and for the unconstrained problem, the descent runs from every start: the file's
    design (clipped into the bounds) and ``starts - 1`` points drawn uniformly in the bounds (seeded). The best start
    per level is the optimum; every start's outcome (value, iterations, why it stopped) is kept, so that convergence
    is reported, not assumed. Its optima are scored point-sampled (:func:`_evaluate`) at the file's field angles."""

    prescription: Prescription
    lens: str
    bounds: tuple[tuple[str, float, float], ...]
    criterion: str
    snr_db: tuple[float, ...]
    rho0: float
    pitch_um: float
    numerics: Numerics
    hold: tuple[str, ...] = ()
    image: str = "file"
    aspherize: tuple[int, ...] = ()
    levels: int = 5
    starts: int = 4
    seed: int = 0
    steps: int = 30
    wavefront: str = "third_order"
    sampling = "point"
    coarse = False

    def __post_init__(self):
        if not self.bounds:
            raise ValueError("the gradient route needs at least one free parameter")
        self._check_names(n for n, _, _ in self.bounds)
        for n, lo, hi in self.bounds:
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise ValueError(f"--vary {n}: the gradient route needs a range LO:HI with finite LO < HI")
        if validate_criterion(self.criterion).from_otf is None:
            raise ValueError(f"--optimise {self.criterion} is not allowed: an OTF criterion (mse_r, mse_s, strehl, "
                             "mtf50)")
        for k, lo, hi in (("levels", 1, 100), ("starts", 1, MAX_STARTS), ("steps", 1, MAX_STEPS)):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"{k} {v!r} is not allowed: {lo} to {hi}")
        self.problem()  # the parameters, the solves, the wavefront route: refused here, before any work

    @property
    def parameters(self) -> tuple[LensParameter, ...]:
        return tuple(self.parameter(n) for n, _, _ in self.bounds)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def lo(self) -> torch.Tensor:
        return torch.tensor([b[1] for b in self.bounds], dtype=torch.float64)

    @property
    def hi(self) -> torch.Tensor:
        return torch.tensor([b[2] for b in self.bounds], dtype=torch.float64)

    def problem(self):
        """A fresh criterion of this run's wavefront model (:data:`lenssim.design_opt.GRADIENT_CRITERIA`)."""
        from lenssim.design_opt import GRADIENT_CRITERIA

        if self.wavefront not in GRADIENT_CRITERIA:
            raise ValueError(f"wavefront {self.wavefront!r} is not allowed: one of {', '.join(GRADIENT_CRITERIA)}")
        return GRADIENT_CRITERIA[self.wavefront](self.prescription, self.parameters, self.snr_db[0], self.criterion,
                                                 rho0=self.rho0, pitch_um=self.pitch_um,
                                                 angles_deg=self.prescription.fields,
                                                 scale=(self.hi - self.lo) / TYPICAL_STEPS, hold=self.hold,
                                                 image=self.image, numerics=self.numerics)

    def start_points(self) -> torch.Tensor:
        """``(starts, P)``: the file's design clipped into the bounds, then uniform draws in them (seeded). A free
        conic or asphere coefficient that is exactly 0 in the file starts one typical step away (a sphere is the apex
        of the cost's cone, where ``C_a`` has no gradient to climb to a level)."""
        file = torch.tensor(list(parameter_values(self.prescription, self.parameters).values()), dtype=torch.float64)
        file = torch.where(torch.isfinite(file), file, (self.lo + self.hi) / 2)
        aspheric = torch.tensor([p.kind == "conic" or p.kind.startswith("A") for p in self.parameters])
        file = torch.where(aspheric & (file == 0), (self.hi - self.lo) / TYPICAL_STEPS, file)
        file = torch.maximum(torch.minimum(file, self.hi), self.lo)
        g = torch.Generator().manual_seed(self.seed)
        draws = self.lo + (self.hi - self.lo) * torch.rand(self.starts - 1, len(self.bounds), generator=g,
                                                           dtype=torch.float64)
        return torch.cat([file[None], draws])

    def to_dict(self) -> dict:
        return {"prescription": self.prescription.to_dict(), "lens": self.lens,
                "bounds": [list(b) for b in zip(self.names, self.lo.tolist(), self.hi.tolist())],
                "criterion": self.criterion, "snr_db": list(self.snr_db), "rho0": self.rho0,
                "pitch_um": self.pitch_um, "numerics": self.numerics.to_dict(), "hold": list(self.hold),
                "image": self.image, "aspherize": list(self.aspherize), "levels": self.levels,
                "starts": self.starts, "seed": self.seed, "steps": self.steps, "wavefront": self.wavefront,
                "lenssim_version": __version__}


def cost_levels(run: LensGradientRun, free: list[dict]) -> list[float]:
    """The cost levels: ``C_u k / levels`` for ``k = 1 .. levels``, ``C_u`` the cost of the unconstrained optimum (the
    best of the unconstrained descents ``free``, :func:`_descend`'s chunks): above it the front is flat, below it
    lies the trade (how much quality a cheaper asphere gives up)."""
    sign = CRITERIA[run.criterion].sign
    ok = [c for c in free if STOP_REASONS[int(c["stopped"])] != "invalid"]
    if not ok:
        raise ValueError("no start of the unconstrained descent could be made (every start is an invalid design): "
                         "change the --vary bounds")
    c_u = float(min(ok, key=lambda c: sign * float(c["value"]))["cost"])
    if not c_u > 0:
        raise ValueError("the unconstrained optimum costs nothing (C_a = 0): there is no cheaper design to trade; free "
                         "a conic or an asphere coefficient")
    return [c_u * k / run.levels for k in range(1, run.levels + 1)]


def _descend(run: LensGradientRun, level: float | None, j: int) -> dict:
    from lenssim.design_opt import optimise_on_iso_cost

    x0 = run.start_points()[j]
    P = len(run.bounds)
    f = run.problem()
    try:
        r = optimise_on_iso_cost(f, x0, level, steps=run.steps, cost_points=run.numerics.cost_points,
                                 bounds={n: (lo, hi) for n, lo, hi in zip(run.names, run.lo.tolist(),
                                                                           run.hi.tolist())})
    except ValueError:  # the start cannot be made, or cannot be brought onto the level
        return {"design": np.full(P, np.nan), "start_design": x0.numpy(), "value": np.nan, "cost": np.nan,
                "iterations": np.int64(0), "evaluations": np.int64(f.evaluations),
                "stopped": np.int64(STOP_REASONS.index("invalid")), "gradient": np.nan}
    return {"design": np.asarray([r.design[n] for n in run.names]), "start_design": x0.numpy(), "value": np.float64(r.value),
            "cost": np.float64(r.cost), "iterations": np.int64(r.iterations), "evaluations": np.int64(r.evaluations),
            "stopped": np.int64(STOP_REASONS.index(r.stopped)), "gradient": np.float64(r.gradient)}


def _gradient_mismatch(run: LensGradientRun, ds: xr.Dataset) -> str | None:
    """Why the finished result ``ds`` makes no sense for ``run``, or None: its starts and parameters are the run's,
    every descent stopped for a known reason, and one that was made has a finite design, value and cost."""
    why = result_mismatch(ds, {"start": np.arange(run.starts), "parameter": np.asarray(run.names)})
    if why:
        return why
    if any(k not in ds for k in _DESCENT_KEYS):
        return f"it holds no {', '.join(k for k in _DESCENT_KEYS if k not in ds)}"
    stopped = np.asarray(ds["stopped"].values)
    if not np.isin(stopped, np.arange(len(STOP_REASONS))).all():
        return "its stopped holds a reason that is not one of " + ", ".join(STOP_REASONS)
    made = stopped != STOP_REASONS.index("invalid")
    for k in ("design", "value", "cost"):
        if not np.isfinite(np.asarray(ds[k].values, dtype=np.float64)[made]).all():
            return f"its {k} of a descent that was made is not finite"
    return None


def run_lens_gradient(run: LensGradientRun, out, *, show_progress: bool = True,
                      max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) every descent and write ``out`` (NetCDF: per ``level`` (NaN: unconstrained) and ``start``, the
    design reached, its value, cost, iterations, evaluations, why it stopped); ``None`` if ``max_chunks`` stopped it
    early. Each (level, start) is a checksummed chunk: first the unconstrained descents, whose optimum's cost sets the
    levels, then each level's."""

    def build(part):
        nonlocal max_chunks
        chunks = []
        for phase in ("free", "level"):
            if phase == "free":
                units = [(None, j) for j in range(run.starts)]
            else:
                units = [(lv, j) for lv in cost_levels(run, chunks) for j in range(run.starts)]
            paths = [part / f"{phase}_{i:05d}.npz" for i in range(len(units))]
            digest = run.digest() + ("" if phase == "free" else "|" + json.dumps([u[0] for u in units[::run.starts]]))

            def read(p, i, units=units, digest=digest):
                got = read_stamped_chunk(p, _DESCENT_KEYS, digest, i, run="gradient run", rows_key="design",
                                         rows=len(run.bounds), what="parameters")
                if not isinstance(got, str) and not np.array_equal(got["start_design"],
                                                                   run.start_points()[units[i][1]].numpy()):
                    return "starts elsewhere than this run's start"  # the coordinates of the piece, verified
                return got

            def compute(i, progress, units=units):
                chunk = _descend(run, *units[i])
                progress(1)
                return chunk

            todo = sum(not q.exists() for q in paths)
            got = resume_chunks(paths, kind="gradient", read=read,
                                write=lambda p, chunk, i, digest=digest: write_stamped_chunk(p, chunk, digest, i),
                                compute=compute, weight=lambda i: 1, desc=f"descents ({phase})", unit="descent",
                                show_progress=show_progress, max_chunks=max_chunks)
            if got is None:
                return None
            if max_chunks is not None:  # the next phase computes what is left of the budget
                max_chunks -= min(todo, max_chunks)
            chunks = got if phase == "free" else got + chunks  # levels first, the unconstrained last
        levels = cost_levels(run, chunks[-run.starts:])
        L, S = len(levels) + 1, run.starts
        data = {}
        for k in _DESCENT_KEYS:
            v = np.stack([np.asarray(c[k]) for c in chunks])
            dims = ("level", "start") + (("parameter",) if v.ndim == 2 else ())
            data[k] = (dims, v.reshape((L, S) + v.shape[1:]))
        ds = xr.Dataset(data, coords={"level": np.asarray(levels + [np.nan]), "start": np.arange(S),
                                      "parameter": list(run.names)})
        ds["stopped"].attrs["flag_meanings"] = " ".join(STOP_REASONS)
        ds["level"].attrs["long_name"] = "cost level C_a (NaN: unconstrained)"
        ds.attrs = {"title": "lenssim gradient trade-off of any lens", "lens": run.lens, "criterion": run.criterion}
        return ds

    return run_resumable(run, out, output="gradient output", kind="gradient run",
                         check=lambda ds: _gradient_mismatch(run, ds), refusal="the descents of a different run",
                         build=build)


def gradient_json(run: LensGradientRun, ds: xr.Dataset) -> dict:
    """``tradeoff.json`` of the gradient route: ``parameters``, ``levels``, ``optima`` (per level ``C``: the best end
    point of every descent, at any level or unconstrained, whose cost is at most ``C``: the front is monotone, as the
    grid route's, and a descent held by a bound off its level still counts where it belongs), ``unconstrained`` (the
    best end point of all), the optimised criterion only, named as ``lenssim optimum`` names it; ``convergence``:
    every start's outcome."""
    sign = CRITERIA[run.criterion].sign
    names = list(run.names)
    levels = [float(v) for v in ds["level"].values[:-1]]
    out = {"parameters": names, "levels": levels, "method": "gradient", "criterion": run.criterion,
           "optima": {run.criterion: []}, "unconstrained": {run.criterion: None}, "convergence": []}
    ends = []
    for li in range(len(levels) + 1):
        for j in range(run.starts):
            stopped = STOP_REASONS[int(ds["stopped"].values[li, j])]
            entry = {"level": None if li == len(levels) else levels[li], "start": j,
                     "from": dict(zip(names, ds["start_design"].values[li, j].tolist())), "stopped": stopped,
                     "iterations": int(ds["iterations"].values[li, j]),
                     "evaluations": int(ds["evaluations"].values[li, j])}
            if stopped != "invalid":
                entry |= {"design": dict(zip(names, ds["design"].values[li, j].tolist())),
                          "value": float(ds["value"].values[li, j]), "cost": float(ds["cost"].values[li, j]),
                          "gradient": float(ds["gradient"].values[li, j])}
                ends.append(entry)
            out["convergence"].append(entry)
    score = np.asarray([sign * e["value"] for e in ends])
    cost = np.asarray([e["cost"] for e in ends])

    def best(limit):
        ok = np.ones(len(ends), dtype=bool) if limit is None else _within(cost, limit, GRADIENT_COST_TOLERANCE)
        if not ok.any():
            return None
        e = ends[_first_best(score, ok)]  # the first of equals: levels in order, then starts
        return {"cost": e["cost"], "value": e["value"], "design": e["design"],
                "descent": {"level": e["level"], "start": e["start"]}}

    out["optima"][run.criterion] = [best(c) for c in levels]
    out["unconstrained"][run.criterion] = best(None)
    return out


def score_optima(run: LensGradientRun, res: dict) -> list[dict | None]:
    """Every criterion (the run's wavefront model, each SNR of the run) at each level's optimum and then the
    unconstrained one: ``{"rms_w", "mse_s": [...], "mse_r": [...], "strehl", "mtf50", "cost"}`` (None where no start
    succeeded), as the grid route and ``evaluate`` score (:func:`_evaluate`: third order with the FFT sizes
    :func:`lenssim.metrics.evaluate_third_order` chooses; exact on the real-ray PSF tables, point
    samples, at the file's angles). Each optimum's ``value`` in ``res`` becomes that score (the descent's own, on the
    FFT sizes it fixed at its start and, for exact, on the degree-8 fit of the OPD over the full pupil, is kept as
    ``descent_value``)."""
    out = []
    for o in res["optima"][run.criterion] + [res["unconstrained"][run.criterion]]:
        if o is None:
            out.append(None)
            continue
        r = _evaluate(run, run.lens_at(o["design"]))
        sc = {k: torch.as_tensor(r[k], dtype=torch.float64).tolist() for k in OPTIMUM_CRITERIA}
        out.append(sc)
        v = sc[run.criterion]
        o["descent_value"], o["value"] = o["value"], float(v[0] if isinstance(v, list) else v)
    return out
