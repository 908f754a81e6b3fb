"""The paper's cost-performance trade-off on any lens (issue 30, item 4): a resumable grid sweep of a prescription's
free parameters, every criterion against the asphere cost, and the optima per cost level.

A :class:`LensTradeoffRun` names the lens, the free parameters (:mod:`lenssim.model.lens_parameters`) with their
grid values (up to :data:`MAX_GRID_PARAMETERS`), what the design holds (:mod:`lenssim.optics.lens_solves`), the
sensor and the SNRs. Every design of the grid is solved, checked (its axial beam through every surface) and scored
by :func:`lenssim.sequential_metrics.evaluate_sequential` (real-ray wavefronts: ``rms_w``, ``mse_s`` and ``mse_r``
per SNR, ``strehl``, ``mtf50``) and priced by :func:`lenssim.optics.cost.prescription_costs` (``cost``: the sum over
its aspheric surfaces of the paper's RMS slope departure). A design that cannot be made (crossing surfaces, a solve
that cannot hold, a beam that misses a surface) is kept, marked invalid with the reason, and never scored.

The optima per cost level (:func:`front`): for each level ``C`` (``levels`` of them, from 0 to the largest valid
cost, evenly) the best valid design of the grid whose cost is at most ``C`` (where the unconstrained optimum costs
more than ``C`` that is the best design on the iso-cost surface ``C_a = C`` to the grid's resolution: the paper's
iso-cost optimum; the singlet's exact iso-cost curves are :mod:`lenssim_studies.tradeoff`). The sweep is chunked,
each chunk a checksummed file (:mod:`lenssim_studies.chunks`): a killed run resumes and verifies what it kept.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from lenssim import __version__
from lenssim.criteria import CRITERIA
from lenssim.model.lens_parameters import LensParameter, parse_parameter
from lenssim.model.numerics import DEFAULT_NUMERICS, Numerics
from lenssim.model.prescription import Prescription
from lenssim.model.spectrum import Spectrum
from lenssim.optics.lens_solves import solve_design
from lenssim.optics.sequential import SequentialLens
from lenssim.optics.psf_bank import TABLE_INITIAL_NODES, TABLE_MAX_NODES
from lenssim.optics.psf_provider import SequentialPSF
from lenssim.sequential_metrics import evaluate_sequential, evaluation_angles
from lenssim.sequential_third_order import evaluate_third_order
from lenssim.validate import ModelValidityWarning, check_distinct, check_snr_db

from .chunks import (finish_resumable, open_resumable, partial_folder, read_stamped_chunk, result_mismatch, resume_chunks,
                     write_stamped_chunk)
from .paper import PAPER_CAMERA

__all__ = ["LensTradeoffRun", "run_lens_tradeoff", "front", "end_to_end_gain", "tradeoff_json", "design_prescription",
           "write_design_files", "TRADEOFF_CRITERIA", "tradeoff_mismatch", "check_psf_sampling",
           "MAX_GRID_PARAMETERS", "MAX_GRID_DESIGNS", "CHUNK_DESIGNS", "TRADEOFF_ANGLES", "WAVEFRONTS"]

TRADEOFF_CRITERIA = ("rms_w", "mse_s", "mse_r", "strehl", "mtf50")
"""What each design is scored on (field averages; ``mse_s`` and ``mse_r`` per SNR)."""
MAX_GRID_PARAMETERS = 3
"""A grid sweep's most free parameters (more: a grid's size grows as the power)."""
MAX_GRID_DESIGNS = 20_000
"""A grid's most designs (each traces its own wavefronts: seconds a design)."""
CHUNK_DESIGNS = 8
"""Designs per chunk file."""
TRADEOFF_ANGLES = 5
"""Field angles of each design's field average (the exact route), from the axis to the lens's largest, evenly."""
WAVEFRONTS = ("exact", "third_order")
"""How each design's wavefront is obtained (:attr:`LensTradeoffRun.wavefront`)."""


def sequential_provider(p: Prescription, seq: SequentialLens, *, pitch_um: float, sampling: str,
                        max_field_deg: float, numerics: Numerics = DEFAULT_NUMERICS, coarse: bool = False,
                        width_px: int = 1, height_px: int = 1, colour_channels=()) -> SequentialPSF:
    """The PSFs of ``seq`` on the paper's sensor (its noise and full wells) with ``width_px`` x ``height_px`` pixels of
    ``pitch_um``, in the lens's own wavelengths (equal weights) or in ``colour_channels`` (each a
    :class:`lenssim.Spectrum`), traced out to ``max_field_deg``; ``coarse``: the wavefront table at its initial field
    nodes only."""
    sensor = replace(PAPER_CAMERA.sensor, pixel_pitch_um=pitch_um, width_px=width_px, height_px=height_px)
    light = Spectrum(p.wavelengths_um, (1.0,) * len(p.wavelengths_um),
                     name=f"the lens's {len(p.wavelengths_um)} wavelength(s)")
    return SequentialPSF(seq, sensor, light, tuple(colour_channels), max_field_deg=max_field_deg, sampling=sampling,
                         numerics=numerics, table_max_nodes=TABLE_INITIAL_NODES if coarse else TABLE_MAX_NODES)


def photo_field(p: Prescription, seq: SequentialLens, shape, *, pitch_um: float | None = None,
                margin_px: float = 0.0) -> tuple[float, float]:
    """The pixel pitch (um) and the largest field angle (deg) of a photo of ``shape`` ``(..., H, W)`` taken through
    ``seq``, where the angle reaches ``margin_px`` past the photo's corners (the blur's windows reach past the frame's
    edges by up to half a core on each axis: their PSFs too). By default the pitch puts that reach at the lens's
    largest field, so the photo spans the lens's field and every PSF asked for lies within it; ``pitch_um``: the given
    pitch, refused (:class:`PhotoFieldError`, with the pitch that would fit) where the lens's chief ray does not pass
    at the reach it gives."""
    from lenssim.optics.psf_bank import image_scale_mm

    H, W = shape[-2:]
    reach_px = math.hypot(H - 1, W - 1) / 2 + margin_px
    scale = image_scale_mm(seq)
    amax = max(p.fields)
    fit_um = scale * math.tan(math.radians(amax)) / reach_px * 1e3 if amax > 0 else None
    if pitch_um is None:
        if fit_um is None:
            raise ValueError("the lens has only the axial field: give a pixel pitch (um) for the sensor")
        return float(fit_um), float(amax)
    reach = math.degrees(math.atan(reach_px * pitch_um * 1e-3 / scale))
    if reach > amax:
        from lenssim.optics.sequential import RayTraceError
        from lenssim.optics.psf_bank import chief_point_mm

        try:
            for lam in p.wavelengths_um:
                chief_point_mm(seq, reach, lam)
        except RayTraceError as exc:
            where = f"{reach:.4g} deg at the photo's corners" + (f" and the blur's {margin_px:g} px margin beyond them"
                                                                 if margin_px else "")
            hint = (f"a pitch of at most {fit_um:.4g} um keeps the photo within the lens's {amax:g} deg field"
                    if fit_um is not None else "the lens gives no field to fit the photo in")
            raise PhotoFieldError(f"a pixel pitch of {pitch_um:g} um puts {where}, where this lens forms no image "
                                  f"({exc}); {hint}", fit_um) from None
    return float(pitch_um), reach


class PhotoFieldError(ValueError):
    """A pixel pitch that puts a photo's corners beyond the field a lens images; ``fit_um`` the pitch that fits."""

    def __init__(self, message: str, fit_um: float | None):
        super().__init__(message)
        self.fit_um = fit_um


@dataclass(frozen=True)
class LensTradeoffRun:
    """A trade-off of the lens ``prescription`` (as read from ``lens``): ``vary`` ``((name, values), ...)`` the free
    parameters and their grid values (names as :func:`lenssim.model.lens_parameters.parse_parameter` reads them),
    ``hold`` and ``image`` the solves, ``aspherize`` surfaces (1-based) made even aspheres, the SNRs (dB), the image
    model's correlation, the pixel pitch (um; the same sensor for every design) and sampling, the numerics, whether
    the wavefront tables are coarse, and the number of cost levels."""

    prescription: Prescription
    lens: str
    vary: tuple[tuple[str, tuple[float, ...]], ...]
    snr_db: tuple[float, ...]
    rho0: float
    pitch_um: float
    sampling: str
    numerics: Numerics
    hold: tuple[str, ...] = ()
    image: str = "file"
    aspherize: tuple[int, ...] = ()
    coarse: bool = True
    levels: int = 30
    angles: int = TRADEOFF_ANGLES
    wavefront: str = "exact"
    """``exact`` (real-ray OPD, :func:`lenssim.sequential_metrics.evaluate_sequential`, at :attr:`angles` field angles
    evenly) or ``third_order`` (the Seidel wavefront, :func:`lenssim.sequential_third_order.evaluate_third_order`, at
    the prescription's own field angles, point samples: the paper's route)."""

    def __post_init__(self):
        if not 1 <= len(self.vary) <= MAX_GRID_PARAMETERS:
            raise ValueError(f"{len(self.vary)} free parameters are not allowed in a grid sweep: 1 to "
                             f"{MAX_GRID_PARAMETERS}")
        names = [self.parameter(n).name for n, _ in self.vary]
        if len(set(names)) != len(names):
            raise ValueError(f"a free parameter is named twice: {', '.join(names)}")
        for n, v in self.vary:
            if not v or not all(math.isfinite(x) for x in v):
                raise ValueError(f"--vary {n}: its values must be finite numbers, at least one")
        if self.size > MAX_GRID_DESIGNS:
            raise ValueError(f"a grid of {self.size} designs is not allowed: at most {MAX_GRID_DESIGNS} (fewer values "
                             "per parameter)")
        from lenssim.optics.lens_solves import IMAGE_PLANES, check_solves

        check_solves(self.prescription, [self.parameter(n) for n, _ in self.vary], hold=self.hold)
        if self.image not in IMAGE_PLANES:
            raise ValueError(f"image plane {self.image!r} is not allowed: one of {', '.join(IMAGE_PLANES)}")
        if self.levels < 2:
            raise ValueError(f"levels={self.levels} is not allowed: at least 2 cost levels")
        check_snr_db(self.snr_db, "snr_db", warn=False)  # the criteria's rule, before the grid (it warns there)
        check_distinct("snr_db", self.snr_db, as_written=True)
        if self.wavefront not in WAVEFRONTS:
            raise ValueError(f"wavefront {self.wavefront!r} is not allowed: one of {', '.join(WAVEFRONTS)}")
        if self.wavefront == "third_order":
            from lenssim.optics.seidel_wavefront import check_third_order_parameters

            check_third_order_parameters([self.parameter(n) for n, _ in self.vary])
            if self.sampling != "point":
                raise ValueError("the third-order route samples the PSF at points (the paper's image model): "
                                 f"sampling {self.sampling!r} is not allowed with it")

    def parameter(self, name: str) -> LensParameter:
        return parse_parameter(self.prescription, name, aspherize=self.aspherize)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.parameter(n).name for n, _ in self.vary)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for _, v in self.vary)

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    def design(self, i: int) -> dict[str, float]:
        """Design ``i`` of the grid (C order: the last parameter fastest) as ``{name: value}``."""
        idx = np.unravel_index(i, self.shape)
        return {name: float(v[j]) for name, (_, v), j in zip(self.names, self.vary, idx)}

    def to_dict(self) -> dict:
        out = {"prescription": self.prescription.to_dict(), "lens": self.lens,
               "vary": [[n, list(v)] for n, v in zip(self.names, (v for _, v in self.vary))],
               "snr_db": list(self.snr_db), "rho0": self.rho0, "pitch_um": self.pitch_um, "sampling": self.sampling,
               "numerics": self.numerics.to_dict(), "hold": list(self.hold), "image": self.image,
               "aspherize": list(self.aspherize), "coarse": self.coarse, "levels": self.levels,
               "angles": self.angles, "lenssim_version": __version__}
        if self.wavefront != "exact":  # the exact route's digests as before this option
            out["wavefront"] = self.wavefront
        return out

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]

    def chunks(self) -> list[tuple[int, int]]:
        return [(k, min(k + CHUNK_DESIGNS, self.size)) for k in range(0, self.size, CHUNK_DESIGNS)]

    @property
    def max_field_deg(self) -> float:
        return max(self.prescription.fields)

    @property
    def evaluation_angles(self) -> tuple[float, ...]:
        """The field angles (deg) each design's criteria average over: the prescription's own for ``third_order`` (the
        paper's sampling), :attr:`angles` evenly from the axis to the largest for ``exact``."""
        if self.wavefront == "third_order":
            return tuple(float(a) for a in self.prescription.fields)
        return evaluation_angles(self.max_field_deg, self.angles)

    def check_sampling(self) -> None:
        """Before any design is scored: pixels on which no design can be, refused (one line). The pixel pitch against
        the lens's diffraction alone (an aberration-free PSF of the file's lens and working F-number): the third-order
        route's point samples need a pitch below ``lambda N_w``; the PSF grid, and an area sample's finer grid, must
        fit ``numerics.max_fft_size``. A design's own aberrations may need more: it is then kept invalid, with the
        reason."""
        from lenssim.optics.aberrations import TERMS
        from lenssim.optics.psf_bank import fft_size
        from lenssim.sequential_third_order import third_order_camera
        from lenssim.validate import ResourceLimitError

        seq = SequentialLens(self.prescription)
        what = f"pixels of {self.pitch_um:g} um ({self.sampling} samples) on {self.lens}"
        try:
            if self.wavefront == "third_order":
                camera = third_order_camera(seq, self.pitch_um, self.evaluation_angles)
                fft_size(camera, torch.zeros(len(self.evaluation_angles), len(camera.spectrum), len(TERMS),
                                             dtype=torch.float64), self.numerics, terms=TERMS)
                return
            check_psf_sampling(sequential_provider(self.prescription, seq, pitch_um=self.pitch_um,
                                                   sampling=self.sampling, max_field_deg=self.max_field_deg,
                                                   numerics=self.numerics, coarse=self.coarse), self.numerics)
        except ResourceLimitError as exc:
            raise ResourceLimitError(f"{what}: even an aberration-free design: {exc}", exc.setting) from None
        except ValueError as exc:
            raise ValueError(f"{what}: {exc}") from None


def check_psf_sampling(psf: SequentialPSF, numerics: Numerics) -> None:
    """Refuse the pixels of ``psf`` if an aberration-free PSF on them (its diffraction alone) needs more than
    ``numerics.max_fft_size``: its pixel grid, or the finer grid an area sample is computed on (a
    :class:`lenssim.validate.ResourceLimitError`; cheap: no ray is traced)."""
    from lenssim.sequential_metrics import _grid_size
    from lenssim.validate import ResourceLimitError

    n = _grid_size(psf, psf.margin_px(), numerics)
    if psf.fft_size(n) > numerics.max_fft_size:
        raise ResourceLimitError(f"a PSF sampled over the pixels' area needs an FFT of {psf.fft_size(n)} samples "
                                 f"({psf.oversample()} per pixel); the limit is max_fft_size = {numerics.max_fft_size}",
                                 "max_fft_size")


def _score(run: LensTradeoffRun, i: int) -> dict:
    """Design ``i``: its criteria, cost and validity (``reason``: '' if valid)."""
    S = len(run.snr_db)
    nan = {"rms_w": math.nan, "mse_s": [math.nan] * S, "mse_r": [math.nan] * S, "strehl": math.nan,
           "mtf50": math.nan, "cost": math.nan, "efl_mm": math.nan}
    values = {run.parameter(n): v for n, v in run.design(i).items()}
    try:
        q, shift = solve_design(run.prescription, values, hold=run.hold, image=run.image)
        seq = SequentialLens(q, image_shift_mm=shift)
        seq.check_aperture()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ModelValidityWarning)
            if run.wavefront == "third_order":
                r = evaluate_third_order(seq, run.snr_db, pitch_um=run.pitch_um, rho0=run.rho0,
                                         angles_deg=run.evaluation_angles, numerics=run.numerics,
                                         criteria=TRADEOFF_CRITERIA + ("cost",))
            else:
                psf = sequential_provider(q, seq, pitch_um=run.pitch_um, sampling=run.sampling,
                                          max_field_deg=run.max_field_deg, numerics=run.numerics, coarse=run.coarse)
                r = evaluate_sequential(psf, run.snr_db, rho0=run.rho0, numerics=run.numerics,
                                        angles_deg=run.evaluation_angles, criteria=TRADEOFF_CRITERIA + ("cost",))
    except ValueError as exc:  # PrescriptionError, SolveError, RayTraceError, ...: the design is invalid
        return nan | {"reason": str(exc).splitlines()[0][:300], "mtf50_capped": False}
    capped = False
    for w in caught:  # the MTF50 lower bound is recorded per design (mtf50_capped); the SNRs are the run's, said
        # once before the grid (run_lens_tradeoff); anything else is passed on
        if issubclass(w.category, ModelValidityWarning) and str(w.message).startswith("MTF50"):
            capped = True
        elif not (issubclass(w.category, ModelValidityWarning) and str(w.message).startswith("SNR [")):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    out = {k: torch.as_tensor(r[k], dtype=torch.float64).tolist() for k in TRADEOFF_CRITERIA}
    out["cost"] = float(r["cost"])  # prescription_costs over each aspheric surface's clear aperture
    out["efl_mm"] = seq.paraxial().efl_mm
    bad = [k for k in TRADEOFF_CRITERIA + ("cost",) if not np.isfinite(np.asarray(out[k])).all()]
    if bad:
        return nan | {"reason": f"not finite: {', '.join(bad)}", "mtf50_capped": False}
    return out | {"reason": "", "mtf50_capped": capped}


_KEYS = TRADEOFF_CRITERIA + ("cost", "efl_mm", "mtf50_capped")


def _compute_chunk(run: LensTradeoffRun, i: int, progress) -> dict:
    k0, k1 = run.chunks()[i]
    rows = []
    for k in range(k0, k1):
        rows.append(_score(run, k))
        progress(1)
    chunk = {key: np.asarray([r[key] for r in rows], dtype=np.float64) for key in _KEYS}
    chunk["reason"] = np.asarray([r["reason"] for r in rows], dtype=np.str_)
    return chunk


def _write_chunk(path: Path, chunk: dict, run: LensTradeoffRun, i: int) -> None:
    write_stamped_chunk(path, chunk, run.digest(), i)


def _read_chunk(path: Path, run: LensTradeoffRun, i: int):
    """The chunk's arrays if ``path`` holds chunk ``i`` of this run intact, else the reason it does not."""
    k0, k1 = run.chunks()[i]
    return read_stamped_chunk(path, _KEYS + ("reason",), run.digest(), i, run="trade-off run", rows_key="cost",
                              rows=k1 - k0, what="designs")


def _dataset(run: LensTradeoffRun, chunks: list[dict]) -> xr.Dataset:
    shape = run.shape
    dims = tuple(run.names)
    coords = {n: np.asarray(v, dtype=np.float64) for n, (_, v) in zip(run.names, run.vary)}
    coords["snr"] = np.asarray(run.snr_db, dtype=np.float64)
    data = {}
    for k in _KEYS:
        v = np.concatenate([c[k] for c in chunks])
        if k == "mtf50_capped":
            data[k] = xr.Variable(dims, v.reshape(shape).astype(np.int8),
                                  {"long_name": "1: the design's MTF50 stays above 0.5 up to Nyquist at some field "
                                                "angle, counted there (a lower bound)"})
            continue
        per_snr = v.ndim == 2
        data[k] = xr.Variable(dims + (("snr",) if per_snr else ()), v.reshape(shape + v.shape[1:]),
                              {"units": CRITERIA[k].units if k in CRITERIA else ("mm" if k == "efl_mm" else "1"),
                               "long_name": CRITERIA[k].description if k in CRITERIA else
                               ("paraxial focal length" if k == "efl_mm" else
                                "asphere cost C_a: sum of the aspheric surfaces' RMS slope departure")})
    reason = np.concatenate([c["reason"] for c in chunks]).reshape(shape)
    data["valid"] = xr.Variable(dims, reason == "", {"long_name": "the design could be made and scored"})
    data["reason"] = xr.Variable(dims, reason.astype(str), {"long_name": "why a design is invalid ('' if valid)"})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs = {"title": "lenssim trade-off of any lens", "lens": run.lens, "lenssim_version": __version__,
                "config": json.dumps(run.to_dict(), sort_keys=True, default=str), "config_digest": run.digest()}
    return ds


def run_lens_tradeoff(run: LensTradeoffRun, out: str | os.PathLike, *, show_progress: bool = True,
                      max_chunks: int | None = None) -> xr.Dataset | None:
    """Run (or resume) the grid sweep and write ``out`` (NetCDF); ``None`` if ``max_chunks`` stopped it early."""
    out = Path(out)
    done = open_resumable(out, run.digest(), "trade-off output", "trade-off", check=tradeoff_mismatch)
    if done is not None:
        return done
    run.check_sampling()
    check_snr_db(run.snr_db)  # outside where the criteria were validated: said once, here
    part = out.with_name(out.name + ".partial")
    with partial_folder(part, "run.json", run.digest(), {"run": run.to_dict()},
                        f"{str(part)!r} holds chunks of a different trade-off; remove it or choose another output"):
        ranges = run.chunks()
        paths = [part / f"chunk_{i:05d}.npz" for i in range(len(ranges))]
        chunks = resume_chunks(paths, kind="trade-off", read=lambda p, i: _read_chunk(p, run, i),
                               write=lambda p, chunk, i: _write_chunk(p, chunk, run, i),
                               compute=lambda i, progress: _compute_chunk(run, i, progress),
                               weight=lambda i: ranges[i][1] - ranges[i][0], desc="designs", unit="design",
                               show_progress=show_progress, max_chunks=max_chunks)
        if chunks is None:
            return None
        ds = _dataset(run, chunks)
        finish_resumable(out, ds, part)
        return ds


def tradeoff_mismatch(ds: xr.Dataset) -> str | None:
    """Why the trade-off ``ds`` makes no sense for the run its ``config`` records, or None: its grid (each parameter's
    coordinate and the variables' dimensions) and SNRs are the run's, ``valid`` says what ``reason`` says, every
    criterion, the cost and the focal length of a valid design are finite (the criteria and the cost >= 0), an invalid
    design's are NaN, and ``mtf50_capped`` is 0 or 1 (0 where invalid)."""
    try:
        d = json.loads(ds.attrs["config"])
        vary = {str(n): np.asarray(v, dtype=np.float64) for n, v in d["vary"]}
        snr = np.asarray(d["snr_db"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return "it carries no readable run record (config)"
    names = tuple(vary)
    missing = [k for k in _KEYS + ("valid", "reason") if k not in ds]
    if missing:
        return f"it holds no {', '.join(missing)}"
    for k in _KEYS + ("valid", "reason"):
        want = names + (("snr",) if k in ("mse_s", "mse_r") else ())
        if tuple(ds[k].dims) != want:
            return f"its {k} is not over the run's grid ({', '.join(want)})"
    why = result_mismatch(ds, {**vary, "snr": snr})
    if why:
        return why
    valid = np.asarray(ds["valid"].values)
    reason = np.asarray(ds["reason"].values).astype(str)
    if valid.dtype != bool or not np.array_equal(valid, reason == ""):
        return "its valid flags are not what its reasons say (valid where no reason is given)"
    for k in TRADEOFF_CRITERIA + ("cost", "efl_mm"):
        v = np.asarray(ds[k].values, dtype=np.float64)
        made, unmade = v[valid], v[~valid]
        if not np.isfinite(made).all() or (k != "efl_mm" and (made < 0).any()):
            return f"its {k} of a valid design is not a finite number" + ("" if k == "efl_mm" else " >= 0")
        if not np.isnan(unmade).all():
            return f"its {k} of an invalid design is a number (an invalid design is never scored)"
    capped = np.asarray(ds["mtf50_capped"].values)
    if not np.isin(capped, (0, 1)).all() or capped[~valid].any():
        return "its mtf50_capped is not 0 or 1 (0 for an invalid design)"
    return None


def _criteria_columns(ds: xr.Dataset) -> dict[str, tuple[np.ndarray, str]]:
    """``{name: (values over the grid, flattened; sense)}``: ``rms_w``, ``mse_s`` and ``mse_r`` at each SNR (named
    ``mse_r@27.6`` beyond the first SNR, as ``lenssim optimum`` names them), ``strehl``, ``mtf50``."""
    out = {}
    snr = [float(v) for v in ds["snr"].values]
    for k in TRADEOFF_CRITERIA:
        v = ds[k].values
        sense = CRITERIA[k].sense
        if "snr" in ds[k].dims:
            for j, s in enumerate(snr):
                out[k if j == 0 else f"{k}@{s:g}"] = (v[..., j].reshape(-1), sense)
        else:
            out[k] = (v.reshape(-1), sense)
    return out


def front(ds: xr.Dataset, levels: int) -> dict:
    """The optima per cost level and unconstrained, per criterion (see the module docstring): ``{"levels": [...],
    "optima": {criterion: [{"cost", "value", "design"} or None per level]}, "unconstrained": {criterion: {...}}}``;
    a level no valid design reaches is None."""
    valid = ds["valid"].values.reshape(-1)
    cost = ds["cost"].values.reshape(-1)
    names = [d for d in ds["valid"].dims]
    grids = np.meshgrid(*(ds[n].values for n in names), indexing="ij")
    designs = np.stack([g.reshape(-1) for g in grids], axis=-1)
    top = float(cost[valid].max()) if valid.any() else 0.0
    lv = [float(v) for v in np.linspace(0.0, top, levels)]
    res = {"parameters": names, "levels": lv, "optima": {}, "unconstrained": {}}

    def entry(i):
        return {"cost": float(cost[i]), "design": {n: float(designs[i, j]) for j, n in enumerate(names)}}

    for name, (v, sense) in _criteria_columns(ds).items():
        score = v if sense == "min" else -v
        ok = valid & np.isfinite(score)
        if not ok.any():
            res["optima"][name] = [None] * len(lv)
            res["unconstrained"][name] = None
            continue
        best = int(np.flatnonzero(ok)[np.argmin(score[ok])])
        res["unconstrained"][name] = entry(best) | {"value": float(v[best])}
        row = []
        for c in lv:
            m = ok & (cost <= c * (1 + 1e-12) + 1e-15)
            if not m.any():
                row.append(None)
                continue
            i = int(np.flatnonzero(m)[np.argmin(score[m])])
            row.append(entry(i) | {"value": float(v[i])})
        res["optima"][name] = row
    res["invalid"] = int((~valid).sum())
    res["designs"] = int(valid.size)
    return res


def end_to_end_gain(ds: xr.Dataset) -> dict:
    """The paper's comparison on this grid, per SNR (``mse_r``, ``mse_r@33.6``, ...): the RMS_W optimum (the
    sequential design) against the designs chosen for the restored image. ``equal_cost``: the best ``mse_r`` among
    valid designs costing at most the RMS_W optimum (``mse_r_ratio``: its ``mse_r`` over the RMS_W optimum's, < 1 when
    designing for the restored image pays); ``equal_quality``: the cheapest valid design restoring at least as well as
    the RMS_W optimum (``cost_saving``: ``1 - its cost / the RMS_W optimum's``). Ties: the first in the grid's order.
    Empty if no design is valid."""
    valid = ds["valid"].values.reshape(-1)
    cols = _criteria_columns(ds)
    rms, _ = cols["rms_w"]
    ok = valid & np.isfinite(rms)
    if not ok.any():
        return {}
    cost = ds["cost"].values.reshape(-1)
    names = [d for d in ds["valid"].dims]
    grids = np.meshgrid(*(ds[n].values for n in names), indexing="ij")

    def design(i):
        return {n: float(g.reshape(-1)[i]) for n, g in zip(names, grids)}

    w = int(np.flatnonzero(ok)[np.argmin(rms[ok])])
    out = {}
    for name, (v, _) in cols.items():
        if name.split("@")[0] != "mse_r":
            continue
        good = valid & np.isfinite(v)
        cheap = good & (cost <= cost[w] * (1 + 1e-12) + 1e-15)
        e = int(np.flatnonzero(cheap)[np.argmin(v[cheap])])
        better = good & (v <= v[w])
        q = int(np.flatnonzero(better)[np.argmin(cost[better])])
        out[name] = {"rms_w_optimum": {"design": design(w), "cost": float(cost[w]), "mse_r": float(v[w])},
                     "equal_cost": {"design": design(e), "cost": float(cost[e]), "mse_r": float(v[e])},
                     "mse_r_ratio": float(v[e] / v[w]),
                     "equal_quality": {"design": design(q), "cost": float(cost[q]), "mse_r": float(v[q])},
                     "cost_saving": float(1 - cost[q] / cost[w]) if cost[w] > 0 else 0.0}
    return out


def tradeoff_json(ds: xr.Dataset, levels: int) -> dict:
    """``tradeoff.json``: :func:`front`, :func:`end_to_end_gain` (``end_to_end_vs_rms_w``) and every invalid design
    with its reason."""
    res = front(ds, levels)
    res["end_to_end_vs_rms_w"] = end_to_end_gain(ds)
    names = res["parameters"]
    reasons = ds["reason"].values.reshape(-1)
    grids = np.meshgrid(*(ds[n].values for n in names), indexing="ij")
    res["invalid_designs"] = [{"design": {n: float(g.reshape(-1)[i]) for n, g in zip(names, grids)},
                               "reason": str(reasons[i])} for i in np.flatnonzero(reasons != "")]
    return res


def tradeoff_figure(ds: xr.Dataset, res: dict, out_dir: Path, title: str) -> Path:
    """Every criterion against the cost: each valid design a dot, the optima per cost level a line (png, svg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .figures import _save

    cols = _criteria_columns(ds)
    cost = ds["cost"].values.reshape(-1)
    valid = ds["valid"].values.reshape(-1)
    n = len(cols)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.3 * nrow), squeeze=False)
    for ax, (name, (v, sense)) in zip(axes.flat, cols.items()):
        ax.scatter(cost[valid], v[valid], s=8, color="0.6", label="grid designs")
        ok = valid & np.isfinite(v)
        order = np.argsort(cost[ok], kind="stable")
        c_sorted, v_sorted = cost[ok][order], v[ok][order]
        best = np.minimum.accumulate(v_sorted) if sense == "min" else np.maximum.accumulate(v_sorted)
        ax.step(c_sorted, best, where="post", color="C1", label="best design at cost <= C_a (the front)")
        u = res["unconstrained"][name]
        if u is not None:
            ax.plot([u["cost"]], [u["value"]], "o", color="C3", label="unconstrained optimum")
        unit = CRITERIA[name.split("@")[0]].units
        ax.set_xlabel("asphere cost C_a (RMS slope departure)")
        base, _, at = name.partition("@")
        if CRITERIA[base].per_snr:  # the first SNR's column carries the bare name (as lenssim optimum names it)
            at = at or f"{float(ds['snr'].values[0]):g}"
            label = f"{base} at {at} dB"
        else:
            label = base
        ax.set_ylabel(label if unit.startswith("1") else f"{label} ({unit})")
        ax.set_title(("lower" if sense == "min" else "higher") + " is better", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, out_dir, "tradeoff")


def design_prescription(run: LensTradeoffRun, design: dict) -> Prescription:
    """The prescription of one design of ``run`` (``{name: value}``), its solves applied and its image shift folded
    into the last thickness (a file that stands alone: ``--lens`` on every command)."""
    q, shift = solve_design(run.prescription, {run.parameter(k): v for k, v in design.items()}, hold=run.hold,
                            image=run.image)
    surfs = list(q.surfaces)
    surfs[-1] = replace(surfs[-1], thickness_mm=surfs[-1].thickness_mm + shift)
    label = ", ".join(f"{k} = {v:.6g}" for k, v in design.items())
    return replace(q, surfaces=tuple(surfs), name=f"{q.name or run.lens} ({label})",
                   notes=(q.notes + " " if q.notes else "") + f"lenssim tradeoff design: {label}; holds "
                   f"{', '.join(run.hold) or 'none'}; image plane {run.image}.")


def write_design_files(run: LensTradeoffRun, res: dict, folder: Path) -> dict[str, str]:
    """Each criterion's unconstrained optimum as a TOML prescription ``folder/NAME.toml`` (``@`` written ``_at_``):
    ``{criterion: file name}``."""
    from lenssim.io.prescription_file import write_prescription_toml

    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, u in res["unconstrained"].items():
        if u is None:
            continue
        fname = name.replace("@", "_at_") + ".toml"
        write_prescription_toml(design_prescription(run, u["design"]), folder / fname)
        out[name] = f"{folder.name}/{fname}"
    return out
