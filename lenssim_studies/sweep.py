"""Resumable design sweeps over a grid of design parameters, written as a labelled NetCDF dataset.

A sweep config (TOML, see ``configs/paper_grid.toml``) names the lens (and optionally the sensor
and the spectrum), the grid of design parameters (any of :data:`lenssim.model.design.PARAMETERS`, e.g.
``s`` and ``Q_back``; their order is the order of the dataset's dimensions), the SNRs, the image
model and the numerical settings. The work is split into fixed chunks (one value of the first
grid parameter each, all values of the others), so every chunk is computed the same way whether
or not the run was interrupted. Each finished chunk is written atomically to ``OUT.partial/``; a
restarted run skips finished chunks, and the final file is assembled from them and written
atomically, so it is identical to an uninterrupted run's.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import xarray as xr

from lenssim import __version__
from lenssim.criteria import lens_criteria
from lenssim.model.design import PARAMETERS
from lenssim.io.files import atomic_write, check_output_file
from lenssim.torch_utils import select_device
from lenssim.validate import ResumeWarning, check_int

from .chunks import (_checksum, _chunk_keys, _compute_chunk, dataset_checksum, finished_result, partial_folder,
                     result_mismatch, resume_chunks, stamp_result, verify_result)
from .config import (SweepConfig, grid_count, grid_values, load_config)

__all__ = ["SweepConfig", "load_config", "grid_values", "grid_count", "run_sweep", "select_device", "ResumeWarning",
           "design_dims", "dataset_checksum", "verify_sweep", "sweep_mismatch"]


def _dataset(cfg: SweepConfig, chunks: list[dict]) -> xr.Dataset:
    st = {k: np.stack([c[k] for c in chunks]) for k in _chunk_keys(cfg)}
    dims = cfg.dims
    coords = {d: cfg.values(d) for d in dims}
    coords.update({"alpha": np.asarray(cfg.lens.field_angles_deg), "snr": np.asarray(cfg.snr_db, dtype=np.float64)})
    data = {}
    for name, c in lens_criteria().items():
        attrs = {"units": c.units, "long_name": f"{c.label}: {c.description}", "sense": c.sense, "role": c.role}
        snr = ("snr",) if c.per_snr else ()
        data[name] = (dims + snr, st[name], attrs)
        if c.from_otf is not None:
            data[f"{name}_alpha"] = (dims + ("alpha",) + snr, st[f"{name}_alpha"],
                                     {"units": c.units, "long_name": f"{c.label} per field angle"})
    data["rms_w_alpha"] = (dims + ("alpha",), st["rms_w_alpha"], {"units": "waves", "long_name": "RMS_w(alpha) over the pupil"})
    data["rms_w_piston_removed"] = (dims, st["rms_w_piston_removed"], {"units": "waves"})
    data["fft_size"] = (dims + ("alpha",), st["fft_size"].astype(np.int32),
                        {"units": "samples", "long_name": "FFT size used per PSF"})
    if cfg.focus is not None:
        data["focus_shift_um"] = (dims, st["focus_shift_um"], {"units": "um", "long_name": (
            f"best image plane behind the paraxial focus, for {cfg.focus['criterion']} at {cfg.focus['snr_db']:g} dB")})
    ds = xr.Dataset(data, coords=coords)
    for d in dims:
        ds[d].attrs = {"long_name": PARAMETERS[d].description, "units": PARAMETERS[d].unit}
    ds["alpha"].attrs = {"long_name": "half field angle", "units": "degree"}
    ds["snr"].attrs = {"long_name": "signal-to-noise ratio per pixel", "units": "dB"}
    ds.attrs = {"title": "lenssim sweep", "lenssim_version": __version__, "design_parameters": " ".join(dims),
                "config": json.dumps(cfg.to_dict(), sort_keys=True), "config_digest": cfg.digest()}
    return stamp_result(ds)


def verify_sweep(ds: xr.Dataset, path) -> None:
    """Refuse a sweep file whose numbers are not the ones the sweep wrote (edited by hand, damaged, or written by a
    version without a checksum: :func:`lenssim_studies.chunks.verify_result`), or that makes no sense for its run
    record (:func:`sweep_mismatch`): ``ValueError`` naming the file."""
    again = "run the sweep again"
    verify_result(ds, path, "sweep", again)
    why = sweep_mismatch(ds)
    if why:
        raise ValueError(f"{str(path)!r} makes no sense for its run record: {why}; {again}")


def sweep_mismatch(ds: xr.Dataset) -> str | None:
    """Why a sweep makes no sense for the config it records, or None: its grid, field angles and SNRs are the config's,
    its criteria over its grid and finite."""
    try:
        d = json.loads(ds.attrs["config"])
        coords = {k: grid_values(*v) for k, v in d["grid"].items()}
        coords["snr"] = np.asarray(d["snr_db"], dtype=np.float64)
        if "field_angles_deg" in d.get("lens", {}):
            coords["alpha"] = np.asarray(d["lens"]["field_angles_deg"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return "it carries no readable run record (config)"
    dims = design_dims(ds)  # the config's grid in the dataset's order (the config's JSON sorts its keys)
    if sorted(dims) != sorted(d["grid"]):
        return f"its design parameters {list(dims)} are not the run's"
    return result_mismatch(ds, coords, finite=[k for k in lens_criteria() if k in ds], dims=dims)


def _write_chunk(path: Path, chunk: dict, cfg: SweepConfig, i: int) -> None:
    meta = {"_index": np.int64(i), "_first_value": np.float64(cfg.values(cfg.dims[0])[i]),
            "_digest": np.str_(cfg.digest()), "_checksum": np.str_(_checksum(chunk))}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **chunk, **meta)
    atomic_write(path, write)


def _read_chunk(path: Path, cfg: SweepConfig, i: int):
    """The chunk's arrays if ``path`` holds chunk ``i`` of this config intact, else the reason it does not."""
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a bad chunk
        return f"cannot be read ({type(exc).__name__})"
    meta = ("_index", "_first_value", "_digest", "_checksum")
    if any(k not in data for k in _chunk_keys(cfg) + meta):
        return "is incomplete (missing arrays or its stamp)"
    first = float(cfg.values(cfg.dims[0])[i])
    if int(data["_index"]) != i or float(data["_first_value"]) != first:
        return (f"holds the chunk of {cfg.dims[0]} = {float(data['_first_value']):g} (index {int(data['_index'])}), "
                f"not {cfg.dims[0]} = {first:g}")
    if str(data["_digest"]) != cfg.digest():
        return "belongs to another config"
    chunk = {k: data[k] for k in _chunk_keys(cfg)}
    if _checksum(chunk) != str(data["_checksum"]):
        return "fails its checksum (corrupted)"
    rest = tuple(len(cfg.values(d)) for d in cfg.dims[1:])
    shape = chunk["rms_w_piston_removed"].shape  # one value per design of the chunk, whatever the criteria
    if shape != rest:
        return f"has the shape {shape}, not {rest}"
    return chunk


def _remove_temporaries(out: Path, part: Path) -> None:
    """Hidden temporaries of an earlier run that was killed (atomic writes in progress)."""
    stale = list(out.parent.glob(f".{out.stem}.*{out.suffix}")) if out.parent.exists() else []
    stale += list(part.glob(".*")) if part.exists() else []
    for p in stale:
        p.unlink(missing_ok=True)


def run_sweep(cfg: SweepConfig, out: str | os.PathLike, *, device: str = "auto", show_progress: bool = True,
              keep_chunks: bool = False, max_chunks: int | None = None,
              memory_limit_bytes: float | None = None, scheduler: str | None = None,
              workers: int | None = None, worker_threads: int | None = None) -> xr.Dataset | None:
    """Run (or resume) a sweep and write ``out`` (NetCDF). Returns the dataset, or ``None`` if
    ``max_chunks`` stopped the run early (the finished chunks stay in ``out.partial/``).

    ``scheduler`` (a dask scheduler's address) or ``workers`` (a local cluster of that many processes) runs
    the chunks as dask tasks (:mod:`lenssim.cluster`); the file written is the same, byte for byte, when the
    tasks compute with this process's number of torch threads (``worker_threads``, the default).

    ``out`` must not be an existing file that is not a finished sweep of the same config: the
    sweep refuses to overwrite anything else. Every finished chunk carries its index, its value of
    the first grid parameter, the config digest and a SHA-256 of its arrays; on a restart each is
    checked, and one that fails (truncated, corrupted, of another config or another position) is
    reported with a :class:`ResumeWarning` naming the file and computed again. Temporaries of a
    killed run are removed.
    """
    out = Path(out)
    dev = select_device(device)
    if scheduler is not None and workers is not None:
        raise ValueError("give either a scheduler address or a number of local workers, not both")
    workers = None if workers is None else check_int("workers", workers, 1)
    worker_threads = None if worker_threads is None else check_int("worker_threads", worker_threads, 1)
    cfg.check(memory_limit_bytes)
    check_output_file(out, "sweep output")  # a folder, pipe or device, a link loop, an unwritable folder: one line
    if out.exists():  # a finished sweep of this config is reused only if its numbers are the ones written
        return finished_result(out, cfg.digest(), "sweep", check=sweep_mismatch)
    part = out.with_name(out.name + ".partial")
    _remove_temporaries(out, part)
    with partial_folder(part, "config.json", cfg.digest(), {"config": cfg.to_dict()},
                        f"{str(part)!r} holds chunks of a different config; remove it or choose another output file"):
        n_first = len(cfg.values(cfg.dims[0]))
        per_chunk = int(np.prod([len(cfg.values(d)) for d in cfg.dims[1:]])) * len(cfg.lens.field_angles_deg)
        paths = [part / f"chunk_{i:05d}.npz" for i in range(n_first)]
        where = scheduler or (f"{workers} local workers" if workers is not None else dev.type)

        def on_cluster(todo):
            from .cluster import compute_chunks, dask_client

            with dask_client(scheduler, workers) as client:
                yield from compute_chunks(client, cfg, todo, device=device, threads=worker_threads)

        chunks = resume_chunks(paths, kind="sweep", read=lambda p, i: _read_chunk(p, cfg, i),
                               write=lambda p, chunk, i: _write_chunk(p, chunk, cfg, i),
                               compute=lambda i, progress: _compute_chunk(cfg, i, dev, progress),
                               weight=lambda i: per_chunk, desc=f"sweep on {where}", show_progress=show_progress,
                               max_chunks=max_chunks,
                               cluster=on_cluster if scheduler is not None or workers is not None else None)
        if chunks is None:
            return None
        ds = _dataset(cfg, chunks)
        atomic_write(out, lambda tmp: ds.to_netcdf(tmp, engine="scipy"))
        if not keep_chunks:
            shutil.rmtree(part)
        return ds


def design_dims(ds: xr.Dataset) -> tuple[str, ...]:
    """The design-parameter dimensions of a sweep dataset, in order."""
    if "design_parameters" in ds.attrs:
        return tuple(str(ds.attrs["design_parameters"]).split())
    return tuple(d for d in ds["rms_w_piston_removed"].dims)
