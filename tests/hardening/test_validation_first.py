"""Class 2 (issue 9): every argument, the input image and the output location are checked before any
computation, and a failed run leaves no output behind."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import pipeline
from lenssim_cli.main import main
from pipeline import write_image


@pytest.fixture
def no_compute(monkeypatch):
    """Fail the test if a simulation starts."""
    def boom(*a, **k):
        raise AssertionError("the computation started before the arguments were checked")
    for name in ("simulate_crops", "simulate_frame"):
        monkeypatch.setattr(pipeline, name, boom)
        monkeypatch.setattr(pipeline.simulate, name, boom)


def _png(path, h, w, value=None):
    rng = np.random.default_rng(0)
    arr = rng.random((3, h, w)).astype(np.float32) if value is None else np.full((3, h, w), value, np.float32)
    write_image(path, torch.from_numpy(arr))
    return str(path)


def _args(tmp_path, *extra, photo=None):
    return ["simulate", photo or "skimage:camera", "--design", "end_to_end_paper", "--out", str(tmp_path / "out"),
            *extra]


@pytest.mark.parametrize("extra, match", [
    (["--crop", "0"], "--crop 0 is not allowed"),
    (["--crop", "8"], "--crop 8 is not allowed"),
    (["--rl", "-1"], "--rl -1 is not allowed"),
    (["--rl", "0"], "--rl 0 is not allowed"),
    (["--seed", "-3"], "--seed -3"),
    (["--angles", "1", "1.0"], "--angles holds 1 more than once"),
    (["--angles", "-5"], "--angles -5 is not allowed"),
    (["--angles", "45"], "field angle=45.0 is not allowed"),
    (["--full-well", "inf"], "--full-well=inf is not allowed"),
    (["--full-well", "1e30"], "--full-well=1e+30 is not allowed"),
    (["--iso", "200"], "ISO 200 is not allowed"),
    (["--scheme", "511", "32", "64"], "window=511"),
    (["--denoise", "5"], "--denoise 5 is not allowed"),
    (["--restore", "nonesuch"], "restoration method 'nonesuch' is not known"),
    (["--full-frame", "--rl", "2"], "--full-frame restores with one method; 2 were given"),
    (["--restore", "tikhonov:weight=-1"], "weight=-1"),
    (["--restore", "wiener:stats=600"], "wiener option stats=600 is not allowed"),
    (["--restore", "wiener", "wiener"], "more than once"),
    (["--device", "tpu"], "device='tpu' is not allowed"),
    (["--Q", "60"], "Q_back must be < "),
])
def test_bad_arguments_stop_before_any_work(tmp_path, capsys, no_compute, extra, match):
    assert main(_args(tmp_path, *extra)) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("shape, value, match", [((1, 1), None, "at least 32 x 32 px"), ((256, 256), 0.0, "is black"),
                                                 ((200, 250), None, "--full-frame needs an image of at least 256")])
def test_bad_images_stop_before_any_work(tmp_path, capsys, no_compute, shape, value, match):
    photo = _png(tmp_path / "in.png", *shape, value=value)
    assert main(_args(tmp_path, "--full-frame", "--crop", "16", "--angles", "0", photo=photo)) == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_unwritable_output_stops_before_any_work(tmp_path, capsys, no_compute):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--out", str(blocker / "sub")]) == 2
    assert "cannot be written" in capsys.readouterr().err
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--out", str(blocker)]) == 2
    assert "is an existing file" in capsys.readouterr().err


def test_an_output_folder_holding_the_input_is_refused(tmp_path, capsys, no_compute):
    photo = _png(tmp_path / "photo.png", 64, 64)
    assert main(["simulate", photo, "--design", "end_to_end_paper", "--out", str(tmp_path)]) == 2
    assert "holds the input" in capsys.readouterr().err


def test_a_run_that_fails_late_leaves_no_partial_outputs(tmp_path, monkeypatch, capsys):
    def broken(*a, **k):
        raise OSError("disk full (simulated)")
    monkeypatch.setattr("lenssim_cli.camera.mosaic_figure", broken)
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--angles", "0", "--crop", "32",
                 "--scheme", "128", "32", "64", "--out", str(tmp_path / "out")]) == 2
    assert "disk full" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    assert not list(tmp_path.glob(".*staging*"))


def test_an_undefined_conic_is_reported_as_such_not_as_a_window_problem(tmp_path, capsys, no_compute):
    assert main(_args(tmp_path, "--s", "-2", "--Q", "17", "--scheme", "128", "32", "64")) == 2
    err = capsys.readouterr().err
    assert "undefined over the 2.0 mm aperture" in err and "window" not in err
