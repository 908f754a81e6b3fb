"""Lens prescription files: the Zemax reader (``lenssim.io.zemax``), our TOML format and the shipped lenses
(``lenssim.io.prescription_file``, ``configs/lenses/``).

The two hand-written Zemax files in ``tests/data/lenses/`` (one UTF-16 LE with a BOM and CRLF line ends, as
OpticStudio saves, one ASCII) hold the shipped Cooke triplet; every bad input is refused in one line naming the
file, the surface (numbered as in the file) and the keyword."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import pytest

from lenssim.io.files import InputFileError
from lenssim.io.prescription_file import (prescription_from_dict, prescription_toml, read_lens,
                                          read_prescription_toml, write_prescription_toml)
from lenssim.io.resources import lens_path, lenses_dir
from lenssim.io.zemax import read_zmx
from lenssim.model.prescription import Prescription, PrescriptionError

DATA = Path(__file__).resolve().parents[1] / "data" / "lenses"
ASCII = DATA / "cooke_triplet_ascii.zmx"
UTF16 = DATA / "cooke_triplet_utf16.zmx"
SHIPPED = ("paper_singlet", "cooke_triplet", "double_gauss", "aspheric_singlet")


def _same_lens(a: Prescription, b: Prescription) -> bool:
    """Equal as lenses: everything but the name, source and notes."""
    return replace(a, name=b.name, source=b.source, notes=b.notes) == b


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert msg and "\n" not in msg and "Traceback" not in msg, msg
    return msg


def _paraxial(p: Prescription) -> tuple[float, float]:
    """(EFL, BFL) of ``p`` (object at infinity) by a y-nu trace at n_d of its model glasses."""
    n, y, nu = 1.0, 1.0, 0.0
    for i, s in enumerate(p.surfaces):
        n2 = s.material[0] if isinstance(s.material, tuple) else 1.0
        nu -= y * s.curvature_per_mm * (n2 - n)
        n = n2
        if i < len(p.surfaces) - 1:
            y += s.thickness_mm * nu / n
    return -n / nu, -y * n / nu


# -- the Zemax reader ------------------------------------------------------------------------------------------------
def test_the_utf16_and_ascii_zemax_files_read_equal_to_the_shipped_toml_lens():
    assert UTF16.read_bytes()[:2] == b"\xff\xfe" and b"\r\n".decode().encode("utf-16-le") in UTF16.read_bytes()
    assert ASCII.read_bytes().isascii()
    toml = read_lens("cooke_triplet")
    for path in (UTF16, ASCII):
        z = read_zmx(path)
        assert _same_lens(z, toml)
        assert z.name == "Cooke triplet (Smith, Modern Optical Engineering, ch. 6)"
        assert z.source == f"Zemax file {path.name}"
        assert z.stop_surface == 5 and z.surfaces[4].comment == "stop"
        assert z.surfaces[0].material == (1.61272, 58.63) and z.surfaces[1].is_air
        assert z.primary_wavelength_um == 0.5875618 and z.fields == (0.0, 8.36, 11.86)
    assert read_lens(str(UTF16)) == read_zmx(UTF16)  # read_lens dispatches on the suffix


def test_zemax_encodings_are_detected_from_the_bytes(tmp_path):
    text = ASCII.read_text(encoding="ascii")
    ref = read_zmx(ASCII)
    variants = {
        "utf16be.zmx": b"\xfe\xff" + text.replace("\n", "\r\n").encode("utf-16-be"),
        "utf16_nobom.zmx": text.encode("utf-16-le"),
        "utf8bom.zmx": b"\xef\xbb\xbf" + text.replace("ch. 6)", "ch. 6) \u00e9").encode("utf-8"),
        "cp1252.zmx": text.replace("NOTE 0 Hand", "NOTE 0 \u00e9 Hand").encode("cp1252"),
        "cr_only.zmx": text.replace("\n", "\r").encode("ascii"),
    }
    for name, raw in variants.items():
        (tmp_path / name).write_bytes(raw)
        z = read_zmx(tmp_path / name)
        assert _same_lens(z, ref), name
    assert read_zmx(tmp_path / "utf8bom.zmx").name.endswith("\u00e9")


def test_zemax_units_are_converted_to_millimetres(tmp_path):
    """The triplet in centimetres: lengths x 10, curvatures / 10, and an even asphere's A_2k x 10^(1 - 2k)."""
    text = ASCII.read_text()
    text = text.replace("UNIT MM", "UNIT CM").replace("ENPD 2.92E+1", "ENPD 2.92")
    text = re.sub(r"DISZ ([0-9.]+)", lambda m: f"DISZ {float(m.group(1)) / 10!r}", text)
    text = re.sub(r"CURV ([-0-9.e]+)", lambda m: f"CURV {float(m.group(1)) * 10!r}", text)
    text = re.sub(r"DIAM ([0-9.]+)", lambda m: f"DIAM {float(m.group(1)) / 10!r}", text)
    text = text.replace("SURF 1\n  TYPE STANDARD", "SURF 1\n  TYPE EVENASPH\n  PARM 1 0\n  PARM 2 1e-3\n  PARM 3 -2e-5")
    f = tmp_path / "cm.zmx"
    f.write_text(text)
    z, ref = read_zmx(f), read_lens("cooke_triplet")
    assert z.entrance_pupil_diameter_mm == pytest.approx(29.2)
    for a, b in zip(z.surfaces, ref.surfaces):
        assert a.curvature_per_mm == pytest.approx(b.curvature_per_mm, rel=1e-12)
        assert a.thickness_mm == pytest.approx(b.thickness_mm, rel=1e-12)
        assert a.semi_diameter_mm == pytest.approx(b.semi_diameter_mm, rel=1e-12)
    assert z.surfaces[0].aspheric_coefficients == pytest.approx((1e-3 * 10**-3, -2e-5 * 10**-5), rel=1e-12)
    inch = tmp_path / "in.zmx"
    inch.write_text(ASCII.read_text().replace("UNIT MM", "UNIT IN"))
    assert read_zmx(inch).surfaces[0].thickness_mm == pytest.approx(5.90 * 25.4)


def test_zemax_even_asphere_and_model_glass(tmp_path):
    """The shipped aspheric singlet as a Zemax EVENASPH file reads equal: PARM 2..8 are A4..A16 (PARM 1, the r^2
    term, is 0), CONI the conic, ___BLANK's 3rd and 4th numbers n_d and V_d."""
    ref = read_lens("aspheric_singlet")
    s1 = ref.surfaces[0]
    parms = "\n".join(f"  PARM {k + 2} {a!r}" for k, a in enumerate(s1.aspheric_coefficients))
    text = f"""VERS 190513 80 123457 L123457
MODE SEQ
NAME asphere
UNIT MM X W X CM MR CPMM
ENPD 46
FTYP 0 0 3 3 0 0 0
XFLN 0 0 0 0 0 0 0 0 0 0 0 0
YFLN 0 0.5 1 0 0 0 0 0 0 0 0 0
WAVM 1 0.4861327 1
WAVM 2 0.5875618 1
WAVM 3 0.6562725 1
PWAV 2
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE EVENASPH
  CURV {s1.curvature_per_mm!r} 0 0 0 0 ""
  PARM 1 0
{parms}
  PARM 8 0
  DISZ 19.4
  GLAS ___BLANK 1 0 1.58913 61.18 0 0 0 0 0 0
  CONI -1.431442
  COMM asphere (L-BAL35)
  DIAM 23 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV 0
  DISZ 37.79
  COMM flat
  DIAM 23 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""
    f = tmp_path / "asphere.zmx"
    f.write_text(text)
    assert _same_lens(read_zmx(f), ref)


def test_zemax_fnum_gives_the_pupil_from_the_paraxial_focal_length(tmp_path):
    f = tmp_path / "fnum.zmx"
    f.write_text(ASCII.read_text().replace("ENPD 2.92E+1", "FNUM 3.465 0"))
    z = read_zmx(f)
    efl = 101.1813  # the trace's focal length of the printed data (the book prints 101.181)
    assert z.entrance_pupil_diameter_mm == pytest.approx(efl / 3.465, rel=1e-5)
    assert z.extra["f_number_given"] == 3.465
    out = tmp_path / "fnum.toml"
    write_prescription_toml(z, out)
    assert read_prescription_toml(out).extra["f_number_given"] == 3.465


def test_zemax_fnum_with_a_glass_the_catalogue_does_not_know_is_refused_in_one_line(tmp_path):
    f = tmp_path / "fnum_glass.zmx"
    f.write_text(ASCII.read_text().replace("ENPD 2.92E+1", "FNUM 3.465 0")
                 .replace("GLAS ___BLANK 1 0 1.64769 33.82", "GLAS NOSUCHGLASS 0 0 1.64769 33.82"))
    with pytest.raises(PrescriptionError) as info:
        read_zmx(f)
    msg = _one_line(info.value)
    assert "FNUM" in msg and "'NOSUCHGLASS' (surface 3)" in msg and "ENPD" in msg
    g = tmp_path / "enpd_glass.zmx"  # with ENPD the name is kept as written, for the optics to resolve
    g.write_text(ASCII.read_text().replace("GLAS ___BLANK 1 0 1.64769 33.82", "GLAS NOSUCHGLASS 0 0 1.64769 33.82"))
    assert read_zmx(g).surfaces[2].material == "NOSUCHGLASS"


def test_zemax_finite_object_with_object_heights(tmp_path):
    text = ASCII.read_text().replace("DISZ INFINITY", "DISZ 1000").replace("FTYP 0 0 3 3", "FTYP 1 0 3 3")
    text = text.replace("YFLN 0 8.36 11.86", "YFLN 0 100 200")
    f = tmp_path / "finite.zmx"
    f.write_text(text)
    z = read_zmx(f)
    assert z.object_distance_mm == 1000.0 and not z.object_at_infinity and z.fields == (0.0, 100.0, 200.0)
    out = tmp_path / "finite.toml"
    write_prescription_toml(z, out)
    assert read_prescription_toml(out) == z
    big = tmp_path / "big.zmx"
    big.write_text(ASCII.read_text().replace("DISZ INFINITY", "DISZ 1.0E+10"))
    assert read_zmx(big).object_at_infinity  # 1e10 lens units and more: at infinity, as OpticStudio takes it


def _bad_zmx(tmp_path, name: str, old: str, new: str, *, count: int = 1) -> Path:
    text = ASCII.read_text()
    assert old in text, old
    f = tmp_path / name
    f.write_text(text.replace(old, new, count))
    return f


# (file name, text replaced, replacement, words the one-line error must hold)
BAD_ZMX = [
    ("mirror.zmx", "  GLAS ___BLANK 1 0 1.64769", "  GLAS MIRROR 0 0 1.64769",
     ["surface 3", "GLAS", "MIRROR", "not supported"]),
    ("coordbrk.zmx", "SURF 4\n  TYPE STANDARD", "SURF 4\n  TYPE COORDBRK", ["surface 4", "TYPE", "COORDBRK"]),
    ("toroidal.zmx", "SURF 6\n  TYPE STANDARD", "SURF 6\n  TYPE TOROIDAL", ["surface 6", "TYPE", "TOROIDAL"]),
    ("grating.zmx", "SURF 2\n  TYPE STANDARD", "SURF 2\n  TYPE DGRATING", ["surface 2", "DGRATING", "grating"]),
    ("decentre.zmx", "  SLAB 3\n", "  SLAB 3\n  DECX 0.5\n", ["surface 2", "DECX", "decentred"]),
    ("tilt.zmx", "  SLAB 4\n", "  SLAB 4\n  TILY 1.5\n", ["surface 3", "TILY", "tilted"]),
    ("nsc.zmx", "MODE SEQ", "MODE NSC", ["MODE", "NSC", "non-sequential"]),
    ("nsobject.zmx", "  SLAB 9\n", "  SLAB 9\n  NSOH STANDARD 0 0\n", ["surface 8", "NSOH", "non-sequential"]),
    ("negative.zmx", "DISZ 12.93", "DISZ -1", ["surface 2", "DISZ", "-1", "not allowed"]),
    ("nan.zmx", "DISZ 12.93", "DISZ NAN", ["surface 2", "DISZ", "NAN", "not a finite number"]),
    ("inf_thickness.zmx", "DISZ 12.93", "DISZ INFINITY", ["surface 2", "DISZ", "INFINITY"]),
    ("nan_curv.zmx", "CURV -0.0234", "CURV nan #", ["surface 3", "CURV", "not a finite number"]),
    ("text_value.zmx", "DISZ 12.93", "DISZ twelve", ["surface 2", "DISZ", "'twelve' is not a number"]),
    ("parm1.zmx", "SURF 6\n  TYPE STANDARD", "SURF 6\n  TYPE EVENASPH\n  PARM 1 0.001",
     ["surface 6", "PARM 1", "r^2"]),
    ("parm_std.zmx", "SURF 6\n  TYPE STANDARD", "SURF 6\n  TYPE STANDARD\n  PARM 2 0.001", ["surface 6", "PARM 2"]),
    ("xfln.zmx", "XFLN 0 0 0", "XFLN 0 5 0", ["XFLN", "off the y axis"]),
    ("ftyp.zmx", "FTYP 0 0 3 3", "FTYP 2 0 3 3", ["FTYP", "paraxial image height"]),
    ("negative_field.zmx", "YFLN 0 8.36", "YFLN 0 -8.36", ["YFLN", "negative"]),
    ("obna.zmx", "ENPD 2.92E+1", "OBNA 0.1 0", ["OBNA", "aperture"]),
    ("no_aperture.zmx", "ENPD 2.92E+1\n", "", ["no aperture", "ENPD"]),
    ("annular.zmx", "  SLAB 3\n", "  SLAB 3\n  CLAP 2 10 0\n", ["surface 2", "CLAP", "annular"]),
    ("obscuration.zmx", "  SLAB 3\n", "  SLAB 3\n  OBSC 2 0\n", ["surface 2", "OBSC", "obscuration"]),
    ("curved_image.zmx", "  SLAB 9\n", "  SLAB 9\n  CURV 0.01\n", ["surface 8", "CURV", "curved image"]),
    ("out_of_order.zmx", "SURF 5\n", "SURF 6\n", ["SURF", "out of order"]),
    ("no_stop.zmx", "  STOP\n", "", ["STOP"]),
    ("unit.zmx", "UNIT MM", "UNIT FT", ["UNIT", "'FT'"]),
    ("pwav.zmx", "PWAV 2", "PWAV 7", ["PWAV", "7"]),
    ("conic.zmx", "  SLAB 3\n", "  SLAB 3\n  CONI 0.9999999e9\n", ["surface 2", "conic", "semi-diameter"]),
]


@pytest.mark.parametrize("name,old,new,words", BAD_ZMX, ids=[b[0] for b in BAD_ZMX])
def test_bad_zemax_input_is_refused_in_one_line_naming_surface_and_keyword(tmp_path, name, old, new, words):
    f = _bad_zmx(tmp_path, name, old, new)
    with pytest.raises(PrescriptionError) as info:
        read_zmx(f)
    msg = _one_line(info.value)
    assert repr(str(f)) in msg, msg
    for w in words:
        assert w.lower() in msg.lower(), (w, msg)


def test_empty_truncated_binary_and_wrong_format_zemax_files_are_refused_in_one_line(tmp_path):
    text = ASCII.read_text()
    cases = {
        "empty.zmx": (b"", "is empty"),
        "bom_only.zmx": (b"\xff\xfe", "is empty"),
        "blank.zmx": (b"\n\n  \n", "is empty"),
        "header_only.zmx": (text[:text.index("SURF 0")].encode(), "no SURF"),
        "cut_after_surface_1.zmx": (text[:text.index("SURF 2")].encode(), "2 SURF blocks"),
        "cut_in_a_glass.zmx": (text[:text.index("  COMM L2 front")].encode(), "cut short"),
        "cut_utf16.zmx": (UTF16.read_bytes()[:1001], "cut short"),
        "binary.zmx": (bytes(range(256)) * 8, "not a text file"),
        "photo.zmx": (b"\xff\xd8\xff\xe0\x00\x10JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00" + bytes(range(200)),
                      "not a text file"),
        "lens.zmx": (b'name = "a TOML lens"\nstop_surface = 1\n', "not a Zemax keyword line"),
        "words.zmx": (b"This is a letter, not a lens.\n", "not a Zemax keyword line"),
    }
    for name, (raw, words) in cases.items():
        f = tmp_path / name
        f.write_bytes(raw)
        with pytest.raises(PrescriptionError) as info:
            read_zmx(f)
        msg = _one_line(info.value)
        assert repr(str(f)) in msg and words in msg, (name, msg)


def test_zemax_files_that_cannot_be_read_are_input_file_errors(tmp_path):
    for bad in (tmp_path / "missing.zmx", tmp_path):
        with pytest.raises(InputFileError) as info:
            read_zmx(bad)
        assert str(bad) in _one_line(info.value)


# -- our TOML format -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_lens_reads_and_round_trips_exactly(tmp_path, name):
    p = read_lens(name)
    assert p == read_prescription_toml(lens_path(name)) == read_lens(f"{name}.toml")
    assert p.source and p.name and p.extra["published"], name
    out = tmp_path / f"{name}.toml"
    write_prescription_toml(p, out)
    q = read_prescription_toml(out)
    assert q == p and q.extra == p.extra and q.notes == p.notes
    assert prescription_toml(q) == out.read_text()  # and writing again gives the same text
    write_prescription_toml(p, out)  # overwriting is atomic and leaves no temporary file
    assert sorted(x.name for x in tmp_path.iterdir()) == [f"{name}.toml"]


def test_the_shipped_lenses_match_their_published_figures():
    """The paraxial focal length and back focal length of each shipped lens (model glasses at n_d) against the
    figures printed in its source."""
    for name, tol in (("cooke_triplet", 1e-3), ("double_gauss", 0.06), ("aspheric_singlet", 1e-2),
                      ("paper_singlet", 1e-9)):
        p = read_lens(name)
        efl, bfl = _paraxial(p)
        pub = p.extra["published"]
        assert efl == pytest.approx(pub["efl_mm"], abs=tol * 10 if name == "double_gauss" else tol), name
        if "bfl_mm" in pub:
            assert bfl == pytest.approx(pub["bfl_mm"], abs=tol), name
            assert p.surfaces[-1].thickness_mm == pytest.approx(pub["bfl_mm"], abs=0.01), name
    e2e = read_lens("paper_singlet")
    assert e2e.fields == tuple(float(a) for a in range(15)) and e2e.wavelengths_um == (0.5,)
    assert e2e.entrance_pupil_diameter_mm == 4.0 and e2e.stop_surface == 1 and e2e.surfaces[1].conic == -2.4
    s, f, n = -0.775, 25.0, 1.5
    assert e2e.surfaces[0].curvature_per_mm == pytest.approx((s + 1) / (2 * f * (n - 1)), rel=1e-12)
    assert e2e.surfaces[1].curvature_per_mm == pytest.approx((s - 1) / (2 * f * (n - 1)), rel=1e-12)
    assert read_lens("double_gauss").stop_surface == 6 and read_lens("cooke_triplet").stop_surface == 5


def test_the_toml_format_is_to_dict_and_keeps_radii_readable(tmp_path):
    p = read_lens("cooke_triplet")
    text = prescription_toml(p)
    assert "radius_mm = 37.4\n" in text and 'radius_mm = "inf"' in text and "[[surfaces]]  # surface 5 (aperture stop)" in text
    d = p.to_dict()
    assert prescription_from_dict(d) == p
    # a curvature whose reciprocal is not exact is written as curvature_per_mm, so that it reads back to the bit
    c = -0.02689317283797865
    assert 1.0 / (1.0 / c) != c
    q = replace(p, surfaces=(replace(p.surfaces[0], curvature_per_mm=c),) + p.surfaces[1:])
    assert f"curvature_per_mm = {c!r}" in prescription_toml(q)
    out = tmp_path / "q.toml"
    write_prescription_toml(q, out)
    assert read_prescription_toml(out).surfaces[0].curvature_per_mm == c
    odd = replace(p, name='quote " backslash \\ tab \t newline \n del \x7f unicode \u00e9\u4e2d', notes="a\nb")
    write_prescription_toml(odd, out)
    assert read_prescription_toml(out).name == odd.name and read_prescription_toml(out).notes == "a\nb"
    with pytest.raises(PrescriptionError, match="extra"):
        prescription_toml(replace(p, extra={"something": 1}))


def _toml_with(tmp_path, old: str, new: str) -> Path:
    text = lens_path("cooke_triplet").read_text()
    assert old in text, old
    f = tmp_path / "bad.toml"
    f.write_text(text.replace(old, new, 1))
    return f


BAD_TOML = [
    ("stop_surface = 5", "stop_surface = 5\ncolour = \"red\"", ["unknown key 'colour'", "allowed: name, source"]),
    ("semi_diameter_mm = 10.3", "semi_diameter_mm = 10.3\nsemidiameter = 1",
     ["surface 5", "unknown key 'semidiameter'", "semi_diameter_mm"]),
    ("entrance_pupil_diameter_mm = 29.2", "entrance_pupil_diameter_mm = 29.2\nf_number = 3",
     ["[aperture]", "unknown key 'f_number'"]),
    ("thickness_mm = 12.93", "thickness_mm = -1.0", ["surface 2", "thickness", "-1", "not allowed"]),
    ("thickness_mm = 12.93", "thickness_mm = nan", ["surface 2", "thickness_mm", "not a finite number"]),
    ("thickness_mm = 12.93", "thickness_mm = \"12.93\"", ["surface 2", "thickness_mm", "not a number"]),
    ("radius_mm = -341.48", "radius_mm = 0", ["surface 2", "radius_mm = 0", "inf"]),
    ("radius_mm = -341.48", "radius_mm = -341.48\ncurvature_per_mm = 0.1", ["surface 2", "not both"]),
    ("radius_mm = -341.48\nthickness_mm = 12.93", "radius_mm = -341.48", ["surface 2", "thickness_mm is missing"]),
    ("material = [1.64769, 33.82]", "material = [1.64769]", ["surface 3", "material"]),
    ("material = [1.64769, 33.82]", "material = [0.5, 33.82]", ["surface 3", "n_d"]),
    ("stop_surface = 5", "stop_surface = 9", ["stop surface 9", "1 to 7"]),
    ('distance_mm = "inf"', 'distance_mm = "far"', ["[object]", "'far'"]),
    ('distance_mm = "inf"', "distance_mm = 500.0", ["angles_deg", "finite distance"]),
    ("angles_deg = [0.0, 8.36, 11.86]", "angles_deg = [0.0, 95.0]", ["fields", "95"]),
    ("primary_um = 0.5875618", "primary_um = 0.55", ["primary wavelength 0.55"]),
    ("comment = \"stop\"", "comment = 3", ["surface 5", "comment", "not a string"]),
    ("efl_mm = 101.181", "efl_mm = {a = 1}", ["published", "efl_mm"]),
]


@pytest.mark.parametrize("old,new,words", BAD_TOML, ids=[f"toml-{i}" for i in range(len(BAD_TOML))])
def test_bad_toml_is_refused_in_one_line_naming_the_key_or_surface(tmp_path, old, new, words):
    f = _toml_with(tmp_path, old, new)
    with pytest.raises(PrescriptionError) as info:
        read_prescription_toml(f)
    msg = _one_line(info.value)
    assert repr(str(f)) in msg, msg
    for w in words:
        assert w in msg, (w, msg)


def test_toml_files_that_are_not_toml_or_cannot_be_read(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(ValueError, match="not valid TOML") as info:
        read_prescription_toml(bad)
    _one_line(info.value)
    binary = tmp_path / "photo.toml"
    binary.write_bytes(b"\xff\xd8\xff\xe0\x00\x10JFIF")
    with pytest.raises(ValueError) as info:
        read_prescription_toml(binary)
    _one_line(info.value)
    with pytest.raises(InputFileError):
        read_prescription_toml(tmp_path / "missing.toml")
    with pytest.raises(PrescriptionError, match="surfaces is missing"):
        prescription_from_dict({"stop_surface": 1, "aperture": {"entrance_pupil_diameter_mm": 1.0}})


# -- read_lens -------------------------------------------------------------------------------------------------------
def test_read_lens_names_the_shipped_lenses_when_the_name_is_unknown(tmp_path):
    assert sorted(p.stem for p in lenses_dir().glob("*.toml")) == sorted(SHIPPED)
    with pytest.raises(InputFileError) as info:
        read_lens("triplet")
    msg = _one_line(info.value)
    assert "'triplet'" in msg and all(n in msg for n in SHIPPED)
    with pytest.raises(InputFileError, match="'.json'"):
        read_lens(tmp_path / "lens.json")
    with pytest.raises(InputFileError):
        read_lens(tmp_path / "missing.zmx")
    local = tmp_path / "mine.toml"
    write_prescription_toml(read_lens("double_gauss"), local)
    assert read_lens(local) == read_lens("double_gauss")
    assert math.isinf(read_lens("double_gauss").object_distance_mm)


def test_a_toml_file_past_the_size_limit_is_refused_before_it_is_parsed(tmp_path, monkeypatch):
    import lenssim.io.files as files
    from lenssim.io.prescription_file import read_lens

    f = tmp_path / "big.toml"
    f.write_text("# " + "x" * 2000 + "\n")
    monkeypatch.setattr(files, "MAX_TOML_BYTES", 1024)
    with pytest.raises(ValueError, match="is larger than 1024 bytes: not allowed for a TOML file"):
        read_lens(str(f))
