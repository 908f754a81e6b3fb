"""Lens glasses: the refractive index as a function of wavelength.

The paper's glass is non-dispersive, ``n = 1.5`` at every wavelength (:class:`ConstantGlass`).
A dispersive glass is any object with a ``name`` and ``index(wavelength_um) -> float``; the lens,
the aberrations and the PSFs ask for the index at each wavelength of the spectrum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ConstantGlass", "SellmeierGlass", "as_glass", "load_glasses", "glass_by_name", "D_LINE_UM", "F_LINE_UM",
           "C_LINE_UM"]

D_LINE_UM = 0.5875618
"""Helium d line (um): where catalogues give n_d, and where a dispersive lens's focal length is specified."""
F_LINE_UM = 0.4861327
C_LINE_UM = 0.6562725
"""Hydrogen F and C lines (um) of the Abbe number ``V_d = (n_d - 1) / (n_F - n_C)``."""


@dataclass(frozen=True)
class ConstantGlass:
    """A glass of the same refractive index ``refractive_index`` (> 1) at every wavelength."""

    refractive_index: float

    def __post_init__(self):
        n = self.refractive_index
        if isinstance(n, bool) or not isinstance(n, (int, float)) or not math.isfinite(n) or not n > 1:
            raise ValueError(f"refractive_index={n!r} is not allowed: a finite number > 1")
        object.__setattr__(self, "refractive_index", float(n))

    @property
    def name(self) -> str:
        return f"n = {self.refractive_index:g}"

    def index(self, wavelength_um: float) -> float:
        """Refractive index at ``wavelength_um`` (the same at every wavelength)."""
        return self.refractive_index

    @property
    def dispersive(self) -> bool:
        return False


@dataclass(frozen=True)
class SellmeierGlass:
    """A dispersive glass: ``n^2 - 1 = sum B_i lambda^2 / (lambda^2 - C_i)`` (``lambda`` in um, ``C_i`` in um^2).

    ``refractive_index`` is the index at ``reference_um`` (default the d line), at which a lens of this
    glass has its nominal focal length.
    """

    name: str
    B: tuple[float, float, float]
    C: tuple[float, float, float]
    reference_um: float = D_LINE_UM
    description: str = ""

    def __post_init__(self):
        try:
            B, C = tuple(float(b) for b in self.B), tuple(float(c) for c in self.C)
        except (TypeError, ValueError):
            raise ValueError(f"glass {self.name!r}: Sellmeier B and C must be numbers") from None
        if len(B) != len(C) or not B or not all(math.isfinite(v) for v in B + C) or any(c < 0 for c in C):
            raise ValueError(f"glass {self.name!r}: Sellmeier B and C must be equally many finite numbers, C >= 0 um^2")
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "C", C)
        n = self.index(self.reference_um)
        if not (math.isfinite(n) and n > 1):
            raise ValueError(f"glass {self.name!r}: n = {n!r} at {self.reference_um} um is not a glass")

    def index(self, wavelength_um: float) -> float:
        """Refractive index at ``wavelength_um`` (um)."""
        l2 = float(wavelength_um) ** 2
        terms = [b * l2 / (l2 - c) for b, c in zip(self.B, self.C)]
        n2 = 1 + sum(terms)
        if not n2 > 1 or any(abs(l2 - c) < 1e-9 for c in self.C):
            raise ValueError(f"glass {self.name!r}: {wavelength_um} um is at a resonance of its Sellmeier formula")
        return math.sqrt(n2)

    @property
    def refractive_index(self) -> float:
        return self.index(self.reference_um)

    @property
    def abbe_number(self) -> float:
        """``V_d = (n_d - 1) / (n_F - n_C)``."""
        return (self.index(D_LINE_UM) - 1) / (self.index(F_LINE_UM) - self.index(C_LINE_UM))

    @property
    def dispersive(self) -> bool:
        return True


def load_glasses(path=None) -> dict:
    """The glass catalogue (default: the built-in ``configs/glasses.toml``): name -> glass, with the
    data-sheet ``n_d`` / ``V_d`` of each dispersive glass in ``catalogue_values`` order (see the file)."""
    from ..io.files import read_toml

    if path is None:
        from ..io.resources import glasses_file

        path = glasses_file()
    raw = read_toml(path, "glass catalogue")
    out = {}
    for name, t in raw.items():
        if "n" in t:
            out[name] = ConstantGlass(t["n"])
        else:
            out[name] = SellmeierGlass(name, tuple(t["B"]), tuple(t["C"]), description=t.get("description", ""))
    return out


def glass_by_name(name: str):
    """A glass of the built-in catalogue; ``ValueError`` listing the names otherwise."""
    table = load_glasses()
    if name not in table:
        raise ValueError(f"glass {name!r} is not in the catalogue; choose from {', '.join(table)}")
    return table[name]

def as_glass(g):
    """A glass object from a glass, a catalogue name or a number (a constant refractive index)."""
    if hasattr(g, "index") and hasattr(g, "name"):
        return g
    if isinstance(g, str):
        return glass_by_name(g)
    return ConstantGlass(g)
