"""A sweep's configuration: the camera, the grid of design parameters, the SNRs, the image model, the
numerics, focus and fixed parameters (:class:`SweepConfig`), read from TOML by :func:`load_config`; where a
config is silent, the paper's scenario (:mod:`lenssim_studies.paper`) fills in.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from lenssim.model.camera import Camera
from lenssim.criteria import lens_criteria
from lenssim.model.design import Design, parameter_name
from lenssim.io.files import read_toml
from lenssim.optics.image_model import PSD_MODELS
from lenssim.model.lens import Lens, LensError
from lenssim.model.numerics import DEFAULT_NUMERICS, Numerics
from lenssim.model.sensor import Sensor
from lenssim.model.spectrum import Spectrum
from lenssim.torch_utils import HOST
from lenssim.validate import ResourceLimitError, check_memory, check_real, listed, quoted

from .paper import PAPER_CAMERA, PAPER_GRID, PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SNR_DB, PAPER_SPECTRUM


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
    if not count < MAX_GRID_VALUES:  # also an overflow to inf, e.g. [-1e308, 0.5] or a step of 5e-324
        size = f"{int(count) + 1}" if np.isfinite(count) else "more than 1e308"
        raise ResourceLimitError(f"the grid [{start:g}, {stop:g}] in steps of {step:g} has {size} values; "
                                 f"at most {MAX_GRID_VALUES} per parameter", "grid")
    return int(np.floor(count)) + 1


def grid_values(start: float, stop: float, step: float) -> np.ndarray:
    """``start, start + step, ...`` up to ``stop`` inclusive (to 1e-9 of a step), rounded to 10 digits."""
    return np.round(start + step * np.arange(grid_count(start, stop, step)), 10)


def _numbers(name: str, v, allowed: str) -> tuple[float, ...]:
    """``v`` (a list of finite numbers) as a tuple of floats; ``ValueError`` naming ``name`` and ``allowed``."""
    if not isinstance(v, (list, tuple)):
        raise ValueError(f"{name}={quoted(v)} is not allowed: a list of numbers ({allowed})")
    return tuple(check_real(name, x) for x in v)


@dataclass(frozen=True)
class SweepConfig:
    """A sweep: camera, grid ``{parameter: (start, stop, step)}``, SNRs (dB), image model, numerics."""

    camera: Camera = PAPER_CAMERA
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
        object.__setattr__(self, "grid", grid)
        fixed = {}
        for k, v in dict(self.fixed).items():
            name = parameter_name(k)
            if name in grid or name in fixed:
                raise ValueError(f"design parameter {name} is both fixed and gridded (or fixed twice)")
            fixed[name] = check_real(f"fixed {name}", v)
        object.__setattr__(self, "fixed", fixed)
        object.__setattr__(self, "snr_db", _numbers("snr_db", self.snr_db, "SNRs in dB"))
        if not self.snr_db:
            raise ValueError("snr_db=[] is not allowed: at least one SNR in dB")
        if self.focus is not None:
            from lenssim.focus import FOCUS_BOUNDS_UM

            f = dict(self.focus)
            bad = set(f) - {"criterion", "snr_db", "bounds_um", "tol_um"}
            if bad:
                raise ValueError(f"[focus]: unknown key(s) {listed(sorted(bad))}; allowed: criterion, snr_db, bounds_um, tol_um")
            if "focus_shift_um" in grid or "focus_shift_um" in self.fixed:
                raise ValueError("focus_shift_um is both gridded and optimised: keep [grid] or [focus]")
            crit = f.get("criterion", "mse_r")
            if not isinstance(crit, str) or crit not in lens_criteria():
                raise ValueError(f"[focus] criterion {quoted(crit)} is not known; valid: "
                                 f"{listed(lens_criteria(), near=[str(crit)])}")
            bounds = _numbers("[focus] bounds_um", f.get("bounds_um", FOCUS_BOUNDS_UM), "[low, high] in um")
            if len(bounds) != 2 or not bounds[0] < bounds[1]:
                raise ValueError(f"[focus] bounds_um={quoted(list(bounds))} is not allowed: [low, high] in um, low < high")
            object.__setattr__(self, "focus", {
                "criterion": crit, "snr_db": check_real("[focus] snr_db", f.get("snr_db", self.snr_db[len(self.snr_db) // 2])),
                "bounds_um": list(bounds), "tol_um": check_real("[focus] tol_um", f.get("tol_um", 1.0), 0.0, lo_open=True)})
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
            vals = {**{k: torch.tensor(x, dtype=torch.float64, device=HOST) for k, x in self.fixed.items()},
                    **dict(zip(rest, axes))}
            vals[self.dims[0]] = torch.tensor(float(v), dtype=torch.float64, device=HOST)
            self.lens.check_design(Design(vals))

    def grid_design(self) -> Design:
        """Every design of the grid, as a design of shape ``(len(dim0), len(dim1), ...)``."""
        axes = np.meshgrid(*(self.values(d) for d in self.dims), indexing="ij")
        vals = {d: torch.from_numpy(a) for d, a in zip(self.dims, axes)}
        vals.update({k: torch.full(axes[0].shape, v, dtype=torch.float64, device=HOST) for k, v in self.fixed.items()})
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
                                 Spectrum(**spec) if spec else PAPER_SPECTRUM,
                                 channels=tuple(Spectrum(**c) for c in d.get("channels", ()))),
                   grid=d["grid"], snr_db=tuple(d["snr_db"]), rho0=d["rho0"], psd_model=d["psd_model"],
                   numerics=Numerics(**d.get("numerics", {})), focus=d.get("focus"),
                   fixed=d.get("fixed", {}))


_NUMERICS_KEYS = ("fill", "margin_px", "min_size", "oversample", "supersample", "cost_points", "max_fft_size")


def paper_lens_with(keys: dict) -> Lens:
    """The paper's lens with the given ``[lens]`` keys changed (a glass or a refractive index replaces the other)."""
    base = PAPER_LENS.to_dict()
    if "glass" in keys or "refractive_index" in keys:
        base.pop("glass", None)
        base.pop("refractive_index", None)
    return Lens.from_dict({**base, **keys})


def paper_sensor_with(keys: dict) -> Sensor:
    """The paper's sensor with the given ``[sensor]`` keys changed."""
    base = PAPER_SENSOR.to_dict()
    base["full_well_e"] = tuple(tuple(p) for p in base["full_well_e"])
    return Sensor(**{**base, **keys})


def load_config(path: str | os.PathLike) -> SweepConfig:
    """Read a sweep config from TOML; unknown keys and bad values raise ``ValueError`` naming them.

    Sections (each changes the paper's scenario, :mod:`lenssim_studies.paper`, where it is silent):
    ``[lens]`` (:class:`lenssim.model.lens.Lens` fields; ``refractive_index`` for a constant
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
        raise ValueError(f"{where}: unknown section(s) {listed(sorted(raw))}; allowed: "
                         f"{listed((f'[{k}]' for k in sections), near=[f'[{k}]' for k in sorted(raw)])}")
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
            from lenssim.model.spectrum import channel_spectra

            ch = dict(sections["channels"])
            bad = set(ch) - {"camera", "illuminant", "per_channel"}
            if bad or "camera" not in ch:
                raise ValueError(f"[channels]: give camera (and optionally illuminant, per_channel); unknown key(s) "
                                 f"{listed(sorted(bad))}" if bad else "[channels]: camera = NAME is missing")
            channels = channel_spectra(**ch)
        camera = Camera(paper_lens_with(lens_kw), paper_sensor_with(sensor_kw), spectrum or PAPER_SPECTRUM,
                        channels=channels)
    except TypeError as exc:
        raise ValueError(f"{where}: {exc}") from None
    except (LensError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    kw = {}
    if "snr_db" in grid:
        kw["snr_db"] = grid.pop("snr_db")
    for key in list(grid):
        try:
            parameter_name(key)
        except ValueError as exc:
            raise ValueError(f"{where} [grid]: {exc}; or snr_db") from None
        v = grid[key]
        if not (isinstance(v, list) and len(v) == 3):
            raise ValueError(f"{where} [grid] {key}={quoted(v)} is not allowed: [start, stop, step]")
    bad = set(numerics) - set(_NUMERICS_KEYS) - {"rho0", "psd_model"}
    if bad:
        raise ValueError(f"{where} [numerics]: unknown key(s) {listed(sorted(bad))}; allowed: "
                         f"{listed(sorted(set(_NUMERICS_KEYS) | {'rho0', 'psd_model'}), near=sorted(bad))}")
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
