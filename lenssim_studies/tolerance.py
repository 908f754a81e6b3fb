"""``lenssim tolerance``: a Monte Carlo of as-built lenses of one design (issue 19, item 3).

``N`` lenses are drawn from a :class:`lenssim.model.tolerances.Tolerances` (seeded: the same seed gives the same
lenses, whatever the chunking), evaluated in chunks by :func:`lenssim.tolerancing.as_built_criteria` (serially or
as dask tasks on the sweep's cluster path), each chunk written with its index, the run's digest and a SHA-256 of
its arrays, so a killed run resumes and every resumed chunk is verified. The result is an xarray dataset
(``lens`` x ``snr``; one variable per criterion, the sampled errors as variables), a summary (mean, median, 90th
and 99th percentiles, the bootstrap standard error of the 90th percentile, yields), a sensitivity table (each
tolerance alone) and figures.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from lenssim import __version__
from lenssim.criteria import CRITERIA
from lenssim.model.camera import Camera
from lenssim.model.design import Design
from lenssim.model.numerics import FAST_NUMERICS, Numerics
from lenssim.model.tolerances import Tolerances
from lenssim.tolerancing import AS_BUILT_CRITERIA, as_built_criteria
from lenssim.validate import check_int

from .chunks import (_checksum, finish_resumable, open_resumable, partial_folder, read_stamped_chunk, result_mismatch,
                     resume_chunks, write_stamped_chunk)

__all__ = ["ToleranceRun", "run_tolerance", "summarise", "sensitivity", "parse_yield", "tolerance_report",
           "tolerance_figures", "nominal_values", "TOLERANCE_FIELD_ANGLES", "DEFAULT_LENSES", "CHUNK_LENSES"]

TOLERANCE_FIELD_ANGLES = (0.0, 3.5, 7.0, 10.5, 14.0)
"""Field angles (deg) of a tolerance run (each at four azimuths): the paper's 0..14 deg every 3.5 deg (its 15
angles would cost 3.4x as much for a field average within 1% of this one on the nominal lens)."""
DEFAULT_LENSES = 1000
"""Lenses of a tolerance run: enough for the 90th percentile of each reported quantity to be known to ~1%
(the report gives each one's bootstrap standard error)."""
CHUNK_LENSES = 50
"""Lenses per chunk (the unit of resumption and of dask tasks)."""
BOOTSTRAP = 400
"""Bootstrap resamples for the standard error of the 90th percentile."""


@dataclass(frozen=True)
class ToleranceRun:
    """One tolerance Monte Carlo: the camera, one design, the tolerances, ``n_lenses`` lenses from ``seed``, the SNRs
    (dB), the image model's ``rho0``, the numerics and the field angles (deg; each at four azimuths)."""

    camera: Camera
    design: Design
    tolerances: Tolerances
    snr_db: tuple[float, ...]
    rho0: float
    n_lenses: int = DEFAULT_LENSES
    seed: int = 0
    numerics: Numerics = field(default_factory=lambda: FAST_NUMERICS)
    field_angles_deg: tuple[float, ...] = TOLERANCE_FIELD_ANGLES
    chunk_lenses: int = CHUNK_LENSES

    def __post_init__(self):
        check_int("number of lenses", self.n_lenses, 1)
        check_int("lenses per chunk", self.chunk_lenses, 1)
        check_int("seed", self.seed, 0)
        d = self.design.to(torch.float64)
        d.floats()
        self.camera.lens.check_design(d)
        object.__setattr__(self, "snr_db", tuple(float(v) for v in self.snr_db))
        object.__setattr__(self, "field_angles_deg", tuple(float(v) for v in self.field_angles_deg))
        object.__setattr__(self, "design", d)
        from lenssim.optics.image_model import noise_variance
        from lenssim.validate import check_memory, check_real

        noise_variance(list(self.snr_db))  # refuses what the criteria would refuse, now
        if not self.field_angles_deg:
            raise ValueError("field angles: give at least one angle (deg)")
        for a in self.field_angles_deg:
            check_real("field angle", a, 0.0, 90.0, hi_open=True, unit="deg")
        self.eval_camera.lens.check_design(d)
        # the lens table (perturbations and criteria per lens, float64) and its working copies
        per_lens = 8 * (len(self.tolerances.to_dict()) + 2 * len(AS_BUILT_CRITERIA()) * len(self.snr_db)) * 4
        check_memory(self.n_lenses * per_lens, f"a tolerance run of {self.n_lenses} lenses (use fewer --lenses)",
                     setting="n_lenses")

    def check_fft_sizes(self) -> None:
        """The nominal lens's PSFs at the run's field angles fit ``numerics.max_fft_size`` (checked before any work;
        a sampled lens beyond it still stops its chunk with the same error)."""
        from lenssim.optics.psf_bank import fft_size, spectral_coefficients

        for cam in self.camera.with_quadrature(self.numerics.spectral_tol).channel_cameras():
            fft_size(cam, spectral_coefficients(cam, self.design, list(self.field_angles_deg)), self.numerics)

    @property
    def eval_camera(self) -> Camera:
        """The camera with the run's field angles."""
        lens = dataclasses.replace(self.camera.lens, field_angles_deg=self.field_angles_deg)
        return dataclasses.replace(self.camera, lens=lens)

    def to_dict(self) -> dict:
        return {"camera": self.camera.to_dict(), "design": self.design.floats(), "design_name": self.design.name,
                "tolerances": self.tolerances.to_dict(), "snr_db": list(self.snr_db), "rho0": self.rho0,
                "n_lenses": self.n_lenses, "seed": self.seed, "numerics": self.numerics.to_dict(),
                "field_angles_deg": list(self.field_angles_deg), "chunk_lenses": self.chunk_lenses,
                "lenssim_version": __version__}

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]

    def chunks(self) -> list[tuple[int, int]]:
        """Lens ranges ``[k0, k1)`` of the chunks."""
        return [(k, min(k + self.chunk_lenses, self.n_lenses)) for k in range(0, self.n_lenses, self.chunk_lenses)]


def _compute_chunk(run: ToleranceRun, i: int, device=None, progress=None) -> dict:
    k0, k1 = run.chunks()[i]
    lenses = run.tolerances.sample(run.n_lenses, seed=run.seed)[k0:k1]
    r = as_built_criteria(run.eval_camera, run.design, lenses, run.snr_db, rho0=run.rho0, numerics=run.numerics,
                          device=device, progress=progress)
    return {**{k: r[k].cpu().numpy() for k in AS_BUILT_CRITERIA()}, "fft_size": r["fft_size"].cpu().numpy()}


def _chunk_task(run: ToleranceRun, digest: str, index: int, device: str, threads: int):
    """On a dask worker: chunk ``index`` -> ``(index, arrays, sha256)`` (the cluster path of the sweeps)."""
    from lenssim.torch_utils import select_device

    from .cluster import ClusterError, _numeric_malloc, with_threads

    _numeric_malloc()
    if run.digest() != digest:
        raise ClusterError(f"the worker's lenssim reads this tolerance run differently (digest {run.digest()} != "
                           f"{digest}): install the client's lenssim version on every worker")
    chunk = with_threads(threads, lambda: _compute_chunk(run, index, select_device(device), None))
    return index, chunk, _checksum(chunk)


def _write_chunk(path: Path, chunk: dict, run: ToleranceRun, i: int) -> None:
    write_stamped_chunk(path, chunk, run.digest(), i)


def _read_chunk(path: Path, run: ToleranceRun, i: int):
    """The chunk's arrays if ``path`` holds chunk ``i`` of this run intact, else the reason it does not."""
    k0, k1 = run.chunks()[i]
    return read_stamped_chunk(path, AS_BUILT_CRITERIA() + ("fft_size",), run.digest(), i, run="tolerance run",
                              rows_key="cost", rows=k1 - k0, what="lenses")


def _dataset(run: ToleranceRun, chunks: list[dict]) -> xr.Dataset:
    lenses = run.tolerances.sample(run.n_lenses, seed=run.seed)
    data = {}
    for k in AS_BUILT_CRITERIA():
        v = np.concatenate([c[k] for c in chunks])
        c = CRITERIA[k]
        dims = ("lens", "snr") if c.per_snr else ("lens",)
        data[k] = xr.Variable(dims, v, {"long_name": c.description, "units": c.units, "sense": c.sense})
    for name, (v, unit) in lenses.variables().items():
        data[name] = xr.Variable(("lens",), v.numpy(), {"units": unit, "long_name": f"sampled error: {name}"})
    sizes = np.concatenate([c["fft_size"] for c in chunks])
    data["fft_size"] = xr.Variable(("lens", "point"), sizes.astype(np.int64), {"long_name": "FFT size per field point"})
    ds = xr.Dataset(data, coords={"lens": np.arange(run.n_lenses), "snr": np.array(run.snr_db)})
    ds["snr"].attrs = {"long_name": "signal-to-noise ratio per pixel", "units": "dB"}
    ds["lens"].attrs = {"long_name": "Monte Carlo lens index"}
    ds.attrs = {"title": "lenssim tolerance Monte Carlo", "lenssim_version": __version__,
                "design": json.dumps(run.design.floats(), sort_keys=True), "design_name": run.design.name or "custom",
                "tolerances": json.dumps(run.tolerances.to_dict(), sort_keys=True),
                "config": json.dumps(run.to_dict(), sort_keys=True), "config_digest": run.digest()}
    return ds


def run_tolerance(run: ToleranceRun, out: str | os.PathLike, *, device: str = "auto", show_progress: bool = True,
                  scheduler: str | None = None, workers: int | None = None, worker_threads: int | None = None,
                  max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) the Monte Carlo and write ``out`` (NetCDF); ``None`` if ``max_chunks`` stopped it early.

    Resumption as the sweeps': finished chunks in ``out.partial/`` carry their index, the run's digest and a SHA-256
    of their arrays; a chunk that fails its check is reported (:class:`lenssim.validate.ResumeWarning`) and computed
    again. ``out`` must not be an existing file other than the finished result of the same run. With ``workers`` or
    ``scheduler`` the chunks are dask tasks (:mod:`lenssim_studies.cluster`); the file is the same, byte for byte.
    """
    from lenssim.torch_utils import select_device

    out = Path(out)
    dev = select_device(device)
    if scheduler is not None and workers is not None:
        raise ValueError("give either a scheduler address or a number of local workers, not both")

    done = open_resumable(out, run.digest(), "tolerance output", "tolerance run",
                          check=lambda ds: result_mismatch(ds, {"lens": np.arange(run.n_lenses), "snr": run.snr_db},
                                                           finite=AS_BUILT_CRITERIA(), dims=("lens",)))
    if done is not None:
        return done
    run.check_fft_sizes()
    part = out.with_name(out.name + ".partial")
    if part.exists():
        for p in part.glob(".*"):
            p.unlink(missing_ok=True)
    with partial_folder(part, "run.json", run.digest(), {"run": run.to_dict()},
                        f"{str(part)!r} holds chunks of a different tolerance run; remove it or choose another output"):
        ranges = run.chunks()
        paths = [part / f"chunk_{i:05d}.npz" for i in range(len(ranges))]
        per_lens = 1 + 4 * sum(a != 0 for a in run.field_angles_deg)  # field points (the axis once)
        where = scheduler or (f"{workers} local workers" if workers is not None else dev.type)

        def on_cluster(todo):
            from .cluster import compute_chunks, dask_client

            with dask_client(scheduler, workers) as client:
                yield from compute_chunks(client, run, todo, device=device, threads=worker_threads, task=_chunk_task,
                                          kind="tolerance")

        chunks = resume_chunks(paths, kind="tolerance", read=lambda p, i: _read_chunk(p, run, i),
                               write=lambda p, chunk, i: _write_chunk(p, chunk, run, i),
                               compute=lambda i, progress: _compute_chunk(run, i, dev, progress),
                               weight=lambda i: (ranges[i][1] - ranges[i][0]) * per_lens, desc=f"tolerance on {where}",
                               show_progress=show_progress, max_chunks=max_chunks,
                               cluster=on_cluster if scheduler is not None or workers is not None else None)
        if chunks is None:
            return None
        ds = _dataset(run, chunks)
        finish_resumable(out, ds, part)
        return ds


def parse_yield(spec: str) -> tuple[str, str, float]:
    """``"CRITERION<=VALUE"`` or ``"CRITERION>=VALUE"`` -> ``(criterion, op, value)``."""
    for op in ("<=", ">="):
        if op in spec:
            name, _, val = spec.partition(op)
            name = name.strip()
            if name not in AS_BUILT_CRITERIA():
                raise ValueError(f"--yield {spec!r}: criterion {name!r} is not allowed; one of "
                                 f"{', '.join(AS_BUILT_CRITERIA())}")
            try:
                v = float(val)
            except ValueError:
                v = float("nan")
            if not math.isfinite(v):
                raise ValueError(f"--yield {spec!r}: the threshold {val.strip()!r} is not a finite number")
            return name, op, v
    raise ValueError(f"--yield {spec!r} is not allowed: CRITERION<=VALUE or CRITERION>=VALUE, e.g. mse_r_nominal<=0.05")


def _values(ds: xr.Dataset, name: str, snr: float) -> np.ndarray:
    v = ds[name]
    return (v.sel(snr=snr) if "snr" in v.dims else v).values


def summarise(ds: xr.Dataset, nominal: dict, snr_db: float, yields=(), *, seed: int = 0) -> dict:
    """Per criterion at ``snr_db``: the nominal value, mean, median, ``p90`` and ``p99`` (the values 90% and 99% of
    the lenses are at least as good as: the 90th and 99th percentiles of a criterion to minimise, the 10th and 1st
    of one to maximise), the bootstrap standard error of ``p90`` (relative), and the yields
    ``[(criterion, op, value)]`` (fraction of lenses meeting each)."""
    rng = np.random.default_rng(seed)
    out = {"snr_db": snr_db, "lenses": int(ds.sizes["lens"]), "criteria": {}, "yields": []}
    N = int(ds.sizes["lens"])
    idx = rng.integers(0, N, size=(BOOTSTRAP, N))
    for k in AS_BUILT_CRITERIA():
        v = _values(ds, k, snr_db)
        worse = CRITERIA[k].sense == "max"  # for a criterion to maximise, 90% of the lenses are above its 10th pct
        q90, q99 = (10.0, 1.0) if worse else (90.0, 99.0)
        p50, p90, p99 = np.percentile(v, (50.0, q90, q99))
        boot = np.percentile(v[idx], q90, axis=1)
        out["criteria"][k] = {"nominal": float(nominal[k]), "mean": float(v.mean()), "median": float(p50),
                              "p90": float(p90), "p99": float(p99),
                              "p90_rel_se": float(boot.std() / abs(p90)) if p90 else 0.0}
    for name, op, thr in yields:
        v = _values(ds, name, snr_db)
        ok = v <= thr if op == "<=" else v >= thr
        out["yields"].append({"criterion": name, "op": op, "threshold": thr, "fraction": float(ok.mean())})
    return out


def nominal_values(run: ToleranceRun, snr_db: float) -> dict:
    """The nominal lens's values of the as-built criteria at ``snr_db``, in the run's field sampling."""
    r = as_built_criteria(run.eval_camera, run.design, Tolerances().sample(1, seed=0), [snr_db], rho0=run.rho0,
                          numerics=run.numerics)
    return {k: float(r[k].reshape(-1)[0]) for k in AS_BUILT_CRITERIA()}


SENSITIVITY_CRITERIA = ("mse_r", "mse_r_nominal")


def sensitivity(run: ToleranceRun, snr_db: float, n_lenses: int, *, log: Callable[[str], None] | None = None) -> list:
    """Each tolerance term alone (the others off; the same seed, so the same draws of that term): the 90th percentile
    of :data:`SENSITIVITY_CRITERIA` at ``snr_db`` over ``n_lenses`` lenses, and its rise above the nominal value."""
    nominal = nominal_values(run, snr_db)
    rows = []
    for term in run.tolerances.terms():
        t = run.tolerances.only(term)
        lenses = t.sample(n_lenses, seed=run.seed)
        r = as_built_criteria(run.eval_camera, run.design, lenses, [snr_db], rho0=run.rho0, numerics=run.numerics)
        row = {"term": term}
        for k in SENSITIVITY_CRITERIA:
            p90 = float(np.percentile(r[k].reshape(n_lenses, -1)[:, 0].numpy(), 90.0))
            row[k] = {"p90": p90, "rise": p90 - nominal[k]}
        rows.append(row)
        if log:
            log(f"  {term}: p90 MSE_R {row['mse_r']['p90']:.5f}, with the nominal restoration "
                f"{row['mse_r_nominal']['p90']:.5f}")
    rows.sort(key=lambda r: -r["mse_r_nominal"]["rise"])
    return rows


def tolerance_report(run: ToleranceRun, summary: dict, sens: list | None, snr_db: float) -> str:
    """Markdown: the statistics table, yields, the sensitivity table."""
    lines = [f"# Tolerance Monte Carlo: {run.design.name or 'custom design'}", "",
             f"{summary['lenses']} lenses, seed {run.seed}, at {snr_db:g} dB; design "
             + ", ".join(f"{k} = {v:g}" for k, v in run.design.floats().items())
             + f"; field angles {', '.join(f'{a:g}' for a in run.field_angles_deg)} deg at 4 azimuths.", "",
             "Tolerances: " + ", ".join(f"{k} = {v:g}" for k, v in run.tolerances.to_dict().items()
                                        if not isinstance(v, bool) and v) +
             f"; focus {'compensated at assembly' if run.tolerances.focus_compensated else 'not compensated'}.", "",
             "| criterion | nominal | mean | median | 90% of lenses as good as | 99% as good as | s.e. of the 90% value |",
             "|---|---|---|---|---|---|---|"]
    for k, s in summary["criteria"].items():
        lines.append(f"| {CRITERIA[k].label} ({k}) | {s['nominal']:.5g} | {s['mean']:.5g} | {s['median']:.5g} | "
                     f"{s['p90']:.5g} | {s['p99']:.5g} | {100 * s['p90_rel_se']:.2f}% |")
    lines += ["", "`mse_r`: each lens restored with its own PSFs (calibrated); `mse_r_nominal`: with the nominal "
              "lens's (the restoration built for the design). The 90% and 99% values are the 90th and 99th "
              "percentiles of a criterion to minimise, the 10th and 1st of one to maximise (MTF50, Strehl).", ""]
    for y in summary["yields"]:
        lines.append(f"Yield: {100 * y['fraction']:.1f}% of the lenses have {y['criterion']} {y['op']} "
                     f"{y['threshold']:g}.")
    if sens:
        lines += ["", "## Sensitivity (each tolerance alone)", "",
                  "| term | p90 MSE_R (calibrated) | rise | p90 MSE_R (nominal restoration) | rise |", "|---|---|---|---|---|"]
        for r in sens:
            lines.append(f"| {r['term']} | {r['mse_r']['p90']:.5f} | {r['mse_r']['rise']:+.5f} | "
                         f"{r['mse_r_nominal']['p90']:.5f} | {r['mse_r_nominal']['rise']:+.5f} |")
    return "\n".join(lines) + "\n"


def tolerance_figures(ds: xr.Dataset, summary: dict, out: Path, snr_db: float, title: str) -> list[Path]:
    """Histograms of MSE_R (calibrated and nominal restoration) and their cumulative distributions, with the nominal
    design and the 90th percentiles marked: ``histogram.png/.svg``, ``cdf.png/.svg`` in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []

    def save(fig, stem):
        for ext in ("png", "svg"):
            fig.savefig(out / f"{stem}.{ext}", dpi=120)
            written.append(out / f"{stem}.{ext}")
        plt.close(fig)

    series = [("mse_r", "restored with its own PSFs (calibrated)", "tab:blue"),
              ("mse_r_nominal", "restored with the nominal PSFs", "tab:red")]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    both = np.concatenate([_values(ds, k, snr_db) for k, _, _ in series])
    bins = np.linspace(both.min(), both.max(), 61)  # one set of bins for both
    for k, label, colour in series:
        v = _values(ds, k, snr_db)
        ax.hist(v, bins=bins, alpha=0.55, color=colour, label=f"{label}: p90 {summary['criteria'][k]['p90']:.4f}")
        ax.axvline(summary["criteria"][k]["p90"], color=colour, ls="--", lw=1)
    ax.axvline(summary["criteria"]["mse_r"]["nominal"], color="k", lw=1.5, label="nominal lens")
    ax.set_xlabel(f"MSE_R at {snr_db:g} dB (unit signal variance)")
    ax.set_ylabel("lenses")
    ax.set_title(f"{title}: {summary['lenses']} as-built lenses", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save(fig, "histogram")
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for k, label, colour in series:
        v = np.sort(_values(ds, k, snr_db))
        ax.step(v, np.arange(1, len(v) + 1) / len(v), where="post", color=colour, label=label)
    ax.axhline(0.9, color="grey", lw=0.8, ls=":")
    ax.axvline(summary["criteria"]["mse_r"]["nominal"], color="k", lw=1.5, label="nominal lens")
    ax.set_xlabel(f"MSE_R at {snr_db:g} dB (unit signal variance)")
    ax.set_ylabel("fraction of lenses at or below")
    ax.set_title(f"{title}: cumulative distribution", fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    save(fig, "cdf")
    return written
