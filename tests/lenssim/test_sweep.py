import json
from pathlib import Path

import numpy as np
import pytest

from lenssim import Camera, Design, Numerics, evaluate

from lenssim_studies.paper import PAPER_SENSOR
from lenssim_studies.sweep import SweepConfig, grid_values, load_config, run_sweep
from lenssim_studies.tradeoff import find_optimum
from lenssim_cli.main import main
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SPECTRUM

TINY = """
[lens]
field_angles_deg = [0, 7, 14]
[grid]
s = [-1.0, -0.5, 0.25]
Q = [-4.0, 0.0, 2.0]
snr_db = [21.6, 27.6]
[numerics]
min_size = 128
"""


@pytest.fixture
def tiny_cfg(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(TINY)
    return load_config(p)


def test_grid_values_match_the_paper_counts():
    assert len(grid_values(-2.0, 1.025, 0.025)) == 122
    assert len(grid_values(-10.0, 1.2, 0.1)) == 113
    cfg = load_config(Path(__file__).resolve().parents[2] / "configs" / "paper_grid.toml")
    assert cfg.dims == ("s", "Q_back")
    assert len(cfg.values("s")) * len(cfg.values("Q")) * len(cfg.lens.field_angles_deg) == 206_790


def test_sweep_values_equal_direct_evaluation(tiny_cfg, tmp_path):
    ds = run_sweep(tiny_cfg, tmp_path / "a.nc", show_progress=False)
    assert dict(ds.sizes) == {"s": 3, "Q_back": 3, "alpha": 3, "snr": 2}
    r = evaluate(tiny_cfg.camera, Design(s=-0.75, Q_back=-2.0), (21.6, 27.6), numerics=Numerics(min_size=128), rho0=PAPER_RHO0)
    np.testing.assert_allclose(ds["mse_r"].sel(s=-0.75, Q_back=-2.0).values, r["mse_r"].numpy(), rtol=1e-6)
    np.testing.assert_allclose(float(ds["cost"].sel(s=-0.75, Q_back=0.0)), 0.0, atol=1e-15)
    assert ds["mse_s"].attrs["units"].startswith("1")
    assert json.loads(ds.attrs["config"])["numerics"]["min_size"] == 128
    assert ds.attrs["design_parameters"] == "s Q_back"
    assert SweepConfig.from_dict(json.loads(ds.attrs["config"])).digest() == tiny_cfg.digest()
    assert not (tmp_path / "a.nc.partial").exists()


def test_interrupted_sweep_resumes_to_an_identical_file(tiny_cfg, tmp_path):
    ref = tmp_path / "ref.nc"
    run_sweep(tiny_cfg, ref, show_progress=False)
    out = tmp_path / "resumed.nc"
    assert run_sweep(tiny_cfg, out, show_progress=False, max_chunks=1) is None
    assert not out.exists() and len(list((tmp_path / "resumed.nc.partial").glob("chunk_*.npz"))) == 1
    assert run_sweep(tiny_cfg, out, show_progress=False, max_chunks=1) is None  # continues, no recompute
    assert len(list((tmp_path / "resumed.nc.partial").glob("chunk_*.npz"))) == 2
    run_sweep(tiny_cfg, out, show_progress=False)
    assert out.read_bytes() == ref.read_bytes()
    # a finished sweep of the same config is reused, not recomputed or overwritten
    before = out.stat().st_mtime_ns
    run_sweep(tiny_cfg, out, show_progress=False)
    assert out.stat().st_mtime_ns == before


def test_sweep_never_overwrites_foreign_files(tiny_cfg, tmp_path):
    foreign = tmp_path / "photo.nc"
    foreign.write_bytes(b"not a sweep")
    with pytest.raises(FileExistsError, match="photo.nc"):
        run_sweep(tiny_cfg, foreign, show_progress=False)
    assert foreign.read_bytes() == b"not a sweep"
    other = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0,)), PAPER_SENSOR, PAPER_SPECTRUM), grid={"s": (-1.0, -1.0, 0.1), "Q": (0.0, 0.0, 0.1)},
                        numerics=Numerics(min_size=64))
    run_sweep(other, tmp_path / "x.nc", show_progress=False, max_chunks=0)
    with pytest.raises(FileExistsError, match="different config"):
        run_sweep(tiny_cfg, tmp_path / "x.nc", show_progress=False)


@pytest.mark.parametrize(
    "text, match",
    [
        ("[grid]\ns = [1, 0, 0.1]\n", "stop=0.0 is below start=1.0"),
        ("[grid]\ns = [0, 1]\n", r"\[start, stop, step\]"),
        ("[grid]\nq = [0, 1, 0.1]\n", "design parameter 'q' is not known; valid: s .alias E1.bending., Q_back .alias Q, S2.conic."),
        ("[lens]\nrefractive_index = 0.9\n", "refractive_index=0.9"),
        ("[lens]\ncolour = 1\n", "colour"),
        ("[numerics]\nfil = 0.5\n", "unknown key"),
        ("[grid]\ns = [-2, -2, 0.1]\nQ = [20, 20, 1]\n", "Q_back=20"),
        ("[sensor]\npixel_pitch_um = -1\n", "pixel_pitch_um=-1"),
        ("[spectrum]\nwavelengths_um = [0.5]\nweights = [1, 2]\n", "1 wavelengths and 2 weights"),
        ("[oops]\n", "unknown section"),
        ("[grid\n", "not valid TOML"),
    ],
)
def test_bad_configs_are_refused_with_their_value(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        load_config(p)


def test_optimum_and_cli(tiny_cfg, tmp_path, capsys):
    path = tmp_path / "a.nc"
    ds = run_sweep(tiny_cfg, path, show_progress=False)
    best = find_optimum(ds, "rms_w")
    assert best["value"] == pytest.approx(float(ds["rms_w"].min()))
    assert main(["optimum", str(path), "--criterion", "mse_r", "--snr", "27.6", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["value"] == pytest.approx(float(ds["mse_r"].sel(snr=27.6).min()))
    assert main(["optimum", str(path), "--criterion", "sharpness"]) == 2
    assert "sharpness" in capsys.readouterr().err
    assert main(["optimum", str(path), "--criterion", "mse_r", "--snr", "40"]) == 2
    assert main(["optimum", str(tmp_path / "missing.nc"), "--criterion", "rms_w"]) == 2


def test_cli_evaluate_json_and_errors(capsys):
    assert main(["evaluate", "--design", "end_to_end_paper", "--snr", "27.6", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["s"] == -0.775 and r["Q_back"] == -2.4 and len(r["mse_r"]) == 1
    assert r["parameters"] == {"s": -0.775, "Q_back": -2.4, "Q_front": 0.0, "focus_shift_um": 0.0} and r["units"]["rms_w"] == "waves"
    assert r["mse_r"][0] < r["mse_s"][0] and len(r["fft_size_per_angle"]) == 15
    assert main(["evaluate", "--s", "-0.5", "--Q", "-1", "--snr", "27.6"]) == 0
    assert "MSE_R@27.6dB" in capsys.readouterr().out
    assert main(["evaluate", "--design", "nope"]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["evaluate", "--s", "-2", "--Q", "30"]) == 2
    assert "Q_back=30" in capsys.readouterr().err
    assert main(["evaluate"]) == 2
    assert "--design NAME" in capsys.readouterr().err
    assert main(["evaluate", "--s", "-2", "--snr", "27.6", "--json"]) == 0  # Q_back takes its default 0
    assert json.loads(capsys.readouterr().out)["Q_back"] == 0.0
    assert PAPER_SENSOR.pixel_pitch_um == 1.5625


def test_a_config_cannot_change_after_its_validation():
    """A SweepConfig is frozen: a change goes through dataclasses.replace, which validates again."""
    import dataclasses

    cfg = SweepConfig(grid={"s": (-1.0, -0.5, 0.25), "Q": (-3.0, 0.0, 1.5)})
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.snr_db = (1e9,)
    with pytest.raises(ValueError, match="psd_model"):
        dataclasses.replace(cfg, psd_model="nope")
