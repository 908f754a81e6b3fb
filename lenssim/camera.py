"""The imaging system a designer names: lens + sensor + spectrum, and the sampling they imply.

PSF sampling (Fraunhofer by FFT): with an ``N x N`` FFT, pixel pitch ``Delta`` and wavelength
``lambda``, the pupil radius spans ``R = N Delta / (2 lambda f#)`` samples (``N / 4`` at the
Nyquist pitch ``lambda f# / 2``). A pitch coarser than Nyquist at the shortest wavelength would
alias the OTF in this model and is refused where PSFs are computed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .geometry import FieldGeometry
from .lens import Lens
from .sensor import Sensor
from .spectrum import Spectrum

__all__ = ["Camera"]


@dataclass(frozen=True)
class Camera:
    """Lens, sensor and spectrum (defaults: the paper's)."""

    lens: Lens = field(default_factory=Lens)
    sensor: Sensor = field(default_factory=Sensor)
    spectrum: Spectrum = field(default_factory=Spectrum)

    def __post_init__(self):
        for k, cls in (("lens", Lens), ("sensor", Sensor), ("spectrum", Spectrum)):
            if not isinstance(getattr(self, k), cls):
                raise ValueError(f"{k}={getattr(self, k)!r} is not allowed: a {cls.__name__}")

    @property
    def geometry(self) -> FieldGeometry:
        return FieldGeometry(self.lens.focal_length_mm, self.sensor.pixel_pitch_um)

    @property
    def pixel_pitch_um(self) -> float:
        return self.sensor.pixel_pitch_um

    def check_sampling(self) -> None:
        """Refuse a pitch coarser than ``lambda_min f# / 2`` (the FFT model's OTF would alias)."""
        nyq = self.lens.nyquist_pitch_um(self.spectrum.shortest_um)
        if not self.pixel_pitch_um <= nyq * (1 + 1e-12):
            raise ValueError(f"pixel_pitch_um={self.pixel_pitch_um!r} is not allowed with this lens and spectrum: "
                             f"must be in (0, {nyq}] um (coarser than lambda f#/2 at {self.spectrum.shortest_um:g} "
                             "um aliases the OTF)")

    def pupil_radius_px(self, n: int, wavelength_um: float) -> float:
        """Pupil radius in samples of an ``n``-point FFT at ``wavelength_um``: ``n Delta / (2 lambda f#)``."""
        self.check_sampling()
        return n * self.pixel_pitch_um / (2 * wavelength_um * self.lens.f_number)

    def geometric_radius_px(self, slope, wavelength_um: float):
        """Geometric blur radius (px) of a wavefront slope ``slope`` (waves per unit pupil radius):
        ``slope lambda f / (y Delta)`` (the transverse ray aberration ``(f / y) grad W`` in pixels)."""
        lens = self.lens
        return slope * wavelength_um * lens.focal_length_mm / (lens.pupil_radius_mm * self.pixel_pitch_um)

    def to_dict(self) -> dict:
        return {"lens": self.lens.to_dict(), "sensor": self.sensor.to_dict(), "spectrum": self.spectrum.to_dict()}
