import math

import pytest
import torch

from lenssim_studies.paper import PAPER_SENSOR
from pipeline.field_map import field_psnr, plot_field_psnr
from pipeline.quality import psnr_srgb
from lenssim_studies.paper import PAPER_CAMERA


def test_field_psnr_tiles_and_angles(tmp_path):
    g = torch.Generator().manual_seed(0)
    ideal = torch.rand(1, 3, 192, 320, generator=g)
    sensor = (ideal + 0.05 * torch.randn(ideal.shape, generator=g)).clamp(0, 1)
    restored = (ideal + 0.01 * torch.randn(ideal.shape, generator=g)).clamp(0, 1)
    maps = field_psnr(ideal, sensor, restored, tile=64, geometry=PAPER_CAMERA.geometry)
    assert maps["restored_db"].shape == (3, 5) and (maps["restored_db"] > maps["sensor_db"]).all()
    assert float(maps["field_deg"][1, 2]) == 0.0  # the middle tile's centre is the optical axis
    # the corner tile: centre 2 tiles across and 1 down from the axis, through the lens's geometry
    r_mm = math.hypot(64, 128) * PAPER_SENSOR.pixel_pitch_um * 1e-3
    assert float(maps["field_deg"][0, 0]) == pytest.approx(math.degrees(math.atan(r_mm / 25.0)), rel=1e-12)
    assert float(maps["sensor_db"][2, 4]) == pytest.approx(psnr_srgb(ideal, sensor, (128, 192, 256, 320)), rel=1e-6)
    png = plot_field_psnr(maps, tmp_path / "f.png", title="test")
    assert png.read_bytes()[:4] == b"\x89PNG" and (tmp_path / "f.svg").exists()
