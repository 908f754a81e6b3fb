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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from . import __version__
from .camera import Camera
from .criteria import CRITERIA
from .design import PARAMETERS, Design, parameter_name
from .files import atomic_write
from .image_model import PSD_MODELS
from .lens import Lens, LensError
from .metrics import evaluate
from .numerics import DEFAULT_NUMERICS, Numerics
from .paper import PAPER_GRID, PAPER_RHO0, PAPER_SNR_DB
from .sensor import Sensor
from .spectrum import Spectrum
from .torch_utils import select_device

__all__ = ["SweepConfig", "load_config", "grid_values", "run_sweep", "select_device"]


def grid_values(start: float, stop: float, step: float) -> np.ndarray:
    """``start, start + step, ...`` up to ``stop`` inclusive (to 1e-9 of a step), rounded to 10 digits."""
    if not step > 0:
        raise ValueError(f"step={step!r} is not allowed: must be > 0")
    if stop < start:
        raise ValueError(f"stop={stop!r} is below start={start!r}")
    count = int(np.floor((stop - start) / step + 1e-9)) + 1
    return np.round(start + step * np.arange(count), 10)


@dataclass
class SweepConfig:
    """A sweep: camera, grid ``{parameter: (start, stop, step)}``, SNRs (dB), image model, numerics."""

    camera: Camera = field(default_factory=Camera)
    grid: dict = field(default_factory=lambda: dict(PAPER_GRID))
    snr_db: tuple[float, ...] = PAPER_SNR_DB
    rho0: float = PAPER_RHO0
    psd_model: str = "discrete"
    numerics: Numerics = DEFAULT_NUMERICS

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
        self.snr_db = tuple(float(x) for x in self.snr_db)
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

    def grid_design(self) -> Design:
        """Every design of the grid, as a design of shape ``(len(dim0), len(dim1), ...)``."""
        axes = np.meshgrid(*(self.values(d) for d in self.dims), indexing="ij")
        return Design({d: torch.from_numpy(a) for d, a in zip(self.dims, axes)})

    def to_dict(self) -> dict:
        return {**self.camera.to_dict(), "grid": {k: list(v) for k, v in self.grid.items()},
                "snr_db": list(self.snr_db), "rho0": self.rho0, "psd_model": self.psd_model,
                "numerics": self.numerics.to_dict()}

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
                                 Spectrum(**spec) if spec else Spectrum()),
                   grid=d["grid"], snr_db=tuple(d["snr_db"]), rho0=d["rho0"], psd_model=d["psd_model"],
                   numerics=Numerics(**d.get("numerics", {})))


_NUMERICS_KEYS = ("fill", "margin_px", "min_size", "oversample", "supersample", "cost_points")


def load_config(path: str | os.PathLike) -> SweepConfig:
    """Read a sweep config from TOML; unknown keys and bad values raise ``ValueError`` naming them.

    Sections: ``[lens]`` (:class:`lenssim.lens.Lens` fields; ``refractive_index`` for a constant
    glass; a legacy ``wavelength_um`` sets a one-line spectrum), ``[sensor]``, ``[spectrum]``
    (``wavelengths_um``, ``weights``), ``[grid]`` (``PARAMETER = [start, stop, step]`` for design
    parameters, ``snr_db``) and ``[numerics]`` (``rho0``, ``psd_model`` and :class:`Numerics` fields).
    """
    path = Path(path)
    where = f"sweep config {str(path)!r}"
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{where} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{where} is not valid TOML: {exc}") from None
    sections = {k: raw.pop(k, {}) for k in ("lens", "sensor", "spectrum", "grid", "numerics")}
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
        camera = Camera(Lens.from_dict(lens_kw), Sensor(**sensor_kw), spectrum or Spectrum())
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
        cfg = SweepConfig(camera=camera, grid=grid or dict(PAPER_GRID), numerics=Numerics(**numerics), **kw)
        camera.lens.check_design(cfg.grid_design())
    except (LensError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    return cfg


def _chunk_keys() -> tuple[str, ...]:
    keys = []
    for name, c in CRITERIA.items():
        keys += [name, f"{name}_alpha"] if c.from_otf is not None else [name]
    return tuple(keys) + ("rms_w_alpha", "rms_w_piston_removed", "fft_size")


def _compute_chunk(cfg: SweepConfig, i: int, device, progress) -> dict:
    rest = cfg.dims[1:]
    axes = np.meshgrid(*(cfg.values(d) for d in rest), indexing="ij") if rest else []
    first = cfg.values(cfg.dims[0])[i]
    vals = {d: torch.from_numpy(np.ascontiguousarray(a)) for d, a in zip(rest, axes)}
    shape = axes[0].shape if rest else ()
    vals[cfg.dims[0]] = torch.full(shape, float(first), dtype=torch.float64)
    res = evaluate(cfg.camera, Design(vals), cfg.snr_db, rho0=cfg.rho0, psd_model=cfg.psd_model,
                   numerics=cfg.numerics, device=device, progress=progress)
    return {k: res[k].cpu().numpy() for k in _chunk_keys()}


def _dataset(cfg: SweepConfig, chunks: list[dict]) -> xr.Dataset:
    st = {k: np.stack([c[k] for c in chunks]) for k in _chunk_keys()}
    dims = cfg.dims
    coords = {d: cfg.values(d) for d in dims}
    coords.update({"alpha": np.asarray(cfg.lens.field_angles_deg), "snr": np.asarray(cfg.snr_db, dtype=np.float64)})
    data = {}
    for name, c in CRITERIA.items():
        attrs = {"units": c.units, "long_name": f"{c.label}: {c.description}"}
        if c.per_snr:
            data[name] = (dims + ("snr",), st[name], attrs)
            if c.from_otf is not None:
                data[f"{name}_alpha"] = (dims + ("alpha", "snr"), st[f"{name}_alpha"],
                                         {"units": c.units, "long_name": f"{c.label} per field angle"})
        else:
            data[name] = (dims, st[name], attrs)
    data["rms_w_alpha"] = (dims + ("alpha",), st["rms_w_alpha"], {"units": "waves", "long_name": "RMS_w(alpha) over the pupil"})
    data["rms_w_piston_removed"] = (dims, st["rms_w_piston_removed"], {"units": "waves"})
    data["fft_size"] = (dims + ("alpha",), st["fft_size"].astype(np.int32),
                        {"units": "samples", "long_name": "FFT size used per PSF"})
    ds = xr.Dataset(data, coords=coords)
    for d in dims:
        ds[d].attrs = {"long_name": PARAMETERS[d].description, "units": PARAMETERS[d].unit}
    ds["alpha"].attrs = {"long_name": "half field angle", "units": "degree"}
    ds["snr"].attrs = {"long_name": "signal-to-noise ratio per pixel", "units": "dB"}
    ds.attrs = {"title": "lenssim sweep", "lenssim_version": __version__, "design_parameters": " ".join(dims),
                "config": json.dumps(cfg.to_dict(), sort_keys=True), "config_digest": cfg.digest()}
    return ds


def run_sweep(cfg: SweepConfig, out: str | os.PathLike, *, device: str = "auto", show_progress: bool = True,
              keep_chunks: bool = False, max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) a sweep and write ``out`` (NetCDF). Returns the dataset, or ``None`` if
    ``max_chunks`` stopped the run early (the finished chunks stay in ``out.partial/``).

    ``out`` must not be an existing file that is not a finished sweep of the same config: the
    sweep refuses to overwrite anything else.
    """
    from tqdm import tqdm

    out = Path(out)
    dev = select_device(device)
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
    part = out.with_name(out.name + ".partial")
    part.mkdir(parents=True, exist_ok=True)
    meta = part / "config.json"
    if meta.exists():
        if json.loads(meta.read_text()).get("digest") != cfg.digest():
            raise FileExistsError(f"{str(part)!r} holds chunks of a different config; remove it or choose "
                                  "another output file")
    else:
        atomic_write(meta, lambda p: Path(p).write_text(json.dumps({"digest": cfg.digest(), "config": cfg.to_dict()})))
    n_first = len(cfg.values(cfg.dims[0]))
    per_chunk = int(np.prod([len(cfg.values(d)) for d in cfg.dims[1:]])) * len(cfg.lens.field_angles_deg)
    paths = [part / f"chunk_{i:05d}.npz" for i in range(n_first)]
    done = sum(p.exists() for p in paths)
    bar = tqdm(total=len(paths) * per_chunk, initial=done * per_chunk, unit="PSF", disable=not show_progress,
               file=sys.stderr, desc=f"sweep on {dev.type}")
    computed = 0
    for i, p in enumerate(paths):
        if p.exists():
            continue
        if max_chunks is not None and computed >= max_chunks:
            bar.close()
            return None
        chunk = _compute_chunk(cfg, i, dev, bar.update)

        def write(tmp, chunk=chunk):
            with open(tmp, "wb") as fh:
                np.savez(fh, **chunk)
        atomic_write(p, write)
        computed += 1
    bar.close()
    chunks = []
    for p in paths:
        with np.load(p) as z:
            chunks.append({k: z[k] for k in _chunk_keys()})
    ds = _dataset(cfg, chunks)
    atomic_write(out, lambda tmp: ds.to_netcdf(tmp, engine="scipy"))
    if not keep_chunks:
        shutil.rmtree(part)
    return ds


def design_dims(ds: xr.Dataset) -> tuple[str, ...]:
    """The design-parameter dimensions of a sweep dataset, in order."""
    if "design_parameters" in ds.attrs:
        return tuple(str(ds.attrs["design_parameters"]).split())
    return tuple(d for d in ds["cost"].dims)
