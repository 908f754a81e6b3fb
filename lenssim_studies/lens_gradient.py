"""The cost-performance front of any lens by iso-cost projected gradient descent, for more free parameters than a
grid holds (``lenssim tradeoff --optimise``; issue 30, item 4).

A :class:`LensGradientRun` names the lens, its free parameters with their bounds, the criterion optimised (at the first
SNR), the solves, the cost levels and the starts. For each cost level ``C`` (``levels`` of them, ``C_max k / levels``
for ``k = 1 .. levels``, ``C_max`` the largest cost among the bounds' corners and the starts) and for the
unconstrained problem, the descent (:func:`lenssim.design_opt.optimise_on_iso_cost` on
:class:`lenssim.lens_design_opt.LensThirdOrderCriterion`) runs from every start: the file's design (clipped into
the bounds) and ``starts - 1`` points drawn uniformly in the bounds (seeded). Each (level, start) is a checksummed
chunk (:mod:`lenssim_studies.chunks`): a killed run resumes. The best start per level is the optimum; every start's
outcome (value, iterations, why it stopped) is kept, so that convergence is reported, not assumed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from lenssim import __version__
from lenssim.model.lens_parameters import LensParameter, parameter_values, parse_parameter
from lenssim.model.numerics import Numerics
from lenssim.model.prescription import Prescription

from .chunks import (finish_resumable, open_resumable, partial_folder, read_stamped_chunk, result_mismatch, resume_chunks,
                     write_stamped_chunk)

__all__ = ["LensGradientRun", "run_lens_gradient", "gradient_json", "STOP_REASONS", "MAX_STARTS", "MAX_STEPS",
           "TYPICAL_STEPS"]

STOP_REASONS = ("gradient", "step", "steps", "invalid")
"""Why a descent stopped (:class:`lenssim.design_opt.IsoCostResult`), and ``invalid``: its start could not be made."""
MAX_STARTS = 64
MAX_STEPS = 500
TYPICAL_STEPS = 20
"""Each parameter's typical step (the optimiser's scale) is its bounds' width over this."""
_KEYS = ("design", "start_design", "value", "cost", "iterations", "evaluations", "stopped", "gradient")


@dataclass(frozen=True)
class LensGradientRun:
    """The gradient route's settings: ``bounds`` ``((name, lo, hi), ...)``, ``criterion`` optimised at ``snr_db[0]``
    (dB), the image model ``rho0``, pixels ``pitch_um`` (um, point samples), ``numerics`` (the FFTs; its
    ``cost_points`` the cost's radii), the solves ``hold``/``image``, ``aspherize`` (1-based surfaces made even
    aspheres), ``levels`` cost levels, ``starts`` starts (seed ``seed``), at most ``steps`` steps a descent."""

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

    def __post_init__(self):
        from lenssim.criteria import validate_criterion

        if not self.bounds:
            raise ValueError("the gradient route needs at least one free parameter")
        names = [self.parameter(n).name for n, _, _ in self.bounds]
        if len(set(names)) != len(names):
            raise ValueError(f"a free parameter is named twice: {', '.join(names)}")
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

    def parameter(self, name: str) -> LensParameter:
        return parse_parameter(self.prescription, name, aspherize=self.aspherize)

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
        """A fresh criterion of this run's wavefront model (:data:`lenssim.lens_design_opt.GRADIENT_CRITERIA`)."""
        from lenssim.lens_design_opt import GRADIENT_CRITERIA

        if self.wavefront not in GRADIENT_CRITERIA:
            raise ValueError(f"wavefront {self.wavefront!r} is not allowed: one of {', '.join(GRADIENT_CRITERIA)}")
        return GRADIENT_CRITERIA[self.wavefront](self.prescription, self.parameters, self.snr_db[0], self.criterion,
                                       rho0=self.rho0, pitch_um=self.pitch_um, angles_deg=self.prescription.fields,
                                       scale=(self.hi - self.lo) / TYPICAL_STEPS, hold=self.hold, image=self.image,
                                       numerics=self.numerics)

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

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]


def cost_levels(run: LensGradientRun, free: list[dict]) -> list[float]:
    """The cost levels: ``C_u k / levels`` for ``k = 1 .. levels``, ``C_u`` the cost of the unconstrained optimum (the
    best of the unconstrained descents ``free``, :func:`_descend`'s chunks): above it the front is flat, below it
    lies the trade (how much quality a cheaper asphere gives up)."""
    from lenssim.criteria import CRITERIA

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


def _mismatch(run: LensGradientRun, ds: xr.Dataset) -> str | None:
    """Why the finished result ``ds`` makes no sense for ``run``, or None: its starts and parameters are the run's,
    every descent stopped for a known reason, and one that was made has a finite design, value and cost."""
    why = result_mismatch(ds, {"start": np.arange(run.starts), "parameter": np.asarray(run.names)})
    if why:
        return why
    if any(k not in ds for k in _KEYS):
        return f"it holds no {', '.join(k for k in _KEYS if k not in ds)}"
    stopped = np.asarray(ds["stopped"].values)
    if not np.isin(stopped, np.arange(len(STOP_REASONS))).all():
        return "its stopped holds a reason that is not one of " + ", ".join(STOP_REASONS)
    made = stopped != STOP_REASONS.index("invalid")
    for k in ("design", "value", "cost"):
        if not np.isfinite(np.asarray(ds[k].values, dtype=np.float64)[made]).all():
            return f"its {k} of a descent that was made is not finite"
    return None


def run_lens_gradient(run: LensGradientRun, out: str | os.PathLike, *, show_progress: bool = True,
                      max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) every descent and write ``out`` (NetCDF: per ``level`` (NaN: unconstrained) and ``start``, the
    design reached, its value, cost, iterations, evaluations, why it stopped); ``None`` if ``max_chunks`` stopped it
    early."""
    out = Path(out)
    done = open_resumable(out, run.digest(), "gradient output", "gradient run", check=lambda ds: _mismatch(run, ds))
    if done is not None:
        return done
    part = out.with_name(out.name + ".partial")
    with partial_folder(part, "run.json", run.digest(), {"run": run.to_dict()},
                        f"{str(part)!r} holds the descents of a different run; remove it or choose another output"):
        chunks = []
        # first the unconstrained descents (level None), whose optimum's cost sets the levels; then each level's
        for phase in ("free", "level"):
            if phase == "free":
                units = [(None, j) for j in range(run.starts)]
            else:
                units = [(lv, j) for lv in cost_levels(run, chunks) for j in range(run.starts)]
            paths = [part / f"{phase}_{i:05d}.npz" for i in range(len(units))]
            digest = run.digest() + ("" if phase == "free" else "|" + json.dumps([u[0] for u in units[::run.starts]]))

            def read(p, i, units=units, digest=digest):
                got = read_stamped_chunk(p, _KEYS, digest, i, run="gradient run", rows_key="design",
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
        for k in _KEYS:
            v = np.stack([np.asarray(c[k]) for c in chunks])
            shape = (L, S) + v.shape[1:]
            dims = ("level", "start") + (("parameter",) if v.ndim == 2 else ())
            data[k] = (dims, v.reshape(shape))
        ds = xr.Dataset(data, coords={"level": np.asarray(levels + [np.nan]), "start": np.arange(S),
                                      "parameter": list(run.names)})
        ds["stopped"].attrs["flag_meanings"] = " ".join(STOP_REASONS)
        ds["level"].attrs["long_name"] = "cost level C_a (NaN: unconstrained)"
        ds.attrs = {"title": "lenssim gradient trade-off of any lens", "lens": run.lens, "criterion": run.criterion,
                    "lenssim_version": __version__, "config": json.dumps(run.to_dict(), sort_keys=True, default=str),
                    "config_digest": run.digest()}
        finish_resumable(out, ds, part)
        return ds


def gradient_json(run: LensGradientRun, ds: xr.Dataset) -> dict:
    """``tradeoff.json`` of the gradient route: ``parameters``, ``levels``, ``optima`` (per level ``C``: the best end
    point of every descent, at any level or unconstrained, whose cost is at most ``C``: the front is monotone, as the
    grid route's, and a descent held by a bound off its level still counts where it belongs), ``unconstrained`` (the
    best end point of all), the optimised criterion only, named as ``lenssim optimum`` names it; ``convergence``:
    every start's outcome."""
    from lenssim.criteria import CRITERIA

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

    def best(limit):
        ok = [e for e in ends if limit is None or e["cost"] <= limit * (1 + 1e-9)]
        if not ok:
            return None
        e = min(ok, key=lambda e: sign * e["value"])  # the first of equals: levels in order, then starts
        return {"cost": e["cost"], "value": e["value"], "design": e["design"],
                "descent": {"level": e["level"], "start": e["start"]}}

    out["optima"][run.criterion] = [best(c) for c in levels]
    out["unconstrained"][run.criterion] = best(None)
    return out


def score_optima(run: LensGradientRun, res: dict) -> list[dict | None]:
    """Every criterion (the run's wavefront model, each SNR of the run) at each level's optimum and then the
    unconstrained one: ``{"rms_w", "mse_s": [...], "mse_r": [...], "strehl", "mtf50", "cost"}`` (None where no start
    succeeded), as the grid route and ``evaluate`` score: third order with the FFT sizes
    :func:`lenssim.metrics.evaluate_third_order` chooses; exact by
    :func:`lenssim.metrics.evaluate_sequential` (the real-ray PSF tables, point samples, at the file's
    angles). Each optimum's ``value`` in ``res`` becomes that score (the descent's own, on the FFT sizes it fixed at
    its start and, for exact, on the degree-8 fit of the OPD over the full pupil, is kept as ``descent_value``)."""
    from lenssim.metrics import evaluate_sequential, evaluate_third_order

    from .lens_tradeoff import TRADEOFF_CRITERIA, sequential_provider

    f = run.problem()
    out = []
    for o in res["optima"][run.criterion] + [res["unconstrained"][run.criterion]]:
        if o is None:
            out.append(None)
            continue
        seq = f.lens_at(torch.tensor([o["design"][n] for n in run.names], dtype=torch.float64))
        if run.wavefront == "exact":
            psf = sequential_provider(seq.prescription, seq, pitch_um=run.pitch_um, sampling="point",
                                      max_field_deg=max(run.prescription.fields), numerics=run.numerics)
            r = evaluate_sequential(psf, run.snr_db, rho0=run.rho0, numerics=run.numerics,
                                    angles_deg=run.prescription.fields, criteria=TRADEOFF_CRITERIA + ("cost",))
        else:
            r = evaluate_third_order(seq, run.snr_db, pitch_um=run.pitch_um, rho0=run.rho0,
                                     angles_deg=run.prescription.fields, numerics=run.numerics,
                                     criteria=TRADEOFF_CRITERIA + ("cost",))
        sc = {k: torch.as_tensor(r[k], dtype=torch.float64).tolist() for k in TRADEOFF_CRITERIA + ("cost",)}
        out.append(sc)
        v = sc[run.criterion]
        o["descent_value"], o["value"] = o["value"], float(v[0] if isinstance(v, list) else v)
    return out


def write_gradient_designs(run: LensGradientRun, res: dict, folder: Path) -> dict[str, str]:
    """Each optimum as a TOML prescription: ``folder/CRITERION.toml`` (unconstrained) and
    ``folder/CRITERION_level_KK.toml`` (level ``KK``, from 01): ``{"unconstrained" or "level_KK": file name}``."""
    from lenssim.io.prescription_file import write_prescription_toml

    from .lens_tradeoff import design_prescription

    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    entries = [(f"level_{k + 1:02d}", o) for k, o in enumerate(res["optima"][run.criterion])]
    entries.append(("unconstrained", res["unconstrained"][run.criterion]))
    for key, o in entries:
        if o is None:
            continue
        fname = run.criterion + ("" if key == "unconstrained" else f"_{key}") + ".toml"
        write_prescription_toml(design_prescription(run, o["design"]), folder / fname)
        out[key] = f"{folder.name}/{fname}"
    return out


def gradient_figure(run: LensGradientRun, res: dict, out_dir: Path, title: str) -> Path:
    """The optimised criterion against the asphere cost: every start's end point per level (grey), the best per level
    (the front, a line), the unconstrained optimum (png, svg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lenssim.criteria import CRITERIA

    from .figures import _save

    fig, ax = plt.subplots(figsize=(5.6, 4.0))
    ends = [c for c in res["convergence"] if "value" in c]
    ax.scatter([c["cost"] for c in ends], [c["value"] for c in ends], s=12, color="0.6",
               label="each start's end point")
    front = [o for o in res["optima"][run.criterion] if o is not None]
    ax.plot([o["cost"] for o in front], [o["value"] for o in front], "o-", color="C1", label="best per cost level")
    u = res["unconstrained"][run.criterion]
    if u is not None:
        ax.plot([u["cost"]], [u["value"]], "*", ms=12, color="C3", label="unconstrained optimum")
    crit = CRITERIA[run.criterion]
    label = f"{run.criterion} at {run.snr_db[0]:g} dB" if crit.per_snr else run.criterion
    ax.set_xlabel("asphere cost C_a (RMS slope departure)")
    ax.set_ylabel(label if crit.units.startswith("1") else f"{label} ({crit.units})")
    ax.set_title(("lower" if crit.sign > 0 else "higher") + " is better; "
                 + ("real-ray" if run.wavefront == "exact" else "third-order") + " wavefront", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, out_dir, "tradeoff")
