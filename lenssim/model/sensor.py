"""The image sensor: pixel pitch, size, full-well capacity per ISO, read noise and ADC depth.

The paper's sensor (:data:`lenssim.paper.PAPER_SENSOR`, the defaults here): 1.5625 um pixels
(the Nyquist pitch ``lambda f# / 2`` of its lens at 0.5 um, but fixed here, independent of the
wavelength), 6000 x 4000 pixels, full well 12,800 / 3,200 / 800 e- at ISO 25 / 100 / 400, no
read noise and no quantisation (the paper's pure photon-noise model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
            raise ValueError(f"iso={iso!r} is not allowed: one of {sorted(table)} (or give the full well directly)")
        return table[iso]

    def to_dict(self) -> dict:
        return {"pixel_pitch_um": self.pixel_pitch_um, "width_px": self.width_px, "height_px": self.height_px,
                "full_well_e": [list(p) for p in self.full_well_e], "read_noise_e": self.read_noise_e,
                "bit_depth": self.bit_depth}
