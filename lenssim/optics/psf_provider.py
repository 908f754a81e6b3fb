"""PSF providers: field position -> PSF, the one thing blur and restoration need from the optics.

The image pipeline (blur, restoration, the exact per-pixel reference) never sees a lens model: it
asks a provider for the PSFs at pixel positions of an array whose optical axis is at
``optical_center``, on an ``n x n`` grid of the sensor's pixels. Two providers:

* :class:`LensPSF`: the model (camera + design, Fourier optics of the third-order pupil),
* :class:`AsBuiltPSF`: one manufactured lens (:mod:`lenssim.optics.as_built`): no rotational symmetry, so one PSF
  per window (the blur's mirror-group sharing is off),
* :class:`FunctionPSF`: any callable ``fn(x_mm, y_mm, n) -> (P, n, n)`` (measured or tabulated PSFs,
  centred, unit sum), with the field geometry it lives in.

A provider returns ``(P, n, n)`` (one PSF for every colour channel) or ``(P, C, n, n)`` (one per
channel); :attr:`channels` says which (1 or C).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..model.camera import Camera
from ..model.design import Design
from ..model.geometry import FieldGeometry
from ..model.numerics import DEFAULT_NUMERICS, Numerics
from ..torch_utils import HOST, tensor_of
from .psf_bank import max_wavefront_slope, pedestal_fraction, spectral_coefficients
from .wavefront_models import validate_wavefront_model

__all__ = ["PSFProvider", "DerivedPSF", "LensPSF", "FunctionPSF", "AsBuiltPSF"]


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
