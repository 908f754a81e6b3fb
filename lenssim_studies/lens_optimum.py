"""Reading a trade-off of any lens (``lenssim tradeoff --lens``'s ``tradeoff.nc``): the best valid design of the grid
for one criterion, unconstrained or at most a cost, what ``lenssim optimum`` prints, and that design as a lens file.

The criteria are named as ``tradeoff.json`` names them: ``rms_w``, ``mse_s``, ``mse_r``, ``strehl``, ``mtf50`` and
``cost`` (``mse_s`` and ``mse_r`` at an SNR of the run: the first by default, ``NAME@SNR`` or ``snr_db`` for another).
A design the sweep marked invalid (``valid`` false) is never chosen. ``max_cost``: the best valid design whose asphere
cost is at most ``C`` (where the unconstrained optimum costs more, the paper's iso-cost optimum to the grid's
resolution; the same tolerance as :func:`lenssim_studies.lens_tradeoff.front`). Ties go to the first design in the
grid's order (C order, the last parameter fastest), as in :func:`~lenssim_studies.lens_tradeoff.front`, so the
unconstrained optimum is the one ``tradeoff.json`` lists and ``designs/NAME.toml`` holds.

:func:`tradeoff_run_from_dict` rebuilds the :class:`~lenssim_studies.lens_tradeoff.LensTradeoffRun` a file's
``config`` attribute records (the inverse of :meth:`LensTradeoffRun.to_dict`), checked against its
``config_digest``; :func:`write_optimum_lens` writes a design of it as a stand-alone TOML prescription.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import xarray as xr

from lenssim import __version__
from lenssim.criteria import CRITERIA
from lenssim.model.numerics import Numerics

from .lens_tradeoff import TRADEOFF_CRITERIA, LensTradeoffRun, design_prescription

__all__ = ["TRADEOFF_TITLE", "TRADEOFF_FILE", "OPTIMUM_CRITERIA", "is_lens_tradeoff", "check_lens_tradeoff",
           "resolve_criterion", "find_lens_optimum", "design_file_name", "tradeoff_run_from_dict", "rebuild_run",
           "write_optimum_lens", "find_sweep_optimum", "check_max_cost", "COST_TOLERANCE", "verify_lens_tradeoff",
           "check_design_file"]

TRADEOFF_TITLE = "lenssim trade-off of any lens"
"""The ``title`` attribute of a trade-off file (:func:`lenssim_studies.lens_tradeoff.run_lens_tradeoff`)."""
TRADEOFF_FILE = "tradeoff.nc"
"""The trade-off's data file in its output folder."""
OPTIMUM_CRITERIA = TRADEOFF_CRITERIA + ("cost",)
"""What a trade-off's optimum may be of (``cost``: the cheapest valid design)."""
COST_TOLERANCE = (1e-12, 1e-15)
"""``cost <= C * (1 + rel) + abs``: a design at the level ``C`` counts (as :func:`lenssim_studies.lens_tradeoff.front`
takes its levels)."""


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
    :func:`lenssim_studies.chunks.verify_result`) or that make no sense for its run record
    (:func:`lenssim_studies.lens_tradeoff.tradeoff_mismatch`): one-line ``ValueError`` naming the file."""
    from .chunks import verify_result
    from .lens_tradeoff import tradeoff_mismatch

    again = "run `lenssim tradeoff` again"
    verify_result(ds, path, "trade-off", again)
    why = tradeoff_mismatch(ds)
    if why:
        raise ValueError(f"{str(path)!r} makes no sense for its run record: {why}; {again}")


def check_design_file(ds: xr.Dataset, design: dict, path: Path) -> bool:
    """Whether the lens file ``path`` (a trade-off's ``designs/NAME.toml``) holds the design ``design`` of the trade-off
    ``ds`` (its solves applied, as :func:`lenssim_studies.lens_tradeoff.write_design_files` wrote it): False if the run
    cannot be rebuilt here (another version of lenssim: the file cannot be vouched for); a one-line ``ValueError``
    if the file holds anything else (changed after the trade-off wrote it)."""
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


def check_max_cost(max_cost) -> float | None:
    if max_cost is None:
        return None
    if isinstance(max_cost, bool) or not isinstance(max_cost, (int, float)) or not math.isfinite(max_cost):
        raise ValueError(f"--max-cost {max_cost!r} is not allowed: a finite asphere cost C_a")
    return float(max_cost)


def _within(cost: np.ndarray, max_cost: float) -> np.ndarray:
    rel, tol = COST_TOLERANCE
    return cost <= max_cost * (1 + rel) + tol


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


def design_file_name(name: str) -> str:
    """The file ``designs/NAME.toml`` of a criterion as ``tradeoff.json`` names it (``@`` written ``_at_``, as
    :func:`lenssim_studies.lens_tradeoff.write_design_files` writes it)."""
    return name.replace("@", "_at_") + ".toml"


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

    def best(mask: np.ndarray) -> int:
        return int(np.flatnonzero(mask)[np.argmin(flat_score[mask])])

    unconstrained = best(ok)
    if max_cost is None:
        i = unconstrained
    else:
        within = ok & _within(flat_cost, max_cost)
        if not within.any():
            raise ValueError(f"--max-cost {max_cost:g} is below every valid design's cost: the cheapest valid design "
                             f"costs {float(flat_cost[ok].min())!r}")
        i = best(within)
    idx = np.unravel_index(i, valid.shape)
    at = dict(zip(dims, (int(k) for k in idx)))
    design = {d: float(ds[d].values[k]) for d, k in at.items()}
    out = {"criterion": base, "snr_db": snr, "name": name, "value": float(value.reshape(-1)[i]),
           "cost": float(flat_cost[i]), "design": design, "max_cost": max_cost}
    for k in OPTIMUM_CRITERIA:
        v = ds[k].isel(at)
        out[k] = ({f"{float(s):g}": float(v.sel(snr=s)) for s in ds["snr"].values} if "snr" in v.dims else float(v))
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


# -- the run a trade-off file records --------------------------------------------------------------------------------
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


def write_optimum_lens(ds: xr.Dataset, design: dict, path: str | Path, *, where: str = "the trade-off file") -> Path:
    """Write the design ``design`` (``{parameter: value}``) of the trade-off ``ds`` as a stand-alone TOML
    prescription ``path`` (its solves applied, its image plane in the last thickness:
    :func:`lenssim_studies.lens_tradeoff.design_prescription`), atomically; returns the path. The caller refuses an
    existing file."""
    from lenssim.io.prescription_file import write_prescription_toml

    run = rebuild_run(ds, where)
    return write_prescription_toml(design_prescription(run, design), path)


# -- the paper singlet's sweep, at most a cost -----------------------------------------------------------------------
def find_sweep_optimum(ds: xr.Dataset, criterion: str, snr: float | None = None, max_cost: float | None = None) -> dict:
    """:func:`lenssim_studies.tradeoff.find_optimum` of a sweep, among the designs whose cost is at most
    ``max_cost`` if given (a one-line ``ValueError`` naming the cheapest cost if none is); adds ``max_cost``."""
    from .tradeoff import find_optimum

    max_cost = check_max_cost(max_cost)
    if max_cost is None:
        return find_optimum(ds, criterion, snr) | {"max_cost": None}
    find_optimum(ds, criterion, snr)  # the criterion and the SNR checked as without a cost limit
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
    masked = ds.copy()
    masked[criterion] = ds[criterion].where(within)
    try:
        r = find_optimum(masked, criterion, snr)
    except ValueError:  # numpy's all-NaN: no design within the cost has a finite value
        raise ValueError(f"--max-cost {max_cost:g}: no design within this cost has a finite {criterion}") from None
    return r | {"max_cost": max_cost}
