"""The camera chain (issue 31): a sensor with a colour filter array, its noise sources and ADC, and the image signal
processor (ISP) that develops its raw data, as named stages over ``(B, C, H, W)`` tensors.

The stages (:data:`CAMERA_STAGES`, a table from name to function, like the restoration methods), in the order a
:class:`CameraChain` runs them; a stage whose term is off is skipped (no random number drawn). The paper's sensor
exposure is this chain with every stage but the photon noise off (:meth:`CameraChain.expose`, which
:func:`pipeline.noise.expose` calls): one forward model, not two.

optics side: the pixel aperture (the sensor's ``fill_factor``) joins the lens's PSFs for the blur and the restoration
(:class:`lenssim.optics.pixel_aperture.PixelAperturePSF`, applied by :mod:`pipeline.simulate`).
sensor side (:meth:`CameraChain.capture`; linear camera RGB in, raw data out)
    ``quantum_efficiency`` (electrons expected per pixel and channel), ``mosaic`` (the Bayer CFA keeps one channel per
    pixel), ``prnu`` (each pixel's fixed gain ``1 + prnu N(0, 1)``), ``photon_noise`` (Poisson), ``dark_current``
    (Poisson dark electrons ``dark_current x exposure``), ``dsnu`` (each pixel's fixed dark offset, Gaussian e- RMS),
    ``read_noise`` (Gaussian e- RMS), ``adc`` (``round(electrons / gain + black)`` clipped to ``[0, white]`` DN, the
    gain spanning the ISO's full well over the ADC's range).
ISP side (:meth:`CameraChain.linearise`, :meth:`CameraChain.develop`)
    ``black_level`` (DN -> electrons, less the black level and the mean dark signal the optical-black pixels
    measure, in units of the image: electrons / ``electrons_per_unit``), ``white_balance`` (per-channel gains: from the
    illuminant, i.e. the sensor's QE, or grey world), ``demosaic`` (:data:`pipeline.cfa.DEMOSAIC_METHODS`),
    ``colour_correction`` (the sensor's 3 x 3 camera RGB -> linear sRGB matrix).

PRNU and DSNU are fixed patterns of the sensor: drawn per :data:`FIXED_PATTERN_TILE_PX` tile of the frame from the
chain's ``fixed_pattern_seed`` and the tile's position, so a crop sees the same pattern as the whole frame there.

Restoration (:mod:`pipeline.restoration`) runs where the chain says (``restore_on``): on the mosaic, each CFA plane
(half the resolution) restored with the lens's PSFs resampled to that plane (:class:`PlanePSF`) on windows of the same
size in the plane's pixels (so each covers four times the frame's area, and there are a quarter as many), before white balance
and demosaicing; or on the developed RGB image (today's place), in the sensor's units (white balance undone and
redone around it) so that the noise description holds in every channel.

The noise description (:meth:`CameraChain.noise_model`, a :class:`NoiseModel`) is derived from the stages that are on:
per pixel, in the sensor's units (electrons / ``electrons_per_unit``), the variance
``x / e + (PRNU x)^2 + (read^2 + dark + DSNU^2 + gain^2 / 12) / e^2`` at a signal ``x``, each term present exactly where
its stage runs; it is what every restoration is given (tests/pipeline/test_noise_model.py checks it against the
variance of the simulated noise by Monte Carlo).

The photon transfer of the sensor side follows EMVA 1288 (release 4.0, 2021), eq. (6)-(8): mean ``mu_y = K (mu_e +
mu_d) + black`` and variance ``sigma_y^2 = K^2 (mu_e + sigma_d^2) + 1/12`` DN^2 (``K`` = 1 / gain DN/e-,
``sigma_d^2`` = read noise^2 + dark electrons + DSNU^2), which the tests check by Monte Carlo.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch

from lenssim import PSFProvider, Sensor
from lenssim.optics.psf_provider import DerivedPSF
from lenssim.registry import Registry
from lenssim.torch_utils import HOST, tensor_of

from .cfa import DEMOSAIC_METHODS, demosaic, mosaic, validate_cfa
from .checks import check_image

__all__ = ["CAMERA_STAGES", "CameraStage", "CameraChain", "NoiseModel", "PlanePSF", "RESTORE_PLACES",
           "WHITE_BALANCE_METHODS", "DEFAULT_EXPOSURE_MS", "FIXED_PATTERN_TILE_PX", "PHOTON_NOISE_SENSOR", "pattern_at",
           "fixed_pattern"]

DEFAULT_EXPOSURE_MS = 10.0
"""Exposure time (ms) when none is given: 1/100 s. It sets only the dark electrons (``dark_current x exposure``); the
signal is set by the ISO's full well, as in the paper."""
FIXED_PATTERN_TILE_PX = 256
"""Side (px) of the tiles the PRNU and DSNU patterns are drawn in (each from the seed and the tile's position)."""
PLANE_PSF_MARGIN_PX = 8
"""Frame pixels beyond a PSF's known support that :class:`PlanePSF` asks its base provider for (the tent reaches 1)."""
RESTORE_PLACES = ("rgb", "mosaic")
"""Where restoration runs: on the demosaicked RGB image (today's place) or on the mosaic's CFA planes."""
WHITE_BALANCE_METHODS = ("illuminant", "grey_world")
"""White-balance gains from the illuminant (the sensor's known per-channel QE: a grey scene stays grey) or from the
image's channel means (grey world)."""
PHOTON_NOISE_SENSOR = Sensor(pixel_pitch_um=1.0, width_px=1, height_px=1, name="photon noise only")
"""The ideal sensor (``sensor=None`` of :func:`pipeline.noise.expose`): every term off, so its chain draws photon noise
only. Its pitch and size are placeholders: the noise stages read only the noise terms."""
_RAW_STAGES = ("quantum_efficiency", "mosaic", "prnu", "photon_noise", "dark_current", "dsnu", "read_noise", "adc")
_ISP_STAGES = ("black_level", "white_balance", "demosaic", "colour_correction")


@dataclass(frozen=True)
class CameraStage:
    """A named stage: ``fn(x, ctx) -> x`` over ``(B, C, H, W)``, which side of the chain it is on, what it models.

    The sensor-side stages after ``quantum_efficiency`` (which makes the chain's own float64 buffer from the image), and
    ``black_level``, may change ``x`` in place: the chain calls them on its own buffers only (a frame's exposure keeps at
    most two float64 frames alive). The other ISP stages return new tensors (one linear image is developed once per
    restoration)."""

    name: str
    fn: Callable
    side: str
    label: str


CAMERA_STAGES = Registry("camera stage")
"""The camera chain's stages by name (:class:`CameraStage`), in the chain's order."""


def _stage(name: str, side: str, label: str):
    def deco(fn):
        CAMERA_STAGES.register(CameraStage(name, fn, side, label))
        return fn
    return deco


def pattern_at(pattern: str, row: int, col: int) -> str:
    """The Bayer pattern read from pixel ``(row, col)`` of a frame whose top-left pixel has ``pattern``."""
    p = validate_cfa(pattern)
    tile = [[p[0], p[1]], [p[2], p[3]]]
    r, c = row % 2, col % 2
    return "".join(tile[(r + i) % 2][(c + j) % 2] for i in (0, 1) for j in (0, 1))


def fixed_pattern(seed: int, salt: int, origin, shape, *, dtype=torch.float64, device=None) -> torch.Tensor:
    """A standard normal pattern ``(H, W)`` fixed to the frame: the pixels ``origin`` ``(row, col)`` onward of the
    frame's pattern, drawn per :data:`FIXED_PATTERN_TILE_PX` tile from ``(seed, salt, tile row, tile column)``."""
    H, W = shape
    r0, c0 = origin
    t = FIXED_PATTERN_TILE_PX
    out = torch.empty(H, W, dtype=dtype, device=HOST)  # drawn on the host: the same pattern on every device
    for tr in range(r0 // t, (r0 + H - 1) // t + 1):
        for tc in range(c0 // t, (c0 + W - 1) // t + 1):
            key = ((int(seed) * 1_000_003 + salt) * 1_000_003 + tr) * 1_000_003 + tc
            g = torch.Generator().manual_seed(key % 2**63)
            tile = torch.randn(t, t, generator=g, dtype=torch.float64, device=HOST)
            a0, a1 = max(tr * t, r0), min((tr + 1) * t, r0 + H)
            b0, b1 = max(tc * t, c0), min((tc + 1) * t, c0 + W)
            out[a0 - r0:a1 - r0, b0 - c0:b1 - c0] = tile[a0 - tr * t:a1 - tr * t, b0 - tc * t:b1 - tc * t].to(dtype)
    return out.to(device)


@dataclass
class _Context:
    """What the stages of one capture or development share."""

    chain: "CameraChain"
    electrons_per_unit: float
    full_well: float
    origin: tuple[int, int]
    generator: torch.Generator | None = None
    gains: torch.Tensor | None = None

    @property
    def sensor(self) -> Sensor:
        return self.chain.sensor

    @property
    def pattern(self) -> str | None:
        return None if self.chain.cfa is None else pattern_at(self.chain.cfa, *self.origin)


def _per_site(values, x: torch.Tensor, ctx: _Context) -> torch.Tensor:
    """Per-channel ``values`` as a tensor broadcasting over ``x``: ``(1, C, 1, 1)`` for an RGB image, the CFA site's
    value at each pixel ``(1, 1, H, W)`` for a mosaic."""
    v = torch.as_tensor(values, dtype=x.dtype, device=x.device)
    if x.shape[1] == 1 and ctx.pattern is not None:
        return mosaic(v.view(1, -1, 1, 1).expand(1, 3, *x.shape[-2:]), ctx.pattern)
    return v.view(1, -1, 1, 1)


def _qe_rel(sensor: Sensor, channels: int) -> tuple[float, ...]:
    """QE of each channel relative to the largest (the exposure puts the peak of the most sensitive channel at the
    full well)."""
    qe = sensor.qe(channels)
    return tuple(q / max(qe) for q in qe)


# ---- sensor side: linear camera RGB (units of the image) -> electrons -> DN -------------------------------------
@_stage("quantum_efficiency", "sensor", "expected photo-electrons: image x electrons_per_unit x QE (relative)")
def _quantum_efficiency(x, ctx):
    rate = x.to(torch.float64) * ctx.electrons_per_unit  # a new buffer: the image itself is never changed
    if ctx.sensor.quantum_efficiency:
        rate.mul_(_per_site(_qe_rel(ctx.sensor, x.shape[1]), rate, ctx))
    return rate.clamp_min_(0)  # a blur's rounding below 0 counts as no light


@_stage("mosaic", "sensor", "Bayer colour filter array: one channel per pixel")
def _mosaic(x, ctx):
    return mosaic(x, ctx.pattern)


@_stage("prnu", "sensor", "photo-response non-uniformity: a fixed gain 1 + PRNU N(0, 1) per pixel")
def _prnu(x, ctx):
    f = fixed_pattern(ctx.chain.fixed_pattern_seed, 1, ctx.origin, x.shape[-2:], dtype=x.dtype, device=x.device)
    return x.mul_(f.mul_(ctx.sensor.prnu_percent / 100).add_(1)).clamp_min_(0)


@_stage("photon_noise", "sensor", "photon (shot) noise: Poisson electrons")
def _photon_noise(x, ctx):
    return torch.poisson(x, generator=ctx.generator)


@_stage("dark_current", "sensor", "dark current: Poisson electrons, dark_current_e_per_s x exposure")
def _dark_current(x, ctx):
    return x.add_(torch.poisson(torch.full_like(x, ctx.chain.dark_electrons), generator=ctx.generator))


@_stage("dsnu", "sensor", "dark-signal non-uniformity: a fixed offset per pixel, Gaussian e- RMS")
def _dsnu(x, ctx):
    f = fixed_pattern(ctx.chain.fixed_pattern_seed, 2, ctx.origin, x.shape[-2:], dtype=x.dtype, device=x.device)
    return x.add_(f.mul_(ctx.sensor.dsnu_e))


@_stage("read_noise", "sensor", "read noise: Gaussian e- RMS")
def _read_noise(x, ctx):
    noise = torch.randn(x.shape, generator=ctx.generator, dtype=x.dtype, device=x.device)
    return x.add_(noise.mul_(ctx.sensor.read_noise_e))


@_stage("adc", "sensor", "ADC: round(electrons / gain + black level), clipped to [0, white level] DN")
def _adc(x, ctx):
    s = ctx.sensor
    gain = s.conversion_gain_e_per_dn(ctx.full_well)
    return x.div_(gain).add_(s.black_level_dn).round_().clamp_(0, s.white_level)


# ---- ISP side: raw data -> linear image (units of the image) -> developed linear sRGB -----------------------------
@_stage("black_level", "isp", "DN -> electrons less the black level and the mean dark signal, in image units")
def _black_level(x, ctx):
    s = ctx.sensor
    if s.bit_depth is not None:
        x.sub_(s.black_level_dn).mul_(s.conversion_gain_e_per_dn(ctx.full_well))
    return x.sub_(ctx.chain.dark_electrons).div_(ctx.electrons_per_unit)


@_stage("white_balance", "isp", "per-channel gains (illuminant: 1 / relative QE; or grey world)")
def _white_balance(x, ctx):
    return x * _per_site(ctx.gains, x, ctx)


@_stage("demosaic", "isp", "demosaicing (colour-demosaicing: bilinear, Malvar 2004, Menon 2007)")
def _demosaic(x, ctx):
    return demosaic(x, ctx.pattern, ctx.chain.demosaic)


@_stage("colour_correction", "isp", "3 x 3 colour-correction matrix: camera RGB -> linear sRGB")
def _colour_correction(x, ctx):
    m = torch.tensor(ctx.sensor.colour_matrix, dtype=x.dtype, device=x.device)
    return torch.einsum("ij,bjhw->bihw", m, x)


@dataclass(frozen=True)
class NoiseModel:
    """The noise of a sensor image as a restoration assumes it, per pixel, in the sensor's units (photo-electrons /
    ``electrons_per_unit``): at an expected signal ``x`` (>= 0) the variance is

        ``x / electrons_per_unit + (prnu x)^2 + signal_independent_var``

    (photon noise, the fixed gain pattern, and the sum of the signal-independent terms in squared image units).
    :meth:`CameraChain.noise_model` derives it from the chain's stages; ``NoiseModel(e)`` alone is photon noise at ``e``
    electrons per unit (``math.inf``: no noise)."""

    electrons_per_unit: float
    signal_independent_var: float = 0.0
    prnu: float = 0.0
    """RMS of each pixel's fixed gain, a fraction of the signal (the sensor's ``prnu_percent`` / 100)."""

    def __post_init__(self):
        e = self.electrons_per_unit
        if isinstance(e, bool) or not isinstance(e, (int, float)) or math.isnan(e) or not e > 0:
            raise ValueError(f"electrons_per_unit={e!r} is not allowed: a number > 0 (inf: no photon noise)")
        for k in ("signal_independent_var", "prnu"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{k}={v!r} is not allowed: a finite number >= 0")
        object.__setattr__(self, "electrons_per_unit", float(e))

    def variance(self, signal):
        """The noise variance (squared image units) at the expected signal ``signal`` (image units; a tensor or a
        number; below 0 counts as 0), elementwise."""
        inv_e = 0.0 if math.isinf(self.electrons_per_unit) else 1.0 / self.electrons_per_unit
        x = signal.clamp_min(0) if isinstance(signal, torch.Tensor) else max(float(signal), 0.0)
        var = x * inv_e
        if self.prnu:
            var = var + (self.prnu * x) ** 2
        return var + self.signal_independent_var


@dataclass(frozen=True)
class CameraChain:
    """A sensor (:class:`lenssim.Sensor`: its CFA, noise terms, ADC, QE, colour matrix) and how its raw data are
    developed: ``demosaic`` method, ``restore_on`` (:data:`RESTORE_PLACES`), ``exposure_ms`` (sets the dark
    electrons), ``white_balance`` (:data:`WHITE_BALANCE_METHODS`), ``fixed_pattern_seed`` (the sensor's PRNU/DSNU)."""

    sensor: Sensor
    demosaic: str = "Malvar2004"
    restore_on: str = "rgb"
    exposure_ms: float = DEFAULT_EXPOSURE_MS
    white_balance: str = "illuminant"
    fixed_pattern_seed: int = 0

    def __post_init__(self):
        if not isinstance(self.sensor, Sensor):
            raise ValueError(f"sensor={self.sensor!r} is not a lenssim.Sensor")
        DEMOSAIC_METHODS.validate(self.demosaic)
        if self.restore_on not in RESTORE_PLACES:
            raise ValueError(f"restore_on={self.restore_on!r} is not allowed: one of {', '.join(RESTORE_PLACES)}")
        if self.restore_on == "mosaic" and self.cfa is None:
            raise ValueError("restoring on the mosaic needs a colour filter array (cfa RGGB, BGGR, GRBG or GBRG)")
        if self.white_balance not in WHITE_BALANCE_METHODS:
            raise ValueError(f"white_balance={self.white_balance!r} is not allowed: one of "
                             f"{', '.join(WHITE_BALANCE_METHODS)}")
        t = self.exposure_ms
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or not t > 0:
            raise ValueError(f"exposure_ms={t!r} is not allowed: a finite time > 0 ms")
        s = self.fixed_pattern_seed
        if isinstance(s, bool) or not isinstance(s, int) or s < 0:
            raise ValueError(f"fixed_pattern_seed={s!r} is not allowed: a whole number >= 0")

    @classmethod
    def of(cls, sensor: "Sensor | CameraChain | None") -> "CameraChain":
        """The chain a sensor sits in: a :class:`CameraChain` as it is, a :class:`lenssim.Sensor` with the chain's
        defaults (its terms on where it sets them: the paper's sensor draws photon noise only), None: photon noise only
        (:data:`PHOTON_NOISE_SENSOR`)."""
        if isinstance(sensor, CameraChain):
            return sensor
        if sensor is None:
            return cls(PHOTON_NOISE_SENSOR)
        if not isinstance(sensor, Sensor):
            raise ValueError(f"sensor is a {type(sensor).__name__}: expected a lenssim.Sensor or a "
                             "pipeline.camera_chain.CameraChain")
        return cls(sensor)

    @property
    def cfa(self) -> str | None:
        return None if self.sensor.cfa == "none" else self.sensor.cfa

    @property
    def dark_electrons(self) -> float:
        """Mean dark electrons per pixel in the exposure."""
        return self.sensor.dark_current_e_per_s * self.exposure_ms * 1e-3

    @property
    def sensor_stages(self) -> tuple[str, ...]:
        """The sensor-side stages this chain runs, in order (those whose term is off left out)."""
        s = self.sensor
        on = {"quantum_efficiency": True, "mosaic": self.cfa is not None, "prnu": s.prnu_percent > 0,
              "photon_noise": True, "dark_current": self.dark_electrons > 0, "dsnu": s.dsnu_e > 0,
              "read_noise": s.read_noise_e > 0, "adc": s.bit_depth is not None}
        return tuple(k for k in _RAW_STAGES if on[k])

    @property
    def isp_stages(self) -> tuple[str, ...]:
        """The ISP stages this chain runs, in order (restoration goes before ``white_balance`` on the mosaic, after
        ``demosaic`` on RGB)."""
        on = {"black_level": True, "white_balance": bool(self.sensor.quantum_efficiency) or
              self.white_balance != "illuminant", "demosaic": self.cfa is not None,
              "colour_correction": bool(self.sensor.colour_matrix)}
        return tuple(k for k in _ISP_STAGES if on[k])

    @property
    def develops(self) -> bool:
        """True if :meth:`develop` changes the linear image (white balance, demosaicing or colour correction), so that
        restoration runs inside it; False: the sensor image is the linearised raw data itself (the paper's sensor)."""
        return self.isp_stages != ("black_level",)

    def to_dict(self) -> dict:
        """The chain by its names (for ``metrics.json``)."""
        return {"cfa": self.cfa or "none", "demosaic": self.demosaic if self.cfa else None,
                "restore_on": self.restore_on, "exposure_ms": self.exposure_ms, "white_balance": self.white_balance,
                "fixed_pattern_seed": self.fixed_pattern_seed, "dark_electrons": self.dark_electrons,
                "pixel_aperture": None if self.sensor.fill_factor is None else
                f"box of {math.sqrt(self.sensor.fill_factor):.4g} px (fill factor {self.sensor.fill_factor:g})",
                "sensor_stages": list(self.sensor_stages), "isp_stages": list(self.isp_stages),
                "sensor": self.sensor.to_dict()}

    def label(self) -> str:
        """A short description for figures (pattern and method by their names)."""
        s = self.sensor
        parts = [s.name or "sensor"]
        if s.fill_factor is not None:
            parts.append(f"fill factor {s.fill_factor:g}")
        if self.cfa:
            parts.append(f"{self.cfa} / {self.demosaic}")
        if s.read_noise_e:
            parts.append(f"read noise {s.read_noise_e:g} e-")
        if s.bit_depth:
            parts.append(f"{s.bit_depth}-bit")
        parts.append(f"restored on {self.restore_on}")
        return ", ".join(parts)

    # ---- the two sides ------------------------------------------------------------------------------------------
    def scene_to_camera(self, scene: torch.Tensor) -> torch.Tensor:
        """The scene's linear sRGB ``(B, 3, H, W)`` in the camera's RGB (the colour matrix inverted; negative values,
        outside the camera's gamut, clipped to 0); unchanged without a colour matrix."""
        if not self.sensor.colour_matrix:
            return scene
        m = torch.linalg.inv(torch.tensor(self.sensor.colour_matrix, dtype=torch.float64, device=HOST)).to(scene)
        return torch.einsum("ij,bjhw->bihw", m, scene).clamp_min_(0)

    def capture(self, image: torch.Tensor, electrons_per_unit: float, full_well: float, *, generator: torch.Generator,
                origin=(0, 0)) -> torch.Tensor:
        """Raw data of the linear camera-RGB image ``(B, C, H, W)`` (>= 0, its pixel ``(0, 0)`` at ``origin`` of the
        frame): DN ``(B, 1, H, W)`` (a CFA) or ``(B, C, H, W)``, float64, electrons without an ADC.
        ``electrons_per_unit``: photo-electrons per unit of the image in the most sensitive channel."""
        check_image(image, "image", nonnegative=True)
        return self._capture(image, electrons_per_unit, full_well, generator, origin)

    def _capture(self, image, electrons_per_unit, full_well, generator, origin) -> torch.Tensor:
        """:meth:`capture` without the check of the image's values (a blur's rounding below 0 counts as 0)."""
        if self.cfa is not None and image.shape[1] != 3:
            raise ValueError(f"a colour filter array samples an RGB image; this one has {image.shape[1]} channel(s)")
        ctx = _Context(self, float(electrons_per_unit), float(full_well), tuple(origin), generator)
        x = image
        for name in self.sensor_stages:
            x = CAMERA_STAGES[name].fn(x, ctx)
        return x

    def linearise(self, raw: torch.Tensor, electrons_per_unit: float, full_well: float, *, origin=(0, 0),
                  in_place: bool = False) -> torch.Tensor:
        """Raw data -> linear image in the sensor's units (electrons / ``electrons_per_unit``: the photon noise's
        variance is the value over ``electrons_per_unit`` in every channel), black level and mean dark signal removed.
        ``in_place``: in ``raw``'s own (floating) buffer, which is then the result."""
        return _black_level(raw if in_place else raw.clone(),
                            _Context(self, float(electrons_per_unit), float(full_well), tuple(origin)))

    def expose(self, image: torch.Tensor, electrons_per_unit: float, full_well: float, *, generator: torch.Generator,
               origin=(0, 0)) -> torch.Tensor:
        """The sensor's reading of a linear camera-RGB image ``(B, C, H, W)`` in the sensor's units and the image's
        dtype (:meth:`capture`, then :meth:`linearise` in the same buffer; the mosaic ``(B, 1, H, W)`` under a CFA): the
        paper's exposure for its sensor (Poisson photo-electrons at ``electrons_per_unit`` per unit, back in image
        units), each further term where the sensor has it.

        The rate is formed in float64 from the image, so a float64 run draws the same counts on any CPU (a float32 rate
        that moves by one rounding between hosts can flip a count); at most two float64 frames are alive at a time (a
        24 MP colour frame's is 580 MB). Values below 0 (a blur's rounding) count as no light."""
        raw = self._capture(image, electrons_per_unit, full_well, generator, origin)
        return self.linearise(raw, electrons_per_unit, full_well, origin=origin, in_place=True).to(image.dtype)

    def white_balance_gains(self, units: torch.Tensor, *, origin=(0, 0), channels: int = 3) -> torch.Tensor:
        """Per-channel gains ``(C,)`` from the sensor's units to the scene's: 1 / relative QE (illuminant), or grey
        world (each channel's mean brought to green's, green's gain the illuminant's)."""
        illum = torch.tensor([1 / q for q in _qe_rel(self.sensor, channels)], dtype=torch.float64, device=HOST)
        if self.white_balance == "illuminant" or channels != 3:
            return illum
        if units.shape[1] == 1:
            from .cfa import cfa_masks

            m = cfa_masks(pattern_at(self.cfa, *origin), *units.shape[-2:], device=units.device)
            means = torch.stack([units[:, 0][:, mk].mean() for mk in m]).to(torch.float64).cpu()
        else:
            means = units.mean(dim=(0, 2, 3)).to(torch.float64).cpu()
        if not bool((means > 0).all()):
            return illum
        return means[1] / means * illum[1]

    def develop(self, units: torch.Tensor, *, gains: torch.Tensor, origin=(0, 0), restore=None) -> torch.Tensor:
        """Linear sRGB ``(B, 3, H, W)`` (or the image's channels without a CFA) from the sensor's units: white balance
        by ``gains``, demosaicing, colour correction; ``restore(image, plane)`` (optional) restores where
        :attr:`restore_on` says: per CFA plane ``plane = (row offset, col offset, channel)`` on the mosaic's plane
        ``(B, 1, H/2, W/2)``, or ``plane = None`` on the RGB image in the sensor's units."""
        ctx = _Context(self, 1.0, 1.0, tuple(origin), gains=gains)
        x = units
        if restore is not None and self.restore_on == "mosaic":
            x = self._restore_planes(x, ctx, restore)
        for name in self.isp_stages[1:]:
            if name == "colour_correction" and restore is not None and self.restore_on == "rgb":
                x = self._restore_rgb(x, ctx, restore)
            x = CAMERA_STAGES[name].fn(x, ctx)
        if restore is not None and self.restore_on == "rgb" and "colour_correction" not in self.isp_stages:
            x = self._restore_rgb(x, ctx, restore)
        return x

    def _restore_rgb(self, x, ctx, restore):
        g = ctx.gains.to(x).view(1, -1, 1, 1)
        if x.shape[1] != g.shape[1]:
            g = g[:, :1]
        return restore(x / g, None) * g

    def _restore_planes(self, x, ctx, restore):
        out = x.clone()
        pattern = ctx.pattern
        for k, f in enumerate(pattern):
            dy, dx = k // 2, k % 2
            out[..., dy::2, dx::2] = restore(x[..., dy::2, dx::2].contiguous(), (dy, dx, "RGB".index(f)))
        return out

    def xyz_to_camera(self) -> tuple[tuple[float, float, float], ...]:
        """XYZ (D65) -> camera RGB (a DNG's ColorMatrix1): colour-science's XYZ -> linear sRGB matrix, then the colour
        matrix inverted (identity without one: the camera's RGB is linear sRGB)."""
        import colour
        import numpy as np

        m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)
        if self.sensor.colour_matrix:
            m = np.linalg.inv(np.asarray(self.sensor.colour_matrix)) @ m
        return tuple(tuple(float(v) for v in row) for row in m)

    def noise_model(self, electrons_per_unit: float, full_well: float) -> NoiseModel:
        """The noise every restoration is given (:class:`NoiseModel`), in the sensor's units (what :meth:`linearise`
        and :meth:`expose` return), at ``electrons_per_unit`` photo-electrons per unit and the ISO's ``full_well``
        (electrons): photon noise ``x / electrons_per_unit`` always, and, each exactly where its stage runs
        (:attr:`sensor_stages`), PRNU ``(prnu x)^2``, read noise ``read^2``, dark current's Poisson electrons (its
        variance, their mean), DSNU ``dsnu^2`` and the ADC's rounding ``gain^2 / 12`` (a uniform error of one DN, in
        electrons), the electrons' terms over ``electrons_per_unit^2``.

        The fixed patterns (PRNU, DSNU) count as noise: they vary from pixel to pixel of one frame as the noise does.
        Holds below the white level (clipping is not modelled) and, for the ADC's term, where the noise before it spans
        about half a DN or more (Widrow's quantisation theorem: the rounding error is then uniform and uncorrelated with
        the signal; any read noise of a real sensor does this). Checked against the variance of the simulated noise by
        Monte Carlo (tests/pipeline/test_noise_model.py)."""
        s, on = self.sensor, self.sensor_stages
        var_e = 0.0
        if "read_noise" in on:
            var_e += s.read_noise_e**2
        if "dark_current" in on:
            var_e += self.dark_electrons
        if "dsnu" in on:
            var_e += s.dsnu_e**2
        if "adc" in on:
            var_e += s.conversion_gain_e_per_dn(full_well) ** 2 / 12
        e = float(electrons_per_unit)
        return NoiseModel(e, var_e / e**2, s.prnu_percent / 100 if "prnu" in on else 0.0)


@dataclass(frozen=True)
class PlanePSF(DerivedPSF):
    """The PSFs of one CFA plane: pixel ``(i, j)`` of the plane is pixel ``(2 i + dy, 2 j + dx)`` of the frame, whose
    PSFs ``base`` gives; the plane's PSF is the frame's convolved with the tent ``[1/2, 1, 1/2]`` in each direction and
    sampled every other pixel (the blurred frame's samples at the plane's pixels, with the scene's missing pixels
    linearly interpolated between the plane's), unit sum; ``channel`` picks the plane's colour of a per-channel
    provider. Mirror-symmetric where ``base`` is (the tent is symmetric)."""

    base: PSFProvider
    dy: int
    dx: int
    channel: int = 0

    channels = 1

    @property
    def geometry(self):
        g = self.base.geometry
        return replace(g, pixel_pitch_um=2 * g.pixel_pitch_um)

    def _frame(self, rows, cols, optical_center):
        r = 2 * tensor_of(rows, torch.float64) + self.dy
        c = 2 * tensor_of(cols, torch.float64) + self.dx
        return r, c, (2 * optical_center[0] + self.dy, 2 * optical_center[1] + self.dx)

    def psf_at_pixels(self, rows, cols, optical_center, n: int, *, centered: bool = True, dtype=None, device=None):
        r, c, oc = self._frame(rows, cols, optical_center)
        # the frame's PSFs on the smallest odd grid that holds their support (known) with a margin, at most the
        # 2 n + 1 frame pixels the plane's n x n grid spans
        ext = int(tensor_of(self.base.extents_px(r, c, oc)).max()) if len(r) else 0
        m = 2 * n + 1 if ext <= 0 else min(2 * n + 1, 2 * (ext // 2) + PLANE_PSF_MARGIN_PX + 1)
        p = self.base.psf_at_pixels(r, c, oc, m, centered=True, dtype=torch.float64, device=device)
        if p.ndim == 4:
            p = p[:, self.channel]
        tent = torch.tensor([0.5, 1.0, 0.5], dtype=p.dtype, device=p.device)
        k = (tent[:, None] * tent[None, :])[None, None]
        q = torch.nn.functional.conv2d(p[:, None], k, padding=1)[:, 0]
        h, ctr = n // 2, m // 2
        lo = max(0, -(-(2 * h - ctr) // 2))  # plane index j <-> frame index ctr + 2 (j - h), within 0..m-1
        hi = min(n - 1, (m - 1 - ctr + 2 * h) // 2)
        f0 = ctr + 2 * (lo - h)
        out = q.new_zeros(q.shape[0], n, n)
        out[:, lo:hi + 1, lo:hi + 1] = q[:, f0::2, f0::2][:, :hi + 1 - lo, :hi + 1 - lo]
        out = out / out.sum(dim=(-2, -1), keepdim=True)
        out = out.to(dtype=dtype or torch.float32)
        return out if centered else torch.fft.ifftshift(out, dim=(-2, -1))

    def extent_px(self, rows, cols, optical_center) -> int:
        r, c, oc = self._frame(rows, cols, optical_center)
        return int(self.base.extent_px(r, c, oc)) // 2 + 2

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        r, c, oc = self._frame(rows, cols, optical_center)
        return tensor_of(self.base.extents_px(r, c, oc)).to(torch.int64) // 2 + 2

    def pedestal_fractions(self, n: int):
        return (0.0,)

    def derivation(self) -> str:
        return f"plane({self.dy},{self.dx},{self.channel})"


assert set(CAMERA_STAGES) == set(_RAW_STAGES + _ISP_STAGES)
