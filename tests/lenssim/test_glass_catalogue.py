"""Glass catalogues (issue 29, item 3): every catalogue glass against its data sheet, lookup by name as lens files
write it, the unknown-name message, the model glass (n_d, V_d), and the glasses that were there before unchanged."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib

import pytest

from lenssim.io.resources import glasses_file
from lenssim.model import glass as glass_module
from lenssim.model.glass import (C_LINE_UM, D_LINE_UM, F_LINE_UM, ModelGlass, SchottGlass, SellmeierGlass, as_glass,
                                 glass_by_name, load_glasses)

RAW = tomllib.loads(glasses_file().read_text())
GLASSES = load_glasses()
DISPERSIVE = [name for name, t in RAW.items() if "n" not in t]

N_D_TOL = 2e-5
"""How close a catalogue glass's formula must come to its data-sheet n_d: a mistyped coefficient misses it."""
V_D_TOL = 0.1
"""... and to its data-sheet Abbe number V_d."""
PLASTIC_N_D_TOL_MAX, PLASTIC_V_D_TOL_MAX = 2e-3, 1.0
"""The widest check a plastic's table may ask for (a fit to one sample against a grade's typical values)."""

REQUIRED = {
    "SCHOTT": "N-BK7 N-SF5 N-SK16 F2 N-F2 F5 N-SSK2 N-SK2 N-SK4 N-SK5 N-K5 N-BAK1 N-BAK4 N-BAF10 N-BAF4 N-SF2 N-SF6 "
              "N-SF10 N-SF11 N-SF57 N-LAK9 N-LAK22 N-LAF2 N-LASF9 N-LASF44 SF1 SF2 SF5 SF6 N-FK5 N-PK51 N-KZFS4",
    "OHARA": "S-BSL7 S-BAL42 S-LAH58 S-TIH53 S-FPL51 S-LAL14",
    "HOYA": "BSC7 E-FD2",
    "CDGM": "H-K9L H-ZF52A",
    "HIKARI": "SK16",
    "plastic": "PMMA",
}
"""The glasses the catalogue must hold, by catalogue (the issue's list, as far as sourced)."""

PINNED_INDEX_AT_0_55_UM = {
    "paper": 1.5,
    "N-BK7": 1.5185223876207927,
    "N-SF5": 1.6771143911586193,
    "PMMA": 1.4923998880107758,
}
"""n at 0.55 um of the glasses that were in the catalogue before it grew (computed before the change)."""
PIN_TOL = 1e-12


# -- every catalogue glass against its data sheet --------------------------------------------------------------------

@pytest.mark.parametrize("name", DISPERSIVE)
def test_every_glass_meets_its_data_sheet(name):
    t, g = RAW[name], GLASSES[name]
    tol_n, tol_v = t.get("n_d_tolerance", N_D_TOL), t.get("V_d_tolerance", V_D_TOL)
    if (tol_n, tol_v) != (N_D_TOL, V_D_TOL):
        assert t["catalogue"] == "plastic", f"{name}: only a plastic may widen the data-sheet check"
        assert tol_n <= PLASTIC_N_D_TOL_MAX and tol_v <= PLASTIC_V_D_TOL_MAX
    assert g.index(D_LINE_UM) == pytest.approx(t["n_d"], abs=tol_n)
    assert g.abbe_number == pytest.approx(t["V_d"], abs=tol_v)
    assert (g.index(D_LINE_UM) - 1) / (g.index(F_LINE_UM) - g.index(C_LINE_UM)) == g.abbe_number
    assert g.refractive_index == g.index(D_LINE_UM) and g.dispersive


@pytest.mark.parametrize("name", DISPERSIVE)
def test_every_glass_names_its_catalogue_and_source(name):
    t, g = RAW[name], GLASSES[name]
    assert t["catalogue"] and g.catalogue == t["catalogue"]
    assert t["catalogue"] in t["description"] or t["catalogue"] == "plastic"
    assert re.search(r"\b(19|20)\d\d\b", t["description"]), f"{name}: the description names no year"
    assert isinstance(g, SchottGlass if t.get("formula") == "schott" else SellmeierGlass)


def test_the_catalogue_holds_the_glasses_asked_for():
    for catalogue, names in REQUIRED.items():
        for name in names.split():
            assert RAW[name]["catalogue"] == catalogue, name


def test_the_glasses_cover_the_visible_smoothly():
    """Normal dispersion over 0.40-0.75 um: each index falls with wavelength, and stays a glass's."""
    lams = [0.40 + 0.01 * i for i in range(36)]
    for name in DISPERSIVE:
        n = [GLASSES[name].index(lam) for lam in lams]
        assert all(a > b for a, b in zip(n, n[1:])), name
        assert 1.4 < n[-1] < n[0] < 2.0, name


# -- the glasses that were there before --------------------------------------------------------------------------------

@pytest.mark.parametrize("name, n", PINNED_INDEX_AT_0_55_UM.items())
def test_existing_glasses_keep_their_index(name, n):
    assert glass_by_name(name).index(0.55) == pytest.approx(n, abs=PIN_TOL, rel=0)
    assert GLASSES[name].index(0.55) == pytest.approx(n, abs=PIN_TOL, rel=0)


def test_existing_glasses_keep_their_name_and_kind():
    assert glass_by_name("paper").refractive_index == 1.5 and not glass_by_name("paper").dispersive
    for name in ("N-BK7", "N-SF5", "PMMA"):
        g = glass_by_name(name)
        assert isinstance(g, SellmeierGlass) and g.name == name and as_glass(name) == g
    bk7 = glass_by_name("N-BK7")
    assert bk7 == SellmeierGlass("N-BK7", bk7.B, bk7.C, description=bk7.description)  # the catalogue is not compared


# -- lookup ------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text", ["N-BK7", "n-bk7", "N-bk7", " N-BK7 ", "SCHOTT:N-BK7", "schott:n-bk7", "Schott : N-BK7"])
def test_lookup_ignores_case_and_takes_a_catalogue_prefix(text):
    g = glass_by_name(text)
    assert g is glass_by_name("N-BK7") and g.name == "N-BK7"


def test_every_glass_is_found_as_zemax_writes_it_and_with_its_catalogue():
    for name, t in RAW.items():
        assert glass_by_name(name.upper()) == GLASSES[name]
        assert glass_by_name(name.lower()).name == GLASSES[name].name
        if "catalogue" in t:
            assert glass_by_name(f"{t['catalogue']}:{name}") == GLASSES[name]
            assert glass_by_name(f"{t['catalogue'].lower()}:{name.lower()}") == GLASSES[name]


def test_zemax_names_of_shipped_and_common_glasses():
    for text, name, catalogue in [("SK16", "SK16", "HIKARI"), ("F2", "F2", "SCHOTT"), ("H-ZF52A", "H-ZF52A", "CDGM"),
                                  ("S-LAH58", "S-LAH58", "OHARA"), ("E-FD2", "E-FD2", "HOYA"), ("pmma", "PMMA", "plastic")]:
        g = glass_by_name(text)
        assert (g.name, g.catalogue) == (name, catalogue)


def test_an_unknown_name_lists_the_catalogues_searched_and_the_closest_names():
    with pytest.raises(ValueError) as e:
        glass_by_name("N-BK8")
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith("glass 'N-BK8' is not in the catalogues searched (SCHOTT, OHARA, HOYA, CDGM, HIKARI, plastic)")
    closest = msg.split("closest: ")[1].split(", ")
    assert closest[0] == "N-BK7" and 1 <= len(closest) <= glass_module.CLOSEST_NAMES
    assert all(c in GLASSES for c in closest)


def test_an_unknown_name_in_a_named_catalogue_searches_that_catalogue_only():
    with pytest.raises(ValueError, match=r"^glass 'OHARA:N-BK7' is not in the catalogues searched \(OHARA\); "
                                         r"closest: ") as e:
        glass_by_name("OHARA:N-BK7")
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match=r"closest: S-LAH58"):
        glass_by_name("OHARA:S-LAH59")


def test_an_unknown_catalogue_and_nonsense_are_one_line_errors():
    with pytest.raises(ValueError, match=r"^glass 'ZEISS:N-BK7': catalogue 'ZEISS' is not one of SCHOTT, OHARA, "):
        glass_by_name("ZEISS:N-BK7")
    with pytest.raises(ValueError, match=r"closest: none$"):
        glass_by_name("qqqqqqqq")
    with pytest.raises(ValueError, match="a string"):
        glass_by_name(1.5)


def test_lookup_sees_the_file_change(tmp_path, monkeypatch):
    """The built-in catalogue is cached under the file's identity: a changed file is read again."""
    import lenssim.io.resources as resources

    path = tmp_path / "glasses.toml"
    path.write_text('[GLASS-1]\ncatalogue = "X"\nB = [1.0]\nC = [0.01]\n')
    monkeypatch.setattr(resources, "glasses_file", lambda: path)
    assert glass_by_name("x:glass-1").name == "GLASS-1"
    path.write_text('[GLASS-22]\ncatalogue = "Y"\nB = [1.0]\nC = [0.01]\nn_d = 1.0\nV_d = 1.0\n')
    assert glass_by_name("y:glass-22").name == "GLASS-22"
    with pytest.raises(ValueError, match=r"catalogues searched \(Y\); closest: GLASS-22$"):
        glass_by_name("GLASS-1")


# -- catalogue files ---------------------------------------------------------------------------------------------------

def test_a_catalogue_file_is_checked_table_by_table(tmp_path):
    def load(text):
        p = tmp_path / "g.toml"
        p.write_text(text)
        return load_glasses(p)

    g = load('[S]\nformula = "schott"\nA = [2.25]\n[N]\nB = [1.0, 0.1]\nC = [0.01, -0.01]\n')
    assert g["S"].index(0.4) == g["S"].index(0.7) == 1.5  # a Schott formula with A0 alone: no dispersion
    assert g["N"].index(0.5) > g["N"].index(0.6)  # a negative C (as OHARA fits have) is a term without resonance
    for text, match in [('[X]\nB = [1.0]\nC = [0.01]\ncatalog = "S"\n', r"^glass 'X': unknown key\(s\) catalog; "),
                        ('[X]\nformula = "cauchy"\nA = [2.0]\n', r"^glass 'X': formula 'cauchy' is not one of "),
                        ('[X]\nformula = "schott"\nB = [1.0]\n', r"^glass 'X': the schott formula needs A"),
                        ("[X]\nB = [1.0]\n", r"^glass 'X': the sellmeier formula needs B and C \(missing C\)"),
                        ('[X]\nformula = "schott"\nA = [2, 0, 0, 0, 0, 0, 0, 0, 0]\n', r"1 to 8 finite numbers"),
                        ('[X]\nformula = "schott"\nA = [0.5]\n', r"outside its Schott formula")]:
        with pytest.raises(ValueError, match=match) as e:
            load(text)
        assert "\n" not in str(e.value)


def test_the_schott_formula_is_the_power_series():
    A = (2.5, -0.01, 0.012, 3e-4, -2e-5, 1e-6, 1e-7, -1e-8)
    g = SchottGlass("T", A)
    lam = 0.55
    powers = (0, 2, -2, -4, -6, -8, -10, -12)
    assert g.index(lam) == pytest.approx(math.sqrt(sum(a * lam**p for a, p in zip(A, powers))), rel=1e-15)
    with pytest.raises(ValueError, match="wavelength"):
        g.index(0.0)


# -- the model glass -----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("n_d, V_d", [(1.5168, 64.17), (1.84666, 23.78), (1.531, 56.0), (1.4, 95.0), (2.0, 15.0)])
def test_a_model_glass_holds_n_d_and_V_d(n_d, V_d):
    g = ModelGlass(n_d, V_d)
    assert g.index(D_LINE_UM) == n_d and g.refractive_index == n_d and g.dispersive
    assert (g.index(D_LINE_UM) - 1) / (g.index(F_LINE_UM) - g.index(C_LINE_UM)) == pytest.approx(V_d, rel=1e-12)
    assert g.abbe_number == pytest.approx(V_d, rel=1e-12)
    b = g.cauchy_b_um2  # n = a + b / lambda^2
    a = n_d - b / D_LINE_UM**2
    for lam in (0.4, 0.55, 0.7, 1.0):
        assert g.index(lam) == pytest.approx(a + b / lam**2, rel=1e-14)


@pytest.mark.parametrize("name, tol", [("N-BK7", 1e-4), ("S-FPL51", 1e-4), ("N-LASF44", 1e-4), ("N-SF11", 5e-4)])
def test_a_model_glass_is_close_to_the_catalogue_glass_of_the_same_n_d_and_V_d(name, tol):
    """Cauchy's two terms against the vendor's formula from the F to the C line (the model has no partial
    dispersion: a dense flint's index bends more, 4e-4 at F for N-SF11, 2e-3 at 0.45 um)."""
    real, model = GLASSES[name], ModelGlass(RAW[name]["n_d"], RAW[name]["V_d"])
    lams = (F_LINE_UM, 0.5, 0.55, D_LINE_UM, 0.6, C_LINE_UM)
    assert max(abs(model.index(lam) - real.index(lam)) for lam in lams) < tol


@pytest.mark.parametrize("n_d, V_d", [(1.5, 0.0), (1.0, 0.0), (1.0, 40.0)])
def test_a_model_glass_without_dispersion_is_constant(n_d, V_d):
    g = ModelGlass(n_d, V_d)
    assert not g.dispersive and g.abbe_number == math.inf and g.cauchy_b_um2 == 0
    assert g.index(0.4) == g.index(D_LINE_UM) == g.index(0.7) == g.index(10.0) == n_d


@pytest.mark.parametrize("n_d, V_d, match", [
    (0.99, 30.0, r"n_d >= 1"), (1.5, -1.0, r"V_d >= 0"), (math.nan, 30.0, "n_d=nan"), (1.5, math.inf, "V_d=inf"),
    (True, 30.0, "n_d=True"), ("1.5", 30.0, "n_d='1.5'"), (1.5, None, "V_d=None")])
def test_a_model_glass_refuses_what_is_not_a_glass(n_d, V_d, match):
    with pytest.raises(ValueError, match=match) as e:
        ModelGlass(n_d, V_d)
    assert "\n" not in str(e.value)


def test_a_model_glass_is_a_frozen_exported_dataclass_with_a_name():
    g = ModelGlass(1.5168, 64.17)
    assert "ModelGlass" in glass_module.__all__ and "SchottGlass" in glass_module.__all__
    assert g.name == "model glass (n_d=1.5168, V_d=64.17)" and as_glass(g) is g
    assert g == ModelGlass(1.5168, 64.17) and isinstance(g.n_d, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.n_d = 1.6
    with pytest.raises(ValueError, match="below 1"):
        ModelGlass(1.01, 0.5).index(10.0)  # far into the infrared a steep Cauchy model falls below 1
    with pytest.raises(ValueError, match="wavelength"):
        g.index(-0.5)
