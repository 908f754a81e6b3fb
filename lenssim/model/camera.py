"""The imaging system a designer names: lens + sensor + spectrum, and the sampling they imply.

PSF sampling (Fraunhofer by FFT): with an ``N x N`` FFT, pixel pitch ``Delta`` and wavelength
``lambda``, the pupil radius spans ``R = N Delta / (2 lambda f#)`` samples (``N / 4`` at the
Nyquist pitch ``lambda f# / 2``). The FFT gives the PSF's values at the pixel centres (point
sampling, as the paper's model): a pitch coarser than Nyquist at some wavelength (``R > N / 4``,
e.g. the paper's sensor in blue light) makes those samples alias exactly as a real sensor's do, and
is allowed with a :class:`lenssim.validate.ModelValidityWarning`; the pupil must still fit the
grid, so a pitch coarser than ``lambda f#`` (``R > N / 2 - 2``) is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from .geometry import FieldGeometry
from .lens import Lens
from .sensor import Sensor
from .spectrum import Spectrum, shared_quadrature, shared_wavelengths

__all__ = ["Camera"]

_QUADRATURE_CACHE: dict = {}
_QUADRATURE_RESULTS: set = set()  # cameras with_quadrature returned (a few per process): not reduced again


@dataclass(frozen=True)
class Camera:
    """Lens, sensor and spectrum (the paper's: :data:`lenssim_studies.paper.PAPER_CAMERA`)."""

    lens: Lens
    sensor: Sensor
    spectrum: Spectrum
    channels: tuple[Spectrum, ...] = ()
    """Colour channels (e.g. :func:`lenssim.model.spectrum.channel_spectra`): each its own spectrum, PSF and
    criteria; empty: one channel, ``spectrum``, shared by every colour (the paper)."""

    def __post_init__(self):
        for k, cls in (("lens", Lens), ("sensor", Sensor), ("spectrum", Spectrum)):
            if not isinstance(getattr(self, k), cls):
                raise ValueError(f"{k}={getattr(self, k)!r} is not allowed: a {cls.__name__}")
        object.__setattr__(self, "channels", tuple(self.channels))
        for c in self.channels:
            if not isinstance(c, Spectrum):
                raise ValueError(f"channels holds {c!r}: expected Spectrum objects")

    def channel_cameras(self) -> tuple["Camera", ...]:
        """One single-spectrum camera per colour channel (just this one without channels)."""
        if not self.channels:
            return (self,)
        return tuple(Camera(self.lens, self.sensor, c) for c in self.channels)

    @property
    def shared_channels(self) -> bool:
        """True if the colour channels all integrate the same wavelengths (a table, or its shared quadrature): the
        optics then compute each wavelength once for every channel."""
        return shared_wavelengths(self.channels)

    def with_quadrature(self, tol: float) -> "Camera":
        """This camera with channels on one table (:func:`lenssim.model.spectrum.channel_table`) reduced to the few
        wavelengths of :func:`lenssim.model.spectrum.shared_quadrature` (error indicator <= ``tol`` px), shared by
        every channel; any other camera, and a camera this method returned, unchanged (reducing the few shared
        wavelengths again as if they were a table would drop some). Cached per camera and ``tol``.

        Channels on shared wavelengths are taken as a table to integrate: the metrics and the PSFs call this with
        ``numerics.spectral_tol``. To use shared wavelengths of one's own as they are, give a bound that keeps every
        one (e.g. ``spectral_tol=1e-9``)."""
        if not self.shared_channels or len(self.channels[0]) <= 2 or self in _QUADRATURE_RESULTS:
            return self
        key = (self, float(tol))
        hit = _QUADRATURE_CACHE.get(key)
        if hit is None:
            chans, _ = shared_quadrature(self.channels, self.spectral_arc_px(self.channels[0].wavelengths_um), tol)
            hit = Camera(self.lens, self.sensor, self.spectrum, chans)
            if len(_QUADRATURE_CACHE) > 64:
                _QUADRATURE_CACHE.clear()
            _QUADRATURE_CACHE[key] = hit
            if hit != self:  # the table itself (a bound that keeps every wavelength) is no result
                _QUADRATURE_RESULTS.add(hit)
        return hit

    def node_camera(self) -> tuple["Camera", tuple[tuple[float, ...], ...]]:
        """For shared channels: a one-spectrum camera on their wavelengths (weights: the channels' mean) and the weights
        ``(C, K)`` of each channel at each wavelength."""
        if not self.shared_channels:
            raise ValueError("node_camera needs colour channels on the same wavelengths (see shared_channels)")
        lam = self.channels[0].wavelengths_um
        mean = tuple(sum(c.weights[k] for c in self.channels) / len(self.channels) for k in range(len(lam)))
        return Camera(self.lens, self.sensor, Spectrum(lam, mean, name="shared wavelengths")), \
            tuple(tuple(c.weights) for c in self.channels)

    @property
    def geometry(self) -> FieldGeometry:
        return FieldGeometry(self.lens.focal_length_mm, self.sensor.pixel_pitch_um)

    @property
    def pixel_pitch_um(self) -> float:
        return self.sensor.pixel_pitch_um

    def check_sampling(self) -> None:
        """Refuse a pitch coarser than ``lambda_min f#`` (the pupil would not fit the FFT grid); warn when it is
        coarser than the Nyquist pitch ``lambda_min f# / 2`` (the sampled PSF aliases, as a real sensor's)."""
        shortest = min(s.shortest_um for s in (self.spectrum, *self.channels))
        nyq = self.lens.nyquist_pitch_um(shortest)
        if not self.pixel_pitch_um < 2 * nyq:
            raise ValueError(f"pixel_pitch_um={self.pixel_pitch_um!r} is not allowed with this lens and spectrum: "
                             f"must be below lambda f# = {2 * nyq:.6g} um at {shortest:g} um (the pupil would not "
                             "fit the FFT grid)")
        if self.pixel_pitch_um > nyq * (1 + 1e-12):
            from ..validate import warn_model

            warn_model(f"the {self.pixel_pitch_um:g} um pixels undersample wavelengths below "
                       f"{2 * self.pixel_pitch_um / self.lens.f_number:.3g} um at f/{self.lens.f_number:g}: their "
                       "sampled PSFs alias, as a real sensor's")

    def pupil_radius_px(self, n: int, wavelength_um: float) -> float:
        """Pupil radius in samples of an ``n``-point FFT at ``wavelength_um``: ``n Delta / (2 lambda f#)``."""
        self.check_sampling()
        return n * self.pixel_pitch_um / (2 * wavelength_um * self.lens.f_number)

    def geometric_radius_px(self, slope, wavelength_um: float):
        """Geometric blur radius (px) of a wavefront slope ``slope`` (waves per unit pupil radius):
        ``slope lambda f / (y Delta)`` (the transverse ray aberration ``(f / y) grad W`` in pixels)."""
        lens = self.lens
        return slope * wavelength_um * lens.focal_length_mm / (lens.pupil_radius_mm * self.pixel_pitch_um)

    def spectral_arc_px(self, wavelengths_um) -> list[float]:
        """The spectral arc length (px) at increasing ``wavelengths_um``, from 0 at the first: how far the PSF moves
        on the sensor between wavelengths, the measure :func:`lenssim.model.spectrum.shared_quadrature` spaces its
        wavelengths by.

        Two parts add up along the spectrum. Axial colour: the marginal ray crosses the image plane at
        ``y (t_img - t(lambda)) / t(lambda)`` (mm, ``t`` the focus distance at ``lambda``), which moves by that much
        between wavelengths whatever the focus; it is design-independent for the thin lens, and the Seidel terms'
        dispersion (about ``dn / (n - 1)`` of them, 1.6% across the visible in N-BK7) is left to the error margin.
        Diffraction: the Airy scale ``lambda f# / Delta`` (px) grows with the wavelength.
        """
        lens = self.lens
        lam = [float(v) for v in wavelengths_um]
        if any(b <= a for a, b in zip(lam, lam[1:])):
            raise ValueError("wavelengths_um must increase")
        t_img = lens.image_distance_mm
        ray_px = [lens.pupil_radius_mm * (t_img - lens.focus_distance_mm(v)) / lens.focus_distance_mm(v) * 1e3
                  / self.pixel_pitch_um for v in lam]
        airy_px = [v * lens.f_number / self.pixel_pitch_um for v in lam]
        arc = [0.0]
        for j in range(1, len(lam)):
            arc.append(arc[-1] + abs(ray_px[j] - ray_px[j - 1]) + abs(airy_px[j] - airy_px[j - 1]))
        return arc

    def to_dict(self) -> dict:
        d = {"lens": self.lens.to_dict(), "sensor": self.sensor.to_dict(), "spectrum": self.spectrum.to_dict()}
        if self.channels:
            d["channels"] = [c.to_dict() for c in self.channels]
        return d
