"""Resumable design sweeps over a grid of design parameters, written as a labelled NetCDF dataset.

A sweep config (TOML, see ``configs/paper_grid.toml``) names the lens (and optionally the sensor
and the spectrum), the grid of design parameters (any of :data:`lenssim.design.PARAMETERS`, e.g.
``s`` and ``Q_back``; their order is the order of the dataset's dimensions), the SNRs, the image
model and the numerical settings. The work is split into fixed chunks (one value of the first
grid parameter each, all values of the others), so every chunk is computed the same way whether
or not the run was interrupted. Each finished chunk is written atomically to ``OUT.partial/``; a
restarted run skips finished chunks, and the final file is assembled from them and written
atomically, so it is identical to an uninterrupted run's.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from . import __version__
from .camera import Camera
from .criteria import CRITERIA
from .design import PARAMETERS, Design, parameter_name
from .files import atomic_write, read_toml
from .image_model import PSD_MODELS
from .lens import Lens, LensError
from .metrics import evaluate
from .numerics import DEFAULT_NUMERICS, Numerics
from .paper import PAPER_GRID, PAPER_RHO0, PAPER_SNR_DB
from .sensor import Sensor
from .spectrum import Spectrum
from .torch_utils import select_device
from .validate import ResourceLimitError, ResumeWarning, check_int, check_memory, check_real

__all__ = ["SweepConfig", "load_config", "grid_values", "grid_count", "run_sweep", "select_device", "ResumeWarning",
           "design_dims"]


MAX_GRID_VALUES = 100_000
"""Most values of one grid parameter (a sweep of more designs than that is refused before allocating)."""


def grid_count(start: float, stop: float, step: float) -> int:
    """Number of values of :func:`grid_values` (checked: finite, ``step > 0``, ``stop >= start``)."""
    for k, v in (("start", start), ("stop", stop), ("step", step)):
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)):
            raise ValueError(f"{k}={v!r} is not allowed: a finite number")
    if not step > 0:
        raise ValueError(f"step={step!r} is not allowed: must be > 0")
    if stop < start:
        raise ValueError(f"stop={stop!r} is below start={start!r}")
    count = (stop - start) / step + 1e-9
    if count >= MAX_GRID_VALUES:
        raise ResourceLimitError(f"the grid [{start:g}, {stop:g}] in steps of {step:g} has {int(count) + 1} values; "
                                 f"at most {MAX_GRID_VALUES} per parameter", "grid")
    return int(np.floor(count)) + 1


def grid_values(start: float, stop: float, step: float) -> np.ndarray:
    """``start, start + step, ...`` up to ``stop`` inclusive (to 1e-9 of a step), rounded to 10 digits."""
    return np.round(start + step * np.arange(grid_count(start, stop, step)), 10)


@dataclass
class SweepConfig:
    """A sweep: camera, grid ``{parameter: (start, stop, step)}``, SNRs (dB), image model, numerics."""

    camera: Camera = field(default_factory=Camera)
    grid: dict = field(default_factory=lambda: dict(PAPER_GRID))
    snr_db: tuple[float, ...] = PAPER_SNR_DB
    rho0: float = PAPER_RHO0
    psd_model: str = "discrete"
    numerics: Numerics = DEFAULT_NUMERICS
    focus: dict | None = None
    """Optimise the image plane at every design instead of gridding it: ``{"criterion": "mse_r", "snr_db":
    27.6, "bounds_um": [-500, 500], "tol_um": 1.0}`` (:func:`lenssim.focus.best_focus_batch`); the sweep then
    stores the best ``focus_shift_um`` of each design, and every criterion there."""
    fixed: dict = field(default_factory=dict)
    """Design parameters held at one value for the whole grid, e.g. ``{"focus_shift_um": -270.0}``."""

    def __post_init__(self):
        grid = {}
        for k, v in dict(self.grid).items():
            try:
                start, stop, step = (float(x) for x in v)
            except (TypeError, ValueError):
                raise ValueError(f"grid {k}={v!r} is not allowed: [start, stop, step]") from None
            grid_values(start, stop, step)
            name = parameter_name(k)
            if name in grid:
                raise ValueError(f"grid parameter {name} is given twice")
            grid[name] = (start, stop, step)
        if not grid:
            raise ValueError("the grid names no design parameter; e.g. s = [start, stop, step]")
        self.grid = grid
        fixed = {}
        for k, v in dict(self.fixed).items():
            name = parameter_name(k)
            if name in grid or name in fixed:
                raise ValueError(f"design parameter {name} is both fixed and gridded (or fixed twice)")
            fixed[name] = check_real(f"fixed {name}", v)
        self.fixed = fixed
        self.snr_db = tuple(float(x) for x in self.snr_db)
        if self.focus is not None:
            from .focus import FOCUS_BOUNDS_UM

            f = dict(self.focus)
            bad = set(f) - {"criterion", "snr_db", "bounds_um", "tol_um"}
            if bad:
                raise ValueError(f"[focus]: unknown key(s) {sorted(bad)}; allowed: criterion, snr_db, bounds_um, tol_um")
            if "focus_shift_um" in grid or "focus_shift_um" in self.fixed:
                raise ValueError("focus_shift_um is both gridded and optimised: keep [grid] or [focus]")
            crit = f.get("criterion", "mse_r")
            if crit not in CRITERIA:
                raise ValueError(f"[focus] criterion {crit!r} is not known; valid: {', '.join(CRITERIA)}")
            self.focus = {"criterion": crit, "snr_db": float(f.get("snr_db", self.snr_db[len(self.snr_db) // 2])),
                          "bounds_um": [float(v) for v in f.get("bounds_um", FOCUS_BOUNDS_UM)],
                          "tol_um": float(f.get("tol_um", 1.0))}
        if self.psd_model not in PSD_MODELS:
            raise ValueError(f"psd_model={self.psd_model!r} is not allowed: one of {', '.join(PSD_MODELS)}")

    @property
    def lens(self) -> Lens:
        return self.camera.lens

    @property
    def dims(self) -> tuple[str, ...]:
        """The design parameters of the grid, in the order of the dataset's dimensions."""
        return tuple(self.grid)

    def values(self, name: str) -> np.ndarray:
        return grid_values(*self.grid[parameter_name(name)])

    def n_designs(self) -> int:
        return int(np.prod([grid_count(*self.grid[d]) for d in self.dims]))

    def result_bytes(self) -> int:
        """Memory (bytes) of the assembled results: every criterion per design, angle and SNR, held about four
        times over while the chunks are stacked into the dataset and written."""
        A, S = len(self.lens.field_angles_deg), len(self.snr_db)
        per_design = (2 * A * S + 2 * S + 2 * A + 3) * 8
        return 4 * self.n_designs() * per_design

    def check(self, memory_limit_bytes: float | None = None) -> None:
        """Before any work: the results fit in memory and every design of the grid is a physical lens (checked one
        value of the first parameter at a time, so memory stays that of one chunk)."""
        check_memory(self.result_bytes(), f"a sweep of {self.n_designs()} designs", memory_limit_bytes)
        rest = self.dims[1:]
        axes = [torch.from_numpy(a) for a in np.meshgrid(*(self.values(d) for d in rest), indexing="ij")] if rest else []
        for v in self.values(self.dims[0]):
            vals = {**{k: torch.tensor(x, dtype=torch.float64) for k, x in self.fixed.items()}, **dict(zip(rest, axes))}
            vals[self.dims[0]] = torch.tensor(float(v), dtype=torch.float64)
            self.lens.check_design(Design(vals))

    def grid_design(self) -> Design:
        """Every design of the grid, as a design of shape ``(len(dim0), len(dim1), ...)``."""
        axes = np.meshgrid(*(self.values(d) for d in self.dims), indexing="ij")
        vals = {d: torch.from_numpy(a) for d, a in zip(self.dims, axes)}
        vals.update({k: torch.full(axes[0].shape, v, dtype=torch.float64) for k, v in self.fixed.items()})
        return Design(vals)

    def to_dict(self) -> dict:
        d = {**self.camera.to_dict(), "grid": {k: list(v) for k, v in self.grid.items()},
             "snr_db": list(self.snr_db), "rho0": self.rho0, "psd_model": self.psd_model,
             "numerics": self.numerics.to_dict()}
        if self.focus is not None:
            d["focus"] = dict(self.focus)
        if self.fixed:
            d["fixed"] = dict(self.fixed)
        return d

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]

    @classmethod
    def from_dict(cls, d: dict) -> "SweepConfig":
        """The inverse of :meth:`to_dict` (as stored in a sweep file's ``config`` attribute)."""
        sens = dict(d.get("sensor", {}))
        if "full_well_e" in sens:
            sens["full_well_e"] = tuple(tuple(p) for p in sens["full_well_e"])
        spec = dict(d.get("spectrum", {}))
        return cls(camera=Camera(Lens.from_dict(d.get("lens", {})), Sensor(**sens),
                                 Spectrum(**spec) if spec else Spectrum(),
                                 channels=tuple(Spectrum(**c) for c in d.get("channels", ()))),
                   grid=d["grid"], snr_db=tuple(d["snr_db"]), rho0=d["rho0"], psd_model=d["psd_model"],
                   numerics=Numerics(**d.get("numerics", {})), focus=d.get("focus"),
                   fixed=d.get("fixed", {}))


_NUMERICS_KEYS = ("fill", "margin_px", "min_size", "oversample", "supersample", "cost_points", "max_fft_size")


def load_config(path: str | os.PathLike) -> SweepConfig:
    """Read a sweep config from TOML; unknown keys and bad values raise ``ValueError`` naming them.

    Sections: ``[lens]`` (:class:`lenssim.lens.Lens` fields; ``refractive_index`` for a constant
    glass; a legacy ``wavelength_um`` sets a one-line spectrum), ``[sensor]``, ``[spectrum]``
    (``wavelengths_um``, ``weights``), ``[channels]`` (a colour camera: ``camera`` = RGB sensitivities of
    colour-science, e.g. "Nikon 5100 (NPL)", ``illuminant`` (default D65), ``per_channel`` wavelengths; the
    sweep then stores the criteria's means over the channels), ``[grid]`` (``PARAMETER = [start, stop, step]`` for design
    parameters, ``snr_db``), ``[fixed]`` (``PARAMETER = value``, held for every design) and ``[numerics]``
    (``rho0``, ``psd_model`` and :class:`Numerics` fields).
    """
    path = Path(path)
    where = f"sweep config {str(path)!r}"
    raw = read_toml(path, "sweep config")
    sections = {k: raw.pop(k, {}) for k in ("lens", "sensor", "spectrum", "channels", "grid", "fixed", "numerics",
                                            "focus")}
    if raw:
        raise ValueError(f"{where}: unknown section(s) {sorted(raw)}; allowed: {', '.join(f'[{k}]' for k in sections)}")
    lens_kw, grid, numerics = dict(sections["lens"]), dict(sections["grid"]), dict(sections["numerics"])
    try:
        spectrum = Spectrum(**sections["spectrum"]) if sections["spectrum"] else None
        if "wavelength_um" in lens_kw:
            lam = lens_kw.pop("wavelength_um")
            if spectrum is not None:
                raise ValueError("[lens] wavelength_um and [spectrum] both set the wavelengths; keep [spectrum]")
            spectrum = Spectrum.monochromatic(lam)
        sensor_kw = dict(sections["sensor"])
        if "full_well_e" in sensor_kw:  # TOML table {"25" = 12800.0, ...}
            sensor_kw["full_well_e"] = tuple((int(k), v) for k, v in dict(sensor_kw["full_well_e"]).items())
        channels = ()
        if sections["channels"]:
            from .spectrum import channel_spectra

            ch = dict(sections["channels"])
            bad = set(ch) - {"camera", "illuminant", "per_channel"}
            if bad or "camera" not in ch:
                raise ValueError(f"[channels]: give camera (and optionally illuminant, per_channel); unknown key(s) "
                                 f"{sorted(bad)}" if bad else "[channels]: camera = NAME is missing")
            channels = channel_spectra(**ch)
        camera = Camera(Lens.from_dict(lens_kw), Sensor(**sensor_kw), spectrum or Spectrum(), channels=channels)
    except TypeError as exc:
        raise ValueError(f"{where}: {exc}") from None
    except (LensError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    kw = {}
    if "snr_db" in grid:
        kw["snr_db"] = tuple(float(x) for x in grid.pop("snr_db"))
    for key in list(grid):
        try:
            parameter_name(key)
        except ValueError as exc:
            raise ValueError(f"{where} [grid]: {exc}; or snr_db") from None
        v = grid[key]
        if not (isinstance(v, list) and len(v) == 3):
            raise ValueError(f"{where} [grid] {key}={v!r} is not allowed: [start, stop, step]")
    bad = set(numerics) - set(_NUMERICS_KEYS) - {"rho0", "psd_model"}
    if bad:
        raise ValueError(f"{where} [numerics]: unknown key(s) {sorted(bad)}; allowed: "
                         f"{sorted(set(_NUMERICS_KEYS) | {'rho0', 'psd_model'})}")
    for k in ("rho0", "psd_model"):
        if k in numerics:
            kw[k] = numerics.pop(k)
    try:
        cfg = SweepConfig(camera=camera, grid=grid or dict(PAPER_GRID), numerics=Numerics(**numerics),
                          focus=sections["focus"] or None, fixed=sections["fixed"], **kw)
        cfg.check()
    except ResourceLimitError as exc:
        raise ResourceLimitError(f"{where}: {exc}", exc.setting) from None
    except (LensError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    return cfg


def _chunk_keys(cfg: SweepConfig | None = None) -> tuple[str, ...]:
    keys = []
    for name, c in CRITERIA.items():
        keys += [name, f"{name}_alpha"] if c.from_otf is not None else [name]
    extra = ("focus_shift_um",) if cfg is not None and cfg.focus is not None else ()
    return tuple(keys) + ("rms_w_alpha", "rms_w_piston_removed", "fft_size") + extra


def _compute_chunk(cfg: SweepConfig, i: int, device, progress) -> dict:
    rest = cfg.dims[1:]
    axes = np.meshgrid(*(cfg.values(d) for d in rest), indexing="ij") if rest else []
    first = cfg.values(cfg.dims[0])[i]
    vals = {d: torch.from_numpy(np.ascontiguousarray(a)) for d, a in zip(rest, axes)}
    shape = axes[0].shape if rest else ()
    vals[cfg.dims[0]] = torch.full(shape, float(first), dtype=torch.float64)
    vals.update({k: torch.full(shape, v, dtype=torch.float64) for k, v in cfg.fixed.items()})
    if cfg.focus is not None:
        from .focus import best_focus_batch

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


def _dataset(cfg: SweepConfig, chunks: list[dict]) -> xr.Dataset:
    st = {k: np.stack([c[k] for c in chunks]) for k in _chunk_keys(cfg)}
    dims = cfg.dims
    coords = {d: cfg.values(d) for d in dims}
    coords.update({"alpha": np.asarray(cfg.lens.field_angles_deg), "snr": np.asarray(cfg.snr_db, dtype=np.float64)})
    data = {}
    for name, c in CRITERIA.items():
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
    return ds


def _checksum(chunk: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(chunk):
        a = np.ascontiguousarray(chunk[k])
        h.update(f"{k}|{a.dtype}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


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
    from tqdm import tqdm

    out = Path(out)
    dev = select_device(device)
    if scheduler is not None and workers is not None:
        raise ValueError("give either a scheduler address or a number of local workers, not both")
    workers = None if workers is None else check_int("workers", workers, 1)
    worker_threads = None if worker_threads is None else check_int("worker_threads", worker_threads, 1)
    cfg.check(memory_limit_bytes)
    if out.exists():
        try:
            with xr.open_dataset(out) as old:
                same = old.attrs.get("config_digest") == cfg.digest()
        except Exception:  # noqa: BLE001 - any unreadable file is not ours to overwrite
            same = False
        if same:
            return xr.load_dataset(out)
        raise FileExistsError(f"{str(out)!r} exists and is not a finished sweep of this config; "
                              "choose another output file or remove it")
    if out.parent.exists() and not os.access(out.parent, os.W_OK):
        raise PermissionError(f"cannot write the sweep into {str(out.parent)!r} (no write permission)")
    part = out.with_name(out.name + ".partial")
    _remove_temporaries(out, part)
    part.mkdir(parents=True, exist_ok=True)
    meta = part / "config.json"
    if meta.exists():
        try:
            digest = json.loads(meta.read_text()).get("digest")
        except (ValueError, OSError):
            digest = None
        if digest != cfg.digest():
            raise FileExistsError(f"{str(part)!r} holds chunks of a different config; remove it or choose "
                                  "another output file")
    else:
        atomic_write(meta, lambda p: Path(p).write_text(json.dumps({"digest": cfg.digest(), "config": cfg.to_dict()})))
    n_first = len(cfg.values(cfg.dims[0]))
    per_chunk = int(np.prod([len(cfg.values(d)) for d in cfg.dims[1:]])) * len(cfg.lens.field_angles_deg)
    paths = [part / f"chunk_{i:05d}.npz" for i in range(n_first)]
    for i, p in enumerate(paths):
        if p.exists():
            got = _read_chunk(p, cfg, i)
            if isinstance(got, str):
                warnings.warn(f"sweep chunk {str(p)!r} {got}; computing it again", ResumeWarning, stacklevel=2)
                p.unlink()
    done = sum(p.exists() for p in paths)
    where = scheduler or (f"{workers} local workers" if workers is not None else dev.type)
    bar = tqdm(total=len(paths) * per_chunk, initial=done * per_chunk, unit="PSF", disable=not show_progress,
               file=sys.stderr, desc=f"sweep on {where}")
    todo = [i for i, p in enumerate(paths) if not p.exists()]
    stopped = max_chunks is not None and len(todo) > max_chunks
    todo = todo[:max_chunks] if max_chunks is not None else todo
    if scheduler is not None or workers is not None:
        from .cluster import compute_chunks, dask_client

        with dask_client(scheduler, workers) as client:
            for i, chunk in compute_chunks(client, cfg, todo, device=device, threads=worker_threads):
                _write_chunk(paths[i], chunk, cfg, i)
                bar.update(per_chunk)
    else:
        for i in todo:
            _write_chunk(paths[i], _compute_chunk(cfg, i, dev, bar.update), cfg, i)
    bar.close()
    if stopped:
        return None
    chunks = []
    for i, p in enumerate(paths):
        got = _read_chunk(p, cfg, i)
        if isinstance(got, str):
            raise ValueError(f"sweep chunk {str(p)!r} {got} after it was written; run the same command again")
        chunks.append(got)
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
