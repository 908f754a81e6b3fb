"""One chunk of a sweep (one value of the first grid parameter, all values of the others): what it holds,
how it is computed and its checksum. Shared by the serial sweep (:mod:`lenssim_studies.sweep`) and the dask
workers (:mod:`lenssim_studies.cluster`), which import it and not each other.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from lenssim.criteria import lens_criteria
from lenssim.model.design import Design
from lenssim.metrics import evaluate
from lenssim.torch_utils import HOST

__all__ = ["_chunk_keys", "_compute_chunk", "chunk_values", "_checksum", "partial_folder", "resume_chunks", "write_stamped_chunk",
           "read_stamped_chunk", "finished_result", "dataset_checksum", "stamp_result", "verify_result",
           "result_mismatch", "is_netcdf", "damaged_netcdf", "run_resumable"]


@contextmanager
def partial_folder(part: Path, meta_name: str, digest: str, payload: dict, refusal: str):
    """The chunk folder ``part`` of a resumable run, created or reopened: its ``meta_name`` file names the run
    (``{"digest": digest, **payload}``), and a folder of another run is refused (``FileExistsError(refusal)``). If the
    run fails, the folder is removed when this run created it and no chunk landed in it (only its ``.json``
    metadata): a run refused or stopped before any result leaves nothing behind; finished chunks stay."""
    from lenssim.io.files import atomic_write_text

    created = not part.exists()
    part.mkdir(parents=True, exist_ok=True)
    try:
        meta = part / meta_name
        if meta.exists():
            try:
                old = json.loads(meta.read_text()).get("digest")
            except (ValueError, OSError):
                old = None
            if old != digest:
                raise FileExistsError(refusal)
        else:
            atomic_write_text(meta, json.dumps({"digest": digest, **payload}))
        yield part
    except BaseException:
        if created and part.is_dir() and not any(p.suffix != ".json" for p in part.iterdir()):
            shutil.rmtree(part, ignore_errors=True)
        raise


def resume_chunks(paths: list[Path], *, kind: str, read, write, compute, weight, desc: str, show_progress: bool,
                  max_chunks: int | None = None, cluster=None, unit: str = "PSF") -> list | None:
    """The chunks of a resumable run, one file each at ``paths``: those already there are kept where they verify, the
    others computed and written, and all of them read back and verified.

    ``read(path, i)`` gives the chunk or a string saying why it is not trusted (a chunk already there is then warned
    about as a :class:`lenssim.validate.ResumeWarning` and computed again; one just written stops the run with a
    ``ValueError``); ``write(path, chunk, i)`` writes it atomically; ``compute(i, progress)`` computes it here, or
    ``cluster(todo)`` (optional) yields ``(i, chunk)`` for the indices ``todo`` as they are done elsewhere.
    ``weight(i)``: chunk ``i``'s share of the progress bar (``desc``, on stderr, counted in ``unit``). With ``max_chunks`` at most
    that many are computed; if any are left, None. ``kind`` names the chunks in messages ("sweep", "tolerance").
    """
    import warnings

    from lenssim.validate import ResumeWarning

    from .progress import progress_bar

    for i, p in enumerate(paths):
        if p.exists():
            got = read(p, i)
            if isinstance(got, str):
                warnings.warn(f"{kind} chunk {str(p)!r} {got}; computing it again", ResumeWarning, stacklevel=3)
                p.unlink()
    total = sum(weight(i) for i in range(len(paths)))
    done = sum(weight(i) for i, p in enumerate(paths) if p.exists())
    bar = progress_bar(total=total, initial=done, unit=unit, show=show_progress, desc=desc)
    todo = [i for i, p in enumerate(paths) if not p.exists()]
    stopped = max_chunks is not None and len(todo) > max_chunks
    todo = todo[:max_chunks] if max_chunks is not None else todo
    if cluster is not None:
        for i, chunk in cluster(todo):
            write(paths[i], chunk, i)
            bar.update(weight(i))
    else:
        for i in todo:
            write(paths[i], compute(i, bar.update), i)
    bar.close()
    if stopped:
        return None
    chunks = []
    for i, p in enumerate(paths):
        got = read(p, i)
        if isinstance(got, str):
            raise ValueError(f"{kind} chunk {str(p)!r} {got} after it was written; run the same command again")
        chunks.append(got)
    return chunks


def _chunk_keys(cfg=None) -> tuple[str, ...]:
    keys = []
    for name, c in lens_criteria().items():
        keys += [name, f"{name}_alpha"] if c.from_otf is not None else [name]
    extra = ("focus_shift_um",) if cfg is not None and cfg.focus is not None else ()
    return tuple(keys) + ("rms_w_alpha", "rms_w_piston_removed", "fft_size") + extra


def chunk_values(cfg, i: int) -> dict:
    """The design values of a sweep's chunk ``i``: the first dimension's ``i``-th value and the other dimensions' full
    grid (``indexing="ij"``), the fixed parameters beside them; ``{name: float64 tensor of the grid's shape}``."""
    rest = cfg.dims[1:]
    axes = np.meshgrid(*(cfg.values(d) for d in rest), indexing="ij") if rest else []
    first = cfg.values(cfg.dims[0])[i]
    vals = {d: torch.from_numpy(np.ascontiguousarray(a)) for d, a in zip(rest, axes)}
    shape = axes[0].shape if rest else ()
    vals[cfg.dims[0]] = torch.full(shape, float(first), dtype=torch.float64, device=HOST)  # as from_numpy's
    vals.update({k: torch.full(shape, v, dtype=torch.float64, device=HOST) for k, v in cfg.fixed.items()})
    return vals


def _compute_chunk(cfg, i: int, device, progress) -> dict:
    vals = chunk_values(cfg, i)
    if cfg.focus is not None:
        from lenssim.focus import best_focus_batch

        f = cfg.focus
        z, _ = best_focus_batch(cfg.camera, Design(vals), f["criterion"], f["snr_db"], bounds_um=f["bounds_um"],
                                tol_um=f["tol_um"], numerics=cfg.numerics, device=device, rho0=cfg.rho0,
                                psd_model=cfg.psd_model)
        vals["focus_shift_um"] = z
    res = evaluate(cfg.camera, Design(vals), cfg.snr_db, rho0=cfg.rho0, psd_model=cfg.psd_model,
                   numerics=cfg.numerics, device=device, progress=progress)
    if cfg.focus is not None:
        res["focus_shift_um"] = vals["focus_shift_um"]
    return {k: res[k].cpu().numpy() for k in _chunk_keys(cfg)}


def _checksum(chunk: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(chunk):
        a = np.ascontiguousarray(chunk[k])
        h.update(f"{k}|{a.dtype}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def write_stamped_chunk(path: Path, chunk: dict, digest: str, index: int) -> None:
    """``chunk``'s arrays written atomically to ``path`` (``.npz``) with its index, the run's digest and a SHA-256 of
    the arrays (what :func:`read_stamped_chunk` verifies)."""
    from lenssim.io.files import atomic_write

    meta = {"_index": np.int64(index), "_digest": np.str_(digest), "_checksum": np.str_(_checksum(chunk))}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **chunk, **meta)
    atomic_write(path, write)


def read_stamped_chunk(path: Path, keys, digest: str, index: int, *, run: str, rows_key: str, rows: int, what: str):
    """The arrays ``keys`` of chunk ``index`` at ``path`` if it is intact and this run's (digest ``digest``, ``rows``
    entries of ``what`` in ``rows_key``), else the reason it is not trusted (``run`` names the run in it)."""
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a bad chunk
        return f"cannot be read ({type(exc).__name__})"
    keys = tuple(keys)
    if any(k not in data for k in keys + ("_index", "_digest", "_checksum")):
        return "is incomplete (missing arrays or its stamp)"
    if int(data["_index"]) != index:
        return f"holds chunk {int(data['_index'])}, not chunk {index}"
    if str(data["_digest"]) != digest:
        return f"belongs to another {run}"
    chunk = {k: data[k] for k in keys}
    if _checksum(chunk) != str(data["_checksum"]):
        return "fails its checksum (corrupted)"
    if chunk[rows_key].shape[:1] != (rows,):
        return f"has {chunk[rows_key].shape[0]} {what}, not {rows}"
    return chunk


def _canonical(a: np.ndarray) -> tuple[str, bytes]:
    """``(type, bytes)`` of an array as a NetCDF-3 file gives it back: text as UTF-8 (NUL between entries), integers and
    booleans as the file stores them (NetCDF-3 has no 64-bit, unsigned or boolean integers: xarray's
    ``coerce_nc3_dtype``), numbers in native byte order."""
    from xarray.backends.netcdf3 import coerce_nc3_dtype

    if a.dtype.kind in "OUS":
        text = "\0".join(v.decode() if isinstance(v, bytes) else str(v) for v in a.reshape(-1).tolist())
        return "str", text.encode()
    if a.dtype.kind in "biu":
        a = coerce_nc3_dtype(a)
    a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("="))
    return a.dtype.str, a.tobytes()


NETCDF_MAGIC = (b"CDF\x01", b"CDF\x02", b"CDF\x05", b"\x89HDF")
"""The first bytes of a NetCDF file (classic, 64-bit offset, 64-bit data; NetCDF-4 is HDF5)."""


def is_netcdf(path) -> bool:
    """Whether ``path`` begins as a NetCDF file does (:data:`NETCDF_MAGIC`)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) in NETCDF_MAGIC
    except OSError:
        return False


def damaged_netcdf(path, again: str) -> str:
    """The one line that refuses a NetCDF result whose data cannot be read back whole."""
    return (f"{str(path)!r} fails its checksum: a NetCDF file whose data cannot be read back (truncated or damaged); "
            f"{again}")


def dataset_checksum(ds) -> str:
    """SHA-256 of every variable and coordinate of a result (name, type, shape and bytes, in name order; each as the
    NetCDF-3 file holds it, so a result and its file read back give the same)."""
    h = hashlib.sha256()
    for name in sorted(map(str, ds.variables)):
        kind, data = _canonical(np.asarray(ds[name].values))
        h.update(f"{name}|{kind}|{ds[name].shape}|".encode())
        h.update(data)
    return h.hexdigest()


def stamp_result(ds):
    """``ds`` with its checksum (``data_sha256``, what :func:`verify_result` checks) among its attributes."""
    ds.attrs["data_sha256"] = dataset_checksum(ds)
    return ds


def verify_result(ds, path, run: str, again: str) -> None:
    """Refuse a result read back whose numbers are not the ones its run wrote: no checksum (written by a version
    without one), data that no longer match it (damaged, edited by hand), or a run record (``config``) that no longer
    matches its digest (``config_digest``). A one-line ``ValueError`` naming the file (``path``), the ``run`` that
    writes it, and ``again`` (what to do)."""
    want = ds.attrs.get("data_sha256")
    if want is None:
        raise ValueError(f"{str(path)!r} carries no data checksum (data_sha256): not a {run} file of this lenssim "
                         f"version; {again}")
    if dataset_checksum(ds) != want:
        raise ValueError(f"{str(path)!r} fails its checksum: it was modified after the {run} wrote it (its data no "
                         f"longer match their SHA-256); {again}")
    config, digest = ds.attrs.get("config"), ds.attrs.get("config_digest")
    if config is not None and hashlib.sha256(str(config).encode()).hexdigest()[:16] != digest:
        raise ValueError(f"{str(path)!r} fails its checksum: its run record (config) was modified after the {run} "
                         f"wrote it (it no longer matches its config_digest); {again}")


def result_mismatch(ds, coords: dict, finite=(), dims=None) -> str | None:
    """Why a result does not make sense for its run record, or None: each coordinate of ``coords`` ``{name: values}``
    must be exactly the run's (its grid, its SNRs...), each variable of ``finite`` finite everywhere, and (``dims``) the
    variables' dimensions those of the run."""
    for name, want in coords.items():
        want = np.asarray(want)
        if name not in ds.coords or ds[name].shape != want.shape or not np.array_equal(ds[name].values, want):
            shown = ", ".join(f"{v:g}" if isinstance(v, (int, float)) else str(v) for v in want.reshape(-1)[:6].tolist())
            return f"its {name} coordinate is not the run's ({shown}" + (", ...)" if want.size > 6 else ")")
    for name in finite:
        if name not in ds:
            return f"it holds no {name}"
        v = np.asarray(ds[name].values)
        if v.dtype.kind == "f" and not np.isfinite(v).all():
            return f"its {name} holds NaN or infinite values"
    if dims is not None:
        for name in finite:
            if tuple(ds[name].dims)[:len(dims)] != tuple(dims):
                return f"its {name} is not over the run's {', '.join(dims)}"
    return None


def finished_result(out: Path, digest: str, run: str, check=None):
    """Before a resumable run writes ``out`` (NetCDF): the dataset already there if it is this run's finished result
    (its ``config_digest``), verified (:func:`verify_result`: its checksum; ``check(ds)``, if given: why it makes no
    sense for this run, or None), None if there is none; any other file is refused (``FileExistsError``, ``run``
    naming the run), never overwritten, and a damaged result too (``ValueError``)."""
    import xarray as xr

    if not out.exists():
        return None
    try:
        with xr.open_dataset(out, engine="scipy") as old:
            same = old.attrs.get("config_digest") == digest
    except Exception:  # noqa: BLE001 - any unreadable file is not ours to overwrite
        if is_netcdf(out):
            raise ValueError(damaged_netcdf(out, f"remove it and run the {run} again")) from None
        same = False
    if not same:
        raise FileExistsError(f"{str(out)!r} exists and is not the finished result of this {run}; choose another "
                              "output or remove it")
    again = f"remove it and run the {run} again"
    try:
        ds = xr.load_dataset(out, engine="scipy")
    except Exception:  # noqa: BLE001 - a header that reads but data that do not (truncated)
        raise ValueError(damaged_netcdf(out, again)) from None
    verify_result(ds, out, run, again)
    why = check(ds) if check is not None else None
    if why:
        raise ValueError(f"{str(out)!r} makes no sense for its run record: {why}; {again}")
    return ds


def open_resumable(out: Path, digest: str, output: str, run: str, check=None):
    """Before a resumable run: ``out`` checked as an output file (``output`` names it in messages), and its finished
    result if it is this run's (:func:`finished_result`, verified; ``run`` names the run, ``check`` as there), else
    None."""
    from lenssim.io.files import check_output_file

    check_output_file(out, output)
    return finished_result(out, digest, run, check)


def finish_resumable(out: Path, ds, part: Path) -> None:
    """A resumable run's end: its dataset stamped with its checksum (:func:`stamp_result`) and written atomically to
    ``out`` (NetCDF), then its chunk folder removed."""
    import shutil

    from lenssim.io.files import atomic_write

    stamp_result(ds)  # verified when the result is read back (finished_result, lenssim optimum)
    atomic_write(out, lambda tmp: ds.to_netcdf(tmp, engine="scipy"))
    shutil.rmtree(part)


def run_resumable(run, out, *, output: str, kind: str, check, refusal: str, build, prepare=None):
    """A resumable run's frame, for a ``run`` with ``digest()`` and ``to_dict()``: ``out`` (NetCDF) checked and, if it is
    this run's finished result, returned verified (:func:`open_resumable`; ``output``, ``kind`` and ``check`` as
    there); else ``prepare()`` (checks before any file is made), then ``build(part)`` in the run's chunk folder
    (:func:`partial_folder`, ``refusal`` what a folder of another run holds) gives the dataset, whose ``attrs`` get the
    run record (``config``, ``config_digest``, ``lenssim_version``), and it is finished (:func:`finish_resumable`).
    ``build`` returns None where it stopped early: so does this."""
    from lenssim import __version__

    out = Path(out)
    done = open_resumable(out, run.digest(), output, kind, check=check)
    if done is not None:
        return done
    if prepare is not None:
        prepare()
    part = out.with_name(out.name + ".partial")
    with partial_folder(part, "run.json", run.digest(), {"run": run.to_dict()},
                        f"{str(part)!r} holds {refusal}; remove it or choose another output"):
        ds = build(part)
        if ds is None:
            return None
        ds.attrs |= {"lenssim_version": __version__, "config": json.dumps(run.to_dict(), sort_keys=True, default=str),
                     "config_digest": run.digest()}
        finish_resumable(out, ds, part)
        return ds
