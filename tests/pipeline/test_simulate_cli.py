import json
import math

import pytest
import torch

from lenssim import Design, LensPSF

from lenssim_studies.paper import PAPER_CAMERA, PAPER_SENSOR
from lenssim_cli.main import main
from pipeline.blur import WindowScheme
from pipeline.io import read_image
from pipeline.scene import resolution_scene, target_tile
from pipeline.simulate import crop_at_field_angle, crops_from_frame, simulate_crops, simulate_frame
import dataclasses

E2E = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))


def test_scene_is_deterministic_and_in_range():
    a = resolution_scene(600, 900, seed=1, geometry=PAPER_CAMERA.geometry)
    assert a.shape == (1, 3, 600, 900) and a.dtype == torch.float32
    assert torch.equal(a, resolution_scene(600, 900, seed=1, geometry=PAPER_CAMERA.geometry))
    assert float(a.min()) >= 0.02 and float(a.max()) <= 0.95
    star = target_tile(64, 0)
    assert set(torch.unique(star).tolist()) <= {0.0, 0.5, 1.0}
    with pytest.raises(ValueError, match="smaller than one"):
        resolution_scene(100, 100, geometry=PAPER_CAMERA.geometry)


def test_crops_sit_at_the_requested_field_angle():
    shape = (1, 3, 4000, 6000)
    for a in (0.0, 5.0, 9.0):
        r0, r1, c0, c1 = crop_at_field_angle(shape, a, 256, PAPER_CAMERA.geometry)
        cy, cx = (r0 + r1 - 1) / 2 - 1999.5, (c0 + c1 - 1) / 2 - 2999.5
        alpha = math.degrees(math.atan(math.hypot(cy, cx) * PAPER_SENSOR.pixel_pitch_um * 1e-3 / 25))
        assert alpha == pytest.approx(a, abs=0.02)


def test_simulate_command_writes_images_and_metrics(tmp_path, capsys):
    out = tmp_path / "sim"
    rc = main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--iso", "400", "--angles", "0",
               "--crop", "64", "--seed", "2", "--rl", "3", "--denoise", "0.5", "--out", str(out)])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    c = m["crops"][0]
    assert m["iso"] == 400 and m["full_well_electrons"] == 800 and "denoised" in m["source"]
    assert c["psnr_restored_db"] > c["psnr_sensor_db"]
    assert c["scores"]["wiener"]["psnr_db"] == c["psnr_restored_db"]
    assert c["scores"]["richardson_lucy"]["psnr_db"] > 0 and 0 < c["scores"]["richardson_lucy"]["ssim"] <= 1
    assert m["methods"] == ["wiener", "richardson_lucy"] and m["parameters"] == {"s": -0.775, "Q_back": -2.4, "Q_front": 0.0, "focus_shift_um": 0.0}
    for kind in ("ideal", "sensor", "restored", "restored_rl"):
        assert (out / f"crop_0deg_{kind}.png").exists()
    assert (out / "mosaic.png").exists()
    assert "sensor -> adaptive Wiener, Richardson-Lucy" in capsys.readouterr().out


def test_crops_centred_at_pixels(tmp_path, capsys):
    """``--at ROW,COL``: the crop centred at that pixel (moved inside at an edge), named by it; its field angle is the
    box's, as --angles reports it."""
    from pipeline.simulate import crop_at_pixel

    assert crop_at_pixel((1, 1, 512, 512), 100, 500, 64) == (68, 132, 448, 512)
    assert crop_at_pixel((512, 512), 0, 0, 64) == (0, 64, 0, 64)
    out = tmp_path / "at"
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--at", "256,256", "100,500",
                 "--crop", "64", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert [c["box_r0_r1_c0_c1"] for c in m["crops"]] == [[224, 288, 224, 288], [68, 132, 448, 512]]
    assert [c["requested_at_row_col"] for c in m["crops"]] == [[256, 256], [100, 500]]
    edge = PAPER_CAMERA.geometry.box_field_angle((1, 1, 512, 512), (68, 132, 448, 512))
    assert m["crops"][0]["field_deg"] == 0.0 and m["crops"][1]["field_deg"] == pytest.approx(edge, abs=1e-3)
    assert edge > 0.5
    assert (out / "crop_r100_c500_restored.png").exists()
    capsys.readouterr()
    for argv, message in ((["--at", "1,2", "--angles", "0"], "--at and --angles both place the crops"),
                          (["--at", "1;2"], "--at '1;2' is not allowed: ROW,COL"),
                          (["--at", "1,-2"], "--at '1,-2' is not allowed: ROW,COL"),
                          (["--at", "600,2"], "--at 600,2 is not allowed: 'skimage:camera' is 512 x 512 px")):
        assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", *argv, "--out",
                     str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad").exists()


def test_simulate_command_errors(tmp_path, capsys):
    assert main(["simulate", "skimage:nothing", "--design", "end_to_end_paper", "--out", str(tmp_path)]) == 2
    assert "nothing" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "missing.jpg"), "--s", "-0.5", "--Q", "-1", "--out", str(tmp_path)]) == 2
    assert "missing.jpg" in capsys.readouterr().err
    assert main(["simulate", "skimage:camera", "--s", "-0.5", "--Q", "-1", "--iso", "200", "--out", str(tmp_path)]) == 2
    assert "ISO 200 is not allowed: one of 25, 100, 400" in capsys.readouterr().err


def test_psnr_table(tmp_path, capsys):
    out = tmp_path / "t"
    rc = main(["psnr-table", "skimage:camera", "--designs", "end_to_end_paper", "rms_w_paper", "--isos", "100", "25",
               "--angles", "0", "--crop", "64", "--out", str(out)])
    assert rc == 0
    lines = (out / "psnr_table.csv").read_text().strip().splitlines()
    assert lines[0].startswith("photo,design,s,Q_back,Q_front,focus_shift_um,iso,method") and len(lines) == 1 + 4
    md = (out / "psnr_table.md").read_text()
    assert "| skimage:camera | end_to_end_paper | 25 |" in md
    rows = [ln.split(",") for ln in lines[1:]]
    by = {(r[1], int(r[6])): float(r[9]) for r in rows}
    assert by[("end_to_end_paper", 25)] > by[("end_to_end_paper", 100)]  # less noise, better restoration
    assert main(["psnr-table", "--designs", "nope", "--out", str(out)]) == 2


def test_the_psnr_table_gets_a_column_per_restoration_and_notes_a_restoration_below_the_sensor_image(tmp_path, capsys):
    """Several --restore methods (issue 45, item 3): one PSNR and SSIM column each, the same numbers as each method
    alone (the same noise draw), and a note wherever a method restores below the sensor image (tikhonov with almost
    no regularisation amplifies the noise)."""
    import csv

    args = ["psnr-table", "skimage:camera", "--designs", "end_to_end_paper", "--isos", "100", "--angles", "0",
            "--crop", "64"]
    assert main([*args, "--restore", "wiener", "tikhonov:weight=1e-7", "--out", str(tmp_path / "both")]) == 0
    assert main([*args, "--out", str(tmp_path / "one")]) == 0
    (both,) = csv.DictReader((tmp_path / "both" / "psnr_table.csv").read_text().splitlines())
    (one,) = csv.DictReader((tmp_path / "one" / "psnr_table.csv").read_text().splitlines())
    assert both["method"] == "wiener tikhonov" and one["method"] == "wiener"
    assert float(both["psnr_wiener_db"]) == float(both["psnr_restored_db"]) == float(one["psnr_restored_db"])
    assert float(both["ssim_wiener"]) == float(one["ssim_restored"])
    assert float(both["psnr_tikhonov_db"]) < float(both["psnr_sensor_db"]) < float(both["psnr_wiener_db"])
    md = (tmp_path / "both" / "psnr_table.md").read_text()
    assert "| PSNR wiener [dB] | PSNR tikhonov [dB] | SSIM wiener | SSIM tikhonov |" in md
    assert "Note: tikhonov restored skimage:camera / end_to_end_paper / ISO 100 below its sensor image" in md
    assert "Note:" not in (tmp_path / "one" / "psnr_table.md").read_text()
    assert main([*args, "--restore", "wiener", "wiener", "--out", str(tmp_path / "dup")]) == 2
    assert "given more than once" in capsys.readouterr().err
    assert main([*args, "--restore", "wiener", "tikhonov", "--as-built", "1", "--out", str(tmp_path / "ab")]) == 2
    assert "--as-built compares the nominal and the lens's own PSFs with one restoration" in capsys.readouterr().err


def test_fig8_mosaic(tmp_path):
    out = tmp_path / "f8"
    assert main(["fig8", "skimage:camera", "--angles", "0", "--crop", "48", "--out", str(out)]) == 0
    png = out / "fig8_mosaic.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (out / "fig8_mosaic.svg").exists()
    tiles = json.loads((out / "fig8_psnr.json").read_text())["tiles"]
    assert {(t["design"], t["iso"]) for t in tiles} == {("rms_w", 25), ("e2e", 400), ("e2e", 100), ("e2e", 25)}


def test_crops_at_several_iso_share_one_blur_and_equal_separate_runs():
    ideal = resolution_scene(600, 900, seed=2, geometry=PAPER_CAMERA.geometry)
    boxes = [crop_at_field_angle(ideal.shape, 0.5, 48, PAPER_CAMERA.geometry)]
    both = simulate_crops(ideal, E2E, [800.0, 12800.0], boxes, seed=4, sensor=PAPER_SENSOR)
    for fwc, res in zip((800.0, 12800.0), both):
        alone = simulate_crops(ideal, E2E, fwc, boxes, seed=4, sensor=PAPER_SENSOR)[0]
        assert torch.equal(res[0].images["wiener"], alone.images["wiener"])
        assert res[0].scores["sensor"] == alone.scores["sensor"]
    assert both[1][0].scores["wiener"]["psnr_db"] > both[0][0].scores["wiener"]["psnr_db"]  # ISO 25 beats ISO 400
    with pytest.raises(ValueError, match="full_well=-1.0"):
        simulate_crops(ideal, E2E, [-1.0], boxes, sensor=PAPER_SENSOR)
    with pytest.raises(ValueError, match="restoration method 'nonesuch' is not known"):
        simulate_crops(ideal, E2E, 800.0, boxes, methods=("nonesuch",), sensor=PAPER_SENSOR)


def test_sensor_read_noise_and_adc_enter_the_sensor_image():
    """A sensor with read noise and a 4-bit ADC: the sensor image gets worse, and only at the quantised levels."""

    ideal = resolution_scene(600, 900, seed=2, geometry=PAPER_CAMERA.geometry)
    boxes = [crop_at_field_angle(ideal.shape, 0.5, 48, PAPER_CAMERA.geometry)]
    clean = simulate_crops(ideal, E2E, 800.0, boxes, seed=4, sensor=PAPER_SENSOR)[0]
    noisy = simulate_crops(ideal, E2E, 800.0, boxes, seed=4, sensor=dataclasses.replace(PAPER_SENSOR, read_noise_e=20.0, bit_depth=4))[0]
    assert noisy.scores["sensor"]["psnr_db"] < clean.scores["sensor"]["psnr_db"] - 0.3
    e = 800.0 / float(ideal.amax())
    levels = noisy.sensor * e / (800.0 / 15)  # digital numbers
    torch.testing.assert_close(levels, levels.round(), rtol=0, atol=1e-3)


def test_full_frame_resumes_from_its_checkpoint(tmp_path):
    ideal = resolution_scene(600, 900, seed=3, geometry=PAPER_CAMERA.geometry)[..., :300, :400]
    scheme = WindowScheme(256, 32, 64)
    first = simulate_frame(ideal, E2E, 3200.0, seed=1, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)
    assert not first.resumed and (tmp_path / "sensor_linear.exr").exists()
    import OpenImageIO as oiio

    from pipeline.simulate import CHECKPOINT_EXR_COMPRESSION

    inp = oiio.ImageInput.open(str(tmp_path / "sensor_linear.exr"))  # written as named (a noisy float hardly compresses)
    assert inp.spec().get_string_attribute("compression") == CHECKPOINT_EXR_COMPRESSION == "none"
    inp.close()
    again = simulate_frame(ideal, E2E, 3200.0, seed=1, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)
    assert again.resumed and "blur" not in again.seconds
    assert torch.equal(again.sensor, first.sensor) and torch.equal(again.restored, first.restored)
    other = simulate_frame(ideal, E2E, 3200.0, seed=2, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)
    assert not other.resumed and not torch.equal(other.sensor, first.sensor)  # another seed: recomputed
    for changed in (WindowScheme(256, 32, 64, fit=False), WindowScheme(256, 32, 64, anchor="origin")):
        simulate_frame(ideal, E2E, 3200.0, seed=2, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)  # the checkpoint: seed 2
        assert not simulate_frame(ideal, E2E, 3200.0, seed=2, scheme=changed, checkpoint=tmp_path, sensor=PAPER_SENSOR).resumed
    # crops cut from the frame are the frame's pixels, at their own field angle
    box = crop_at_field_angle(ideal.shape, 0.3, 64, PAPER_CAMERA.geometry)
    c = crops_from_frame(ideal, first, [box], PAPER_CAMERA.geometry)[0]
    assert torch.equal(c.images["wiener"], first.restored[..., box[0]:box[1], box[2]:box[3]])
    assert c.field_deg == pytest.approx(0.3, abs=0.02) and c.scores["wiener"]["psnr_db"] > c.scores["sensor"]["psnr_db"]


def test_simulate_full_frame_command(tmp_path, capsys):
    out = tmp_path / "ff"
    rc = main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--full-frame", "--exr", "--bits", "16",
               "--angles", "0", "0.4", "--crop", "64", "--out", str(out)])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    f = m["full_frame"]
    assert f["shape_c_h_w"] == [1, 512, 512] and f["windows_per_pass"] == 17 * 17 and not f["resumed"]
    assert f["psnr_restored_db"] > f["psnr_sensor_db"] and f["ssim_restored"] > f["ssim_sensor"]
    sensor, info = read_image(out / "sensor.png")
    assert sensor.shape == (1, 1, 512, 512) and info.file_format == "uint16"
    lin, info = read_image(out / "restored_linear.exr")
    assert info.linear and lin.shape == (1, 1, 512, 512)
    assert not (out / ".checkpoint").exists()  # removed once the run is complete
    tiles = f["field_psnr_256px_tiles"]
    assert len(tiles["restored_db"]) == 2 and len(tiles["restored_db"][0]) == 2  # 512 px / 256 px tiles
    assert tiles["field_deg"][0][0] == pytest.approx(tiles["field_deg"][1][1])  # symmetric about the centre
    assert (out / "field_psnr.png").read_bytes()[:4] == b"\x89PNG" and (out / "field_psnr.svg").exists()
    assert [c["requested_deg"] for c in m["crops"]] == [0, 0.4]
    assert "whole frame: PSNR sensor" in capsys.readouterr().out
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--full-frame", "--rl", "2",
                 "--out", str(out)]) == 2


def test_default_crops_land_on_the_diagonal_targets():
    scene = resolution_scene(geometry=PAPER_CAMERA.geometry)
    star, bars = target_tile(256, 0), target_tile(256, 1)
    for a, t in ((0.0, star), (4.0, star), (12.0, star), (6.0, bars)):
        r0, r1, c0, c1 = crop_at_field_angle(scene.shape, a, 256, PAPER_CAMERA.geometry)
        grey = scene[0, 0, r0:r1, c0:c1]  # the white-lit channel: 0.05 + 0.9 * target
        err = float((grey - (0.05 + 0.9 * t).clamp(0.02, 0.95)).abs().mean())
        assert err < 0.02, (a, err)  # within a pixel or two of the target's centre


def test_console_script_exits_cleanly(tmp_path):
    """The installed entry point: exit status of main, complete outputs, no teardown noise on stderr."""
    import subprocess
    import sys

    run = lambda *a: subprocess.run([sys.executable, "-m", "lenssim_cli.main", *a], capture_output=True, text=True)  # noqa: E731
    ok = run("simulate", "skimage:camera", "--design", "end_to_end_paper", "--angles", "0", "--crop", "48",
             "--out", str(tmp_path / "c"))
    assert ok.returncode == 0 and "sensor -> adaptive Wiener" in ok.stdout
    assert json.loads((tmp_path / "c" / "metrics.json").read_text())["crops"]
    assert "leaked" not in ok.stderr
    bad = run("simulate", "skimage:nothing", "--design", "end_to_end_paper", "--out", str(tmp_path / "d"))
    assert bad.returncode == 2 and "nothing" in bad.stderr


def test_simulate_any_full_well_and_window_scheme(tmp_path, capsys):
    out = tmp_path / "fw"
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--full-well", "1600",
                 "--scheme", "256", "32", "64", "--angles", "0", "--crop", "48", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["full_well_electrons"] == 1600 and m["iso"] is None and m["scheme_window_stride_core"] == [256, 32, 64]
    assert "(1600 e- full well)" in capsys.readouterr().out
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--full-well", "0", "--out", str(out)]) == 2
    assert "--full-well=0.0 is not allowed" in capsys.readouterr().err
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--scheme", "511", "32", "64",
                 "--out", str(out)]) == 2
    assert "window=511" in capsys.readouterr().err


def test_restoration_with_a_wrong_psf_loses_what_the_right_one_gains():
    """Blur and restoration PSFs apart: the image blurred by one lens and restored with the PSFs of a
    deliberately wrong one (the conventional design, far sharper off axis) scores worse than restored
    with its own; the sensor image is the same either way (same blur, same seed)."""
    ideal = resolution_scene(600, 900, seed=2, geometry=PAPER_CAMERA.geometry)
    boxes = [crop_at_field_angle(ideal.shape, 0.5, 64, PAPER_CAMERA.geometry)]
    wrong = LensPSF(PAPER_CAMERA, Design(s=0.5, Q_back=-10.0))
    right = simulate_crops(ideal, E2E, 3200.0, boxes, seed=4, methods=("wiener", "tikhonov"), sensor=PAPER_SENSOR)[0]
    mis = simulate_crops(ideal, E2E, 3200.0, boxes, seed=4, methods=("wiener", "tikhonov"), restoration_psf=wrong, sensor=PAPER_SENSOR)[0]
    assert torch.equal(right.sensor, mis.sensor)
    for m in ("wiener", "tikhonov"):
        assert mis.scores[m]["psnr_db"] < right.scores[m]["psnr_db"] - 0.5
    ideal = ideal[..., :300, :400]
    scheme = WindowScheme(256, 32, 64)
    own = simulate_frame(ideal, E2E, 3200.0, seed=1, scheme=scheme, method="tikhonov", sensor=PAPER_SENSOR)
    other = simulate_frame(ideal, E2E, 3200.0, seed=1, scheme=scheme, method="tikhonov", restoration_psf=wrong, sensor=PAPER_SENSOR)
    assert torch.equal(own.sensor, other.sensor) and own.method == "tikhonov"
    err = lambda r: float(((r.restored - ideal) ** 2).mean())  # noqa: E731
    assert err(other) > 1.2 * err(own)


def test_any_registered_method_with_options_on_crops_psnr_table_fig8_and_the_full_frame(tmp_path, capsys):
    out = tmp_path / "t"
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--angles", "0", "--crop", "64",
                 "--restore", "tikhonov:weight=0.003", "wiener", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["methods"] == ["tikhonov", "wiener"] and m["restored_method"] == "tikhonov"
    assert m["restorations"][0] == {"name": "tikhonov", "options": {"weight": 0.003, "strength": 1.0, "order": 1}}
    c = m["crops"][0]
    assert c["psnr_restored_db"] == c["scores"]["tikhonov"]["psnr_db"] and (out / "crop_0deg_restored_tikhonov.png").exists()
    ff = tmp_path / "ff"
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--full-frame", "--angles", "0",
                 "--crop", "64", "--restore", "tikhonov", "--out", str(ff)]) == 0
    f = json.loads((ff / "metrics.json").read_text())["full_frame"]
    assert f["method"] == "tikhonov" and f["psnr_restored_db"] > f["psnr_sensor_db"]
    t = tmp_path / "table"
    assert main(["psnr-table", "skimage:camera", "--designs", "end_to_end_paper", "--isos", "100", "--angles", "0",
                 "--crop", "64", "--restore", "richardson_lucy:iterations=5", "--out", str(t)]) == 0
    assert "Richardson-Lucy (iterations=5)" in (t / "psnr_table.md").read_text()
    f8 = tmp_path / "f8"
    assert main(["fig8", "skimage:camera", "--angles", "0", "--crop", "48", "--restore", "tikhonov",
                 "--out", str(f8)]) == 0


def test_score_frame_equals_the_per_image_metrics():
    from pipeline.quality import psnr_srgb, ssim_srgb
    from pipeline.simulate import score_frame

    ideal = resolution_scene(600, 900, seed=3, geometry=PAPER_CAMERA.geometry)[..., :256, :512]
    frame = simulate_frame(ideal, E2E, 3200.0, seed=1, scheme=WindowScheme(256, 32, 64), sensor=PAPER_SENSOR)
    seen = []
    s = score_frame(ideal, frame, PAPER_CAMERA.geometry, on_encoded=lambda kind, enc, img: seen.append(kind))
    assert seen == ["sensor", "restored"]
    assert s["psnr_sensor_db"] == psnr_srgb(ideal, frame.sensor) and s["ssim_restored"] == ssim_srgb(ideal, frame.restored)
    assert s["maps"]["restored_db"].shape == (1, 2) and s["maps"]["field_deg"].shape == (1, 2)
    with pytest.raises(ValueError, match="smaller than one 512-px tile"):
        score_frame(ideal, frame, PAPER_CAMERA.geometry, tile=512)
    # the callback runs in a worker thread while the image is scored: its error comes back to the caller
    import threading

    where = []

    def failing(kind, enc, img):
        where.append(threading.current_thread() is threading.main_thread())
        raise OSError(f"disk full writing {kind}")

    with pytest.raises(OSError, match="disk full writing sensor"):
        score_frame(ideal, frame, PAPER_CAMERA.geometry, on_encoded=failing)
    assert where == [False]


@pytest.mark.parametrize("shape,size", [((400, 600), 256), ((512, 512), 128), ((2848, 4272), 256), ((4000, 6000), 256)])
def test_default_angles_fit_the_frame(shape, size):
    """The largest fitting angle's crop lies inside the frame where crop_at_field_angle puts it (not moved); the
    chosen angles are the preferred ones that fit, else evenly from the axis to it."""
    from pipeline.simulate import fitting_angles, largest_crop_angle_deg

    g = PAPER_CAMERA.geometry
    edge = largest_crop_angle_deg(shape, size, g)
    box = crop_at_field_angle((1, 1) + shape, edge, size, g)
    assert g.box_field_angle((1, 1) + shape, box) == pytest.approx(edge, abs=0.02)
    chosen = fitting_angles(shape, size, g, (0.0, 4.0, 8.0, 12.0))
    assert all(a <= edge + 0.25 for a in chosen) and chosen[0] == 0.0 and len(chosen) >= 3
    for a in chosen:
        crop_at_field_angle((1, 1) + shape, a, size, g)  # no error


def test_every_camera_command_runs_with_its_defaults_on_a_small_photo(tmp_path, capsys):
    """skimage:coffee (600 x 400 px) holds 1.2 deg of field: the default angles (0, 4, 8, 12 deg; the table's and
    Fig. 8's) do not fit, so each command chooses angles that do and says which; an explicit angle outside the
    frame stays an error."""
    assert main(["simulate", "skimage:coffee", "--design", "end_to_end_paper", "--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    assert "crop angles 0, " in err and "give --angles to choose" in err
    m = json.loads((tmp_path / "s" / "metrics.json").read_text())
    assert len(m["crops"]) == 4 and m["crops"][0]["requested_deg"] == 0
    assert main(["psnr-table", "skimage:coffee", "--designs", "end_to_end_paper", "--isos", "100", "--crop", "64",
                 "--out", str(tmp_path / "t")]) == 0
    assert "angles_deg" in (tmp_path / "t" / "psnr_table.csv").read_text().splitlines()[0]
    assert main(["fig8", "skimage:coffee", "--crop", "48", "--out", str(tmp_path / "f")]) == 0
    assert main(["simulate", "skimage:coffee", "--design", "end_to_end_paper", "--angles", "4",
                 "--out", str(tmp_path / "bad")]) == 2
    assert "field angle=4.0 is not allowed" in capsys.readouterr().err


def test_the_psnr_table_names_photos_by_file_name_and_keeps_the_path_in_the_csv(tmp_path):
    import numpy as np

    from pipeline.io import write_image

    photo = tmp_path / "deep" / "folder" / "holiday.png"
    photo.parent.mkdir(parents=True)
    g = np.random.default_rng(1)
    write_image(photo, torch.from_numpy(g.random((3, 300, 400)).astype(np.float32)), bits=8)
    assert main(["psnr-table", str(photo), "--designs", "end_to_end_paper", "--isos", "100", "--crop", "64",
                 "--out", str(tmp_path / "t")]) == 0
    md = (tmp_path / "t" / "psnr_table.md").read_text()
    assert "| holiday.png | end_to_end_paper |" in md and str(photo.parent) not in md
    assert str(photo) in (tmp_path / "t" / "psnr_table.csv").read_text()
