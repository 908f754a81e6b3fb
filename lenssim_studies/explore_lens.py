"""The explorer on any lens (issue 32): ``lenssim explore --lens LENS --vary NAME=LO:HI ...``.

A :class:`LensExplorer` is an :class:`lenssim_studies.explore.Explorer` whose design is a lens file (a shipped name,
a TOML or a Zemax file) with the free parameters the user names (as ``lenssim tradeoff --lens`` names them:
``S5.conic``, ``S7.A4``, ``E1.bending``, ``focus_um``, ...), each a slider over its range. Every number is the one the
command line gives for the same design:

* the criteria are :func:`lenssim_studies.lens_tradeoff._score`'s, i.e. ``lenssim tradeoff --lens``'s for that design
  (real-ray wavefronts at its field angles, its sensor: the nominal lens's Nyquist pitch, point samples, or
  ``pixel_pitch_um``'s area samples; its fast numerics);
* the cost map is a grid of those over the first two free parameters (the others at their first values),
* the photo is simulated as ``lenssim simulate --lens`` does (the photo spans the lens's largest field at its
  corners, or ``pixel_pitch_um``; the lens's own wavelengths, area samples), so the exported command (with the design
  written as a lens file, :meth:`LensExplorer.lens_toml`) reproduces the panel,
* the restoration lab's manufactured lens is a copy drawn from the per-surface grade
  (:mod:`lenssim.model.surface_tolerances`): radii, thicknesses, conics, indices and the despace, focus compensated;
  its decentres and tilts are left out (a decentred lens's PSFs are known along one azimuth, not over a photo).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from lenssim.model.numerics import FAST_NUMERICS, Numerics
from lenssim.model.prescription import Prescription

from .explore import MAP_CRITERIA, Explorer, Slider, _CachedPSF, psf_mtf_figure
from .lens_tradeoff import (MAX_GRID_PARAMETERS, LensTradeoffRun, _score, design_prescription, photo_field,
                            sequential_provider)

__all__ = ["LensExplorer", "LensControls", "FreeParameter", "LENS_MAP_VALUES", "LENS_PSF_FIELDS",
           "LENS_EXPORT_FILE", "SLIDER_STEPS"]

LENS_MAP_VALUES = 9
"""Values per axis of a lens's cost map (9 x 9 = 81 designs, computed once in the background)."""
LENS_PSF_FIELDS = (0.0, 1 / 3, 2 / 3, 1.0)
"""Field angles of the PSF and MTF panel, as fractions of the lens's largest."""
SLIDER_STEPS = 100
"""Steps across a free parameter's range when its step is not given."""
LENS_EXPORT_FILE = "explored_lens.toml"
"""The name the exported command gives the design's lens file (downloaded from the page)."""
NO_AXIS = "(one free parameter)"
"""The map's vertical axis when the lens has one free parameter."""


@dataclass(frozen=True)
class FreeParameter:
    """A free parameter (its canonical name, :func:`lenssim.model.lens_parameters.parse_parameter`'s) and its slider:
    range ``start`` .. ``end`` and ``step``, in the parameter's unit."""

    name: str
    start: float
    end: float
    step: float

    def __post_init__(self):
        if not (math.isfinite(self.start) and math.isfinite(self.end) and self.start < self.end):
            raise ValueError(f"--vary {self.name}={self.start:g}:{self.end:g} is not allowed: finite LO < HI")
        if not (math.isfinite(self.step) and 0 < self.step <= self.end - self.start):
            raise ValueError(f"--vary {self.name}: step {self.step:g} is not allowed: more than 0 and at most HI - LO")


@dataclass(frozen=True)
class LensControls:
    """The design the sliders select on any lens: ``((name, value), ...)`` of its free parameters."""

    values: tuple[tuple[str, float], ...]
    glass: str = "paper"
    """Unused (a lens file names its own glasses); kept so the page treats both kinds of controls alike."""

    def as_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in self.values}

    def key(self) -> tuple:
        return tuple((n, round(float(v), 12)) for n, v in self.values)


@dataclass
class LensExplorer(Explorer):
    """The explorer on the lens ``prescription`` (as the user named it: ``lens``) with the free parameters ``free``
    (1 to :data:`lenssim_studies.lens_tradeoff.MAX_GRID_PARAMETERS`), the solves ``hold`` and ``image`` and the
    surfaces made even aspheres (``aspherize``, 1-based) as ``lenssim tradeoff --lens`` takes them; ``pixel_pitch_um``:
    the sensor's pitch (um) instead of the defaults (see the module docstring)."""

    prescription: Prescription | None = None
    lens: str = ""
    free: tuple[FreeParameter, ...] = ()
    hold: tuple[str, ...] = ()
    image: str = "file"
    aspherize: tuple[int, ...] = ()
    pixel_pitch_um: float | None = None
    numerics: Numerics = FAST_NUMERICS
    map_values: int = LENS_MAP_VALUES
    """Values per axis of the cost map."""
    has_glass = False

    def __post_init__(self):
        from lenssim.model.lens_parameters import parameter_values
        from lenssim.optics.sequential import SequentialLens

        if self.prescription is None:
            raise ValueError("a lens is needed")
        if not 2 <= self.map_values <= 101:
            raise ValueError(f"map_values={self.map_values} is not allowed: 2 to 101 values per axis")
        if not 1 <= len(self.free) <= MAX_GRID_PARAMETERS:
            raise ValueError(f"{len(self.free)} free parameters are not allowed: 1 to {MAX_GRID_PARAMETERS} (--vary)")
        if self.pixel_pitch_um is not None and not (math.isfinite(self.pixel_pitch_um) and self.pixel_pitch_um > 0):
            raise ValueError(f"--pixel-pitch {self.pixel_pitch_um:g} is not allowed: a pixel pitch in um, > 0")
        seq = SequentialLens(self.prescription)
        seq.check_aperture()
        if self.pixel_pitch_um is None and max(self.prescription.fields) <= 0:
            raise ValueError(f"--lens {self.lens} has only the axial field: give --pixel-pitch UM for the sensor")
        self.free = tuple(replace(f, name=self._parameter(f.name).name) for f in self.free)
        file_values = parameter_values(self.prescription, [self._parameter(f.name) for f in self.free])
        # the sliders start at the file's design (each value kept inside its range)
        self.file_values = {f.name: float(file_values[f.name]) for f in self.free}
        self.start = LensControls(tuple((f.name, min(max(self.file_values[f.name], f.start), f.end))
                                        for f in self.free))
        par = seq.paraxial()
        if self.pixel_pitch_um is None:  # tradeoff's sensor: the nominal lens's Nyquist pitch, point samples
            pitch = self.prescription.primary_wavelength_um * par.working_f_number / 2
            self._criteria_pitch, self._sampling = pitch, "point"
        else:
            self._criteria_pitch, self._sampling = float(self.pixel_pitch_um), "area"
        self.tradeoff_run(self.start)  # checks the solves and the image plane (one line each)

    def _parameter(self, name: str):
        from lenssim.model.lens_parameters import parse_parameter

        return parse_parameter(self.prescription, name, aspherize=self.aspherize)

    def tradeoff_run(self, controls: LensControls, grid: dict | None = None) -> LensTradeoffRun:
        """The one-design trade-off run of ``controls`` (``grid``: ``{name: values}`` instead for those parameters),
        whose :func:`lenssim_studies.lens_tradeoff._score` gives the criteria."""
        vals = controls.as_dict()
        vary = tuple((f.name, tuple(grid[f.name]) if grid and f.name in grid else (vals[f.name],)) for f in self.free)
        return LensTradeoffRun(self.prescription, self.lens, vary, tuple(self.snr_db), self.rho0, self._criteria_pitch,
                               self._sampling, self.numerics, hold=self.hold, image=self.image,
                               aspherize=self.aspherize, coarse=True)

    # ---- the page's design controls -------------------------------------------------------------------------------
    def sliders(self, start=None) -> list[Slider]:
        s = (self.start if start is None else start).as_dict()
        out = []
        for f in self.free:
            p = self._parameter(f.name)
            out.append(Slider(f.name, f"{f.name} [{p.unit}]" if p.unit not in ("", "1") else f.name, f.start, f.end,
                              f.step, s[f.name]))
        return out

    def controls_from(self, values: dict, glass: str = "paper") -> LensControls:
        return LensControls(tuple((f.name, float(values[f.name])) for f in self.free))

    @property
    def map_axes(self) -> tuple[str, str]:
        return (self.free[0].name, self.free[1].name if len(self.free) > 1 else NO_AXIS)

    def map_point(self, controls) -> tuple[float, float]:
        v = controls.as_dict()
        x, y = self.map_axes
        return (v[x], v.get(y, 0.0))

    def named_points(self) -> dict[str, tuple[float, float]]:
        x, y = self.map_axes
        return {"the file's design": (self.file_values[x], self.file_values.get(y, 0.0))}

    def axis_label(self, key: str) -> str:
        if key == NO_AXIS:
            return key
        p = self._parameter(key)
        return f"{key} ({p.description}" + (f", {p.unit})" if p.unit not in ("", "1") else ")")

    def map_note(self) -> str:
        rest = [f"{n} = {v:.6g}" for n, v in self.start.values[2:]]
        return f"{self.lens}" + (f"; {', '.join(rest)}" if rest else "")

    def design_label(self, controls) -> str:
        return f"{self.lens}: " + ", ".join(f"{n} = {v:.5g}" for n, v in controls.values)

    # ---- design ---------------------------------------------------------------------------------------------------
    def check(self, controls: LensControls):
        """The solved lens of ``controls``: ``(prescription, SequentialLens)`` (one-line ``ValueError`` when the design
        cannot be made)."""
        def make():
            from lenssim.optics.lens_solves import solve_design
            from lenssim.optics.sequential import SequentialLens

            values = {self._parameter(n): v for n, v in controls.values}
            q, shift = solve_design(self.prescription, values, hold=self.hold, image=self.image)
            seq = SequentialLens(q, image_shift_mm=shift)
            seq.check_aperture()
            return q, seq
        return self._cache("solved").get_or(controls.key(), make)

    def criteria(self, controls: LensControls) -> dict:
        """``lenssim tradeoff --lens``'s criteria of the design (MSE_R per SNR, MSE_S at the reference SNR, RMS_W in
        waves, Strehl, MTF50 in cycles/mm, the cost C_a, the focal length in mm), averaged over its field angles."""
        def make():
            from lenssim_studies.paper import PAPER

            self.check(controls)
            r = _score(self.tradeoff_run(controls), 0)
            if r["reason"]:
                raise ValueError(f"this design is refused: {r['reason']}")
            out = {f"MSE_R at {s:g} dB": float(v) for s, v in zip(self.snr_db, r["mse_r"])}
            ref = min(range(len(self.snr_db)), key=lambda i: abs(self.snr_db[i] - PAPER.reference_snr_db))
            out[f"MSE_S at {self.snr_db[ref]:g} dB"] = float(r["mse_s"][ref])
            out.update({"RMS_W [waves]": float(r["rms_w"]), "Strehl": float(r["strehl"]),
                        "MTF50 [cycles/mm]": float(r["mtf50"]), "cost C_a": float(r["cost"]),
                        "EFL [mm]": float(r["efl_mm"])})
            return out
        return self._cache("criteria").get_or(controls.key(), make)

    def optics_figure(self, controls: LensControls, angles=None) -> bytes:
        """PNG: the PSF (log10, axes in um) at each of :data:`LENS_PSF_FIELDS` of the lens's largest field (along the
        image's x axis) on the criteria's sensor, and the MTFs (x and y) there against cycles/mm."""
        amax = max(self.prescription.fields)
        angles = tuple(f * amax for f in LENS_PSF_FIELDS) if angles is None else tuple(angles)

        def make():
            from lenssim.optics.psf_bank import image_scale_mm

            q, seq = self.check(controls)
            pitch = self._criteria_pitch
            scale = image_scale_mm(seq)
            cols = [round(scale * math.tan(math.radians(a)) / (pitch * 1e-3)) for a in angles]
            rows = [0] * len(cols)
            shown = [math.degrees(math.atan(c * pitch * 1e-3 / scale)) for c in cols]  # at whole pixels
            prov = sequential_provider(q, seq, pitch_um=pitch, sampling=self._sampling,
                                       max_field_deg=max(max(shown) * (1 + 1e-9), 1e-9), numerics=self.numerics,
                                       coarse=True)
            n = int(prov.extent_px(torch.tensor(rows), torch.tensor(cols), (0.0, 0.0)))
            n = max(32, n + n % 2)
            psfs = prov.psf_at_pixels(torch.tensor(rows), torch.tensor(cols), (0.0, 0.0), n, dtype=torch.float64)
            psfs = psfs.reshape(len(angles), -1, n, n).mean(1)
            kind = "point samples" if self._sampling == "point" else "pixels"
            return psf_mtf_figure(list(psfs), shown, pitch,
                                  f"{self.design_label(controls)}: PSFs (log10, {pitch:.4g} um {kind}) and MTFs")
        return self._cache("optics").get_or(controls.key() + angles, make)

    # ---- the cost map --------------------------------------------------------------------------------------------
    def compute_map(self, progress=None) -> dict:
        """The criteria on a :attr:`map_values`-value grid of the first two free parameters over their ranges
        (the others at their first values; once; ``progress(done, total)`` after each design): ``{x name, y name,
        criterion: (len(y), len(x)[, S]) arrays}``; designs that cannot be made are NaN."""
        with self._lock:
            if self.map_data is not None:
                return self.map_data
            xn, yn = self.map_axes
            fx = self.free[0]
            xs = np.linspace(fx.start, fx.end, self.map_values)
            grid = {xn: xs}
            if yn != NO_AXIS:
                fy = self.free[1]
                ys = np.linspace(fy.start, fy.end, self.map_values)
                grid[yn] = ys
            else:
                ys = np.zeros(1)
            run = self.tradeoff_run(self.start, grid={k: tuple(float(v) for v in g) for k, g in grid.items()})
            S = len(self.snr_db)
            out = {xn: xs, yn: ys, "mse_r": np.full((len(ys), len(xs), S), np.nan),
                   "mse_s": np.full((len(ys), len(xs), S), np.nan),
                   **{k: np.full((len(ys), len(xs)), np.nan) for k in ("rms_w", "strehl", "mtf50", "cost")}}
            for i in range(run.size):
                d = run.design(i)
                ix = int(np.argmin(np.abs(xs - d[xn])))
                iy = 0 if yn == NO_AXIS else int(np.argmin(np.abs(ys - d[yn])))
                r = _score(run, i)
                if not r["reason"]:
                    for k in MAP_CRITERIA:
                        out[k][iy, ix] = r[k]
                self.map_progress = (i + 1, run.size)
                if progress is not None:
                    progress(*self.map_progress)
            self.map_data = out
            return out

    def load_map(self, ds) -> None:
        raise ValueError("--sweep is a sweep of the paper's singlet: a lens's map is computed by the explorer")

    # ---- photo -----------------------------------------------------------------------------------------------------
    def _photo_field(self, shape=None) -> tuple[float, float]:
        """The pixel pitch (um) of a photo of ``shape`` (the explorer's own by default) and the largest field angle its
        blur asks PSFs at (deg), as ``lenssim simulate --lens`` takes them."""
        from pipeline.blur import PAPER_SCHEME

        shape = tuple(self.photo_shape if shape is None else shape)
        return self._cache("field").get_or(tuple(shape), lambda: photo_field(
            self.prescription, self._nominal(), shape, pitch_um=self.pixel_pitch_um, margin_px=PAPER_SCHEME.core))

    def _nominal(self):
        from lenssim.optics.sequential import SequentialLens

        return SequentialLens(self.prescription)

    @property
    def sensor(self):
        return self.sensor_for(self.photo_shape)

    def sensor_for(self, shape):
        """The sensor a photo of ``shape`` is simulated on: the paper's noise and ISO table, the photo's pixels at
        :meth:`_photo_field`'s pitch."""
        from lenssim_studies.paper import PAPER_CAMERA

        H, W = shape[-2:]
        return replace(PAPER_CAMERA.sensor, pixel_pitch_um=self._photo_field(shape)[0], width_px=int(W),
                       height_px=int(H))

    def _provider(self, controls: LensControls, lens=None, shape=None):
        """The PSFs of the design (or of the manufactured ``lens``, a SequentialLens) over a photo of ``shape`` (the
        explorer's own by default)."""
        shape = tuple(self.photo_shape if shape is None else shape)

        def make():
            q, seq = self.check(controls)
            pitch, amax = self._photo_field(shape)
            H, W = shape[-2:]
            return _CachedPSF(sequential_provider(q, seq if lens is None else lens, pitch_um=pitch, sampling="area",
                                                  max_field_deg=amax, width_px=int(W), height_px=int(H)))
        key = controls.key() + (shape, None if lens is None else lens.cache_key())
        return self._cache("psf").get_or(key, make)

    def check_grade(self, grade: str) -> None:
        from lenssim.model.surface_tolerances import surface_grade

        surface_grade(grade)

    def _built_provider(self, controls: LensControls, grade: str, lens_seed: int, shape=None):
        from lenssim.model.surface_tolerances import surface_grade
        from lenssim.sequential_tolerance import manufactured_lens

        q, seq = self.check(controls)
        centred = replace(surface_grade(grade), surface_decentre_um=0.0, surface_tilt_arcmin=0.0,
                          element_decentre_um=0.0, element_tilt_arcmin=0.0)
        pert = centred.sample(q, 1, seed=int(lens_seed))
        return self._provider(controls, manufactured_lens(seq, pert, 0), shape)

    # ---- export ---------------------------------------------------------------------------------------------------
    def is_file_design(self, controls: LensControls) -> bool:
        """Whether ``controls`` is the lens exactly as its file gives it (no solve, no change)."""
        return (not self.hold and self.image == "file"
                and all(v == self.file_values[n] for n, v in controls.values))

    def lens_toml(self, controls: LensControls) -> str:
        """The design as a lens file (TOML; its solves applied and its image plane folded into the last thickness):
        what ``--lens`` of every command takes."""
        from lenssim.io.prescription_file import prescription_toml

        return prescription_toml(design_prescription(self.tradeoff_run(controls), controls.as_dict()))

    def design_arguments(self, controls: LensControls) -> list[str]:
        parts = ["--lens", self.lens if self.is_file_design(controls) else LENS_EXPORT_FILE]
        if self.pixel_pitch_um is not None:
            parts += ["--pixel-pitch", f"{self.pixel_pitch_um:g}"]
        return parts

