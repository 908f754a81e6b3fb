"""Errors that waited on a path no test walked (issue 18): each test here failed on the code before its fix."""

from __future__ import annotations

import dataclasses

import pytest
import torch

import lenssim.optics.cost
from lenssim import Design, LensError, slope_departure_cost
from lenssim_studies.paper import PAPER_CAMERA


def test_a_non_finite_asphere_cost_is_a_lens_error_not_a_name_error(monkeypatch):
    """``cost.py`` raised ``LensError`` without importing it: the error path was a NameError."""
    monkeypatch.setattr(lenssim.optics.cost, "surface_cost", lambda c, Q, y, n: torch.full_like(c, float("nan")))
    with pytest.raises(LensError, match="not finite"):
        slope_departure_cost(PAPER_CAMERA.lens, Design(s=-0.775, Q_back=-2.4))


def test_the_full_frame_uses_the_camera_s_own_sensor(tmp_path, monkeypatch):
    """``simulate --full-frame`` passed the paper's sensor to the frame where crops pass the camera's: a custom
    sensor's read noise and ADC were ignored on whole frames."""
    import lenssim_cli.camera
    import pipeline.simulate
    from lenssim_cli.main import main

    sensor = dataclasses.replace(PAPER_CAMERA.sensor, read_noise_e=3.0, bit_depth=12)
    custom = dataclasses.replace(PAPER_CAMERA, sensor=sensor)
    monkeypatch.setattr(lenssim_cli.camera, "camera_from_args", lambda args: custom)
    seen = {}

    def frame(*args, sensor, **kwargs):
        seen["sensor"] = sensor
        raise RuntimeError("stop after the sensor is seen")

    monkeypatch.setattr(pipeline.simulate, "simulate_frame", frame)
    with pytest.raises(RuntimeError, match="stop after"):
        main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--full-frame", "--angles", "0",
              "--out", str(tmp_path / "ff")])
    assert seen["sensor"] == sensor
