import json
import math

import pytest
import torch

from lenssim import PAPER_LENS
from pipeline.cli import main
from pipeline.scene import resolution_scene, target_tile
from pipeline.simulate import crop_at_field_angle


def test_scene_is_deterministic_and_in_range():
    a = resolution_scene(600, 900, seed=1)
    assert a.shape == (1, 3, 600, 900) and a.dtype == torch.float32
    assert torch.equal(a, resolution_scene(600, 900, seed=1))
    assert float(a.min()) >= 0.02 and float(a.max()) <= 0.95
    star = target_tile(64, 0)
    assert set(torch.unique(star).tolist()) <= {0.0, 0.5, 1.0}
    with pytest.raises(ValueError, match="smaller than one"):
        resolution_scene(100, 100)


def test_crops_sit_at_the_requested_field_angle():
    shape = (1, 3, 4000, 6000)
    for a in (0.0, 5.0, 9.0):
        r0, r1, c0, c1 = crop_at_field_angle(shape, a, 256)
        cy, cx = (r0 + r1 - 1) / 2 - 1999.5, (c0 + c1 - 1) / 2 - 2999.5
        alpha = math.degrees(math.atan(math.hypot(cy, cx) * PAPER_LENS.pixel_pitch_um * 1e-3 / 25))
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
    assert c["psnr_richardson_lucy_db"] > 0 and 0 < c["ssim_richardson_lucy"] <= 1
    for kind in ("ideal", "sensor", "restored", "restored_rl"):
        assert (out / f"crop_0deg_{kind}.png").exists()
    assert (out / "mosaic.png").exists()
    assert "PSNR sensor -> restored" in capsys.readouterr().out


def test_simulate_command_errors(tmp_path, capsys):
    assert main(["simulate", "skimage:nothing", "--design", "end_to_end_paper", "--out", str(tmp_path)]) == 2
    assert "nothing" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "missing.jpg"), "--s", "-0.5", "--Q", "-1", "--out", str(tmp_path)]) == 2
    assert "missing.jpg" in capsys.readouterr().err
    assert main(["simulate", "skimage:camera", "--s", "-0.5", "--Q", "-1", "--iso", "200", "--out", str(tmp_path)]) == 2
    assert "iso=200" in capsys.readouterr().err


def test_psnr_table(tmp_path, capsys):
    out = tmp_path / "t"
    rc = main(["psnr-table", "skimage:camera", "--designs", "end_to_end_paper", "rms_w_paper", "--isos", "100", "25",
               "--angles", "0", "--crop", "64", "--out", str(out)])
    assert rc == 0
    lines = (out / "psnr_table.csv").read_text().strip().splitlines()
    assert lines[0].startswith("photo,design,s,Q,iso") and len(lines) == 1 + 4
    md = (out / "psnr_table.md").read_text()
    assert "| skimage:camera | end_to_end_paper | 25 |" in md
    rows = [ln.split(",") for ln in lines[1:]]
    by = {(r[1], int(r[4])): float(r[6]) for r in rows}
    assert by[("end_to_end_paper", 25)] > by[("end_to_end_paper", 100)]  # less noise, better restoration
    assert main(["psnr-table", "--designs", "nope", "--out", str(out)]) == 2


def test_fig8_mosaic(tmp_path):
    out = tmp_path / "f8"
    assert main(["fig8", "skimage:camera", "--angles", "0", "--crop", "48", "--out", str(out)]) == 0
    png = out / "fig8_mosaic.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (out / "fig8_mosaic.svg").exists()
    tiles = json.loads((out / "fig8_psnr.json").read_text())["tiles"]
    assert {(t["design"], t["iso"]) for t in tiles} == {("rms_w", 25), ("e2e", 400), ("e2e", 100), ("e2e", 25)}
