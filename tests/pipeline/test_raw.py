"""RAW in (pipeline.raw): DNGs written by pipeline.dng are read back by LibRaw as linear camera RGB in [0, 1], the
header's pattern, levels and white balance reported, the pixel count checked before decoding, bad files refused in one
line naming the file."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from pipeline.cfa import CFA_PATTERNS, cfa_masks
from pipeline.dng import write_dng
from pipeline.io import ImageFileError

rawpy = pytest.importorskip("rawpy", reason="RAW in reads through LibRaw: pip install rawpy")

from pipeline.raw import RAW_EXTENSIONS, is_raw_path, raw_info, read_raw  # noqa: E402

H, W = 64, 96
BLACK, WHITE = 64, 4095
LSB = 1 / 65535  # LibRaw's output truncates to whole 16-bit values


def level(dn):
    """Linear level of ``dn`` (DN) between the black and white levels."""
    return (dn - BLACK) / (WHITE - BLACK)


def dng(path, planes, pattern="RGGB", neutral=(1.0, 1.0, 1.0)):
    """A DNG of the scene ``planes`` (R, G, B levels above black, DN; scalars or (H, W) arrays) under ``pattern``."""
    m = cfa_masks(pattern, H, W).to(torch.float64)
    dn = BLACK + sum(m[k] * torch.as_tensor(planes[k], dtype=torch.float64) for k in range(3))
    return write_dng(path, dn.round(), pattern, black_level=BLACK, white_level=WHITE, as_shot_neutral=neutral)


def test_is_raw_path():
    assert is_raw_path("a/IMG_0001.DNG") and is_raw_path("x.nef") and is_raw_path("x.Cr3")
    assert not is_raw_path("photo.jpg") and not is_raw_path("dng") and not is_raw_path("x.tif")
    assert all(e == e.lower() and e.startswith(".") for e in RAW_EXTENSIONS)


@pytest.mark.parametrize("pattern", CFA_PATTERNS)
def test_header_values_and_a_flat_grey_read_back_linear(tmp_path, pattern):
    path = dng(tmp_path / "grey.dng", (936, 936, 936), pattern, neutral=(0.5, 1.0, 0.8))
    info = raw_info(path)
    assert (info.width_px, info.height_px, info.raw_pattern) == (W, H, pattern)
    assert info.black_level_dn == (BLACK,) * 4 and info.white_level_dn == WHITE
    assert info.camera_white_balance == pytest.approx((2.0, 1.0, 1.25))
    # LibRaw gives a DNG's matrix as zeros: the file's own ColorMatrix1 (write_dng's default, the identity) is read
    assert info.rgb_xyz_matrix == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert info.rgb_xyz_matrix_source == "DNG ColorMatrix1 (CalibrationIlluminant1 21, D65)"
    json.dumps(info.to_dict(), allow_nan=False)

    # a flat mosaic with a neutral (1, 1, 1) white balance: grey at (DN - black) / (white - black), truncated
    path = dng(tmp_path / "flat.dng", (936, 936, 936), pattern)
    img, info2 = read_raw(path, max_pixels=H * W)
    assert img.shape == (1, 3, H, W) and img.dtype == torch.float32 and info2.path == str(path)
    assert float(img.min()) >= 0 and float(img.max()) <= 1
    assert float(img.min()) == float(img.max())  # every pixel and channel the same: grey, borders included
    assert float(img.max()) == pytest.approx(np.floor(level(1000.0) * 65535) / 65535, abs=1e-7)


def test_a_grey_scene_under_the_as_shot_white_balance_comes_back_grey(tmp_path):
    g = 940  # DN above black in green; red and blue answer 0.5 and 0.8 of it (the as-shot neutral)
    img, info = read_raw(dng(tmp_path / "wb.dng", (g // 2, g, g * 4 // 5), neutral=(0.5, 1.0, 0.8)), max_pixels=H * W)
    means = img.mean(dim=(0, 2, 3))
    assert float(means.max() - means.min()) <= LSB + 1e-7
    assert float(means[1]) == pytest.approx(level(BLACK + g), abs=LSB + 1e-7)  # green's multiplier is the smallest: 1


@pytest.mark.parametrize("pattern", CFA_PATTERNS)
def test_a_coloured_scene_keeps_its_channels(tmp_path, pattern):
    planes = (1600, 800, 400)
    img, _ = read_raw(dng(tmp_path / "colour.dng", planes, pattern), max_pixels=H * W)
    got = img[0, :, 8:-8, 8:-8].mean(dim=(1, 2))
    want = torch.tensor([level(BLACK + p) for p in planes], dtype=torch.float32)
    assert torch.allclose(got, want, atol=LSB + 1e-7)  # red stays red, blue blue: the pattern is honoured


def test_full_scale_is_the_white_level_not_the_brightest_pixel(tmp_path):
    # LibRaw would by default take a brightest pixel above 75 % of white as the white level: turned off
    planes = np.full((H, W), 936.0)
    planes[10:20, 10:30] = 3500 - BLACK
    img, _ = read_raw(dng(tmp_path / "patch.dng", (planes,) * 3), max_pixels=H * W)
    assert float(img[0, 1, 40, 60]) == pytest.approx(level(1000.0), abs=LSB)
    assert float(img[0, 1, 15, 20]) == pytest.approx(level(3500.0), abs=LSB)
    img, _ = read_raw(dng(tmp_path / "white.dng", (WHITE - BLACK,) * 3), max_pixels=H * W)
    assert float(img.min()) == 1.0


def test_the_pixel_count_is_refused_before_anything_is_decoded(tmp_path, monkeypatch):
    path = dng(tmp_path / "big.dng", (500, 500, 500))
    calls = []

    class Spy(rawpy.RawPy):
        def unpack(self):
            calls.append("unpack")
            return super().unpack()

        def postprocess(self, *a, **k):
            calls.append("postprocess")
            return super().postprocess(*a, **k)

    monkeypatch.setattr(rawpy, "RawPy", Spy)
    for call in (lambda: read_raw(path, max_pixels=H * W - 1), lambda: raw_info(path, max_pixels=1000)):
        with pytest.raises(ImageFileError, match=r"big\.dng.* 96 x 64 = 6,144 pixels: more than the limit of") as e:
            call()
        assert "\n" not in str(e.value)
    assert calls == []
    read_raw(path, max_pixels=H * W)
    assert calls == ["unpack", "postprocess"]
    with pytest.raises(ValueError, match="max_pixels=0 is not allowed"):
        read_raw(path, max_pixels=0)


def test_bad_files_are_refused_in_one_line_naming_the_file(tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    good = dng(tmp_path / "good.dng", (500, 500, 500)).read_bytes()
    (tmp_path / "cut.dng").write_bytes(good[: len(good) // 2])  # header whole, pixel data cut
    (tmp_path / "stub.dng").write_bytes(good[:100])  # header cut
    (tmp_path / "notes.dng").write_text("not a raw file\n" * 20)
    (tmp_path / "empty.dng").write_bytes(b"")
    (tmp_path / "folder.dng").mkdir()
    dng(tmp_path / "black.dng", (0, 0, 0))
    for name, match in (("cut.dng", "cannot read RAW photo 'cut.dng': .*Unexpected end of file"),
                        ("stub.dng", "cannot read RAW photo 'stub.dng'"),
                        ("notes.dng", "cannot read RAW photo 'notes.dng': Unsupported file format"),
                        ("empty.dng", "RAW photo 'empty.dng' is empty"),
                        ("missing.dng", "RAW photo 'missing.dng' does not exist"),
                        ("folder.dng", "RAW photo 'folder.dng' is not a file"),
                        ("black.dng", "RAW photo 'black.dng' is black")):
        with pytest.raises(ImageFileError, match=match) as e:
            read_raw(name, max_pixels=10**6)
        assert "\n" not in str(e.value), str(e.value)
        if name != "black.dng":
            with pytest.raises(ImageFileError, match=f"'{name}'"):
                raw_info(name, what="photo")
    assert capfd.readouterr().err == ""  # LibRaw's own messages went into the errors, not onto the terminal


# --- A DNG's own colour matrix (issue 43): LibRaw gives a DNG's rgb_xyz_matrix as zeros ------------------------------

CAMERA_MATRIX = ((0.6722, -0.0635, -0.0963), (-0.4287, 1.246, 0.2046), (-0.0908, 0.2067, 0.6018))
"""An XYZ -> camera matrix with a real camera's four-decimal entries (each an exact rational: read back exactly)."""


def _rationals(values):
    """Numerator, denominator pairs (SRATIONAL) of exact decimal ``values``."""
    from fractions import Fraction

    return [x for v in values for x in (Fraction(str(v)).numerator, Fraction(str(v)).denominator)]


def _dng_with_tags(path, monkeypatch, add=(), drop=()):
    """A grey DNG by pipeline.dng.write_dng (ColorMatrix1 = :data:`CAMERA_MATRIX`, D65) with the tags ``add`` (tifffile
    extratags) written besides or instead of (``drop``, by code) its own."""
    import tifffile

    real = tifffile.imwrite

    def imwrite(tmp, data, **kw):
        kw["extratags"] = [t for t in kw["extratags"] if t[0] not in drop] + list(add)
        return real(tmp, data, **kw)

    with monkeypatch.context() as m:
        m.setattr(tifffile, "imwrite", imwrite)
        return write_dng(path, torch.full((H, W), 1000.0), "RGGB", black_level=BLACK, white_level=WHITE,
                         color_matrix=CAMERA_MATRIX)


def _second(matrix, illuminant):
    return [(50722, "2i", 9, _rationals(np.ravel(matrix)), True), (50779, "H", 1, (illuminant,), True)]


def test_a_dng_s_color_matrix_is_read_back_exactly_and_recorded_with_its_source(tmp_path, monkeypatch):
    from pipeline.photo import open_photo

    path = _dng_with_tags(tmp_path / "cm.dng", monkeypatch)
    for info in (raw_info(path), read_raw(path, max_pixels=H * W)[1]):
        assert info.rgb_xyz_matrix == CAMERA_MATRIX  # exactly: the rationals' quotients
        assert info.rgb_xyz_matrix_source == "DNG ColorMatrix1 (CalibrationIlluminant1 21, D65)"
        assert info.rgb_xyz_matrix_note is None
    raw = open_photo(str(path)).metadata["raw"]  # what metrics.json records under raw
    assert raw["rgb_xyz_matrix"] == [list(r) for r in CAMERA_MATRIX]
    assert raw["rgb_xyz_matrix_source"].startswith("DNG ColorMatrix1") and raw["rgb_xyz_matrix_note"] is None
    json.dumps(raw, allow_nan=False)


A_MATRIX = ((0.8, -0.2, -0.1), (-0.5, 1.3, 0.2), (-0.1, 0.25, 0.55))
"""A second matrix, told apart from :data:`CAMERA_MATRIX`."""


@pytest.mark.parametrize("ill1, ill2, want", [(17, 21, 2), (21, 17, 1), (17, 23, 1), (21, 21, 1)])
def test_of_two_color_matrices_the_d65_one_is_recorded(tmp_path, monkeypatch, ill1, ill2, want):
    """ColorMatrix2 is recorded only when it alone is calibrated under D65 (21); else ColorMatrix1."""
    path = _dng_with_tags(tmp_path / "two.dng", monkeypatch, add=[(50778, "H", 1, (ill1,), True)] + _second(A_MATRIX, ill2),
                          drop=(50778,))
    info = raw_info(path)
    assert info.rgb_xyz_matrix == (CAMERA_MATRIX if want == 1 else A_MATRIX)
    ill = ill1 if want == 1 else ill2
    name = {17: "standard light A", 21: "D65", 23: "D50"}[ill]
    assert info.rgb_xyz_matrix_source == f"DNG ColorMatrix{want} (CalibrationIlluminant{want} {ill}, {name})"
    assert info.rgb_xyz_matrix_note is None


def test_a_dng_without_a_color_matrix_records_null_and_says_so(tmp_path, monkeypatch):
    info = raw_info(_dng_with_tags(tmp_path / "none.dng", monkeypatch, drop=(50721, 50778)))
    assert info.rgb_xyz_matrix is None and info.rgb_xyz_matrix_source is None
    assert info.rgb_xyz_matrix_note == "the DNG has no ColorMatrix1 or ColorMatrix2 tag"
    assert info.to_dict()["rgb_xyz_matrix"] is None


HOSTILE = {  # ColorMatrix1 as written instead of the real one, and what the note must say
    "six values": ((50721, "2i", 6, _rationals([1, 0, 0, 0, 1, 0]), True), "ColorMatrix1 has 6 values, not 9"),
    "a 4-colour camera's 4 x 3": ((50721, "2i", 12, _rationals([1, 0, 0, 0, 1, 0, 0, 0, 1, 0.5, 0.5, 0]), True),
                                  "ColorMatrix1 has 12 values, not 9"),
    "zero denominators": ((50721, "2i", 9, [1, 0] * 9, True), "ColorMatrix1 has a zero denominator"),
    "one zero denominator": ((50721, "2i", 9, _rationals([1, 0, 0, 0, 1, 0, 0, 0]) + [1, 0], True),
                             "ColorMatrix1 has a zero denominator"),
    "all zeros": ((50721, "2i", 9, [0, 1] * 9, True), "ColorMatrix1 is all zeros"),
    "text": ((50721, "s", 0, "XYZ to camera", True), "ColorMatrix1 is of TIFF type 2, not a rational"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_color_matrix_is_not_used_and_noted_in_one_line(tmp_path, monkeypatch, capfd, case):
    tag, said = HOSTILE[case]
    path = _dng_with_tags(tmp_path / "bad.dng", monkeypatch, add=[tag], drop=(50721,))
    img, info = read_raw(path, max_pixels=H * W)  # the photo itself reads as ever
    assert img.shape == (1, 3, H, W)
    assert info.rgb_xyz_matrix is None and info.rgb_xyz_matrix_source is None
    assert info.rgb_xyz_matrix_note.startswith(said) and info.rgb_xyz_matrix_note.endswith(": not used")
    assert "\n" not in info.rgb_xyz_matrix_note
    json.dumps(info.to_dict(), allow_nan=False)
    # the same tag as ColorMatrix1 beside a good ColorMatrix2: the good one is recorded, the bad one noted
    path = _dng_with_tags(tmp_path / "bad2.dng", monkeypatch, add=[tag] + _second(A_MATRIX, 17), drop=(50721,))
    info = raw_info(path)
    assert info.rgb_xyz_matrix == A_MATRIX and info.rgb_xyz_matrix_source.startswith("DNG ColorMatrix2")
    assert info.rgb_xyz_matrix_note.startswith(said)
    assert capfd.readouterr().err == ""


def test_a_color_matrix_tag_that_points_past_the_file_is_noted_not_a_traceback(tmp_path, monkeypatch, capfd):
    """ColorMatrix1's count patched to 2^31 - 1 (its values would lie far past the file's end): tifffile drops the tag;
    its complaint becomes the note, not a line on standard error."""
    import struct

    import tifffile

    path = _dng_with_tags(tmp_path / "count.dng", monkeypatch)
    with tifffile.TiffFile(path) as tif:
        at = tif.pages.first.tags[50721].offset
    with open(path, "r+b") as fh:
        fh.seek(at + 4)  # an IFD entry: tag (2 bytes), type (2), count (4), value or offset (4); little-endian
        fh.write(struct.pack("<I", 2**31 - 1))
    info = raw_info(path)
    assert info.rgb_xyz_matrix is None
    assert info.rgb_xyz_matrix_note.startswith("a colour-matrix tag could not be read (tifffile: ")
    assert "50721" in info.rgb_xyz_matrix_note and len(info.rgb_xyz_matrix_note) <= 200
    assert capfd.readouterr().err == ""
