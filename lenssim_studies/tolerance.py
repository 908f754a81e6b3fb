"""``lenssim tolerance`` (and ``lenssim tolerance --lens``): the resumable Monte Carlo of manufactured copies of a lens of
either kind (issues 19, item 3, and 29).

**The paper's singlet** (:class:`ToleranceRun`): ``N`` lenses drawn from a :class:`lenssim.model.tolerances.Tolerances`
(seeded: the same seed gives the same lenses, whatever the chunking), evaluated in chunks of :data:`CHUNK_LENSES` by the
batched closed form :func:`lenssim.tolerancing.as_built_criteria` (serially or as dask tasks on the sweep's cluster
path); a summary (mean, median, 90th and 99th percentiles, the bootstrap standard error of the 90th percentile,
yields), a sensitivity table (each tolerance alone) and figures.

**Any sequential lens** (:class:`LensToleranceRun`): copies with tolerances per surface, each traced on real rays
(:func:`lenssim.tolerancing.lens_copies`), in chunks of :data:`CHUNK_COPIES` (in this process, or as dask tasks on
the same cluster path, each worker evaluating the nominal lens once); the nominal lens's values at the copies' and the
default numerics are variables of the result.

One machinery for both (:func:`run_tolerance`): each chunk written to ``out.partial/chunk_NNNNN.npz`` with its index,
the run's digest and a SHA-256 of its arrays, so a killed run resumes where it stopped, every resumed chunk is verified
(a chunk that fails is reported as a :class:`lenssim.validate.ResumeWarning` and computed again), and the finished
dataset (``lens`` x ``snr``; one variable per criterion, the sampled errors as variables) is the same, byte for byte,
as an uninterrupted run's.
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
from lenssim.model.tolerances import SurfaceTolerances, Tolerances
from lenssim.optics.psf_provider import SequentialPSF
from lenssim.tolerancing import AS_BUILT_CRITERIA, COPY_CRITERIA, as_built_criteria, lens_copies, tolerance_angles
from lenssim.torch_utils import tensor_of
from lenssim.validate import check_int

from .chunks import (_checksum, finish_resumable, open_resumable, partial_folder, read_stamped_chunk, result_mismatch,
                     resume_chunks, write_stamped_chunk)

__all__ = ["Digested", "AtFieldAngles", "ToleranceRun", "LensToleranceRun", "run_tolerance", "summarise", "summarise_lens_tolerance", "spread",
           "sensitivity", "parse_yield", "tolerance_report", "lens_tolerance_report", "markdown_table",
           "tolerance_figures", "nominal_values", "TOLERANCE_FIELD_ANGLES", "DEFAULT_LENSES", "CHUNK_LENSES",
           "CHUNK_COPIES"]

TOLERANCE_FIELD_ANGLES = (0.0, 3.5, 7.0, 10.5, 14.0)
"""Field angles (deg) of a tolerance run of the singlet (each at four azimuths): the paper's 0..14 deg every 3.5 deg
(its 15 angles would cost 3.4x as much for a field average within 1% of this one on the nominal lens)."""
DEFAULT_LENSES = 1000
"""Lenses of a tolerance run of the singlet: enough for the 90th percentile of each reported quantity to be known to
~1% (the report gives each one's bootstrap standard error)."""
CHUNK_LENSES = 50
"""Singlet lenses per chunk (the unit of resumption and of dask tasks)."""
CHUNK_COPIES = 5
"""Copies of any lens per chunk file (each copy traces its own wavefront tables: a chunk is seconds to a minute)."""
BOOTSTRAP = 400
"""Bootstrap resamples for the standard error of the 90th percentile."""
_ROW_KEYS = COPY_CRITERIA + ("image_shift_mm", "efl_mm")


class Digested:
    """Settings named by their digest: the SHA-256 (16 hex digits) of :meth:`to_dict`."""

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]


class AtFieldAngles:
    """A Monte Carlo of the singlet's ``camera`` sampled at its own ``field_angles_deg`` (deg)."""

    @property
    def eval_camera(self) -> Camera:
        """The camera with the run's field angles: the nominal criteria and the Monte Carlo sample one field."""
        lens = dataclasses.replace(self.camera.lens, field_angles_deg=self.field_angles_deg)
        return dataclasses.replace(self.camera, lens=lens)


class _MonteCarlo(Digested):
    """What a Monte Carlo run of either kind shares: its digest and its chunks (``count`` copies, ``per_chunk`` a
    chunk)."""

    def chunks(self) -> list[tuple[int, int]]:
        """Copy ranges ``[k0, k1)`` of the chunks."""
        return [(k, min(k + self.per_chunk, self.count)) for k in range(0, self.count, self.per_chunk)]


@dataclass(frozen=True)
class ToleranceRun(_MonteCarlo, AtFieldAngles):
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

    def to_dict(self) -> dict:
        return {"camera": self.camera.to_dict(), "design": self.design.floats(), "design_name": self.design.name,
                "tolerances": self.tolerances.to_dict(), "snr_db": list(self.snr_db), "rho0": self.rho0,
                "n_lenses": self.n_lenses, "seed": self.seed, "numerics": self.numerics.to_dict(),
                "field_angles_deg": list(self.field_angles_deg), "chunk_lenses": self.chunk_lenses,
                "lenssim_version": __version__}

    count = property(lambda self: self.n_lenses)
    per_chunk = property(lambda self: self.chunk_lenses)
    finite = property(lambda self: AS_BUILT_CRITERIA())
    chunk_keys = property(lambda self: AS_BUILT_CRITERIA() + ("fft_size",))
    rows_key, what = "cost", "lenses"


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


@dataclass(frozen=True)
class LensToleranceRun(_MonteCarlo):
    """Everything that sets a Monte Carlo of any lens: the nominal lens's provider (lens, sensor, light, sampling),
    the tolerances, the number of copies and seed, the SNRs (dB), the image model's correlation, the field angles
    (deg; None: :func:`lenssim.tolerancing.tolerance_angles`), the numerics and whether the copies' tables are
    coarse."""

    psf: SequentialPSF
    tolerances: SurfaceTolerances
    n_copies: int
    seed: int
    snr_db: tuple[float, ...]
    rho0: float
    numerics: Numerics
    angles_deg: tuple[float, ...] | None = None
    coarse: bool = True
    chunk_copies: int = CHUNK_COPIES

    count = property(lambda self: self.n_copies)
    per_chunk = property(lambda self: self.chunk_copies)
    finite = chunk_keys = _ROW_KEYS
    rows_key, what = "efl_mm", "copies"

    @property
    def angles(self) -> tuple[float, ...]:
        return tolerance_angles(self.psf, self.angles_deg)

    def to_dict(self) -> dict:
        return {"psf": json.loads(self.psf.fingerprint()), "lens_cache_key": self.psf.lens.cache_key(),
                "tolerances": self.tolerances.to_dict(), "n_copies": self.n_copies, "seed": self.seed,
                "snr_db": list(self.snr_db), "rho0": self.rho0, "numerics": self.numerics.to_dict(),
                "angles_deg": list(self.angles), "coarse": self.coarse, "chunk_copies": self.chunk_copies,
                "lenssim_version": __version__}


def _singlet_plan(run: ToleranceRun, device, scheduler, workers, worker_threads):
    """How the singlet's chunks are computed: ``(compute, dataset, weight, desc, unit, cluster)`` of
    :func:`run_tolerance` (its FFT sizes checked first)."""
    from lenssim.torch_utils import select_device

    dev = select_device(device)
    run.check_fft_sizes()
    ranges = run.chunks()
    per_lens = 1 + 4 * sum(a != 0 for a in run.field_angles_deg)  # field points (the axis once)
    where = scheduler or (f"{workers} local workers" if workers is not None else dev.type)

    def on_cluster(todo):
        from .cluster import compute_chunks, dask_client

        with dask_client(scheduler, workers) as client:
            yield from compute_chunks(client, run, todo, device=device, threads=worker_threads, task=_chunk_task,
                                      kind="tolerance")

    return (lambda i, progress: _compute_chunk(run, i, dev, progress), lambda chunks: _dataset(run, chunks),
            lambda i: (ranges[i][1] - ranges[i][0]) * per_lens, f"tolerance on {where}", "PSF",
            on_cluster if scheduler is not None or workers is not None else None)


def _lens_copy_rows(copy, ranges, i: int, progress) -> dict:
    """Chunk ``i`` of a Monte Carlo of any lens: its copies' rows (``copy(k)``) as arrays of :data:`_ROW_KEYS`."""
    rows = []
    for k in range(*ranges[i]):
        rows.append(copy(k))
        if progress is not None:
            progress(1)
    return {key: np.stack([np.asarray(torch.as_tensor(r[key], dtype=torch.float64)) for r in rows])
            for key in _ROW_KEYS}


_WORKER_COPIES: dict[str, Callable] = {}
"""On a dask worker: the copy function of the Monte Carlo of any lens with this digest (its nominal lens evaluated
once per worker process: the reference of every copy)."""


def _lens_chunk_task(run: LensToleranceRun, digest: str, index: int, device: str, threads: int):
    """On a dask worker: chunk ``index`` of a Monte Carlo of any lens -> ``(index, arrays, sha256)`` (``device`` is
    the cluster path's argument: the real-ray tracer of a lens of floats runs on the host)."""
    from .cluster import ClusterError, _numeric_malloc, with_threads

    _numeric_malloc()
    if run.digest() != digest:
        raise ClusterError(f"the worker's lenssim reads this tolerance run differently (digest {run.digest()} != "
                           f"{digest}): install the client's lenssim version on every worker")

    def compute():
        if digest not in _WORKER_COPIES:
            _WORKER_COPIES.clear()  # one run's nominal lens kept at a time
            _WORKER_COPIES[digest] = lens_copies(run.psf, run.tolerances, run.n_copies, seed=run.seed,
                                                 snr_db=run.snr_db, rho0=run.rho0, angles_deg=run.angles,
                                                 coarse=run.coarse, numerics=run.numerics, compare_default=False)[0]
        return _lens_copy_rows(_WORKER_COPIES[digest], run.chunks(), index, None)

    chunk = with_threads(threads, compute)
    return index, chunk, _checksum(chunk)


def _lens_plan(run: LensToleranceRun, scheduler=None, workers=None, worker_threads=None):
    """How the copies of any lens are computed: ``(compute, dataset, weight, desc, unit, cluster)`` of
    :func:`run_tolerance` (the nominal lens evaluated first: the reference of every copy, :func:`lens_copies`). With
    ``scheduler`` or ``workers`` the chunks are dask tasks, each worker evaluating the nominal lens once for itself
    (its copies' numerics only); the copies are the same computation as in this process (equal bit for bit at the
    same torch threads per task, ``worker_threads``)."""
    copy, dataset = lens_copies(run.psf, run.tolerances, run.n_copies, seed=run.seed, snr_db=run.snr_db,
                                rho0=run.rho0, angles_deg=run.angles, coarse=run.coarse, numerics=run.numerics)
    ranges = run.chunks()
    where = scheduler or (f"{workers} local workers" if workers is not None else None)

    def on_cluster(todo):
        from .cluster import compute_chunks, dask_client

        with dask_client(scheduler, workers) as client:
            yield from compute_chunks(client, run, todo, device="cpu", threads=worker_threads, task=_lens_chunk_task,
                                      kind="tolerance")

    return (lambda i, progress: _lens_copy_rows(copy, ranges, i, progress),
            lambda chunks: dataset([{key: torch.from_numpy(np.asarray(c[key][j])) for key in _ROW_KEYS}
                                    for c in chunks for j in range(c["efl_mm"].shape[0])]),
            lambda i: ranges[i][1] - ranges[i][0], "manufactured copies" + (f" on {where}" if where else ""), "copy",
            on_cluster if where else None)


def run_tolerance(run: ToleranceRun | LensToleranceRun, out: str | os.PathLike, *, device: str = "auto",
                  show_progress: bool = True, scheduler: str | None = None, workers: int | None = None,
                  worker_threads: int | None = None, max_chunks: int | None = None,
                  attrs: dict | None = None) -> xr.Dataset | None:
    """Run (or resume) the Monte Carlo of either kind and write ``out`` (NetCDF); ``None`` if ``max_chunks`` stopped
    it early.

    Resumption as the sweeps': finished chunks in ``out.partial/`` carry their index, the run's digest and a SHA-256
    of their arrays; a chunk that fails its check is reported (:class:`lenssim.validate.ResumeWarning`) and computed
    again. ``out`` must not be an existing file other than the finished result of the same run (verified before it is
    returned). With ``workers`` or ``scheduler`` the chunks are dask tasks (:mod:`lenssim_studies.cluster`); the file
    is the same, byte for byte, at the same torch threads per task (``worker_threads``, default this process's).
    ``attrs``: more attributes of the dataset (descriptive: not part of the digest).
    """
    out = Path(out)
    if scheduler is not None and workers is not None:
        raise ValueError("give either a scheduler address or a number of local workers, not both")
    lens = isinstance(run, LensToleranceRun)
    digest = run.digest()
    done = open_resumable(out, digest, "tolerance output", "tolerance run",
                          check=lambda ds: result_mismatch(ds, {"lens": np.arange(run.count), "snr": run.snr_db},
                                                           finite=run.finite, dims=("lens",)))
    if done is not None:
        return done
    compute, dataset, weight, desc, unit, cluster = (
        _lens_plan(run, scheduler, workers, worker_threads) if lens
        else _singlet_plan(run, device, scheduler, workers, worker_threads))
    part = out.with_name(out.name + ".partial")
    if part.exists():
        for p in part.glob(".*"):
            p.unlink(missing_ok=True)
    with partial_folder(part, "run.json", digest, {"run": run.to_dict()},
                        f"{str(part)!r} holds chunks of a different tolerance run; remove it or choose another output"):
        ranges = run.chunks()
        paths = [part / f"chunk_{i:05d}.npz" for i in range(len(ranges))]

        def read(path, i):
            return read_stamped_chunk(path, run.chunk_keys, digest, i, run="tolerance run", rows_key=run.rows_key,
                                      rows=ranges[i][1] - ranges[i][0], what=run.what)

        chunks = resume_chunks(paths, kind="tolerance", read=read,
                               write=lambda p, chunk, i: write_stamped_chunk(p, chunk, digest, i), compute=compute,
                               weight=weight, desc=desc, unit=unit, show_progress=show_progress,
                               max_chunks=max_chunks, cluster=cluster)
        if chunks is None:
            return None
        ds = dataset(chunks)
        ds.attrs.update(attrs or {})
        ds.attrs["config_digest"] = digest
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


def _snr_index(ds, ref_snr: float) -> int:
    snr = [float(v) for v in ds["snr"].values]
    for j, v in enumerate(snr):
        if math.isclose(v, ref_snr, abs_tol=1e-9):
            return j
    raise ValueError(f"reference SNR {ref_snr:g} dB is not allowed: one of the run's {snr}")


def _values(ds: xr.Dataset, name: str, snr: float) -> np.ndarray:
    """``name``'s values per lens at ``snr`` (dB) of a Monte Carlo of either kind (of the run's SNRs)."""
    v = ds[name]
    return (v.isel(snr=_snr_index(ds, snr)) if "snr" in v.dims else v).values


def spread(v: np.ndarray, seed: int, *, worse_low: bool = False) -> dict:
    """The spread of a criterion over ``N`` lenses ``v``: mean, median, ``p90`` and ``p99`` (the values 90% and 99% of
    the lenses are at least as good as: the 90th and 99th percentiles of a criterion to minimise, the 10th and 1st of
    one to maximise, ``worse_low``), and the bootstrap standard error of ``p90`` (relative; :data:`BOOTSTRAP`
    resamples drawn from ``seed``: the same draws for every criterion of ``N`` lenses)."""
    idx = np.random.default_rng(seed).integers(0, len(v), size=(BOOTSTRAP, len(v)))
    q90, q99 = (10.0, 1.0) if worse_low else (90.0, 99.0)
    p50, p90, p99 = np.percentile(v, (50.0, q90, q99))
    boot = np.percentile(v[idx], q90, axis=1)
    return {"mean": float(v.mean()), "median": float(p50), "p90": float(p90), "p99": float(p99),
            "p90_rel_se": float(boot.std() / abs(p90)) if p90 else 0.0}


def summarise(ds: xr.Dataset, nominal: dict, snr_db: float, yields=(), *, seed: int = 0) -> dict:
    """The singlet's Monte Carlo: per criterion at ``snr_db``, the nominal value and its :func:`spread` over the
    lenses, and the yields ``[(criterion, op, value)]`` (fraction of lenses meeting each)."""
    out = {"snr_db": snr_db, "lenses": int(ds.sizes["lens"]), "criteria": {}, "yields": []}
    for k in AS_BUILT_CRITERIA():
        # for a criterion to maximise, 90% of the lenses are above its 10th percentile
        out["criteria"][k] = {"nominal": float(nominal[k]),
                              **spread(_values(ds, k, snr_db), seed, worse_low=CRITERIA[k].sense == "max")}
    for name, op, thr in yields:
        v = _values(ds, name, snr_db)
        ok = v <= thr if op == "<=" else v >= thr
        out["yields"].append({"criterion": name, "op": op, "threshold": thr, "fraction": float(ok.mean())})
    return out


def summarise_lens_tolerance(ds, ref_snr: float) -> dict:
    """The Monte Carlo of any lens: mean, median and 90th percentile over the copies of ``mse_r`` and
    ``mse_r_nominal`` at ``ref_snr`` (and of ``mse_s``, ``rms_w``), with the nominal's values beside them, and the
    coarse numerics' effect on the nominal."""
    j = _snr_index(ds, ref_snr)
    out = {"reference_snr_db": float(ref_snr), "lenses": int(ds.sizes["lens"])}
    for k in COPY_CRITERIA:
        v = tensor_of(ds[k].values, torch.float64)
        nom = tensor_of(ds[f"nominal_{k}"].values, torch.float64)
        full = tensor_of(ds[f"nominal_default_{k}"].values, torch.float64)
        if v.ndim == 2:
            v, nom, full = v[:, j], nom[j], full[j]
        out[k] = {"mean": float(v.mean()), "median": float(v.median()) if v.numel() % 2 else float(v.quantile(0.5)),
                  "p90": float(v.quantile(0.9)), "min": float(v.min()), "max": float(v.max()),
                  "nominal": float(nom), "nominal_default_numerics": float(full),
                  "coarse_effect": float(nom / full - 1) if float(full) else 0.0}
    return out


def markdown_table(header, rows) -> list[str]:
    """The lines of a Markdown table: ``header`` (column titles) and ``rows`` (each a sequence of cell texts)."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + [
        "| " + " | ".join(r) + " |" for r in rows]


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
    """Markdown of the singlet's Monte Carlo: the statistics table, yields, the sensitivity table."""
    lines = [f"# Tolerance Monte Carlo: {run.design.name or 'custom design'}", "",
             f"{summary['lenses']} lenses, seed {run.seed}, at {snr_db:g} dB; design "
             + ", ".join(f"{k} = {v:g}" for k, v in run.design.floats().items())
             + f"; field angles {', '.join(f'{a:g}' for a in run.field_angles_deg)} deg at 4 azimuths.", "",
             "Tolerances: " + ", ".join(f"{k} = {v:g}" for k, v in run.tolerances.to_dict().items()
                                        if not isinstance(v, bool) and v) +
             f"; focus {'compensated at assembly' if run.tolerances.focus_compensated else 'not compensated'}.", ""]
    lines += markdown_table(("criterion", "nominal", "mean", "median", "90% of lenses as good as", "99% as good as",
                             "s.e. of the 90% value"),
                            [(f"{CRITERIA[k].label} ({k})", f"{s['nominal']:.5g}", f"{s['mean']:.5g}",
                              f"{s['median']:.5g}", f"{s['p90']:.5g}", f"{s['p99']:.5g}",
                              f"{100 * s['p90_rel_se']:.2f}%") for k, s in summary["criteria"].items()])
    lines += ["", "`mse_r`: each lens restored with its own PSFs (calibrated); `mse_r_nominal`: with the nominal "
              "lens's (the restoration built for the design). The 90% and 99% values are the 90th and 99th "
              "percentiles of a criterion to minimise, the 10th and 1st of one to maximise (MTF50, Strehl).", ""]
    for y in summary["yields"]:
        lines.append(f"Yield: {100 * y['fraction']:.1f}% of the lenses have {y['criterion']} {y['op']} "
                     f"{y['threshold']:g}.")
    if sens:
        lines += ["", "## Sensitivity (each tolerance alone)", ""] + markdown_table(
            ("term", "p90 MSE_R (calibrated)", "rise", "p90 MSE_R (nominal restoration)", "rise"),
            [(r["term"], f"{r['mse_r']['p90']:.5f}", f"{r['mse_r']['rise']:+.5f}", f"{r['mse_r_nominal']['p90']:.5f}",
              f"{r['mse_r_nominal']['rise']:+.5f}") for r in sens])
    return "\n".join(lines) + "\n"


def lens_tolerance_report(ds, summary: dict) -> str:
    """Markdown of a Monte Carlo of any lens (its dataset and :func:`summarise_lens_tolerance`)."""
    tol = json.loads(ds.attrs["tolerances"])
    lines = [f"# Tolerance Monte Carlo: {ds.attrs['lens'] or 'lens'}", "",
             f"{summary['lenses']} manufactured copies (seed {ds.attrs['seed']}), pixels "
             f"{ds.attrs['pixel_pitch_um']:.4g} um ({ds.attrs['sampling']}), field angles "
             + ", ".join(f"{a:.3g}" for a in ds.attrs["angles_deg"]) + " deg, SNR "
             f"{summary['reference_snr_db']:g} dB.", "",
             "Tolerances (+/- limits, each 2 standard deviations): " + ", ".join(
                 f"{k} {v:g}" for k, v in tol.items() if k != "focus_compensated")
             + f"; focus compensated: {'yes' if tol['focus_compensated'] else 'no'}. Not modelled: "
             + ds.attrs["not_modelled"] + ".", ""]
    lines += markdown_table(("criterion", "nominal", "mean", "median", "p90", "max"),
                            [(k, *(f"{summary[k][c]:.5g}" for c in ("nominal", "mean", "median", "p90", "max")))
                             for k in COPY_CRITERIA])
    lines += ["", "mse_r: restored with each copy's own PSFs; mse_r_nominal: with the Wiener filter of the nominal "
              "lens. Copies at coarser numerics (" + ds.attrs["numerics"] + "): the nominal's mse_r differs from the "
              f"default numerics by {summary['mse_r']['coarse_effect']:+.2e} (relative).", ""]
    return "\n".join(lines)


def tolerance_figures(ds: xr.Dataset, summary: dict, out: Path, snr_db: float, title: str) -> list[Path]:
    """Histograms of MSE_R (calibrated and nominal restoration) and their cumulative distributions, with the nominal
    design and the 90th percentiles marked: ``histogram.png/.svg``, ``cdf.png/.svg`` in ``out``."""
    from .figures import _plt, _save

    plt = _plt()
    written = []

    def save(fig, stem):
        written.extend([_save(fig, out, stem, dpi=120), out / f"{stem}.svg"])

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
