"""The design criteria, as a registry: name -> how it is computed, its sense, role, label and unit.

Two kinds (Sections 2.2-2.3 of the paper):

* **OTF criteria**, computed per field angle from the pixel-sampled OTF of each PSF (an
  :class:`OTFContext`: the OTF with its frequency axes, the image model, the noise variances, the camera,
  an optional reference OTF), then averaged over the field: ``mse_s`` and ``mse_r`` (the paper's),
  ``strehl`` and ``mtf50``;
* **design criteria**, computed from the design and its wavefront coefficients directly: ``rms_w``
  and ``cost`` (``C_a``, :mod:`lenssim.optics.cost`).

Each criterion declares its **sense** (``"min"``: smaller is better, or ``"max"``), whether it depends on
the SNR (``per_snr``) and its **role** (``"quality"`` or ``"cost"``); evaluate, sweeps, optima, the
trade-off, focus and the command line read these and never a criterion's name.

Adding a criterion is one file in this package (``lenssim/criteria/NAME.py``) that calls
:func:`register`: every module here is imported when the package is (the paper's four first, in the
paper's order, then the others by file name).

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Sections 2.1-2.3, Eqs. (2)-(6).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..model.camera import Camera
from ..registry import Registry, import_plugins

__all__ = ["Criterion", "OTFContext", "CRITERIA", "register", "validate_criterion", "otf_criteria",
           "quality_criteria", "lens_criteria", "quarter_weights", "wavefront_rms_per_field", "SENSES", "ROLES"]

SENSES = ("min", "max")
ROLES = ("quality", "cost")


def quarter_weights(n: int, dtype, device) -> torch.Tensor:
    """Weights ``(n/2+1, n/2+1)`` that turn a quarter-plane sum into the mean over the ``n x n`` DFT grid
    of a function even in both axes."""
    w = torch.full((n // 2 + 1,), 2.0, dtype=dtype, device=device)
    w[0] = 1.0
    w[-1] = 1.0
    return w[:, None] * w[None, :] / float(n * n)


@dataclass
class OTFContext:
    """What an OTF criterion sees of one batch of PSFs (one FFT size), with its sampling.

    ``H``: quarter-plane OTFs ``(B, m/2+1, m/2+1)`` (axes ``(fy, fx)``, sample ``k`` at ``k / m`` cycles/pixel,
    ``0 .. 1/2``; ``m = n * oversample``), normalised to ``H(0) = 1``; ``H2 = |H|^2``; ``psd`` the image model
    ``P_x`` on the same grid (unit signal variance); ``weights`` the quarter-plane integration weights (their
    sum with an even function is its mean over the ``m x m`` DFT grid); ``pw = psd * weights``; ``sigma2``
    ``(S,)`` the noise variances (unit signal variance); ``n`` the FFT size of the PSFs; ``camera`` (pixel
    pitch, spectrum; a sensor ``fill_factor`` multiplies the pixel aperture's MTF into ``H``, ``H2``, the reference and
    the diffraction-limited OTF); ``reference``: an optional reference OTF ``(B, m/2+1, m/2+1)`` on the same grid (e.g. a
    nominal lens's, for a restoration designed for it).
    """

    H: torch.Tensor
    H2: torch.Tensor
    psd: torch.Tensor
    weights: torch.Tensor
    pw: torch.Tensor
    sigma2: torch.Tensor
    n: int
    camera: Camera
    numerics: object = None
    reference: torch.Tensor | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        # a sensor with a pixel aperture: its box MTF is part of the system's OTF (and of a reference's)
        mtf = self.pixel_mtf()
        if mtf is not None:
            self.H = self.H * mtf
            self.H2 = self.H2 * mtf.square()
            if self.reference is not None:
                self.reference = self.reference * mtf

    def pixel_mtf(self) -> torch.Tensor | None:
        """The pixel aperture's MTF on the quarter plane ``(m/2+1, m/2+1)`` (:mod:`lenssim.optics.pixel_aperture`),
        None for point sampling (no ``fill_factor`` on the camera's sensor)."""
        ff = getattr(self.camera.sensor, "fill_factor", None)
        if ff is None:
            return None
        from ..optics.pixel_aperture import pixel_aperture_mtf

        f = torch.arange(self.H.shape[-1], dtype=torch.float64, device=self.H.device) / self.m
        return pixel_aperture_mtf(f, f, ff).to(self.H.real.dtype)

    @property
    def m(self) -> int:
        """Frequency samples per axis of the full grid (``n * oversample``)."""
        return 2 * (self.H.shape[-1] - 1)

    @property
    def freq_cycles_per_pixel(self) -> torch.Tensor:
        """The quarter plane's frequency axis ``(m/2+1,)`` in cycles/pixel (0 .. 0.5), float64."""
        return torch.arange(self.m // 2 + 1, dtype=torch.float64, device=self.H.device) / self.m

    @property
    def freq_cycles_per_mm(self) -> torch.Tensor:
        """The quarter plane's frequency axis ``(m/2+1,)`` in cycles/mm on the sensor, float64."""
        return self.freq_cycles_per_pixel / (self.camera.sensor.pixel_pitch_um * 1e-3)

    def diffraction_limited(self) -> torch.Tensor:
        """The aberration-free OTF ``(1, m/2+1, m/2+1)`` of the same camera on the same grid (computed once)."""
        if "dl" not in self._cache:
            from ..optics.psf_bank import otf_quarter_spectrum

            zero = torch.zeros(1, len(self.camera.spectrum), self._terms(), dtype=self.H.real.dtype,
                               device=self.H.device)
            kw = {"numerics": self.numerics} if self.numerics is not None else {}
            self._cache["dl"] = otf_quarter_spectrum(self.camera, zero, self.n, oversample=self.m // self.n, **kw)
        mtf = self.pixel_mtf()  # the aberration-free camera has the same pixels
        return self._cache["dl"] if mtf is None else self._cache["dl"] * mtf

    def _terms(self) -> int:
        from ..optics.aberrations import N_TERMS

        return N_TERMS

    def integrate(self, f: torch.Tensor) -> torch.Tensor:
        """Mean over the full ``m x m`` frequency grid of a function even in both axes given on the quarter
        plane ``(..., m/2+1, m/2+1)``: ``(...)`` in float64."""
        return (f * self.weights).sum(dim=(-2, -1)).to(torch.float64)


@dataclass(frozen=True)
class Criterion:
    """A design criterion.

    ``from_otf(ctx: OTFContext) -> (B, S)`` if ``per_snr`` else ``(B,)`` (float64), per PSF, for OTF criteria
    (averaged over the field by :func:`lenssim.metrics.evaluate`); ``from_design(camera, design, coeffs,
    numerics) -> (*)`` for design criteria (``coeffs`` ``(*, A, K, T)`` in waves, design in float64).
    ``sense``: ``"min"`` (smaller is better) or ``"max"``; ``role``: ``"quality"`` or ``"cost"``;
    ``needs_reference``: the criterion compares the lens with a reference lens (``OTFContext.reference``, e.g. a
    restoration built for the nominal lens applied to an as-built one): it is computed where a reference is given
    (:mod:`lenssim.tolerancing`), not by :func:`lenssim.metrics.evaluate` and the sweeps of one lens.
    """

    name: str
    label: str
    description: str
    units: str
    per_snr: bool
    from_otf: Callable | None = None
    from_design: Callable | None = None
    sense: str = "min"
    role: str = "quality"
    needs_reference: bool = False

    def __post_init__(self):
        if (self.from_otf is None) == (self.from_design is None):
            raise ValueError(f"criterion {self.name!r}: give exactly one of from_otf and from_design")
        if self.sense not in SENSES:
            raise ValueError(f"criterion {self.name!r}: sense={self.sense!r} is not allowed; one of {', '.join(SENSES)}")
        if self.role not in ROLES:
            raise ValueError(f"criterion {self.name!r}: role={self.role!r} is not allowed; one of {', '.join(ROLES)}")

    @property
    def sign(self) -> float:
        """+1 for a criterion to minimise, -1 for one to maximise: ``sign * value`` is always minimised."""
        return 1.0 if self.sense == "min" else -1.0


CRITERIA: Registry = Registry("criterion")
"""The registry: name -> :class:`Criterion` (filled by the modules of this package)."""

register = CRITERIA.register
"""Add a :class:`Criterion` to :data:`CRITERIA` (a name may be registered once)."""

validate_criterion = CRITERIA.validate
"""The registered criterion of a name; ``ValueError`` listing the valid names otherwise."""


def lens_criteria() -> dict:
    """The registered criteria of one lens, by name (those that need no reference lens): what
    :func:`lenssim.metrics.evaluate`, the sweeps and the trade-off compute."""
    return {k: c for k, c in CRITERIA.items() if not c.needs_reference}


def otf_criteria(*, reference: bool = False) -> tuple[str, ...]:
    """Names of the registered OTF criteria of one lens; with ``reference``, also those that compare the lens with
    a reference lens."""
    return tuple(k for k, c in CRITERIA.items() if c.from_otf is not None and (reference or not c.needs_reference))


def quality_criteria() -> tuple[str, ...]:
    """Names of the registered criteria of one lens whose role is image quality (everything but costs)."""
    return tuple(k for k, c in lens_criteria().items() if c.role == "quality")


def wavefront_rms_per_field(camera, coeffs: torch.Tensor, piston_removed: bool = False, terms=None) -> torch.Tensor:
    """``RMS_w(alpha)`` ``(*, A)`` in waves at the spectrum's reference wavelength, from ``(*, A, K, T)``
    (``terms``: their monomial table, default :data:`lenssim.optics.aberrations.TERMS`).

    Over a spectrum: the weighted mean square over the wavelengths (``W_k lambda_k / lambda_ref`` in
    reference waves).
    """
    from ..optics.aberrations import rms_wavefront

    spec = camera.spectrum
    if len(spec) == 1:
        return rms_wavefront(coeffs[..., 0, :], piston_removed, terms)
    ms = sum(w * rms_wavefront(coeffs[..., k, :] * (lam / spec.reference_um), piston_removed, terms) ** 2
             for k, (lam, w) in enumerate(zip(spec.wavelengths_um, spec.weights)))
    return torch.sqrt(ms)


# the paper's criteria first, in its order: RMS_W, MSE_S, MSE_R, C_a
import_plugins(__name__, __path__, first=("wavefront", "mse", "cost"))
