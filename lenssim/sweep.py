"""Resumable design sweeps over (s, Q), written as a labelled NetCDF dataset.

A sweep config (TOML, see ``configs/paper_grid.toml``) names the lens, the grid of shape factors
``s`` and conic constants ``Q``, the field angles, the SNRs and the numerical settings. The work
is split into fixed chunks (one ``s`` value each, all ``Q``), so every chunk is computed the same
way whether or not the run was interrupted. Each finished chunk is written atomically to
``OUT.partial/``; a restarted run skips finished chunks, and the final file is assembled from
them and written atomically, so it is identical to an uninterrupted run's.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from . import __version__
from .files import atomic_write
from .image_model import PAPER_RHO0, PAPER_SNR_DB
from .lens import ThinLens
from .metrics import DEFAULT_FILL, DEFAULT_MIN_SIZE, DEFAULT_OVERSAMPLE, evaluate

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
    """A sweep: lens, (s, Q) grid, SNRs (dB) and numerical settings."""

    lens: ThinLens = field(default_factory=ThinLens)
    s: tuple[float, float, float] = (-2.0, 1.025, 0.025)  # start, stop, step
    Q: tuple[float, float, float] = (-10.0, 1.2, 0.1)
    snr_db: tuple[float, ...] = PAPER_SNR_DB
    rho0: float = PAPER_RHO0
    psd_model: str = "discrete"
    fill: float = DEFAULT_FILL
    min_size: int = DEFAULT_MIN_SIZE
    oversample: int = DEFAULT_OVERSAMPLE
    cost_points: int = 101

    @property
    def s_values(self) -> np.ndarray:
        return grid_values(*self.s)

    @property
    def Q_values(self) -> np.ndarray:
        return grid_values(*self.Q)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["lens"] = asdict(self.lens)
        return d

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]


def load_config(path: str | os.PathLike) -> SweepConfig:
    """Read a sweep config from TOML; unknown keys and bad values raise ``ValueError`` naming them."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"sweep config {str(path)!r} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"sweep config {str(path)!r} is not valid TOML: {exc}") from None
    lens_kw = raw.pop("lens", {})
    grid = raw.pop("grid", {})
    numerics = raw.pop("numerics", {})
    if raw:
        raise ValueError(f"sweep config {str(path)!r}: unknown section(s) {sorted(raw)}; "
                         "allowed: [lens], [grid], [numerics]")
    try:
        lens = ThinLens(**lens_kw)
    except TypeError as exc:
        raise ValueError(f"sweep config {str(path)!r} [lens]: {exc}") from None
    kw = {}
    for key in ("s", "Q"):
        if key in grid:
            v = grid.pop(key)
            if not (isinstance(v, list) and len(v) == 3):
                raise ValueError(f"sweep config [grid] {key}={v!r} is not allowed: [start, stop, step]")
            kw[key] = tuple(float(x) for x in v)
            grid_values(*kw[key])
    if "snr_db" in grid:
        kw["snr_db"] = tuple(float(x) for x in grid.pop("snr_db"))
    if grid:
        raise ValueError(f"sweep config [grid]: unknown key(s) {sorted(grid)}; allowed: s, Q, snr_db")
    allowed = {"rho0", "psd_model", "fill", "min_size", "oversample", "cost_points"}
    bad = set(numerics) - allowed
    if bad:
        raise ValueError(f"sweep config [numerics]: unknown key(s) {sorted(bad)}; allowed: {sorted(allowed)}")
    kw.update(numerics)
    cfg = SweepConfig(lens=lens, **kw)
    S, Qg = np.meshgrid(cfg.s_values, cfg.Q_values, indexing="ij")
    lens.check_design(torch.from_numpy(S), torch.from_numpy(Qg))
    return cfg


def select_device(name: str = "auto") -> torch.device:
    """``auto`` picks CUDA when available, else CPU; ``cpu``/``cuda``/``cuda:N`` are taken as given."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    dev = torch.device(name)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device={name!r} is not available: no CUDA device; use 'cpu' or 'auto'")
    return dev


_CHUNK_KEYS = ("rms_w", "rms_w_alpha", "rms_w_piston_removed", "mse_s", "mse_r", "mse_s_alpha", "mse_r_alpha",
               "cost", "fft_size")


def _compute_chunk(cfg: SweepConfig, s_value: float, device, progress) -> dict:
    Qv = torch.from_numpy(cfg.Q_values)
    res = evaluate(cfg.lens, torch.full_like(Qv, s_value), Qv, cfg.snr_db, rho0=cfg.rho0, psd_model=cfg.psd_model,
                   fill=cfg.fill, min_size=cfg.min_size, oversample=cfg.oversample, cost_points=cfg.cost_points,
                   device=device, progress=progress)
    return {k: res[k].cpu().numpy() for k in _CHUNK_KEYS}


def _dataset(cfg: SweepConfig, chunks: list[dict]) -> xr.Dataset:
    st = {k: np.stack([c[k] for c in chunks]) for k in _CHUNK_KEYS}
    coords = {"s": cfg.s_values, "Q": cfg.Q_values, "alpha": np.asarray(cfg.lens.field_angles_deg),
              "snr": np.asarray(cfg.snr_db, dtype=np.float64)}
    dims2, dimsA, dimsS, dimsAS = ("s", "Q"), ("s", "Q", "alpha"), ("s", "Q", "snr"), ("s", "Q", "alpha", "snr")
    ds = xr.Dataset(
        {
            "rms_w": (dims2, st["rms_w"], {"units": "waves", "long_name": "RMS_W: field RMS of the wavefront, no piston removal"}),
            "rms_w_alpha": (dimsA, st["rms_w_alpha"], {"units": "waves", "long_name": "RMS_w(alpha) over the pupil"}),
            "rms_w_piston_removed": (dims2, st["rms_w_piston_removed"], {"units": "waves"}),
            "mse_s": (dimsS, st["mse_s"], {"units": "1 (unit signal variance)", "long_name": "MSE_S sensor image, field average"}),
            "mse_r": (dimsS, st["mse_r"], {"units": "1 (unit signal variance)", "long_name": "MSE_R after Wiener restoration, field average"}),
            "mse_s_alpha": (dimsAS, st["mse_s_alpha"], {"units": "1"}),
            "mse_r_alpha": (dimsAS, st["mse_r_alpha"], {"units": "1"}),
            "cost": (dims2, st["cost"], {"units": "1 (slope)", "long_name": "C_a: RMS slope departure of the asphere"}),
            "fft_size": (dimsA, st["fft_size"].astype(np.int32), {"units": "samples", "long_name": "FFT size used per PSF"}),
        },
        coords=coords,
    )
    ds["s"].attrs = {"long_name": "shape factor", "units": "1"}
    ds["Q"].attrs = {"long_name": "conic constant of the posterior surface", "units": "1"}
    ds["alpha"].attrs = {"long_name": "half field angle", "units": "degree"}
    ds["snr"].attrs = {"long_name": "signal-to-noise ratio per pixel", "units": "dB"}
    ds.attrs = {"title": "lenssim sweep", "lenssim_version": __version__, "config": json.dumps(cfg.to_dict(), sort_keys=True),
                "config_digest": cfg.digest()}
    return ds


def run_sweep(cfg: SweepConfig, out: str | os.PathLike, *, device: str = "auto", show_progress: bool = True,
              keep_chunks: bool = False, max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) a sweep and write ``out`` (NetCDF). Returns the dataset, or ``None`` if
    ``max_chunks`` stopped the run early (the finished chunks stay in ``out.partial/``).

    ``out`` must not be an existing file that is not a finished sweep of the same config: the
    command refuses to overwrite anything else.
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
                              "choose another --out or remove it")
    part = out.with_name(out.name + ".partial")
    part.mkdir(parents=True, exist_ok=True)
    meta = part / "config.json"
    if meta.exists():
        if json.loads(meta.read_text()).get("digest") != cfg.digest():
            raise FileExistsError(f"{str(part)!r} holds chunks of a different config; remove it or choose another --out")
    else:
        atomic_write(meta, lambda p: Path(p).write_text(json.dumps({"digest": cfg.digest(), "config": cfg.to_dict()})))
    s_vals = cfg.s_values
    per_chunk = len(cfg.Q_values) * len(cfg.lens.field_angles_deg)
    paths = [part / f"chunk_{i:05d}.npz" for i in range(len(s_vals))]
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
        chunk = _compute_chunk(cfg, float(s_vals[i]), dev, bar.update)

        def write(tmp, chunk=chunk):
            with open(tmp, "wb") as fh:
                np.savez(fh, **chunk)
        atomic_write(p, write)
        computed += 1
    bar.close()
    chunks = []
    for p in paths:
        with np.load(p) as z:
            chunks.append({k: z[k] for k in _CHUNK_KEYS})
    ds = _dataset(cfg, chunks)
    atomic_write(out, lambda tmp: ds.to_netcdf(tmp, engine="scipy"))
    if not keep_chunks:
        shutil.rmtree(part)
    return ds



