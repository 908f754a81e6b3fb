"""The explorer's computations (issue 32): what each control of ``lenssim explore`` changes, as pure functions of the
controls' values, with caches, so that the web page (:mod:`lenssim_cli.explore`) only lays them out and so that they
are tested and timed without a browser.

An :class:`Explorer` holds one lens, one camera and one photo; its update functions return plain data and PNG bytes:

* :meth:`Explorer.criteria`: the design's criteria (MSE_R per SNR, MSE_S, RMS_W, Strehl, MTF50, cost),
* :meth:`Explorer.optics_figure`: PSFs across the field (log scale, axes in um) and MTF curves per field angle,
* :meth:`Explorer.cost_map`: a criterion over the plane of two free parameters with iso-cost curves, the named designs
  and the selected one (the map from a sweep file, or computed once on a coarse grid, :meth:`Explorer.compute_map`),
* :meth:`Explorer.photo_panel`: a crop of the photo at a clicked position through the chosen camera chain: ideal, sensor
  image and restored image with PSNR/SSIM,
* :meth:`Explorer.restoration_lab`: two restoration methods side by side on the same noisy crop, and a manufactured
  lens restored with the nominal PSFs and with its own,
* :func:`command_line`: the ``lenssim simulate`` command that reproduces the photo panel.

The lens is one description, its free parameters the sliders (:class:`FreeParameter`, a design :class:`Controls`):

* the paper's singlet (no ``prescription``): its free parameters are :class:`lenssim.model.design.Design`'s (``s``,
  ``Q_back``, ``Q_front``, ``focus_shift_um``; their lens names ``E1.bending``, ``S2.conic``, ... are the same
  parameters), its glass a control, and its numbers the batched closed forms, the fast path (:func:`lenssim.evaluate`,
  :class:`lenssim.LensPSF`; the map over the paper's (s, Q_back) plane, or a ``lenssim sweep``'s);
* any lens (``lenssim explore --lens LENS --vary NAME=LO:HI ...``) with the free parameters named as ``lenssim
  tradeoff --lens`` names them, every number the command line's for the same design (docs/explore.md): the criteria and
  the map ``tradeoff --lens``'s (:func:`lenssim_studies.tradeoff._score`), the photo ``simulate --lens``'s (the
  exported command names the design's lens file, :meth:`Explorer.lens_toml`), the restoration lab's manufactured lens
  a centred copy drawn from the per-surface grade (a decentred lens's PSFs are known along one azimuth only).

PSF providers are cached by design (and lens sample), simulated crops by everything they depend on, so a control
changes only what depends on it.

The page runs these functions in worker threads, one page's photo beside another's: the caches are safe to share
between threads; each photo shown is a :class:`ShownPhoto` whose tag keys every result made from it (a result of a
photo never answers for another, whichever thread finishes first); the long ones (:meth:`Explorer.photo_panel`,
:meth:`Explorer.restoration_lab`) take a ``cancel`` event, checked between their steps (:class:`Cancelled`).
"""

from __future__ import annotations

import io
import itertools
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from lenssim import AsBuiltPSF, Camera, Design, LensPSF, PSFProvider, evaluate
from lenssim.model.design import PARAMETERS, parameter_name
from lenssim.model.numerics import FAST_NUMERICS, Numerics
from lenssim.model.prescription import Prescription
from lenssim.model.tolerances import GRADES, SurfaceTolerances
from lenssim.optics.psf_provider import DerivedPSF
from pipeline.photo import Photo

from .tradeoff import (MAX_GRID_PARAMETERS, LensTradeoffRun, _score, design_prescription, photo_field,
                       sequential_provider)
from .paper import PAPER, PAPER_CAMERA, PAPER_DESIGNS

__all__ = ["Explorer", "Controls", "DesignControls", "FreeParameter", "PhotoControls", "Slider", "ShownPhoto",
           "Cancelled", "command_line", "figure_png", "psf_window_px", "ensquared_half_width", "EXPLORE_CROP_PX",
           "SINGLET_FREE", "SINGLET_MAP_VALUES", "LENS_MAP_VALUES", "PSF_ANGLES_DEG", "LENS_PSF_FIELDS",
           "LENS_EXPORT_FILE", "SLIDER_STEPS", "CACHE_ENTRIES"]

EXPLORE_CROP_PX = 256
"""Side (px) of the photo panel's crop."""
SINGLET_MAP_VALUES = {"Q_back": 15, "s": 13}
"""Values per axis of the singlet's cost map over its sliders' ranges when no sweep file is given: 195 designs, ~1 min
once."""
LENS_MAP_VALUES = 9
"""Values per axis of a lens's cost map (9 x 9 = 81 designs, computed once in the background)."""
PSF_ANGLES_DEG = (0.0, 4.0, 8.0, 12.0)
"""Field angles (deg) of the singlet's PSF and MTF panel."""
LENS_PSF_FIELDS = (0.0, 1 / 3, 2 / 3, 1.0)
"""Field angles of a lens's PSF and MTF panel, as fractions of the lens's largest."""
SLIDER_STEPS = 100
"""Steps across a free parameter's range when its step is not given."""
LENS_EXPORT_FILE = "explored_lens.toml"
"""The name the exported command gives a lens's design file (downloaded from the page)."""
NO_AXIS = "(one free parameter)"
"""The map's vertical axis when the lens has one free parameter."""
PSF_WINDOW_ENERGY = 0.99
"""Fraction of each PSF's energy inside the square window the PSF panels share (sized to the widest PSF shown)."""
PSF_WINDOW_MARGIN = 1.5
"""The shared window's half-width is this times the widest PSF's :data:`PSF_WINDOW_ENERGY` half-width, so that the
faint edge of the PSF is seen inside it."""
PSF_WINDOW_MIN_PX = 8
"""Smallest half-width (samples) of the PSF window: a sharp PSF still shows its first rings."""
PSF_DECADES = 5.0
"""Decades of the PSF panels' shared log10 colour scale, below the brightest sample shown."""
CACHE_ENTRIES = 64
"""Results kept per cache (least recently used dropped)."""
PSF_CACHE_REQUESTS = 96
"""PSF requests (each a batch of a few windows' PSFs, ~1 MB each) a design's provider keeps for the next picture: a 256 px
crop asks for about 40."""
BLUR_CACHE_REGIONS = 8
"""Blurred crop regions (each the crop and the restoration's reach, ~10-30 MB) a design's provider keeps: a new ISO,
seed, chain or restoration of the same crop skips the blur."""
MAP_CRITERIA = ("mse_r", "mse_s", "rms_w", "strehl", "mtf50", "cost")


class Cancelled(Exception):
    """A computation stopped between two of its steps because its ``cancel`` event was set (nothing is kept)."""


def _stop_if(cancel: threading.Event | None) -> None:
    """Raise :class:`Cancelled` when ``cancel`` is set (between the steps of a long computation)."""
    if cancel is not None and cancel.is_set():
        raise Cancelled()


class _LRU(OrderedDict):
    """A dict that keeps its last ``size`` entries used (:data:`CACHE_ENTRIES` by default), safe to share between
    threads (two threads missing the same key both make it; the last one made is kept)."""

    def __init__(self, size: int = CACHE_ENTRIES):
        super().__init__()
        self.size = size
        self._guard = threading.RLock()

    def __setitem__(self, key, value):
        with self._guard:
            super().__setitem__(key, value)
            while len(self) > self.size:
                self.popitem(last=False)

    def get(self, key, default=None):
        with self._guard:
            return super().get(key, default)

    def clear(self):
        with self._guard:
            super().clear()

    def get_or(self, key, make):
        """The entry ``key``, made by ``make()`` (and kept) when missing; ``make`` runs without the lock."""
        with self._guard:
            if key in self:
                self.move_to_end(key)
                return self[key]
        value = make()
        self[key] = value
        return value


class _Tagged:
    """The part of a blurred-region cache (:attr:`_CachedPSF.blurred`) that belongs to one photo (its tag prefixed to
    every key): :func:`pipeline.simulate.simulate_crops` takes it as its ``blur_cache``."""

    def __init__(self, lru: _LRU, tag: int):
        self.lru, self.tag = lru, tag

    def get(self, key, default=None):
        return self.lru.get((self.tag, key), default)

    def __contains__(self, key) -> bool:
        with self.lru._guard:
            return (self.tag, key) in self.lru

    def __setitem__(self, key, value):
        self.lru[(self.tag, key)] = value


class _CachedPSF(DerivedPSF):
    """A PSF provider whose PSFs are kept (the last :data:`PSF_CACHE_REQUESTS` requests): the blur and the restoration
    ask for the same windows' PSFs, and so does every ISO, seed and chain of the same crop. ``blurred`` keeps the
    blurred regions of its crops (:func:`pipeline.simulate.simulate_crops`'s ``blur_cache``, through
    :class:`_Tagged`: keyed by the photo too)."""

    def __init__(self, base: PSFProvider):
        self.base = base
        self._kept = _LRU(PSF_CACHE_REQUESTS)
        self.blurred = _LRU(BLUR_CACHE_REGIONS)

    def psf_at_pixels(self, rows, cols, optical_center, n, *, centered=True, dtype=None, device=None):
        if dtype == torch.float64:  # not the passes' (float32): e.g. the blur zones' estimate, ~40 MB a request
            return self.base.psf_at_pixels(rows, cols, optical_center, n, centered=centered, dtype=dtype, device=device)
        key = (tuple(torch.as_tensor(rows).tolist()), tuple(torch.as_tensor(cols).tolist()),
               tuple(float(v) for v in optical_center), int(n), bool(centered), dtype, str(device))
        return self._kept.get_or(key, lambda: self.base.psf_at_pixels(rows, cols, optical_center, n,
                                                                      centered=centered, dtype=dtype, device=device))


@dataclass(frozen=True)
class Slider:
    """One design control of the page: its key (the value's name in :meth:`Explorer.controls_from`), label (with the
    unit), range, step and first value."""

    key: str
    label: str
    start: float
    end: float
    step: float
    value: float


@dataclass(frozen=True)
class FreeParameter:
    """A free parameter of the lens and its slider: its name (made canonical by the explorer: the singlet's
    :data:`lenssim.model.design.PARAMETERS` names, any lens's :func:`lenssim.model.lens_parameters.parse_parameter`
    names), range ``start`` .. ``end`` and ``step`` in the parameter's unit; the slider's ``label`` and the map axis's
    ``description`` and ``unit`` ("": the parameter's own)."""

    name: str
    start: float
    end: float
    step: float
    label: str = ""
    description: str = ""
    unit: str = ""

    def __post_init__(self):
        if not (math.isfinite(self.start) and math.isfinite(self.end) and self.start < self.end):
            raise ValueError(f"--vary {self.name}={self.start:g}:{self.end:g} is not allowed: finite LO < HI")
        if not (math.isfinite(self.step) and 0 < self.step <= self.end - self.start):
            raise ValueError(f"--vary {self.name}: step {self.step:g} is not allowed: more than 0 and at most HI - LO")


SINGLET_FREE = (
    FreeParameter("s", -2.0, 1.0, PARAMETERS["s"].step, "s (bending)", "bending"),
    FreeParameter("Q_back", -10.0, 1.2, PARAMETERS["Q_back"].step, "Q_back (back conic)"),
    FreeParameter("Q_front", -10.0, 10.0, PARAMETERS["Q_front"].step, "Q_front (front conic)"),
    FreeParameter("focus_shift_um", -500.0, 500.0, PARAMETERS["focus_shift_um"].step, "focus shift [um]"))
"""The paper's singlet's sliders, its :class:`lenssim.model.design.Design` parameters over the ranges the page offers
(the map's plane: s from -2 to 1, Q_back from -10 to 1.2), each by its registry's step."""
PAPER_PLANE = ("Q_back", "s")
"""The singlet's cost map's (horizontal, vertical) parameters: the paper's plane."""


@dataclass(frozen=True)
class Controls:
    """The design the sliders select: ``((name, value), ...)`` of the lens's free parameters, and the singlet's glass (a
    catalogue name, ``configs/glasses.toml``; ``"paper"``: the paper's non-dispersive n = 1.5; a lens file names its own
    glasses)."""

    values: tuple[tuple[str, float], ...]
    glass: str = "paper"

    def as_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in self.values}

    def key(self) -> tuple:
        return tuple((n, round(float(v), 12)) for n, v in self.values) + (self.glass,)


class DesignControls(Controls):
    """The singlet's controls by its parameters' names (by default the paper's end-to-end design, a spherical front
    surface, the paraxial focus and the paper's glass)."""

    def __init__(self, s: float = PAPER_DESIGNS["end_to_end_paper"].values["s"].item(),
                 Q_back: float = PAPER_DESIGNS["end_to_end_paper"].values["Q_back"].item(), Q_front: float = 0.0,
                 focus_shift_um: float = 0.0, glass: str = "paper"):
        super().__init__((("s", float(s)), ("Q_back", float(Q_back)), ("Q_front", float(Q_front)),
                          ("focus_shift_um", float(focus_shift_um))), glass)


@dataclass(frozen=True, eq=False)
class ShownPhoto:
    """A photo the explorer simulates (:class:`pipeline.photo.Photo`), its source as shown, and a tag of its own: every
    result made from it is cached under the tag, so that two photos (two pages, or one page before and after a pick)
    never share a result, even when they have the same size."""

    photo: Photo
    source: str
    tag: int

    @property
    def shape(self) -> tuple:
        return tuple(self.photo.shape)


_PHOTO_TAGS = itertools.count(1)
"""Tags of :class:`ShownPhoto` (each photo its own)."""


@dataclass(frozen=True)
class PhotoControls:
    """The photo panel's controls: crop centre (row, col, px; None: the frame's centre), ISO, seed, the camera chain
    (sensor preset, CFA, demosaicing), the restoration (``NAME[:key=value,...]``) and a full well (e-) overriding the
    ISO's."""

    center: tuple[int, int] | None = None
    iso: int = 100
    seed: int = 0
    sensor: str | None = None
    cfa: str = "none"
    demosaic: str = "Malvar2004"
    restore: str = "wiener"
    full_well: float | None = None
    """Electrons at the image's peak, in place of the ISO's full well (None: the ISO's)."""


def _png(rgb: torch.Tensor) -> bytes:
    """8-bit sRGB PNG bytes of a linear image ``(1, C, H, W)``."""
    import matplotlib.image

    from pipeline.colour_space import linear_to_srgb

    a = linear_to_srgb(rgb.clamp(0, 1))[0].detach().to("cpu", torch.float32).numpy()
    a = np.repeat(a, 3, axis=0) if a.shape[0] == 1 else a
    buf = io.BytesIO()
    matplotlib.image.imsave(buf, np.ascontiguousarray(a.transpose(1, 2, 0)), format="png")
    return buf.getvalue()


def ensquared_half_width(psf: torch.Tensor, fraction: float) -> int:
    """The smallest half-width ``h`` (samples) whose square ``(2h + 1)`` samples on a side, centred at ``[n//2, n//2]``,
    holds ``fraction`` of the PSF's sum (``psf``: ``(n, n)``, non-negative; the array's half-size when no square
    inside it does)."""
    p = psf.detach().to("cpu", torch.float64)
    n = p.shape[-1]
    c = n // 2
    idx = (torch.arange(n) - c).abs()
    ring = torch.maximum(idx[:, None], idx[None, :])  # the square each sample lies on
    held = torch.bincount(ring.flatten(), weights=p.flatten()).cumsum(0)
    total = float(held[-1])
    if not total > 0:
        return 0
    inside = torch.nonzero(held >= fraction * total)
    return int(inside[0]) if len(inside) else c


def psf_window_px(psfs) -> int:
    """Half-width (samples) of the square window the PSF panels share: :data:`PSF_WINDOW_MARGIN` times the widest
    PSF's :data:`PSF_WINDOW_ENERGY` half-width (:func:`ensquared_half_width`), at least :data:`PSF_WINDOW_MIN_PX`, at
    most what the arrays hold."""
    widest = max(ensquared_half_width(p, PSF_WINDOW_ENERGY) for p in psfs)
    room = min((p.shape[-1] - 1) // 2 for p in psfs)
    return int(min(room, max(PSF_WINDOW_MIN_PX, math.ceil(PSF_WINDOW_MARGIN * widest))))


def psf_mtf_figure(psfs, angles_deg, pitch_um: float, title: str) -> bytes:
    """PNG: each PSF (``(n, n)``, centred at ``[n//2, n//2]``) in log10 on one window sized to the widest of them
    (:func:`psf_window_px`; axes in um, its size in the title) and one colour scale (:data:`PSF_DECADES` below the
    brightest sample), labelled by its field angle (deg), and the MTFs along x and y (line spreads' transforms) against
    cycles/mm."""
    from matplotlib.figure import Figure  # no pyplot: the page draws in worker threads

    fig = Figure(figsize=(3.0 * (len(psfs) + 1), 3.2), layout="constrained")
    axes = fig.subplots(1, len(psfs) + 1)
    h = psf_window_px(psfs)
    e = (h + 0.5) * pitch_um  # the window's edge: the outer samples' edges
    shown = [p[p.shape[-1] // 2 - h:p.shape[-1] // 2 + h + 1, p.shape[-1] // 2 - h:p.shape[-1] // 2 + h + 1]
             for p in psfs]
    top = math.log10(max(float(s.max()) for s in shown) or 1e-300)
    for ax, a, p, s in zip(axes, angles_deg, psfs, shown):
        n = p.shape[-1]
        im = ax.imshow(torch.log10(s.clamp_min(1e-300)).numpy(), cmap="magma", vmin=top - PSF_DECADES, vmax=top,
                       extent=[-e, e, e, -e])
        ax.set_title(f"PSF at {a:.3g} deg", fontsize=9)
        ax.set_xlabel("x [um]", fontsize=8)
        ax.tick_params(labelsize=7)
        f = torch.fft.rfftfreq(n, d=pitch_um * 1e-3)  # cycles/mm
        mtf_x = torch.fft.rfft(p.sum(0)).abs()
        mtf_y = torch.fft.rfft(p.sum(1)).abs()
        axes[-1].plot(f.numpy(), (mtf_x / mtf_x[0]).numpy(), label=f"{a:.3g} deg, x")
        axes[-1].plot(f.numpy(), (mtf_y / mtf_y[0]).numpy(), "--", label=f"{a:.3g} deg, y")
    fig.colorbar(im, ax=axes[len(psfs) - 1], label="log10 PSF (each sample)", shrink=0.8)
    axes[0].set_ylabel("y [um]", fontsize=8)
    axes[-1].set_xlabel("spatial frequency [cycles/mm]", fontsize=8)
    axes[-1].set_ylabel("MTF", fontsize=8)
    axes[-1].set_title("MTF across the field", fontsize=9)
    axes[-1].set_ylim(0, 1.02)
    axes[-1].legend(fontsize=6, ncol=2)
    axes[-1].tick_params(labelsize=7)
    fig.suptitle(f"{title}\nwindow +-{e:.3g} um (each PSF's {PSF_WINDOW_ENERGY:.0%} energy square inside, "
                 f"x{PSF_WINDOW_MARGIN:g}); one colour scale", fontsize=9)
    return figure_png(fig)


def figure_png(fig, dpi: int = 90) -> bytes:
    """PNG bytes of a matplotlib figure (``dpi``: dots per inch)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


@dataclass
class Explorer:
    """The explorer's state and caches for one lens, one camera and one photo (linear ``(1, C, H, W)``, or a
    :class:`pipeline.photo.Photo`; None: the generated scene is made at the sensor's size on first use).

    No ``prescription``: the paper's singlet (``camera``'s lens) with the sliders ``free`` (:data:`SINGLET_FREE` by
    default) at ``start`` (:class:`DesignControls` by default). Else the lens ``prescription`` (named ``lens`` by the
    user) with the free parameters ``free`` (1 to :data:`lenssim_studies.tradeoff.MAX_GRID_PARAMETERS`; the
    sliders start at the file's design), the solves ``hold``, ``image`` and the even aspheres ``aspherize`` (1-based)
    as ``lenssim tradeoff --lens`` takes them, and ``pixel_pitch_um`` the sensor's pitch (um) instead of the defaults.
    ``map_values``: values per axis of the cost map (:data:`SINGLET_MAP_VALUES`, :data:`LENS_MAP_VALUES` by default)."""

    camera: Camera = PAPER_CAMERA
    photo: object = None
    photo_source: str = "generated scene"
    snr_db: tuple = tuple(PAPER.snr_db)
    rho0: float = PAPER.rho0
    map_data: dict | None = None
    prescription: Prescription | None = None
    lens: str = ""
    free: tuple[FreeParameter, ...] = ()
    start: Controls | None = None
    hold: tuple[str, ...] = ()
    image: str = "file"
    aspherize: tuple[int, ...] = ()
    pixel_pitch_um: float | None = None
    numerics: Numerics = FAST_NUMERICS
    map_values: int | None = None
    _caches: dict = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    map_progress: tuple = (0, 0)
    _shown: ShownPhoto | None = field(default=None, repr=False)
    _photo_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self):
        if self.map_values is not None and not 2 <= self.map_values <= 101:
            raise ValueError(f"map_values={self.map_values} is not allowed: 2 to 101 values per axis")
        if self.prescription is None:
            self.free = tuple(self._described(f) for f in self.free or SINGLET_FREE)
            self.start = DesignControls() if self.start is None else self.start
            self.named = {name: d.floats() for name, d in PAPER_DESIGNS.items()}
            self.map_axes = PAPER_PLANE
            return
        from lenssim.model.lens_parameters import parameter_values
        from lenssim.optics.sequential import SequentialLens

        if not 1 <= len(self.free) <= MAX_GRID_PARAMETERS:
            raise ValueError(f"{len(self.free)} free parameters are not allowed: 1 to {MAX_GRID_PARAMETERS} (--vary)")
        if self.pixel_pitch_um is not None and not (math.isfinite(self.pixel_pitch_um) and self.pixel_pitch_um > 0):
            raise ValueError(f"--pixel-pitch {self.pixel_pitch_um:g} is not allowed: a pixel pitch in um, > 0")
        seq = SequentialLens(self.prescription)
        seq.check_aperture()
        if self.pixel_pitch_um is None and max(self.prescription.fields) <= 0:
            raise ValueError(f"--lens {self.lens} has only the axial field: give --pixel-pitch UM for the sensor")
        self.free = tuple(self._described(f) for f in self.free)
        file_values = parameter_values(self.prescription, [self._parameter(f.name) for f in self.free])
        # the sliders start at the file's design (each value kept inside its range)
        self.file_values = {f.name: float(file_values[f.name]) for f in self.free}
        self.start = Controls(tuple((f.name, min(max(self.file_values[f.name], f.start), f.end)) for f in self.free))
        self.named = {"the file's design": self.file_values}
        self.map_axes = (self.free[0].name, self.free[1].name if len(self.free) > 1 else NO_AXIS)
        if self.pixel_pitch_um is None:  # tradeoff's sensor: the nominal lens's Nyquist pitch, point samples
            pitch = self.prescription.primary_wavelength_um * seq.paraxial().working_f_number / 2
            self._criteria_pitch, self._sampling = pitch, "point"
        else:
            self._criteria_pitch, self._sampling = float(self.pixel_pitch_um), "area"
        self.tradeoff_run(self.start)  # checks the solves and the image plane (one line each)

    def _cache(self, name: str) -> _LRU:
        return self._caches.setdefault(name, _LRU())

    def _parameter(self, name: str):
        """The free parameter ``name`` of the lens (its canonical name, description and unit; a one-line
        ``ValueError`` listing the valid names otherwise)."""
        if self.prescription is None:
            return PARAMETERS[parameter_name(name)]
        from lenssim.model.lens_parameters import parse_parameter

        return parse_parameter(self.prescription, name, aspherize=self.aspherize)

    def _described(self, f: FreeParameter) -> FreeParameter:
        p = self._parameter(f.name)
        return replace(f, name=p.name, description=f.description or p.description, unit=f.unit or p.unit)

    def tradeoff_run(self, controls: Controls, grid: dict | None = None) -> LensTradeoffRun:
        """Any lens: the one-design trade-off run of ``controls`` (``grid``: ``{name: values}`` instead for those
        parameters), whose :func:`lenssim_studies.tradeoff._score` gives the criteria."""
        vals = controls.as_dict()
        vary = tuple((f.name, tuple(grid[f.name]) if grid and f.name in grid else (vals[f.name],)) for f in self.free)
        return LensTradeoffRun(self.prescription, self.lens, vary, tuple(self.snr_db), self.rho0, self._criteria_pitch,
                               self._sampling, self.numerics, hold=self.hold, image=self.image,
                               aspherize=self.aspherize, coarse=True)

    # ---- what the page's design controls are ---------------------------------------------------------------------
    def sliders(self, start: Controls | None = None) -> list[Slider]:
        """The design sliders, at ``start``'s values (the explorer's :attr:`start` otherwise)."""
        s = (self.start if start is None else start).as_dict()
        return [Slider(f.name, f.label or (f"{f.name} [{f.unit}]" if f.unit not in ("", "1") else f.name), f.start,
                       f.end, f.step, s[f.name]) for f in self.free]

    def controls_from(self, values: dict, glass: str = "paper") -> Controls:
        """The design of the sliders' ``{key: value}`` (keys of :meth:`sliders`) and the glass (the singlet's)."""
        return Controls(tuple((f.name, float(values[f.name])) for f in self.free), glass)

    def map_ranges(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The ranges of the map's (horizontal, vertical) parameters (:attr:`map_axes`: slider keys, also the keys of
        :attr:`map_data`), as their sliders give them (the map is drawn over these from the start, before it is
        computed)."""
        ranges = {f.name: (f.start, f.end) for f in self.free}
        return tuple(ranges.get(k, (-0.5, 0.5)) for k in self.map_axes)

    def map_point(self, controls: Controls) -> tuple[float, float]:
        """Where ``controls`` sits on the map (horizontal, vertical)."""
        v = controls.as_dict()
        x, y = self.map_axes
        return (v[x], v.get(y, 0.0))

    def named_points(self) -> dict[str, tuple[float, float]]:
        """The named designs marked on the map: ``{name: (horizontal, vertical)}``."""
        x, y = self.map_axes
        return {name: (v[x], v.get(y, 0.0)) for name, v in self.named.items()}

    def axis_label(self, key: str) -> str:
        """A map axis's label."""
        f = next((f for f in self.free if f.name == key), None)
        if f is None:
            return key
        return f"{key} ({f.description}" + (f", {f.unit})" if f.unit not in ("", "1") else ")")

    def map_note(self) -> str:
        """What the map's designs hold fixed (shown under the map)."""
        if self.prescription is None:
            return "the paper's glass, n = 1.5"
        rest = [f"{n} = {v:.6g}" for n, v in self.start.values[2:]]
        return f"{self.lens}" + (f"; {', '.join(rest)}" if rest else "")

    def design_label(self, controls: Controls) -> str:
        if self.prescription is None:
            return Design(controls.as_dict()).label() + ("" if controls.glass == "paper" else f", {controls.glass}")
        return f"{self.lens}: " + ", ".join(f"{n} = {v:.5g}" for n, v in controls.values)

    # ---- design ---------------------------------------------------------------------------------------------------
    def camera_for(self, controls: Controls) -> Camera:
        """The singlet's camera with the lens made of ``controls.glass`` (the explorer's own camera for ``"paper"``)."""
        if controls.glass == "paper":
            return self.camera

        def make():
            from lenssim import Lens

            lens = Lens.from_dict({**self.camera.lens.to_dict(), "glass": controls.glass, "refractive_index": None})
            return replace(self.camera, lens=lens)
        return self._cache("camera").get_or(controls.glass, make)

    def check(self, controls: Controls):
        """The design of ``controls``, checked (a one-line ``ValueError`` when it cannot be made): the singlet's
        :class:`lenssim.model.design.Design`, any lens's solved ``(prescription, SequentialLens)``."""
        if self.prescription is None:
            d = Design(controls.as_dict())
            self.camera_for(controls).lens.check_design(d.to(torch.float64))
            return d

        def make():
            from lenssim.optics.lens_solves import solve_design
            from lenssim.optics.sequential import SequentialLens

            values = {self._parameter(n): v for n, v in controls.values}
            q, shift = solve_design(self.prescription, values, hold=self.hold, image=self.image)
            seq = SequentialLens(q, image_shift_mm=shift)
            seq.check_aperture()
            return q, seq
        return self._cache("solved").get_or(controls.key(), make)

    def criteria(self, controls: Controls) -> dict:
        """``{label: value}``: MSE_R at each SNR, MSE_S at the reference SNR, RMS_W (waves), Strehl, MTF50
        (cycles/mm) and the cost C_a, averaged over the field: the singlet's as :func:`lenssim.evaluate` gives them, any
        lens's as ``lenssim tradeoff --lens`` does (with its focal length, mm)."""
        def make():
            if self.prescription is None:
                r = evaluate(self.camera_for(controls), self.check(controls), self.snr_db, rho0=self.rho0)
            else:
                self.check(controls)
                r = _score(self.tradeoff_run(controls), 0)
                if r["reason"]:
                    raise ValueError(f"this design is refused: {r['reason']}")
            out = {f"MSE_R at {s:g} dB": float(v) for s, v in zip(self.snr_db, r["mse_r"])}
            ref = min(range(len(self.snr_db)), key=lambda i: abs(self.snr_db[i] - PAPER.reference_snr_db))
            out[f"MSE_S at {self.snr_db[ref]:g} dB"] = float(r["mse_s"][ref])
            out.update({"RMS_W [waves]": float(r["rms_w"]), "Strehl": float(r["strehl"]),
                        "MTF50 [cycles/mm]": float(r["mtf50"]), "cost C_a": float(r["cost"])})
            if self.prescription is not None:
                out["EFL [mm]"] = float(r["efl_mm"])
            return out
        return self._cache("criteria").get_or(controls.key(), make)

    def optics_figure(self, controls: Controls, angles=None) -> bytes:
        """PNG: the PSF (log10, axes in um) at each field angle of ``angles`` (deg; the singlet's
        :data:`PSF_ANGLES_DEG` along the sensor's diagonal, a lens's :data:`LENS_PSF_FIELDS` of its largest field along
        the image's x axis, on the criteria's sensor) and the MTFs (x and y) there against cycles/mm."""
        if angles is None:
            angles = (PSF_ANGLES_DEG if self.prescription is None
                      else tuple(f * max(self.prescription.fields) for f in LENS_PSF_FIELDS))
        angles = tuple(angles)

        def make():
            psfs, shown, pitch, samples = (self._singlet_psfs if self.prescription is None
                                           else self._lens_psfs)(controls, angles)
            return psf_mtf_figure(psfs, shown, pitch, f"{self.design_label(controls)}: PSFs (log10, {samples}) and MTFs")
        return self._cache("optics").get_or(controls.key() + angles, make)

    def _singlet_psfs(self, controls: Controls, angles) -> tuple:
        """The singlet's PSFs at ``angles`` along the sensor's diagonal, those angles, the pitch (um) and its words."""
        from lenssim import psf_at

        d = self.check(controls)
        cam = self.camera_for(controls)
        pitch = cam.sensor.pixel_pitch_um
        azi = math.atan2(cam.sensor.height_px, cam.sensor.width_px)
        psfs = []
        for a in angles:
            r = float(cam.geometry.image_height_mm(a))
            psfs.append(psf_at(cam, d, r * math.cos(azi), r * math.sin(azi))[0])
        return psfs, angles, pitch, f"{pitch:g} um pixels"

    def _lens_psfs(self, controls: Controls, angles) -> tuple:
        """A lens's PSFs on the criteria's sensor at the whole pixels nearest ``angles`` along the image's x axis, the
        angles they are at, the pitch (um) and its words."""
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
        return list(psfs), shown, pitch, f"{pitch:.4g} um {kind}"

    # ---- the cost map --------------------------------------------------------------------------------------------
    def _axis_values(self, name: str) -> np.ndarray:
        """The map's values of the free parameter ``name`` over its slider's range."""
        if name == NO_AXIS:
            return np.zeros(1)
        f = next(f for f in self.free if f.name == name)
        count = self.map_values or (SINGLET_MAP_VALUES[name] if self.prescription is None else LENS_MAP_VALUES)
        return np.linspace(f.start, f.end, count)

    def compute_map(self, progress=None) -> dict:
        """The criteria on a grid of the map's two parameters (:attr:`map_axes`) over their sliders' ranges (once;
        ``progress(done, total)`` after each design): ``{x name, y name, criterion: (len(y), len(x)[, S]) arrays}``;
        designs that cannot be made are NaN. The singlet's other parameters at their defaults, any lens's at their
        first values."""
        with self._lock:
            if self.map_data is not None:
                return self.map_data
            xn, yn = self.map_axes
            xs, ys = self._axis_values(xn), self._axis_values(yn)
            S = len(self.snr_db)
            out = {xn: xs, yn: ys, **{k: np.full((len(ys), len(xs)) + ((S,) if k in ("mse_r", "mse_s") else ()), np.nan)
                                      for k in MAP_CRITERIA}}
            for done, (iy, ix, r) in enumerate((self._singlet_grid if self.prescription is None
                                                else self._lens_grid)(xs, ys), 1):
                if r is not None:
                    for k in MAP_CRITERIA:
                        out[k][iy, ix] = np.asarray(r[k])
                self.map_progress = (done, xs.size * ys.size)
                if progress is not None:
                    progress(*self.map_progress)
            self.map_data = out
            return out

    def _singlet_grid(self, xs, ys):
        """``(iy, ix, criteria or None)`` of each design of the singlet's map (:func:`lenssim.evaluate`; None: the lens
        refuses it), row by row."""
        xn, yn = self.map_axes
        for iy, yv in enumerate(ys):
            for ix, xv in enumerate(xs):
                try:  # the paper's glass
                    r = evaluate(self.camera, self.check(Controls(((xn, float(xv)), (yn, float(yv))))), self.snr_db,
                                 rho0=self.rho0)
                except ValueError:
                    r = None
                yield iy, ix, r

    def _lens_grid(self, xs, ys):
        """``(iy, ix, criteria or None)`` of each design of a lens's map (one trade-off run over the grid; None: the
        design cannot be made)."""
        xn, yn = self.map_axes
        grid = {xn: xs} if yn == NO_AXIS else {xn: xs, yn: ys}
        run = self.tradeoff_run(self.start, grid={k: tuple(float(v) for v in g) for k, g in grid.items()})
        for i in range(run.size):
            d = run.design(i)
            r = _score(run, i)
            yield (0 if yn == NO_AXIS else int(np.argmin(np.abs(ys - d[yn]))), int(np.argmin(np.abs(xs - d[xn]))),
                   None if r["reason"] else r)

    def load_map(self, ds) -> None:
        """Use a sweep's dataset (:func:`lenssim_studies.sweep.run_sweep`'s, with dimensions ``s`` and ``Q_back``)
        as the singlet's map."""
        if self.prescription is not None:
            raise ValueError("--sweep is a sweep of the paper's singlet: a lens's map is computed by the explorer")
        need = {"s", "Q_back"}
        if not need <= set(ds.dims):
            raise ValueError(f"the sweep's dimensions are {sorted(ds.dims)}: the map needs s and Q_back")
        ds = ds.transpose("s", "Q_back", ...)
        out = {"s": ds["s"].values, "Q_back": ds["Q_back"].values}
        for k in MAP_CRITERIA:
            if k in ds:
                out[k] = ds[k].values
        self.map_data = out

    def map_layer(self, criterion: str, snr_index: int) -> dict | None:
        """The map of ``criterion`` (at the SNR of ``snr_index`` for the per-SNR ones): ``{"x", "y"`` (the values of
        :attr:`map_axes`), ``"x_name", "y_name", "z"`` (len(y), len(x)), ``"log10"``: whether z is log10 of the
        criterion, ``"log10_cost"`` (same shape, NaN where refused)``}``; None while the map is not computed."""
        if criterion not in MAP_CRITERIA:
            raise ValueError(f"criterion {criterion!r} is not allowed: one of {', '.join(MAP_CRITERIA)}")
        m = self.map_data
        if m is None:
            return None
        v = m[criterion]
        if v.ndim == 3:
            v = v[..., snr_index]
        logscale = criterion in ("mse_r", "mse_s", "cost", "rms_w")
        z = np.log10(np.where(v > 0, v, np.nan)) if logscale else v
        cost = m.get("cost")
        lc = None if cost is None else np.log10(np.where(cost > 0, cost, np.nan))
        xn, yn = self.map_axes
        return {"x": m[xn], "y": m[yn], "x_name": xn, "y_name": yn, "z": z, "log10": logscale, "log10_cost": lc}

    def cost_map(self, criterion: str, snr_index: int, selected: DesignControls) -> bytes:
        """PNG: ``criterion`` (log10 where positive and spanning decades) over the (s, Q_back) plane, the cost's
        iso-cost curves, the named designs (labels outlined in white, readable on every colour) and ``selected``; a
        note while the map is not computed yet."""
        from matplotlib import patheffects
        from matplotlib.figure import Figure  # no pyplot: the page draws in worker threads

        layer = self.map_layer(criterion, snr_index)
        fig = Figure(figsize=(5.6, 4.4), layout="constrained")
        ax = fig.subplots()
        if layer is None:
            done, total = self.map_progress
            ax.text(0.5, 0.5, f"computing the map: {done} of {total or '?'} designs", ha="center", va="center")
            ax.set_axis_off()
            return figure_png(fig)
        z, logscale = layer["z"], layer["log10"]
        x, y = layer["x"], layer["y"]
        im = ax.pcolormesh(x, y, z, shading="nearest", cmap="viridis")
        fig.colorbar(im, ax=ax, label=("log10 " if logscale else "") + criterion
                     + (f" at {self.snr_db[snr_index]:g} dB" if criterion in ("mse_r", "mse_s") else ""))
        lc = layer["log10_cost"]
        if lc is not None and np.isfinite(lc).sum() > 3 and min(lc.shape) > 1 and np.nanmax(lc) > np.nanmin(lc):
            c = ax.contour(x, y, lc, levels=6, colors="w", linewidths=0.7)
            ax.clabel(c, fontsize=6, fmt=lambda v: f"C_a 1e{v:.1f}")
        for name, (px, py) in self.named_points().items():
            ax.plot(px, py, "o", mfc="none", mec="r", ms=7)
            ax.annotate(name, (px, py), fontsize=6, color="r", xytext=(3, 3), textcoords="offset points",
                        path_effects=[patheffects.withStroke(linewidth=2.5, foreground="w")])
        sx, sy = self.map_point(selected)
        ax.plot(sx, sy, "x", color="k", ms=10, mew=2, label="selected")
        ax.set_xlabel(self.axis_label(layer["x_name"]))
        ax.set_ylabel(self.axis_label(layer["y_name"]))
        ax.set_title("criterion over the design plane; white: iso-cost curves", fontsize=9)
        ax.legend(fontsize=7, loc="lower left")
        return figure_png(fig)

    # ---- photo -----------------------------------------------------------------------------------------------------
    def new_photo(self, photo, source: str) -> ShownPhoto:
        """``photo`` (linear ``(1, C, H, W)``, a :class:`pipeline.photo.Photo`, or None: the generated scene at the
        sensor's size) as a photo of its own to simulate (:class:`ShownPhoto`): what a page passes as ``photo=``."""
        if photo is None:
            from pipeline.photo import open_photo

            photo = open_photo(None, self.camera)
            source = photo.source
        if not isinstance(photo, Photo):
            photo = Photo.of(photo, source)
        return ShownPhoto(photo, source, next(_PHOTO_TAGS))

    @property
    def shown_photo(self) -> ShownPhoto:
        """The explorer's own photo (what an update function uses when no ``photo`` is passed)."""
        with self._photo_lock:
            if self._shown is None:
                self._shown = self.new_photo(self.photo, self.photo_source)
                self.photo, self.photo_source = self._shown.photo, self._shown.source
            return self._shown

    def _ideal(self, photo: ShownPhoto | None = None) -> Photo:
        return (photo or self.shown_photo).photo

    def set_photo(self, photo, source: str) -> None:
        """Make ``photo`` the explorer's own: the results of the previous one are dropped (its panels, labs, blurred
        regions; each was kept under its photo's tag, so none answers for this one)."""
        shown = self.new_photo(photo, source)
        with self._photo_lock:
            self._shown = shown
            self.photo, self.photo_source = shown.photo, shown.source
        for k in ("photo", "lab"):
            self._caches.pop(k, None)
        for prov in list(self._cache("psf").values()):
            prov.blurred.clear()

    @property
    def photo_shape(self) -> tuple:
        return self.shown_photo.shape

    def crop_box(self, center, shape=None) -> tuple[int, int, int, int]:
        """The :data:`EXPLORE_CROP_PX` box centred as near ``center`` (row, col; None: the frame's centre) as fits the
        photo (of ``shape``; the explorer's own by default)."""
        from pipeline.simulate import crop_at_pixel

        H, W = (self.photo_shape if shape is None else shape)[-2:]
        r, c = (H // 2, W // 2) if center is None else (min(max(int(center[0]), 0), H - 1),
                                                        min(max(int(center[1]), 0), W - 1))
        return crop_at_pixel((H, W), r, c, min(EXPLORE_CROP_PX, H, W))

    def _chain(self, pc: PhotoControls):
        if pc.sensor is None and pc.cfa == "none":
            return None
        from lenssim.io.sensor_file import DEFAULT_SENSOR, load_sensor
        from pipeline.camera_chain import CameraChain

        s = load_sensor(pc.sensor or DEFAULT_SENSOR)
        if pc.cfa != "none":
            s = replace(s, cfa=pc.cfa)
        return CameraChain(s, demosaic=pc.demosaic)

    def _full_well(self, pc: PhotoControls, chain, shape) -> float:
        if pc.full_well is not None:
            from pipeline.checks import check_full_well

            return check_full_well(pc.full_well, "full well")
        table = self.sensor_for(shape) if chain is None else chain.sensor
        return table.full_well_for_iso(pc.iso)

    def sensor_for(self, shape) -> object:
        """The sensor a photo of ``shape`` is simulated on (its pixels, noise and ISO table): the singlet's camera's; for
        any lens the paper's noise and ISO table, the photo's pixels at :meth:`_photo_field`'s pitch."""
        if self.prescription is None:
            return self.camera.sensor
        H, W = shape[-2:]
        return replace(PAPER_CAMERA.sensor, pixel_pitch_um=self._photo_field(shape)[0], width_px=int(W),
                       height_px=int(H))

    def _photo_field(self, shape=None) -> tuple[float, float]:
        """Any lens: the pixel pitch (um) of a photo of ``shape`` (the explorer's own by default) and the largest field
        angle its blur asks PSFs at (deg), as ``lenssim simulate --lens`` takes them."""
        from lenssim.optics.sequential import SequentialLens
        from pipeline.blur import PAPER_SCHEME

        shape = tuple(self.photo_shape if shape is None else shape)
        return self._cache("field").get_or(shape, lambda: photo_field(
            self.prescription, SequentialLens(self.prescription), shape, pitch_um=self.pixel_pitch_um,
            margin_px=PAPER_SCHEME.core))

    def _provider(self, controls: Controls, lens=None, shape=None):
        """The design's PSFs (of the manufactured ``lens``, if given: the singlet's tolerance sample, any lens's
        SequentialLens) over a photo of ``shape`` (the explorer's own by default; the singlet's: the same for every
        photo)."""
        if self.prescription is None:
            d, cam = self.check(controls), self.camera_for(controls)
            key = controls.key() + (None if lens is None else id(lens),)
            return self._cache("psf").get_or(key, lambda: _CachedPSF(LensPSF(cam, d) if lens is None
                                                                     else AsBuiltPSF(cam, d, lens)))
        shape = tuple(self.photo_shape if shape is None else shape)

        def make():
            q, seq = self.check(controls)
            pitch, amax = self._photo_field(shape)
            H, W = shape[-2:]
            return _CachedPSF(sequential_provider(q, seq if lens is None else lens, pitch_um=pitch, sampling="area",
                                                  max_field_deg=amax, width_px=int(W), height_px=int(H)))
        return self._cache("psf").get_or(controls.key() + (shape, None if lens is None else lens.cache_key()), make)

    def check_grade(self, grade: str) -> None:
        """A one-line ``ValueError`` unless ``grade`` names a tolerance grade (the singlet's; any lens's per-surface)."""
        if self.prescription is not None:
            SurfaceTolerances.grade(grade)
        elif grade not in GRADES:
            raise ValueError(f"grade {grade!r} is not allowed: one of {', '.join(GRADES)}")

    def _built_provider(self, controls: Controls, grade: str, lens_seed: int, shape=None):
        """The PSFs of one manufactured lens of ``controls``'s design (drawn from ``grade`` with ``lens_seed``; any
        lens's centred: see the module docstring)."""
        if self.prescription is None:
            return self._provider(controls, GRADES[grade].sample(1, seed=lens_seed), shape)
        from lenssim.tolerancing import manufactured_lens

        q, seq = self.check(controls)
        centred = replace(SurfaceTolerances.grade(grade), surface_decentre_um=0.0, surface_tilt_arcmin=0.0,
                          element_decentre_um=0.0, element_tilt_arcmin=0.0)
        pert = centred.sample(q, 1, seed=int(lens_seed))
        return self._provider(controls, manufactured_lens(seq, pert, 0), shape)

    def _crops(self, shown: ShownPhoto, pc: PhotoControls, cancel: threading.Event | None):
        """``(box, run)``: the crop box of ``pc`` on ``shown`` and ``run(provider, method, restoration_psf=None)``, its
        crop blurred, noised through ``pc``'s chain and restored: ``(result, method's name)`` (``cancel`` set before:
        :class:`Cancelled`)."""
        from pipeline.simulate import simulate_crops

        chain = self._chain(pc)
        fw = self._full_well(pc, chain, shown.shape)
        box = self.crop_box(pc.center, shown.shape)
        sensor = chain or self.sensor_for(shown.shape)

        def run(prov, method, restoration_psf=None):
            _stop_if(cancel)
            (r,) = simulate_crops(shown.photo, prov, fw, [box], seed=pc.seed, methods=(method,), sensor=sensor,
                                  restoration_psf=restoration_psf, blur_cache=_Tagged(prov.blurred, shown.tag),
                                  blur_zones="auto")
            return r, r.methods[0]
        return box, run

    def photo_panel(self, controls: Controls, pc: PhotoControls, *, photo: ShownPhoto | None = None,
                    cancel: threading.Event | None = None) -> dict:
        """The crop at ``pc.center`` of ``photo`` (the explorer's own by default) through the design and the chain:
        ``{"box", "field_deg", "png": {"ideal", "sensor", "restored"}, "scores": {"sensor", "restored"}}`` (PSNR dB
        and SSIM in sRGB). ``cancel`` set before the crop is simulated: :class:`Cancelled`."""
        shown = photo or self.shown_photo

        def make():
            box, run = self._crops(shown, pc, cancel)
            r, name = run(self._provider(controls, shape=shown.shape), pc.restore)
            return {"box": box, "field_deg": r.field_deg,
                    "png": {"ideal": _png(r.ideal), "sensor": _png(r.sensor), "restored": _png(r.images[name])},
                    "scores": {"sensor": r.scores["sensor"], "restored": r.scores[name]}}
        return self._cache("photo").get_or((shown.tag, controls.key(), pc), make)

    def restoration_lab(self, controls: Controls, pc: PhotoControls, method_a: str, method_b: str,
                        grade: str = "commercial", lens_seed: int = 0, *, photo: ShownPhoto | None = None,
                        cancel: threading.Event | None = None) -> dict:
        """Two restorations of the same noisy crop of ``photo`` (the explorer's own by default; ``method_a``,
        ``method_b``: ``NAME[:key=value,...]``), and one manufactured lens (drawn from ``grade`` with ``lens_seed``)
        restored with the nominal PSFs and with its own: ``{"png": {...}, "scores": {...}}`` keyed ``a``, ``b``,
        ``nominal``, ``own``. ``cancel`` is checked before each of its four simulations (:class:`Cancelled`)."""
        self.check_grade(grade)
        shown = photo or self.shown_photo

        def make():
            box, run = self._crops(shown, pc, cancel)
            nominal = self._provider(controls, shape=shown.shape)
            # each method from the same noisy crop (the same seed; the blurred region is cached: one blur)
            runs = {"a": run(nominal, method_a), "b": run(nominal, method_b)}
            _stop_if(cancel)
            built = self._built_provider(controls, grade, lens_seed, shown.shape)
            runs.update({tag: run(built, pc.restore, prov) for tag, prov in (("nominal", nominal), ("own", built))})
            return {"png": {tag: _png(r.images[m]) for tag, (r, m) in runs.items()},
                    "scores": {tag: r.scores[m] for tag, (r, m) in runs.items()}}
        return self._cache("lab").get_or((shown.tag, controls.key(), pc, method_a, method_b, grade, lens_seed), make)

    # ---- export ---------------------------------------------------------------------------------------------------
    def design_arguments(self, controls: Controls) -> list[str]:
        """The command-line arguments that select ``controls``'s design (any lens: its file, or the design's
        :data:`LENS_EXPORT_FILE`, :meth:`lens_toml`)."""
        if self.prescription is not None:
            parts = ["--lens", self.lens if self.is_file_design(controls) else LENS_EXPORT_FILE]
            return parts + ([] if self.pixel_pitch_um is None else ["--pixel-pitch", f"{self.pixel_pitch_um:g}"])
        v = controls.as_dict()
        parts = ["--s", f"{v['s']:g}", "--Q_back", f"{v['Q_back']:g}"]
        for name in ("Q_front", "focus_shift_um"):
            if v.get(name):
                parts += [f"--{name}", f"{v[name]:g}"]
        return parts + ([] if controls.glass == "paper" else ["--glass", controls.glass])

    def is_file_design(self, controls: Controls) -> bool:
        """Whether ``controls`` is the lens exactly as its file gives it (no solve, no change)."""
        return (self.prescription is not None and not self.hold and self.image == "file"
                and all(v == self.file_values[n] for n, v in controls.values))

    def lens_toml(self, controls: Controls) -> str:
        """Any lens: the design as a lens file (TOML; its solves applied and its image plane folded into the last
        thickness): what ``--lens`` of every command takes."""
        from lenssim.io.prescription_file import prescription_toml

        return prescription_toml(design_prescription(self.tradeoff_run(controls), controls.as_dict()))


def command_line(photo: str | None, controls, pc: PhotoControls, explorer: Explorer, shape=None) -> str:
    """The ``lenssim simulate`` command that reproduces the photo panel (its crop, centred at the same pixel, on a
    photo of ``shape``: the explorer's own by default)."""
    import shlex

    box = explorer.crop_box(pc.center, shape)
    size = box[1] - box[0]
    parts = ["lenssim", "simulate"] + ([photo] if photo else []) + explorer.design_arguments(controls)
    parts += (["--iso", str(pc.iso)] if pc.full_well is None else ["--full-well", f"{pc.full_well:g}"])
    parts += ["--seed", str(pc.seed), "--crop", str(size), "--at", f"{box[0] + size // 2},{box[2] + size // 2}",
              "--restore", pc.restore]
    if pc.sensor:
        parts += ["--sensor", pc.sensor]
    if pc.cfa != "none":
        parts += ["--cfa", pc.cfa, "--demosaic", pc.demosaic]
    parts += ["--out", "results/explore"]
    return shlex.join(parts)
