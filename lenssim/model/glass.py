"""Lens glasses: the refractive index as a function of wavelength.

The paper's glass is non-dispersive, ``n = 1.5`` at every wavelength (:class:`ConstantGlass`).
A dispersive glass is any object with a ``name`` and ``index(wavelength_um) -> float``; the lens,
the aberrations and the PSFs ask for the index at each wavelength of the spectrum.

The built-in catalogue (``configs/glasses.toml``) holds vendor glasses (SCHOTT, OHARA, HOYA, CDGM, HIKARI) and
moulding plastics, each with its vendor's dispersion formula: Sellmeier (:class:`SellmeierGlass`) or the Schott
power series (:class:`SchottGlass`). :func:`glass_by_name` finds one by name the way a lens file names it
(``"N-BK7"``, ``"n-bk7"``, ``"SCHOTT:N-BK7"``). A glass known only by its ``n_d`` and ``V_d`` (Zemax's
``GLAS ___BLANK 1 0 nd vd``) is a :class:`ModelGlass`.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field

from ..validate import listed, quoted

__all__ = ["ConstantGlass", "SellmeierGlass", "SchottGlass", "ModelGlass", "as_glass", "load_glasses",
           "glass_by_name", "D_LINE_UM", "F_LINE_UM", "C_LINE_UM", "CATALOGUE_SEPARATOR"]

D_LINE_UM = 0.5875618
"""Helium d line (um): where catalogues give n_d, and where a dispersive lens's focal length is specified."""
F_LINE_UM = 0.4861327
C_LINE_UM = 0.6562725
"""Hydrogen F and C lines (um) of the Abbe number ``V_d = (n_d - 1) / (n_F - n_C)``."""

CATALOGUE_SEPARATOR = ":"
"""Between a catalogue and a glass name in a qualified name: ``"SCHOTT:N-BK7"``."""

SCHOTT_POWERS = (0, 2, -2, -4, -6, -8, -10, -12)
"""Powers of ``lambda`` (um) of the Schott formula's coefficients ``A0, A1, ...`` (Zemax's "Schott" formula has six,
its "Extended" eight)."""

CLOSEST_NAMES = 3
"""How many of the closest catalogue names an unknown glass name's error lists."""


def _abbe_number(glass) -> float:
    """``V_d = (n_d - 1) / (n_F - n_C)`` of ``glass`` from its ``index``."""
    return (glass.index(D_LINE_UM) - 1) / (glass.index(F_LINE_UM) - glass.index(C_LINE_UM))


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


class _DispersiveGlass:
    """What the dispersive catalogue glasses share: the index at their ``reference_um`` and the Abbe number."""

    @property
    def refractive_index(self) -> float:
        return self.index(self.reference_um)

    @property
    def abbe_number(self) -> float:
        """``V_d = (n_d - 1) / (n_F - n_C)``."""
        return _abbe_number(self)

    @property
    def dispersive(self) -> bool:
        return True


@dataclass(frozen=True)
class SellmeierGlass(_DispersiveGlass):
    """A dispersive glass: ``n^2 - 1 = sum B_i lambda^2 / (lambda^2 - C_i)`` (``lambda`` in um, ``C_i`` in um^2;
    a vendor's fit may have a ``C_i < 0``, a term without a resonance).

    ``refractive_index`` is the index at ``reference_um`` (default the d line), at which a lens of this
    glass has its nominal focal length. ``catalogue`` names the vendor's catalogue (not compared).
    """

    name: str
    B: tuple[float, float, float]
    C: tuple[float, float, float]
    reference_um: float = D_LINE_UM
    description: str = ""
    catalogue: str = field(default="", compare=False)

    def __post_init__(self):
        try:
            B, C = tuple(float(b) for b in self.B), tuple(float(c) for c in self.C)
        except (TypeError, ValueError):
            raise ValueError(f"glass {self.name!r}: Sellmeier B and C must be numbers") from None
        if len(B) != len(C) or not B or not all(math.isfinite(v) for v in B + C):
            raise ValueError(f"glass {self.name!r}: Sellmeier B and C must be equally many finite numbers (C in um^2)")
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



@dataclass(frozen=True)
class SchottGlass(_DispersiveGlass):
    """A dispersive glass by the Schott power series ``n^2 = A0 + A1 lambda^2 + A2 lambda^-2 + A3 lambda^-4 +
    A4 lambda^-6 + A5 lambda^-8 (+ A6 lambda^-10 + A7 lambda^-12)`` (``lambda`` in um; the powers are
    :data:`SCHOTT_POWERS`), as HOYA, CDGM and HIKARI publish some glasses.

    ``refractive_index`` is the index at ``reference_um`` (default the d line). ``catalogue`` is not compared.
    """

    name: str
    A: tuple[float, ...]
    reference_um: float = D_LINE_UM
    description: str = ""
    catalogue: str = field(default="", compare=False)

    def __post_init__(self):
        try:
            A = tuple(float(a) for a in self.A)
        except (TypeError, ValueError):
            raise ValueError(f"glass {self.name!r}: Schott-formula A must be numbers") from None
        if not 1 <= len(A) <= len(SCHOTT_POWERS) or not all(math.isfinite(a) for a in A):
            raise ValueError(f"glass {self.name!r}: Schott-formula A must be 1 to {len(SCHOTT_POWERS)} finite numbers")
        object.__setattr__(self, "A", A)
        n = self.index(self.reference_um)
        if not (math.isfinite(n) and n > 1):
            raise ValueError(f"glass {self.name!r}: n = {n!r} at {self.reference_um} um is not a glass")

    def index(self, wavelength_um: float) -> float:
        """Refractive index at ``wavelength_um`` (um)."""
        lam = float(wavelength_um)
        if not (math.isfinite(lam) and lam > 0):
            raise ValueError(f"glass {self.name!r}: wavelength {wavelength_um!r} um is not allowed: a number > 0")
        n2 = sum(a * lam**p for a, p in zip(self.A, SCHOTT_POWERS))
        if not n2 > 1:
            raise ValueError(f"glass {self.name!r}: {wavelength_um} um is outside its Schott formula (n^2 = {n2:g})")
        return math.sqrt(n2)



@dataclass(frozen=True)
class ModelGlass:
    """A glass known by its d-line index ``n_d`` and Abbe number ``V_d`` only (Zemax's model glass,
    ``GLAS ___BLANK 1 0 n_d V_d ...``).

    Dispersion model: the two-term Cauchy formula ``n(lambda) = a + b / lambda^2`` (``lambda`` in um, ``b`` in um^2),
    with ``a`` and ``b`` chosen so that ``n(d) = n_d`` and ``n(F) - n(C) = (n_d - 1) / V_d`` hold exactly (to
    rounding): ``b = (n_d - 1) / (V_d (lambda_F^-2 - lambda_C^-2))``, ``a = n_d - b / lambda_d^2``. ``V_d = 0``
    means no dispersion (``n_d`` at every wavelength, Zemax's convention), as does ``n_d = 1`` (an air-like medium).
    The model knows nothing of a real glass's partial dispersion (Zemax's ``dPgF``): against the vendor's formula of
    a glass with the same ``n_d``, ``V_d`` it is within 1e-4 from the F to the C line for crowns (N-BK7, S-FPL51,
    N-LASF44) and 5e-4 for a dense flint (N-SF11), whose index bends more (2e-3 off at 0.45 um).
    """

    n_d: float
    V_d: float

    def __post_init__(self):
        for label, v in (("n_d", self.n_d), ("V_d", self.V_d)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"model glass {label}={v!r} is not allowed: a finite number")
        if self.n_d < 1 or self.V_d < 0:
            raise ValueError(f"model glass (n_d={self.n_d!r}, V_d={self.V_d!r}) is not allowed: n_d >= 1 "
                             "(1: air-like), V_d >= 0 (0: no dispersion)")
        object.__setattr__(self, "n_d", float(self.n_d))
        object.__setattr__(self, "V_d", float(self.V_d))

    @property
    def name(self) -> str:
        return f"model glass (n_d={self.n_d!r}, V_d={self.V_d!r})"

    @property
    def dispersive(self) -> bool:
        return self.V_d > 0 and self.n_d > 1

    @property
    def cauchy_b_um2(self) -> float:
        """``b`` of ``n = a + b / lambda^2`` (um^2); 0 without dispersion."""
        if not self.dispersive:
            return 0.0
        return (self.n_d - 1) / (self.V_d * (F_LINE_UM**-2 - C_LINE_UM**-2))

    def index(self, wavelength_um: float) -> float:
        """Refractive index at ``wavelength_um`` (um)."""
        if not self.dispersive:
            return self.n_d
        lam = float(wavelength_um)
        if not (math.isfinite(lam) and lam > 0):
            raise ValueError(f"{self.name}: wavelength {wavelength_um!r} um is not allowed: a number > 0")
        b = self.cauchy_b_um2
        n = self.n_d + b * (lam**-2 - D_LINE_UM**-2)
        if not n >= 1:
            raise ValueError(f"{self.name}: n = {n:g} at {wavelength_um} um, below 1: too far from the d line for "
                             "its Cauchy model")
        return n

    @property
    def refractive_index(self) -> float:
        """``n_d``."""
        return self.n_d

    @property
    def abbe_number(self) -> float:
        """``V_d`` from the model's F, d and C indices (``V_d`` to rounding; ``inf`` without dispersion)."""
        return _abbe_number(self) if self.dispersive else math.inf


_TABLE_KEYS = {"n", "formula", "B", "C", "A", "catalogue", "n_d", "V_d", "n_d_tolerance", "V_d_tolerance",
               "description"}
"""The keys a glass table may have (see ``configs/glasses.toml``)."""

FORMULAS = ("sellmeier", "schott")
"""Dispersion formulas of a catalogue table (``formula``; default ``sellmeier``)."""


def _glass_from_table(name: str, t: dict):
    if not isinstance(t, dict):
        raise ValueError(f"glass catalogue: {quoted(name)} is not a table")
    unknown = sorted(set(t) - _TABLE_KEYS)
    if unknown:
        raise ValueError(f"glass {quoted(name)}: unknown key(s) {listed(unknown)}; allowed: "
                         f"{listed(sorted(_TABLE_KEYS), near=unknown)}")
    if "n" in t:
        return ConstantGlass(t["n"])
    catalogue, description = str(t.get("catalogue", "")), str(t.get("description", ""))
    formula = t.get("formula", FORMULAS[0])
    if formula not in FORMULAS:
        raise ValueError(f"glass {quoted(name)}: formula {quoted(formula)} is not one of {', '.join(FORMULAS)}")
    needed = ("B", "C") if formula == "sellmeier" else ("A",)
    missing = [k for k in needed if k not in t]
    if missing:
        raise ValueError(f"glass {quoted(name)}: the {formula} formula needs {' and '.join(needed)} (missing {', '.join(missing)})")
    if formula == "sellmeier":
        return SellmeierGlass(name, tuple(t["B"]), tuple(t["C"]), description=description, catalogue=catalogue)
    return SchottGlass(name, tuple(t["A"]), description=description, catalogue=catalogue)


def load_glasses(path=None) -> dict:
    """The glass catalogue (default: the built-in ``configs/glasses.toml``): name -> glass, in the file's order.
    A table is a constant glass (``n``) or a dispersive one (``formula`` ``sellmeier``: ``B``, ``C``; ``schott``:
    ``A``), with its ``catalogue``, the data-sheet ``n_d`` / ``V_d`` the tests check it against, and a
    ``description`` naming the source (see the file)."""
    from ..io.files import read_toml

    if path is None:
        from ..io.resources import glasses_file

        path = glasses_file()
    raw = read_toml(path, "glass catalogue")
    return {name: _glass_from_table(name, t) for name, t in raw.items()}


_builtin_cache: dict = {}
"""The built-in catalogue as last read, under the file's (path, mtime_ns, size): :func:`glass_by_name` rereads it
only when the file changes (its glasses are immutable)."""


def _builtin_glasses() -> dict:
    from ..io.resources import glasses_file

    path = glasses_file()
    try:
        st = path.stat()
        key = (str(path), st.st_mtime_ns, st.st_size)
    except OSError:
        return load_glasses(path)  # load_glasses says what is wrong with the file
    if key not in _builtin_cache:
        _builtin_cache.clear()
        _builtin_cache[key] = load_glasses(path)
    return _builtin_cache[key]


def _catalogues(table: dict) -> list[str]:
    """The catalogue names of ``table``'s glasses, in order of first appearance."""
    out = []
    for g in table.values():
        c = getattr(g, "catalogue", "")
        if c and c not in out:
            out.append(c)
    return out


def glass_by_name(name: str):
    """A glass of the built-in catalogue by name, as a lens file names it: any case (``"n-bk7"``, Zemax's
    ``"N-BK7"``), optionally qualified by its catalogue (``"SCHOTT:N-BK7"``; :data:`CATALOGUE_SEPARATOR`).
    Of two names that differ only in case, the first in the file is found. ``ValueError`` (one line, the catalogues
    searched and the closest names) otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"glass name {quoted(name)} is not allowed: a string")
    table = _builtin_glasses()
    catalogues = _catalogues(table)
    text = name.strip()
    candidates = list(table)
    searched = catalogues
    if CATALOGUE_SEPARATOR in text:
        prefix, _, text = (s.strip() for s in text.partition(CATALOGUE_SEPARATOR))
        by_upper = {c.upper(): c for c in catalogues}
        if prefix.upper() not in by_upper:
            raise ValueError(f"glass {quoted(name)}: catalogue {quoted(prefix)} is not one of {', '.join(catalogues)}")
        cat = by_upper[prefix.upper()]
        candidates = [k for k, g in table.items() if getattr(g, "catalogue", "") == cat]
        searched = [cat]
    for k in candidates:
        if k.upper() == text.upper():
            return table[k]
    by_upper = {k.upper(): k for k in reversed(candidates)}  # the first in the file wins
    close = difflib.get_close_matches(text.upper(), list(by_upper), n=CLOSEST_NAMES)
    closest = ", ".join(by_upper[c] for c in close) or "none"
    raise ValueError(f"glass {quoted(name)} is not in the catalogues searched ({', '.join(searched)}); closest: {closest}")


def as_glass(g):
    """A glass object from a glass, a catalogue name or a number (a constant refractive index)."""
    if hasattr(g, "index") and hasattr(g, "name"):
        return g
    if isinstance(g, str):
        return glass_by_name(g)
    return ConstantGlass(g)
