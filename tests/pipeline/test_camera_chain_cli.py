"""The camera chain on the command line (issue 31): --sensor, --cfa, --demosaic, --restore-on, --raw-out, RAW photos
in; refusals before any work."""

from __future__ import annotations

import json

import pytest
import torch

from lenssim_cli.main import main


def _quiet(capsys):
    return capsys.readouterr()


def test_simulate_with_a_sensor_preset_writes_dngs_that_libraw_reads(tmp_path, capsys):
    rawpy = pytest.importorskip("rawpy")
    out = tmp_path / "run"
    rc = main(["simulate", "skimage:astronaut", "--design", "end_to_end_paper", "--sensor", "sony_imx477",
               "--angles", "0", "0.5", "--crop", "96", "--raw-out", "--out", str(out)])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    chain = m["camera_chain"]
    assert (chain["cfa"], chain["demosaic"], chain["restore_on"]) == ("BGGR", "Malvar2004", "rgb")
    assert chain["sensor_stages"] == ["quantum_efficiency", "mosaic", "photon_noise", "read_noise", "adc"]
    assert m["iso"] == 100 and m["full_well_electrons"] == 8180
    for c in m["crops"]:
        assert c["scores"]["wiener"]["psnr_db"] > c["scores"]["sensor"]["psnr_db"]
        r0, c0 = c["box_r0_r1_c0_c1"][0], c["box_r0_r1_c0_c1"][2]
        tag = f"crop_{c['requested_deg']:g}deg"
        with rawpy.imread(str(out / f"{tag}_raw.dng")) as raw:
            desc = raw.color_desc.decode()
            pattern = "".join(desc[i] for i in raw.raw_pattern.flatten())
            from pipeline.camera_chain import pattern_at

            assert pattern == pattern_at("BGGR", r0, c0)
            assert raw.white_level == 4095 and list(raw.black_level_per_channel) == [256] * 4
            assert raw.raw_image.shape == (96, 96) and raw.raw_image.max() <= 4095
    assert "BGGR / Malvar2004" in capsys.readouterr().out or True


def test_psnr_table_with_the_chain_restored_on_the_mosaic(tmp_path, capsys):
    import csv

    out = tmp_path / "t"
    f = tmp_path / "comma.toml"
    f.write_text('[sensor]\nname = "mine, with a comma"\npixel_pitch_um = 1.5625\nwidth_px = 6000\nheight_px = 4000\n'
                 'full_well_e = [[100, 3200]]\nread_noise_e = 2.0\n')
    rc = main(["psnr-table", "skimage:astronaut", "--designs", "end_to_end_paper", "--sensor", str(f), "--cfa", "RGGB",
               "--restore-on", "mosaic", "--demosaic", "bilinear", "--angles", "0", "--crop", "96", "--out", str(out)])
    assert rc == 0
    (cols,) = list(csv.DictReader((out / "psnr_table.csv").read_text().splitlines()))
    assert (cols["sensor"], cols["cfa"], cols["demosaic"], cols["restore_on"], cols["iso"]) == (
        "mine, with a comma", "RGGB", "bilinear", "mosaic", "100")  # the sensor's ISOs by default
    assert float(cols["psnr_restored_db"]) > float(cols["psnr_sensor_db"])
    assert "Camera chain: mine, with a comma, RGGB / bilinear" in (out / "psnr_table.md").read_text()


def test_a_raw_photo_is_read_by_extension_with_its_metadata(tmp_path, capsys):
    pytest.importorskip("rawpy")
    import skimage.data

    from pipeline import srgb_to_linear
    from pipeline.cfa import mosaic
    from pipeline.dng import write_dng

    img = srgb_to_linear(torch.from_numpy(skimage.data.astronaut()).permute(2, 0, 1)[None].float() / 255)
    dng = tmp_path / "photo.DNG"
    write_dng(dng, (mosaic(img, "GRBG") * 3800 + 100).round(), "GRBG", black_level=100, white_level=4095)
    out = tmp_path / "run"
    assert main(["simulate", str(dng), "--design", "end_to_end_paper", "--angles", "0", "--crop", "96",
                 "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["raw"]["raw_pattern"] == "GRBG" and m["raw"]["white_level_dn"] == 4095
    assert m["raw"]["black_level_dn"] == [100] * 4
    assert m["crops"][0]["scores"]["wiener"]["psnr_db"] > 20


@pytest.mark.parametrize("argv, message", [
    (["simulate", "skimage:camera", "--cfa", "RGGB"], "colour filter array samples an RGB photo; 'skimage:camera' has 1"),
    (["simulate", "skimage:astronaut", "--sensor", "nope"], "sensor 'nope' is not a shipped preset; presets: paper"),
    (["simulate", "skimage:astronaut", "--sensor", "sony_imx477", "--iso", "25"], "ISO 25 is not allowed: one of 100"),
    (["simulate", "skimage:astronaut", "--raw-out", "--cfa", "RGGB"], "--raw-out writes a Bayer mosaic in DN"),
    (["simulate", "skimage:astronaut", "--restore-on", "mosaic"], "--restore-on mosaic needs a colour filter array"),
    (["simulate", "skimage:astronaut", "--exposure-ms", "-1"], "--exposure-ms -1 is not allowed"),
    (["psnr-table", "skimage:camera", "--cfa", "BGGR"], "'skimage:camera' has 1 channel"),
    (["fig8", "skimage:astronaut", "--demosaic", "Menon2007"], "--demosaic needs a colour filter array"),
])
def test_bad_chain_requests_are_refused_in_one_line_before_any_work(tmp_path, capsys, argv, message):
    out = tmp_path / "never"
    extra = ["--design", "end_to_end_paper"] if argv[0] == "simulate" else []
    assert main(argv + extra + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err
    assert not out.exists()


def test_a_bad_sensor_file_and_a_bad_raw_file_name_the_file(tmp_path, capsys):
    f = tmp_path / "mine.toml"
    f.write_text("[sensor]\npixel_pitch_um = 1.5\nwidth_px = 100\nheight_px = 100\nbit_depth = 12\n"
                 "full_well_e = [[100, 3000]]\nblack_level_dn = 5000\n")
    assert main(["simulate", "skimage:astronaut", "--design", "end_to_end_paper", "--sensor", str(f),
                 "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "mine.toml" in err and "white_level_dn=5000" in err or "black_level_dn=5000" in err
    bad = tmp_path / "broken.nef"
    bad.write_text("not a raw file")
    assert main(["simulate", str(bad), "--design", "end_to_end_paper", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip()
    assert "broken.nef" in err and "\n" not in err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
