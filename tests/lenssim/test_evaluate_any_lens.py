"""``lenssim evaluate --lens LENS`` (issue 29): every criterion of any lens over its field; what it prints is what the
library computes; flags of the paper's singlet refused beside ``--lens`` in one line."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from lenssim.io.prescription_file import read_lens
from lenssim.optics.sequential import SequentialLens
from lenssim_cli.main import main

LENS_FILE = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")


def test_evaluate_any_lens_json(capsys):
    assert main(["evaluate", "--lens", LENS_FILE, "--snr", "21.6", "33.6", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    par = SequentialLens(read_lens(LENS_FILE)).paraxial()
    # the default sensor: the Nyquist pitch at the primary wavelength, point samples (the paper's camera)
    assert rep["pixel_pitch_um"] == pytest.approx(0.55 * par.working_f_number / 2)
    assert rep["sampling"] == "point" and rep["snr_db"] == [21.6, 33.6]
    assert rep["alpha_deg"][0] == 0 and rep["alpha_deg"][-1] == pytest.approx(3.0) and len(rep["alpha_deg"]) == 15
    for name in ("mse_s", "mse_r"):
        assert len(rep[name]) == 2 and all(math.isfinite(v) and v > 0 for v in rep[name])
        assert rep[name][0] > rep[name][1]  # more noise, more error
        # the field average is the mean of the per-field values
        assert rep[name][1] == pytest.approx(sum(r[1] for r in rep[f"{name}_alpha"]) / 15, rel=1e-9)
    assert all(r <= s for r, s in zip(rep["mse_r"], rep["mse_s"]))  # Wiener restoration never adds error
    assert 0 < rep["strehl"] <= 1 and rep["rms_w"] > rep["rms_w_piston_removed_waves"] > 0
    assert rep["units"]["rms_w"] == "waves" and rep["units"]["mtf50"] == "cycles/mm"
    assert rep["cost"] == 0 and rep["cost_per_surface"] == {}  # spherical surfaces only: no asphere to pay for


def test_evaluate_any_lens_prints_a_table(capsys):
    assert main(["evaluate", "--lens", LENS_FILE, "--pixel-pitch", "6", "--refocus", "paraxial"]) == 0
    out = capsys.readouterr().out
    assert "MSE_R@27.6dB" in out and "RMS_W [waves]" in out and "(area samples)" in out and "paraxial" in out


@pytest.mark.parametrize("argv, match", [
    (["--design", "end_to_end_paper"], "--design describe"),
    (["--s", "-0.7"], "--s describe"),
    (["--best-focus", "mse_r"], "with --lens use --refocus best"),
    (["--wavefront", "third_order"], "--wavefront third_order with --lens"),
    (["--pixel-pitch", "-1"], "--pixel-pitch -1 is not allowed"),
    (["--pixel-pitch", "10", "--sampling", "point"], "sampling 'point' is not allowed"),
])
def test_evaluate_any_lens_refuses_in_one_line(capsys, argv, match):
    assert main(["evaluate", "--lens", LENS_FILE, *argv]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1


def test_sampling_without_lens_is_refused(capsys):
    assert main(["evaluate", "--design", "end_to_end_paper", "--sampling", "area"]) == 2
    assert "--sampling applies to --lens" in capsys.readouterr().err


def test_a_psf_beyond_the_largest_grid_is_refused_in_one_line(tmp_path, capsys):
    """The PSF's grid beyond --max-fft-size: one line naming the setting (it once raised a TypeError instead)."""
    from lenssim_cli.main import main

    lens = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")
    assert main(["evaluate", "--lens", lens, "--pixel-pitch", "0.5", "--max-fft-size", "64"]) == 2
    err = capsys.readouterr().err
    assert "pixel grid" in err and "--max-fft-size" in err and len(err.strip().splitlines()) == 1
