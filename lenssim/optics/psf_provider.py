"""PSF providers: field position -> PSF, the one thing blur and restoration need from the optics.

The image pipeline (blur, restoration, the exact per-pixel reference) never sees a lens model: it
asks a provider for the PSFs at pixel positions of an array whose optical axis is at
``optical_center``, on an ``n x n`` grid of the sensor's pixels. The providers:

* :class:`LensPSF`: the model (camera + design, Fourier optics of the third-order pupil),
* :class:`SequentialPSF`: any sequential lens (Fourier optics of the real-ray wavefront, field by field, from the
  wavefront table of :mod:`lenssim.optics.psf_bank`; see :func:`lenssim.optics.psf_bank.psfs_from_table`): its PSF
  is centred on the pixel at field angle ``atan(r / m)`` (the paraxial mapping, :attr:`SequentialPSF.geometry`) shifted
  by the lens's distortion, so distortion is rendered in a simulated image, as a camera records it,
* :class:`AsBuiltPSF`: one manufactured lens (:mod:`lenssim.optics.as_built`): no rotational symmetry, so one PSF
  per window (the blur's mirror-group sharing is off),
* :class:`FunctionPSF`: any callable ``fn(x_mm, y_mm, n) -> (P, n, n)`` (measured or tabulated PSFs,
  centred, unit sum), with the field geometry it lives in.

A provider returns ``(P, n, n)`` (one PSF for every colour channel) or ``(P, C, n, n)`` (one per
channel); :attr:`channels` says which (1 or C).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..model.camera import Camera
from ..model.design import Design
from ..model.geometry import FieldGeometry
from ..model.numerics import DEFAULT_NUMERICS, Numerics
from ..model.sensor import Sensor
from ..model.spectrum import Spectrum, shared_quadrature, shared_wavelengths
from ..torch_utils import HOST, tensor_of
from .psf_bank import (SAMPLINGS, TABLE_MAX_NODES, WavefrontTable, _paraxial_image_heights, cached_wavefront_table,
                       image_scale_mm, max_wavefront_slope, nice_fft_size, pedestal_fraction, psfs_from_table,
                       spectral_coefficients)
from .sequential import Fields, SequentialLens
from .wavefront_models import validate_wavefront_model

__all__ = ["PSFProvider", "DerivedPSF", "LensPSF", "FunctionPSF", "AsBuiltPSF", "SequentialPSF",
           "MIN_PUPIL_RADIUS_SAMPLES"]

MIN_PUPIL_RADIUS_SAMPLES = 24
"""The FFT is at least large enough for the pupil's radius to span this many samples at every wavelength."""
DIFFRACTION_MARGIN_AIRY = 16.0
"""The PSF's diameter exceeds the rays' spot by this many ``lambda N_w``: the Airy pattern holds 97.5% of its light
within a radius of 8 ``lambda N_w`` (``1 - J0^2 - J1^2`` at ``8 pi``); each PSF is renormalised to unit sum on its
window, so the far wings' few percent are given back to the window in proportion."""
MIN_MARGIN_PX = 4
"""The least diffraction margin (px) of a PSF's diameter."""
MIN_AREA_OVERSAMPLE = 3
"""``sampling="area"`` integrates each pixel over at least this many samples across."""
EXTENT_PUPIL_POINTS = 96
"""Pupil points traced per field and wavelength for :meth:`SequentialPSF.estimated_extent_px` (half on the rim)."""
EXTENT_FIELDS = 5
"""Field angles (evenly from the axis to the largest) of :meth:`SequentialPSF.estimated_extent_px`."""


class PSFProvider:
    """Interface: :attr:`geometry`, :attr:`channels`, :meth:`psf_at_pixels` and :meth:`extent_px`."""

    geometry: FieldGeometry
    channels: int = 1
    mirror_symmetric: bool = False
    """True if the PSF at the mirror image of a field position, about a line through the optical axis along the
    rows, the columns or the diagonal, is the mirror image of the PSF (a rotationally symmetric lens on square
    pixels); the windowed blur then computes one PSF for up to 8 windows."""

    def psf_at_pixels(self, rows, cols, optical_center, n: int, *, centered: bool = True, dtype=None,
                      device=None) -> torch.Tensor:
        """PSFs ``(P, n, n)`` or ``(P, C, n, n)`` (unit sum) at pixel positions ``rows``, ``cols`` ``(P,)``."""
        raise NotImplementedError

    def extent_px(self, rows, cols, optical_center) -> int:
        """Diameter (px) of the largest PSF support over the positions (0 if unknown)."""
        return 0

    def spectrum(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The wavelengths (um) and weights the PSFs integrate (empty if unknown)."""
        return (), ()

    def pedestal_fractions(self, n: int) -> tuple[float, ...]:
        """Per channel (:attr:`channels` values), the fraction of each PSF's light on the ``n x n`` grid that is spread
        evenly over the whole grid (a uniform pedestal, part of the PSF's unit sum): the light the sampled model
        diffracts beyond what the grid resolves. The windowed blur convolves it as a mean over ``n x n`` px instead of
        folding it into smaller windows. 0 (none) unless the provider says so."""
        return (0.0,) * self.channels

    def bank(self, rows, cols, optical_center, n: int, *, centered: bool = True, dtype=None, device=None):
        """The PSFs at pixel positions ``rows``, ``cols`` ``(P,)`` as a :class:`lenssim.optics.bank.PSFBank`: with the
        pixel pitch and the spectrum, so their grid and their OTFs' frequency axes are known, not inferred."""
        from .bank import PSFBank

        lams, weights = self.spectrum()
        return PSFBank(self.psf_at_pixels(rows, cols, optical_center, n, centered=centered, dtype=dtype, device=device),
                       self.geometry.pixel_pitch_um, lams, weights, centered)

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        """Diameter (px) of the PSF support at each position, ``(P,)`` int64 (0 if unknown): here
        :meth:`extent_px` everywhere; a provider that knows how its PSFs grow over the field says so."""
        rows = tensor_of(rows)
        return torch.full((rows.numel(),), int(self.extent_px(rows, cols, optical_center)), dtype=torch.int64,
                          device=rows.device)


class DerivedPSF(PSFProvider):
    """A provider made from another, ``base``: everything is ``base``'s unless a subclass says otherwise (the pixel
    aperture's, a CFA plane's, a cache's PSFs)."""

    base: PSFProvider

    @property
    def geometry(self) -> FieldGeometry:
        return self.base.geometry

    @property
    def channels(self) -> int:
        return self.base.channels

    @property
    def mirror_symmetric(self) -> bool:
        return bool(self.base.mirror_symmetric)

    def psf_at_pixels(self, rows, cols, optical_center, n: int, *, centered: bool = True, dtype=None, device=None):
        return self.base.psf_at_pixels(rows, cols, optical_center, n, centered=centered, dtype=dtype, device=device)

    def extent_px(self, rows, cols, optical_center) -> int:
        return self.base.extent_px(rows, cols, optical_center)

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        return self.base.extents_px(rows, cols, optical_center)

    def spectrum(self):
        return self.base.spectrum()

    def pedestal_fractions(self, n: int):
        return self.base.pedestal_fractions(n)

    def fingerprint(self):
        """``base``'s fingerprint and :meth:`derivation` (None when ``base`` has none: no resuming then)."""
        key = getattr(self.base, "fingerprint", None)
        return None if not callable(key) or key() is None else f"{key()}|{self.derivation()}"

    def derivation(self) -> str:
        """What this provider changes of ``base``'s PSFs, for its fingerprint ("": nothing)."""
        return ""


class _CameraPSF(PSFProvider):
    """What the providers of a camera model share: its colour channels, field geometry, spectrum, and the largest of
    their per-position supports (``extents_px``)."""

    @property
    def channels(self) -> int:
        """1 (one PSF for every colour) or the camera's number of colour channels."""
        return max(1, len(self.camera.channels))

    @property
    def geometry(self) -> FieldGeometry:
        return self.camera.geometry

    def spectrum(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The camera's wavelengths (um) and weights (one channel; a colour camera's channels each integrate their
        own, :attr:`lenssim.Camera.channels`)."""
        return tuple(self.camera.spectrum.wavelengths_um), tuple(self.camera.spectrum.weights)

    def pedestal_fractions(self, n: int) -> tuple[float, ...]:
        """Each channel's :func:`lenssim.optics.psf_bank.pedestal_fraction` on an ``n x n`` grid."""
        return tuple(pedestal_fraction(cam, n, self.numerics) for cam in self.quadrature_camera.channel_cameras())

    @property
    def quadrature_camera(self) -> Camera:
        """The camera whose wavelengths the PSFs integrate: colour channels on one table reduced to their shared
        quadrature (:meth:`lenssim.Camera.with_quadrature` under ``numerics.spectral_tol``)."""
        return self.camera.with_quadrature(self.numerics.spectral_tol)

    def _support_cameras(self) -> tuple[Camera, ...]:
        """The cameras whose wavelengths a PSF's support is the largest over: the shared wavelengths once (every
        channel integrates them), else each channel's own."""
        q = self.quadrature_camera
        return (q.node_camera()[0],) if q.channels and q.shared_channels else q.channel_cameras()

    @staticmethod
    def _radius_px(cam: Camera, slopes: torch.Tensor) -> torch.Tensor:
        """The largest geometric radius (px) over ``cam``'s wavelengths for the wavefront slopes ``(P, K)``."""
        lam = torch.tensor(cam.spectrum.wavelengths_um, dtype=torch.float64, device=slopes.device)
        return cam.geometric_radius_px(slopes.to(torch.float64), lam).amax(dim=-1)

    def extent_px(self, rows, cols, optical_center) -> int:
        """The largest geometric PSF diameter over the positions + margin (the margin alone for no position)."""
        e = self.extents_px(rows, cols, optical_center)
        return int(e.max()) if e.numel() else self.numerics.margin_px


@dataclass(frozen=True)
class LensPSF(_CameraPSF):
    """The model's PSFs: the camera (lens, sensor pitch, spectrum) with one design (single values)."""

    camera: Camera
    design: Design
    numerics: Numerics = field(default_factory=lambda: DEFAULT_NUMERICS)
    wavefront: str = "third_order"
    """A model of :data:`lenssim.optics.wavefront_models.WAVEFRONT_MODELS`: ``third_order`` (the paper's Seidel model) or
    ``exact`` (the OPD of an exact ray trace at each PSF's field angle; one-wavelength cameras)."""

    def __post_init__(self):
        model = validate_wavefront_model(self.wavefront)
        if model.check is not None:
            model.check(self.camera)
        d = self.design.to(torch.float64)
        self.camera.lens.check_design(d)
        d.floats()  # one design: every parameter a single value
        object.__setattr__(self, "design", d)
        self.camera.check_sampling()

    @property
    def mirror_symmetric(self) -> bool:
        """True: the model's lens is rotationally symmetric (third order or exact) and its pixels square."""
        return True

    def _design_like(self, t: torch.Tensor) -> Design:
        return self.design.map(lambda v: torch.full_like(t, float(v.reshape(()))))

    def psf_at_pixels(self, rows, cols, optical_center, n, *, centered=True, dtype=None, device=None):
        x_mm, y_mm = self.geometry.offsets_mm(tensor_of(rows).to(device), tensor_of(cols).to(device), optical_center)
        return validate_wavefront_model(self.wavefront).psfs(self, x_mm, y_mm, n, centered, dtype)

    def fingerprint(self) -> str:
        """A stable description of these PSFs (camera, design, numerics), e.g. for checkpoints."""
        return json.dumps({"camera": self.camera.to_dict(), "design": self.design.floats(),
                           "numerics": self.numerics.to_dict(), "wavefront": self.wavefront}, sort_keys=True)

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        """Geometric PSF diameter (px) at each position, ``(P,)`` int64: ``2 G lambda f / (y Delta)`` with ``G`` the
        largest wavefront slope over the pupil (largest over the wavelengths), rounded up, + the margin."""
        x_mm, y_mm = self.geometry.offsets_mm(rows, cols, optical_center)
        # the support depends on the field angle only: each angle once (a frame's mirror-image windows share theirs)
        a, inv = torch.unique(self.geometry.field_angle_deg(x_mm, y_mm).flatten(), return_inverse=True)
        half = torch.zeros_like(a, dtype=torch.float64)
        for cam in self._support_cameras():
            c = spectral_coefficients(cam, self._design_like(a), a, elementwise=True)  # (A, K, T)
            half = torch.maximum(half, self._radius_px(cam, max_wavefront_slope(c)))
        half = half * validate_wavefront_model(self.wavefront).support_factor
        return (torch.ceil(2 * half).to(torch.int64) + self.numerics.margin_px)[inv]


@dataclass(frozen=True)
class FunctionPSF(PSFProvider):
    """PSFs from ``fn(x_mm, y_mm, n) -> (P, n, n)`` or ``(P, C, n, n)`` (centred at ``[n//2, n//2]``, unit sum).

    ``x_mm``, ``y_mm`` ``(P,)`` are image-plane positions from the optical axis; ``geometry`` maps
    pixels to mm (e.g. ``Camera().geometry``); ``channels`` is 1 or the number of channels of ``fn``'s
    output; ``extent`` (px) the PSF support diameter, if known (checked against the windows);
    ``mirror_symmetric``: declare it only for PSFs of a rotationally symmetric system (see
    :class:`PSFProvider`).
    """

    fn: Callable
    geometry: FieldGeometry
    channels: int = 1
    extent: int = 0
    mirror_symmetric: bool = False

    def psf_at_pixels(self, rows, cols, optical_center, n, *, centered=True, dtype=None, device=None):
        x_mm, y_mm = self.geometry.offsets_mm(rows, cols, optical_center)
        p = tensor_of(self.fn(x_mm, y_mm, n))
        expect = (len(x_mm), n, n) if self.channels == 1 else (len(x_mm), self.channels, n, n)
        if tuple(p.shape) != expect:
            raise ValueError(f"PSF function returned shape {tuple(p.shape)}: expected {expect}")
        p = p.to(dtype=dtype or p.dtype, device=device)
        return p if centered else torch.fft.ifftshift(p, dim=(-2, -1))

    def extent_px(self, rows, cols, optical_center) -> int:
        return int(self.extent)


@dataclass(frozen=True)
class AsBuiltPSF(_CameraPSF):
    """The PSFs of one as-built lens: ``lens`` holds one sampled lens (:class:`lenssim.model.tolerances.Perturbations`
    of length 1) of ``design`` on ``camera``; third-order wavefront of :func:`lenssim.optics.as_built.as_built_coefficients`
    at each PSF's field angle and azimuth, non-symmetric, each PSF centred on its as-built chief ray."""

    camera: Camera
    design: Design
    lens: object
    numerics: Numerics = field(default_factory=lambda: DEFAULT_NUMERICS)
    mirror_symmetric: bool = False

    def __post_init__(self):
        if len(self.lens) != 1:
            raise ValueError(f"AsBuiltPSF takes one lens; {len(self.lens)} were given (index the sample: lenses[i])")
        d = self.design.to(torch.float64)
        self.camera.lens.check_design(d)
        d.floats()
        object.__setattr__(self, "design", d)
        self.camera.check_sampling()

    def _coeffs(self, cam, x_mm, y_mm):
        from .as_built import as_built_coefficients

        alpha = self.geometry.field_angle_deg(x_mm, y_mm).reshape(-1).to(torch.float64).cpu()
        az = torch.rad2deg(torch.atan2(y_mm, x_mm)).reshape(-1).to(torch.float64).cpu()
        return as_built_coefficients(cam, self.design, self.lens, alpha, az)[0], az  # (P, K, 6)

    def psf_at_pixels(self, rows, cols, optical_center, n, *, centered=True, dtype=None, device=None):
        from .as_built import AS_BUILT_TERMS
        from .psf_bank import psf

        x_mm, y_mm = self.geometry.offsets_mm(rows, cols, optical_center)
        out = []
        for cam in self.quadrature_camera.channel_cameras():
            c, az = self._coeffs(cam, x_mm, y_mm)
            out.append(psf(cam, c.to(device), n, azimuth_deg=az.to(device), centered=centered, dtype=dtype,
                           numerics=self.numerics, terms=AS_BUILT_TERMS))
        return out[0] if not self.camera.channels else torch.stack(out, dim=1)

    def fingerprint(self) -> str:
        vals = {k: [float(x) for x in v.reshape(-1)] for k, (v, _) in self.lens.variables().items()}
        return json.dumps({"camera": self.camera.to_dict(), "design": self.design.floats(), "as_built": vals,
                           "tolerances": self.lens.tolerances.to_dict(), "numerics": self.numerics.to_dict()},
                          sort_keys=True)

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        """Geometric PSF diameter (px) at each position (the largest wavefront slope over the pupil, every
        wavelength) + the margin, ``(P,)`` int64."""
        from .as_built import AS_BUILT_TERMS

        x_mm, y_mm = self.geometry.offsets_mm(rows, cols, optical_center)
        half = torch.zeros(x_mm.numel(), dtype=torch.float64, device=HOST)  # as the coefficients (_coeffs)
        for cam in self._support_cameras():
            c, _ = self._coeffs(cam, x_mm, y_mm)  # (P, K, T)
            half = torch.maximum(half, self._radius_px(cam, max_wavefront_slope(c, AS_BUILT_TERMS)))
        return torch.ceil(2 * half).to(torch.int64) + self.numerics.margin_px


@dataclass(frozen=True)
class SequentialPSF(PSFProvider):
    """The PSFs of ``lens`` (object at infinity) on ``sensor``'s pixels in the spectrum ``light`` (or in colour
    channels ``colour_channels``, each a :class:`lenssim.Spectrum`): see the module docstring. ``max_field_deg`` is the largest field angle the
    PSFs are asked at (the table is traced that far; default: the lens's largest field); ``sampling`` one of
    :data:`SAMPLINGS`."""

    lens: SequentialLens
    sensor: Sensor
    light: Spectrum
    colour_channels: tuple = ()
    max_field_deg: float | None = None
    sampling: str = "area"
    numerics: Numerics = field(default_factory=lambda: DEFAULT_NUMERICS)
    mirror_symmetric: bool = True
    table_max_nodes: int = TABLE_MAX_NODES
    """Most field-angle nodes of the wavefront table (:func:`wavefront_table`); :data:`TABLE_INITIAL_NODES` (or
    fewer) traces the initial nodes only, no bisection (a coarser, faster table)."""

    def __post_init__(self):
        p = self.lens.prescription
        if not p.object_at_infinity:
            raise ValueError("a lens imaging an object at a finite distance is not supported on a sensor yet: its "
                             "PSFs are defined per field angle (object at infinity)")
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"sampling={self.sampling!r} is not allowed: one of {', '.join(SAMPLINGS)}")
        object.__setattr__(self, "colour_channels", tuple(self.colour_channels))
        amax = max(p.fields) if self.max_field_deg is None else float(self.max_field_deg)
        if not (math.isfinite(amax) and 0 <= amax < 90):
            raise ValueError(f"max_field_deg={amax!r} is not allowed: a field angle from 0 to below 90 degrees")
        object.__setattr__(self, "max_field_deg", amax)
        if not self.lens.is_centred:  # not rotationally symmetric: no mirror groups in a blur
            object.__setattr__(self, "mirror_symmetric", False)
        par = self.lens.paraxial()
        if not (math.isfinite(par.working_f_number) and par.working_f_number > 0):
            raise ValueError("the lens has no finite working F-number (its image is at infinity)")
        object.__setattr__(self, "_cache", {})
        if self.sampling == "point":
            lam = min(self._all_wavelengths())
            if not self.sensor.pixel_pitch_um < lam * par.working_f_number:
                raise ValueError(f"pixel pitch {self.sensor.pixel_pitch_um:g} um with sampling 'point' is not allowed "
                                 f"with this lens: below lambda N_w = {lam * par.working_f_number:.4g} um at {lam:g} um "
                                 "(use sampling 'area')")

    # -- what the pipeline reads ---------------------------------------------------------------------------------------
    @property
    def working_f_number(self) -> float:
        return self.lens.paraxial().working_f_number

    @property
    def image_scale_mm(self) -> float:
        """Paraxial image height (mm) per unit ``tan(field angle)`` on the image plane, at the primary wavelength (the
        focal length for a lens focused at infinity)."""
        if "scale" not in self._cache:
            self._cache["scale"] = image_scale_mm(self.lens)
        return self._cache["scale"]

    @property
    def geometry(self) -> FieldGeometry:
        return FieldGeometry(self.image_scale_mm, self.sensor.pixel_pitch_um)

    @property
    def channels(self) -> int:
        """1 (one PSF for every colour) or the number of colour channels."""
        return max(1, len(self.colour_channels))

    def _all_wavelengths(self) -> tuple[float, ...]:
        return tuple(sorted({w for s in (self.light, *self.colour_channels) for w in s.wavelengths_um}))

    def quadrature(self) -> tuple[tuple[float, ...], tuple[tuple[float, ...], ...]]:
        """The wavelengths (um) the PSFs integrate and each channel's weight at them ``(C, K)``: the spectrum's own, or
        for channels on one table a few shared by all (:func:`lenssim.model.spectrum.shared_quadrature`, spaced by the
        lens's spectral arc: axial and lateral colour and the diffraction scale, in pixels)."""
        if "quad" in self._cache:
            return self._cache["quad"]
        chans = self.colour_channels
        if not chans:
            q = (tuple(self.light.wavelengths_um), (tuple(self.light.weights),))
        elif shared_wavelengths(chans) and len(chans[0]) > 2:
            chans, _ = shared_quadrature(chans, self._spectral_arc_px(chans[0].wavelengths_um),
                                         self.numerics.spectral_tol)
            q = (tuple(chans[0].wavelengths_um), tuple(tuple(c.weights) for c in chans))
        else:
            lams = self._all_wavelengths()
            rows = []
            for c in chans:
                w = dict(zip(c.wavelengths_um, c.weights))
                rows.append(tuple(w.get(v, 0.0) for v in lams))
            q = (lams, tuple(rows))
        self._cache["quad"] = q
        return q

    def _spectral_arc_px(self, wavelengths_um) -> list[float]:
        pitch_mm = self.sensor.pixel_pitch_um * 1e-3
        z = self.lens.image_z_mm
        tan_max = math.tan(math.radians(self.max_field_deg))
        pts = []
        for lam in wavelengths_um:
            marg, chief = _paraxial_image_heights(self.lens, lam, z, tan_max)
            airy = lam * self.lens.paraxial(lam).working_f_number * 1e-3
            pts.append((marg / pitch_mm, chief / pitch_mm, airy / pitch_mm))
        arc = [0.0]
        for a, b in zip(pts, pts[1:]):
            arc.append(arc[-1] + sum(abs(x - y) for x, y in zip(a, b)))
        return arc

    def spectrum(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The wavelengths (um) the PSFs integrate and their weights (the channels' mean)."""
        lams, w = self.quadrature()
        return lams, tuple(sum(row[k] for row in w) / len(w) for k in range(len(lams)))

    def table(self, progress=None) -> WavefrontTable:
        """The :class:`WavefrontTable` (traced once, on first use; shared in the process by providers of the same lens,
        image plane, wavelengths and largest angle: :func:`lenssim.optics.psf_bank.cached_wavefront_table`)."""
        if "table" not in self._cache:
            self._cache["table"] = cached_wavefront_table(self.lens, self.quadrature()[0], self.max_field_deg,
                                                          self.image_scale_mm, max_nodes=self.table_max_nodes,
                                                          progress=progress)
        return self._cache["table"]

    def oversample(self) -> int:
        """Samples per pixel (odd) of the grid the PSFs are computed on."""
        if self.sampling == "point":
            return 1
        nyq = min(self.quadrature()[0]) * self.working_f_number / 2  # um
        s = max(MIN_AREA_OVERSAMPLE, math.ceil(self.sensor.pixel_pitch_um / nyq))
        return s + 1 - s % 2

    def fft_size(self, n: int) -> int:
        """The FFT size for ``n x n``-pixel PSFs: the fine window ``n s`` and the pupil's radius at least
        :data:`MIN_PUPIL_RADIUS_SAMPLES` at the longest wavelength."""
        s = self.oversample()
        fine_um = self.sensor.pixel_pitch_um / s
        lam_max = max(self.quadrature()[0])
        need = math.ceil(MIN_PUPIL_RADIUS_SAMPLES * 2 * lam_max * self.working_f_number / fine_um)
        return nice_fft_size(max((n + 1) * s, need))  # the window n s around the centre, for odd and even n

    def estimated_extent_px(self) -> int:
        """The PSF diameter (px) over the whole traced field, estimated from a few rays before any wavefront table is
        traced (the table of a badly blurred lens takes minutes): :data:`EXTENT_PUPIL_POINTS` pupil points (the rim
        and a grid inside) at :data:`EXTENT_FIELDS` field angles from the axis to :attr:`max_field_deg`, every
        wavelength, the largest distance of a ray's image point from the paraxial point doubled, + :meth:`margin_px`
        (as :meth:`extents_px`). A lower bound: 8-19% below the table's extent on the test singlet, the Cooke triplet,
        the double Gauss and a phone lens (the table also traces rays just beyond the pupil's rim), so a refusal
        from it is never wrong and a PSF it passes is checked again batch by batch (:meth:`check_fft_size`). The pupil
        points are CPU float64 tensors, as every ray of a :class:`SequentialLens` of floats (one design)."""
        n_rim = EXTENT_PUPIL_POINTS // 2
        t = torch.arange(n_rim, dtype=torch.float64, device=HOST) * (2 * math.pi / n_rim)
        g = torch.linspace(-1, 1, math.isqrt(EXTENT_PUPIL_POINTS - n_rim), dtype=torch.float64, device=HOST)
        gy, gx = torch.meshgrid(g, g, indexing="ij")
        inside = gx**2 + gy**2 < 1
        px = torch.cat([torch.cos(t), gx[inside]])
        py = torch.cat([torch.sin(t), gy[inside]])
        spot = 0.0
        fields = Fields([self.max_field_deg * k / (EXTENT_FIELDS - 1) for k in range(EXTENT_FIELDS)])
        for lam in self.quadrature()[0]:  # every field at once, each as alone
            w = self.lens.wavefront(fields, px, py, lam)
            for f, alpha in enumerate(fields.values):
                paraxial = self.image_scale_mm * math.tan(math.radians(alpha))
                pts = w.image_mm[f][w.valid[f]][:, :2]
                if pts.numel():
                    spot = max(spot, float(torch.hypot(pts[:, 0], pts[:, 1] - paraxial).max()))
        return math.ceil(2 * spot / (self.sensor.pixel_pitch_um * 1e-3)) + self.margin_px()

    def check_fft_size(self, n: int, what: str = "") -> int:
        """:meth:`fft_size` of ``n x n``-pixel PSFs, refused (:class:`lenssim.validate.ResourceLimitError`, setting
        ``max_fft_size``) above ``numerics.max_fft_size``: one such FFT grid is ``16 N^2`` bytes (complex128)."""
        N = self.fft_size(n)
        if N > self.numerics.max_fft_size:
            from ..validate import ResourceLimitError

            raise ResourceLimitError(
                f"{what or 'the lens'}: its PSF spans {n} px ({n * self.sensor.pixel_pitch_um * 1e-3:.3g} mm) on "
                f"{self.sensor.pixel_pitch_um:.4g} um pixels, sampled {self.oversample()} times per pixel for its F/"
                f"{self.working_f_number:.3g} beam: an FFT of {N} samples ({16 * N * N / 2**30:.3g} GiB per PSF), more "
                f"than the limit max_fft_size = {self.numerics.max_fft_size}", "max_fft_size")
        return N

    def margin_px(self) -> int:
        """Pixels added to the geometric PSF diameter for diffraction: :data:`DIFFRACTION_MARGIN_AIRY` times
        ``lambda N_w`` at the longest wavelength, at least :data:`MIN_MARGIN_PX`."""
        lam = max(self.quadrature()[0])
        return max(MIN_MARGIN_PX, math.ceil(DIFFRACTION_MARGIN_AIRY * lam * self.working_f_number
                                            / self.sensor.pixel_pitch_um))

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        """PSF diameter (px) at each position: twice the largest distance of a ray's image point from the pixel (every
        wavelength; distortion and lateral colour included), rounded up, + :meth:`margin_px`."""
        x, y = self.geometry.offsets_mm(rows, cols, optical_center)
        alpha = self.geometry.field_angle_deg(x, y).reshape(-1).cpu()  # the table's device
        self._check_angles(alpha)
        r = self.table().spot_radius_at(alpha)
        return torch.ceil(2 * r / (self.sensor.pixel_pitch_um * 1e-3)).to(torch.int64) + self.margin_px()

    def extent_px(self, rows, cols, optical_center) -> int:
        e = self.extents_px(rows, cols, optical_center)
        return int(e.max()) if e.numel() else self.margin_px()

    def _check_angles(self, alpha):
        if alpha.numel() and float(alpha.max()) > self.max_field_deg * (1 + 1e-9) + 1e-9:
            raise ValueError(f"field angle {float(alpha.max()):.4g} deg is beyond the {self.max_field_deg:.4g} deg "
                             "this lens's PSFs were set up for (max_field_deg)")

    def psf_at_pixels(self, rows, cols, optical_center, n, *, centered=True, dtype=None, device=None,
                      pedestal: bool = True, distortion: bool = True):
        """PSFs ``(P, n, n)`` (one channel) or ``(P, C, n, n)`` at pixel positions, unit sum each.

        Each PSF is computed on the support it needs (the largest of the positions' :meth:`extents_px`, at most ``n``)
        and laid in the middle of the ``n x n`` grid (a blur's window may be far larger than the PSF). The light the
        FFT puts beyond that support (the far wings of diffraction and aberration) is spread evenly over the whole
        ``n x n`` grid, a uniform pedestal as in today's model (:meth:`PSFProvider.pedestal_fractions`), so no light
        is lost or moved into the core; ``pedestal=False`` renormalises the support to unit sum instead.
        ``distortion=False``: each PSF about its chief ray's point, not the pixel (:func:`psfs_from_table`)."""
        r = tensor_of(rows).cpu()
        c = tensor_of(cols).cpu()
        x, y = self.geometry.offsets_mm(r, c, optical_center)
        x, y = x.reshape(-1), y.reshape(-1)
        alpha = self.geometry.field_angle_deg(x, y)
        self._check_angles(alpha)
        phi = torch.atan2(y, x)
        k = int(self.extents_px(r, c, optical_center).max()) if alpha.numel() else n
        out = self.psfs_at_angles(alpha, phi, n, k, pedestal=pedestal, distortion=distortion,
                                  complex_dtype=torch.complex128 if dtype == torch.float64 else torch.complex64)
        if not self.colour_channels:
            out = out[:, 0]
        out = out.to(dtype=dtype or torch.float32, device=device)
        return out if centered else torch.fft.ifftshift(out, dim=(-2, -1))

    def psfs_at_angles(self, alpha_deg, phi_rad, n: int, support_px: int, *, table: WavefrontTable | None = None,
                       pedestal: bool = True, distortion: bool = True, complex_dtype=torch.complex64) -> torch.Tensor:
        """PSFs ``(P, C, n, n)`` float64 (unit sum) at field angles ``alpha_deg`` and image-plane azimuths ``phi_rad``
        ``(P,)``, centred at ``[n//2, n//2]``, computed on ``support_px`` pixels (at most ``n``; given ``n``'s parity,
        so the support lies symmetrically about the grid's centre) and laid in the middle of the grid, the light
        beyond the support spread evenly over it (``pedestal``) or the support renormalised; ``table``: another
        wavefront table on this one's wavelengths (default :meth:`table`; e.g. the aberration-free pupil)."""
        if not self.lens.is_centred:
            _check_misaligned(phi_rad, distortion)
        k = min(n, int(support_px))
        k = min(n, k + (n - k) % 2)
        small, captured = psfs_from_table(
            self.table() if table is None else table, self.quadrature()[1], alpha_deg, phi_rad, k, self.oversample(),
            self.check_fft_size(k), self.sensor.pixel_pitch_um, self.working_f_number, self.sampling,
            complex_dtype=complex_dtype, distortion=distortion)
        out = torch.zeros(*small.shape[:-2], n, n, dtype=small.dtype, device=small.device)
        o = n // 2 - k // 2
        if pedestal:
            out += ((1 - captured) / (n * n))[..., None, None]
            small = small * captured[..., None, None]
        out[..., o:o + k, o:o + k] += small
        return out

    def fingerprint(self) -> str:
        """A stable description of these PSFs (lens, image plane, sensor, spectrum, sampling, numerics)."""
        d = {"prescription": self.lens.prescription.to_dict(), "image_shift_mm": self.lens.image_shift_mm,
             "sensor": self.sensor.to_dict(), "spectrum": self.light.to_dict(),
             "channels": [c.to_dict() for c in self.colour_channels], "max_field_deg": self.max_field_deg,
             "sampling": self.sampling, "numerics": self.numerics.to_dict()}
        if getattr(self.lens, "index_offsets", None):  # a manufactured copy's glass errors (absent: as before)
            d["index_offsets"] = {str(k): v for k, v in self.lens.index_offsets.items()}
        if not self.lens.is_centred:  # a manufactured copy's decentres and tilts (absent: as before)
            d["lens_cache_key"] = self.lens.cache_key()
        if self.table_max_nodes != TABLE_MAX_NODES:
            d["table_max_nodes"] = self.table_max_nodes
        return json.dumps(d, sort_keys=True, default=str)


def _check_misaligned(phi_rad, distortion: bool) -> None:
    """A misaligned lens (not rotationally symmetric) has PSFs along its ``+y`` field only (image azimuth ``pi/2``;
    other azimuths are :meth:`SequentialLens.rotated`'s ``+y``), about the chief ray's point (its boresight shift is
    not a radial distortion)."""
    phi = tensor_of(phi_rad, torch.float64)
    if phi.numel() and bool(((phi - math.pi / 2).abs() > 1e-12).any()):
        raise ValueError("a decentred or tilted lens's PSFs are defined along its +y field only (image azimuth 90 "
                         "deg): take the other azimuths from SequentialLens.rotated")
    if distortion:
        raise ValueError("a decentred or tilted lens's PSFs are about the chief ray's point only (distortion=False)")
