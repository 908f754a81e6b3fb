"""``lenssim simulate --lens LENS`` (issue 29): any lens through the camera pipeline. The photo spans the lens's field
(its largest field angle at the frame's corners) unless ``--pixel-pitch`` says otherwise; what metrics.json says of
the lens is what the library computes; flags of the paper's singlet are refused beside ``--lens``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from lenssim.io.prescription_file import read_lens
from lenssim.optics.sequential import SequentialLens
from lenssim_cli.main import main

LENS_FILE = Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml"
"""A small F/8 plano-convex singlet (N-BK7), 3 degrees of field, one wavelength: a quick wavefront table, small PSFs."""


@pytest.fixture(scope="module")
def lens_file():
    return LENS_FILE


def test_simulate_any_lens_spans_its_field_and_reports_it(lens_file, tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", "skimage:camera", "--lens", str(lens_file), "--crop", "64", "--angles", "0", "2.5",
                 "--out", str(out)]) == 0
    rep = json.loads((out / "metrics.json").read_text())
    lens = rep["lens"]
    seq = SequentialLens(read_lens(str(lens_file)))
    par = seq.paraxial()
    assert lens["efl_mm"] == pytest.approx(par.efl_mm) and lens["f_number"] == pytest.approx(par.f_number)
    # skimage's camera is 512 x 512: the farthest PSF the blur asks for, the blur windows' 64 px core margin past the
    # corner pixel's centre, lies at the lens's largest field, 3 degrees (issue 43: the photo spans the lens's field)
    reach_px = math.hypot(511, 511) / 2 + 64
    assert lens["pixel_pitch_um"] == pytest.approx(lens["image_scale_mm"] * math.tan(math.radians(3.0)) / reach_px * 1e3)
    assert lens["image_scale_mm"] == pytest.approx(par.efl_mm, rel=1e-3)  # focused near infinity: the scale is f
    assert lens["psf_field_deg"] == 3.0 == lens["lens_field_deg"]  # the table reaches the lens's field, not beyond
    corner = math.degrees(math.atan(math.hypot(511, 511) / 2 * lens["pixel_pitch_um"] * 1e-3 / lens["image_scale_mm"]))
    assert lens["corner_field_deg"] == pytest.approx(corner) and corner < 3.0
    assert lens["wavefront_table_error_waves"] <= 0.01
    assert rep["wavelengths_um"] == [0.55]
    crops = rep["crops"]
    assert [c["requested_deg"] for c in crops] == [0.0, 2.5]
    for c in crops:
        assert math.isfinite(c["psnr_sensor_db"]) and math.isfinite(c["psnr_restored_db"])
    assert crops[0]["psnr_restored_db"] > crops[0]["psnr_sensor_db"]  # on the detailed centre, restoration helps
    for f in ("mosaic.png", "index.html", "crop_0deg_sensor.png"):
        assert (out / f).exists(), f
    assert rep["optics"].startswith("Test plano-convex singlet")
    assert f"{lens['pixel_pitch_um']:.3g} um pixels, corners at {corner:.3g} deg" in rep["optics"]  # the figures' titles


def test_a_finer_pixel_pitch_blurs_more_pixels(lens_file, tmp_path):
    """The same lens on a sensor of finer pixels: the PSF covers more pixels, so the sensor image of the same scene
    crop loses more detail (lower PSNR) - the pitch is used, not ignored."""
    runs = {}
    for pitch in ("4", "1"):
        out = tmp_path / pitch
        assert main(["simulate", "skimage:camera", "--lens", str(lens_file), "--pixel-pitch", pitch, "--crop", "64",
                     "--angles", "0", "--iso", "100", "--out", str(out)]) == 0
        runs[pitch] = json.loads((out / "metrics.json").read_text())
    assert runs["1"]["lens"]["pixel_pitch_um"] == 1.0 and runs["1"]["lens"]["pixel_pitch_from"] == "--pixel-pitch"
    assert runs["1"]["crops"][0]["psnr_sensor_db"] < runs["4"]["crops"][0]["psnr_sensor_db"]


@pytest.mark.parametrize("extra, match", [
    (["--design", "end_to_end_paper"], "--design describe"),
    (["--s", "0.5"], "--s describe"),
    (["--glass", "N-BK7"], "--glass describe"),
    (["--wavefront", "third_order"], "--wavefront third_order with --lens"),
    (["--pixel-pitch", "0"], "--pixel-pitch 0 is not allowed"),
])
def test_paper_flags_beside_any_lens_are_refused_in_one_line(lens_file, tmp_path, capsys, extra, match):
    assert main(["simulate", "skimage:camera", "--lens", str(lens_file), *extra, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0]
    assert not (tmp_path / "x").exists()


def test_lens_only_flags_need_a_lens(tmp_path, capsys):
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--refocus", "best",
                 "--out", str(tmp_path / "x")]) == 2
    assert "--refocus applies to --lens" in capsys.readouterr().err


def test_an_unknown_lens_is_refused_before_the_photo_is_read(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "missing.png"), "--lens", "no_such_lens", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "no_such_lens" in err or "missing.png" in err


def test_psnr_table_takes_lenses_and_agrees_with_simulate(lens_file, tmp_path, capsys):
    """``psnr-table --lens``: a row per lens and ISO (no paper design unless asked for), each the mean over the crops
    of what ``simulate --lens`` reports for the same photo, crops, ISO and seed."""
    import csv

    common = ["--crop", "64", "--angles", "0", "2", "--seed", "3"]
    assert main(["psnr-table", "skimage:camera", "--lens", str(lens_file), "--isos", "100", "25", *common,
                 "--out", str(tmp_path / "t")]) == 0
    rows = list(csv.DictReader((tmp_path / "t" / "psnr_table.csv").read_text().splitlines()))
    assert [(r["design"], r["iso"]) for r in rows] == [("lens test_singlet.toml", "100"), ("lens test_singlet.toml", "25")]
    assert main(["simulate", "skimage:camera", "--lens", str(lens_file), "--iso", "100", *common,
                 "--out", str(tmp_path / "s")]) == 0
    crops = json.loads((tmp_path / "s" / "metrics.json").read_text())["crops"]
    for key in ("psnr_sensor_db", "psnr_restored_db"):
        assert float(rows[0][key]) == pytest.approx(sum(c[key] for c in crops) / len(crops), abs=1e-6)
    assert float(rows[1]["psnr_restored_db"]) > float(rows[0]["psnr_restored_db"])  # ISO 25: less noise


@pytest.mark.parametrize("extra, match", [
    (["--as-built", "1"], "--as-built describe"),
    (["--lens", "cooke_triplet", "cooke_triplet"], "--lens cooke_triplet is given twice"),
    (["--lens", "no_such_lens"], "no_such_lens"),
    (["--pixel-pitch", "3"], "--pixel-pitch applies to --lens"),
])
def test_psnr_table_lens_refusals(tmp_path, capsys, extra, match):
    argv = ["psnr-table", "skimage:camera", "--isos", "100", "--out", str(tmp_path / "t"), *extra]
    if "--lens" not in extra and "--pixel-pitch" not in extra:
        argv += ["--lens", "cooke_triplet"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t").exists()


def test_fig8_mosaic_of_any_lens(lens_file, tmp_path, capsys):
    """``fig8 --lens``: the lens's sensor image and its restorations at the paper's three ISOs, a row per crop angle;
    the tiles' PSNRs are the pipeline's (less noise, higher restored PSNR)."""
    out = tmp_path / "f8"
    assert main(["fig8", "skimage:camera", "--lens", str(lens_file), "--crop", "64", "--angles", "0", "2",
                 "--out", str(out)]) == 0
    assert (out / "lens_mosaic.png").stat().st_size > 0 and (out / "lens_mosaic.svg").exists()
    tiles = json.loads((out / "fig8_psnr.json").read_text())["tiles"]
    # the crop's centre pixel is at the field angle to within half a pixel
    assert [(round(t["field_deg"], 1), t["iso"]) for t in tiles] == [(0.0, 400), (0.0, 100), (0.0, 25), (2.0, 400),
                                                                     (2.0, 100), (2.0, 25)]
    assert tiles[0]["design"] == "Test plano-convex singlet"
    assert tiles[0]["psnr_restored_db"] < tiles[1]["psnr_restored_db"] < tiles[2]["psnr_restored_db"]


def test_psnr_table_places_every_crop_of_every_photo_before_any_work(lens_file, tmp_path, capsys, monkeypatch):
    """With a fixed pixel pitch a smaller photo spans less field: an --angles the second photo cannot hold is refused
    in one line before the first photo is simulated (it was refused after the first photo's work)."""
    import numpy as np
    from PIL import Image

    import pipeline

    small = tmp_path / "small.png"
    Image.fromarray((np.random.default_rng(0).random((160, 160, 3)) * 255).astype(np.uint8)).save(small)
    calls = []
    monkeypatch.setattr(pipeline, "simulate_crops", lambda *a, **k: calls.append(1) or (_ for _ in ()).throw(
        AssertionError("simulated before every crop was placed")))
    argv = ["psnr-table", "skimage:camera", str(small), "--lens", str(lens_file), "--pixel-pitch", "5", "--crop", "64",
            "--angles", "0", "2", "--isos", "100", "--out", str(tmp_path / "t")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "field angle=2.0 is not allowed" in err and len(err.strip().splitlines()) == 1
    assert not calls and not (tmp_path / "t").exists()


def _far_out_of_focus(tmp_path):
    """The paper's singlet with its back radius -2.05 mm: an F/1 lens ~21 mm out of focus (issue 43)."""
    text = (Path(__file__).parents[2] / "configs" / "lenses" / "paper_singlet.toml").read_text()
    path = tmp_path / "fast.toml"
    path.write_text(text.replace("curvature_per_mm = -0.071", "curvature_per_mm = -0.487804878"))
    return path


@pytest.mark.parametrize("extra, match", [
    ((), "its PSF spans about"),  # the blur is wider than the photo
    (("--pixel-pitch", "1"), "its PSF spans about"),
])
def test_a_lens_whose_psf_is_out_of_bounds_is_refused_before_any_work(tmp_path, capsys, extra, match):
    """Issue 43: such a lens took 11.5 GB and minutes with no message. Its PSF's size comes from a few rays before any
    wavefront table or PSF: refused in one line, nothing written."""
    import time

    t0 = time.perf_counter()
    assert main(["simulate", "skimage:camera", "--lens", str(_far_out_of_focus(tmp_path)), "--crop", "128", "--angles",
                 "0", *extra, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1 and not (tmp_path / "o").exists()
    assert time.perf_counter() - t0 < 60  # bounded: not the minutes of a wavefront table


def test_a_psf_whose_fft_exceeds_the_limit_is_refused_with_the_flag_that_raises_it(lens_file, tmp_path, capsys):
    assert main(["simulate", "skimage:camera", "--lens", str(lens_file), "--crop", "64", "--angles", "0",
                 "--max-fft-size", "32", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "an FFT of" in err and "max_fft_size = 32" in err and "--max-fft-size" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_a_pixel_pitch_beyond_the_lens_field_says_what_fits(tmp_path, capsys):
    """Issue 43: a pitch putting the photo's corners where the chief ray no longer passes was a ray-trace error deep in
    the work; now one line, before any work, with the pitch that fits, which does."""
    from lenssim_studies.tradeoff import photo_field

    assert main(["simulate", "skimage:camera", "--lens", "cooke_triplet", "--pixel-pitch", "400", "--crop", "64",
                 "--angles", "0", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--pixel-pitch 400 is not allowed" in err and "at most" in err
    assert not (tmp_path / "o").exists()
    fit = float(err.split("at most ")[1].split(" um")[0])
    p = read_lens("cooke_triplet")
    pitch, reach = photo_field(p, SequentialLens(p), (1, 3, 512, 512), pitch_um=fit, margin_px=64)
    assert pitch == fit and reach == pytest.approx(max(p.fields), rel=1e-3)  # the lens's field, to the 4 digits given


def test_a_crop_moved_inside_the_frame_is_named_where_it_went(lens_file, tmp_path, capsys):
    """Issue 43: a crop asked at 26 deg and moved to 22.2 deg was still named crop_26deg_*."""
    out = tmp_path / "ok"
    assert main(["simulate", "skimage:camera", "--lens", str(lens_file), "--pixel-pitch", "5", "--crop", "128",
                 "--angles", "0", "2", "--iso", "100", "--out", str(out)]) == 0
    assert "pixel pitch 5 um (--pixel-pitch)" in capsys.readouterr().err
    c0, c2 = json.loads((out / "metrics.json").read_text())["crops"]
    assert c2["requested_deg"] == 2 and c2["field_deg"] < 1.75  # the corners lie at 2.08 deg: moved inside
    assert (out / "crop_0deg_sensor.png").exists()
    assert (out / f"crop_2deg_moved_to_{c2['field_deg']:.2f}deg_sensor.png").exists()
    assert not (out / "crop_2deg_sensor.png").exists()
