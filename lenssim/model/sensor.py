"""The image sensor: pixel pitch, size, full-well capacity per ISO, read noise and ADC depth.

The paper's sensor (:data:`lenssim.paper.PAPER_SENSOR`, the defaults here): 1.5625 um pixels
(the Nyquist pitch ``lambda f# / 2`` of its lens at 0.5 um, but fixed here, independent of the
wavelength), 6000 x 4000 pixels, full well 12,800 / 3,200 / 800 e- at ISO 25 / 100 / 400, no
read noise and no quantisation (the paper's pure photon-noise model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..validate import listed, quoted

__all__ = ["Sensor"]


@dataclass(frozen=True, kw_only=True)
class Sensor:
    """A sensor: pixel pitch (um), size (px), full well per ISO (``full_well_e``, ``(iso, electrons)`` pairs; empty:
    no ISO table, give full wells directly), read noise (electrons RMS) and ADC bits (``bit_depth`` None: no
    quantisation)."""

    pixel_pitch_um: float
    width_px: int
    height_px: int
    full_well_e: tuple[tuple[int, float], ...] = ()
    read_noise_e: float = 0.0
    bit_depth: int | None = None
    name: str = ""
    source: str = ""
    quantum_efficiency: tuple[float, ...] = ()
    """Per colour channel (R, G, B), the fraction of photons that become electrons (0, 1]; empty: 1 (the paper)."""
    dark_current_e_per_s: float = 0.0
    black_level_dn: int = 0
    white_level_dn: int | None = None
    """The ADC's largest value (DN); None: ``2^bit_depth - 1``."""
    prnu_percent: float = 0.0
    dsnu_e: float = 0.0
    fill_factor: float | None = None
    """The fraction of the pixel's area that collects light (a centred square of side ``sqrt(fill_factor)`` px; its
    box MTF enters every design criterion and the image pipeline's PSFs, :mod:`lenssim.optics.pixel_aperture`); None:
    point sampling, no pixel aperture (the paper)."""
    cfa: str = "none"
    """The Bayer pattern from the top-left pixel (RGGB, BGGR, GRBG, GBRG) or ``"none"``."""
    colour_matrix: tuple[tuple[float, float, float], ...] = ()
    """Camera RGB -> linear sRGB (3 x 3, rows: sRGB R, G, B); empty: identity (the scene's RGB is the camera's)."""

    def __post_init__(self):
        p = self.pixel_pitch_um
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not math.isfinite(p) or not p > 0:
            raise ValueError(f"pixel_pitch_um={p!r} is not allowed: a finite number > 0 um")
        object.__setattr__(self, "pixel_pitch_um", float(p))
        for k in ("width_px", "height_px"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{k}={v!r} is not allowed: a positive whole number of pixels")
        try:
            table = tuple(sorted((int(i), float(e)) for i, e in dict(self.full_well_e).items()))
        except (TypeError, ValueError):
            raise ValueError(f"full_well_e={self.full_well_e!r} is not allowed: (iso, electrons) pairs") from None
        for iso, e in table:
            if not (iso > 0 and math.isfinite(e) and e > 0):
                raise ValueError(f"full_well_e: ISO {iso} -> {e!r} e- is not allowed: ISO > 0 and a finite full "
                                 "well > 0 electrons")
        object.__setattr__(self, "full_well_e", table)
        r = self.read_noise_e
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r) or r < 0:
            raise ValueError(f"read_noise_e={r!r} is not allowed: a finite number >= 0 electrons (RMS)")
        object.__setattr__(self, "read_noise_e", float(r))
        b = self.bit_depth
        if b is not None and (isinstance(b, bool) or not isinstance(b, int) or not 1 <= b <= 32):
            raise ValueError(f"bit_depth={b!r} is not allowed: None (no quantisation) or 1..32 bits")
        for k in ("name", "source"):
            if not isinstance(getattr(self, k), str):
                raise ValueError(f"{k}={getattr(self, k)!r} is not allowed: text")
        qe = self.quantum_efficiency
        try:
            qe = tuple(float(q) for q in qe)
        except (TypeError, ValueError):
            raise ValueError(f"quantum_efficiency={self.quantum_efficiency!r} is not allowed: one fraction per colour "
                             "channel (R, G, B)") from None
        if qe and (len(qe) != 3 or not all(math.isfinite(q) and 0 < q <= 1 for q in qe)):
            raise ValueError(f"quantum_efficiency={self.quantum_efficiency!r} is not allowed: three fractions in (0, 1] "
                             "(R, G, B), or none")
        object.__setattr__(self, "quantum_efficiency", qe)
        for k, unit in (("dark_current_e_per_s", "e-/s"), ("prnu_percent", "% RMS"), ("dsnu_e", "e- RMS")):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{k}={v!r} is not allowed: a finite number >= 0 ({unit})")
            object.__setattr__(self, k, float(v))
        if self.prnu_percent > 100:
            raise ValueError(f"prnu_percent={self.prnu_percent!r} is not allowed: 0 to 100 (% RMS of the signal)")
        for k in ("black_level_dn", "white_level_dn"):
            v = getattr(self, k)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
                raise ValueError(f"{k}={v!r} is not allowed: a whole number >= 0 (DN)")
        if b is None and (self.black_level_dn or self.white_level_dn is not None):
            raise ValueError("black_level_dn / white_level_dn need an ADC: give bit_depth")
        if b is not None:
            top = 2**b - 1
            white = top if self.white_level_dn is None else self.white_level_dn
            if white > top:
                raise ValueError(f"white_level_dn={white} is not allowed: at most 2^bit_depth - 1 = {top} DN")
            if not self.black_level_dn < white:
                raise ValueError(f"black_level_dn={self.black_level_dn} is not allowed: below the white level "
                                 f"({white} DN)")
        f = self.fill_factor
        if f is not None and (isinstance(f, bool) or not isinstance(f, (int, float)) or not math.isfinite(f)
                              or not 0 < f <= 1):
            raise ValueError(f"fill_factor={f!r} is not allowed: a fraction in (0, 1], or None (point sampling)")
        if f is not None:
            object.__setattr__(self, "fill_factor", float(f))
        c = str(self.cfa).upper() if str(self.cfa).lower() != "none" else "none"
        if c not in ("none", "RGGB", "BGGR", "GRBG", "GBRG"):
            raise ValueError(f"cfa={self.cfa!r} is not allowed: none, RGGB, BGGR, GRBG or GBRG")
        object.__setattr__(self, "cfa", c)
        m = self.colour_matrix
        try:
            m = tuple(tuple(float(v) for v in row) for row in m)
        except (TypeError, ValueError):
            raise ValueError(f"colour_matrix={self.colour_matrix!r} is not allowed: 3 rows of 3 numbers") from None
        if m and (len(m) != 3 or any(len(r) != 3 for r in m) or not all(math.isfinite(v) for r in m for v in r)):
            raise ValueError(f"colour_matrix={self.colour_matrix!r} is not allowed: 3 rows of 3 finite numbers "
                             "(camera RGB -> linear sRGB), or none")
        if m:
            import numpy as np

            if abs(np.linalg.det(np.array(m))) < 1e-9:
                raise ValueError(f"colour_matrix={m!r} is not allowed: it is singular (the scene could not be "
                                 "expressed in the camera's RGB)")
        object.__setattr__(self, "colour_matrix", m)

    @property
    def white_level(self) -> int | None:
        """The ADC's largest value (DN), None without an ADC."""
        if self.bit_depth is None:
            return None
        return 2**self.bit_depth - 1 if self.white_level_dn is None else self.white_level_dn

    def conversion_gain_e_per_dn(self, full_well: float) -> float | None:
        """Electrons per DN at the ISO whose full well is ``full_well`` electrons (the ADC's range spans it); None
        without an ADC."""
        if self.bit_depth is None:
            return None
        return float(full_well) / (self.white_level - self.black_level_dn)

    def qe(self, channels: int) -> tuple[float, ...]:
        """The quantum efficiency of each of ``channels`` colour channels (1 each when not given)."""
        if not self.quantum_efficiency:
            return (1.0,) * channels
        if channels != len(self.quantum_efficiency):
            raise ValueError(f"the sensor's quantum efficiency has {len(self.quantum_efficiency)} channels; the image "
                             f"has {channels}")
        return self.quantum_efficiency

    @property
    def chain_terms(self) -> bool:
        """True if any of the camera chain's terms beyond the paper's (read noise, ADC) is set."""
        return self.to_dict().keys() - _BASE_KEYS != set()

    @property
    def pixel_pitch_mm(self) -> float:
        return self.pixel_pitch_um * 1e-3

    @property
    def shape(self) -> tuple[int, int]:
        """``(height_px, width_px)``."""
        return self.height_px, self.width_px

    @property
    def isos(self) -> tuple[int, ...]:
        return tuple(i for i, _ in self.full_well_e)

    def full_well_for_iso(self, iso: int) -> float:
        """Full-well capacity (electrons) at ``iso``."""
        table = dict(self.full_well_e)
        if iso not in table:
            raise ValueError(f"iso={quoted(iso)} is not allowed: one of {listed(sorted(table))} (or give the full well directly)")
        return table[iso]

    def to_dict(self) -> dict:
        """The sensor's terms (those of the camera chain only where set: the paper's sensor's description, and the
        digests of runs made with it, are unchanged)."""
        d = {"pixel_pitch_um": self.pixel_pitch_um, "width_px": self.width_px, "height_px": self.height_px,
             "full_well_e": [list(p) for p in self.full_well_e], "read_noise_e": self.read_noise_e,
             "bit_depth": self.bit_depth}
        for k, default in _CHAIN_DEFAULTS.items():
            v = getattr(self, k)
            if v != default:
                d[k] = [list(r) for r in v] if k == "colour_matrix" else list(v) if isinstance(v, tuple) else v
        return d


_CHAIN_DEFAULTS = {"name": "", "source": "", "quantum_efficiency": (), "dark_current_e_per_s": 0.0, "black_level_dn": 0,
                   "white_level_dn": None, "prnu_percent": 0.0, "dsnu_e": 0.0, "fill_factor": None, "cfa": "none",
                   "colour_matrix": ()}
_BASE_KEYS = {"pixel_pitch_um", "width_px", "height_px", "full_well_e", "read_noise_e", "bit_depth", "name", "source"}
