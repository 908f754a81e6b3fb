"""Sweep configs for colour cameras and fixed parameters; the white-light and exact-wavefront studies."""

from __future__ import annotations

import json
import warnings

import pytest

from lenssim import Camera, Design, Numerics, evaluate

from lenssim_studies.paper import PAPER_CAMERA
from lenssim.optics.cost import slope_departure_cost
from lenssim_studies.sweep import SweepConfig, load_config, run_sweep
from lenssim.validate import ModelValidityWarning
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SPECTRUM

FAST = Numerics(oversample=1)


@pytest.fixture(autouse=True)
def _quiet_model_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelValidityWarning)
        yield


def test_a_sweep_config_names_colour_channels_and_fixed_parameters(tmp_path):
    cfg_file = tmp_path / "c.toml"
    cfg_file.write_text('[lens]\nglass = "N-BK7"\nfield_angles_deg = [0, 7, 14]\n'
                        '[channels]\ncamera = "Nikon 5100 (NPL)"\nper_channel = 2\n'
                        '[grid]\ns = [-0.9, -0.7, 0.2]\nQ = [-3.0, -1.0, 2.0]\nsnr_db = [27.6]\n'
                        '[fixed]\nfocus_shift_um = -250.0\n[numerics]\noversample = 1\n')
    cfg = load_config(cfg_file)
    assert len(cfg.camera.channels) == 3 and cfg.fixed == {"focus_shift_um": -250.0}
    assert SweepConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))).digest() == cfg.digest()
    ds = run_sweep(cfg, tmp_path / "s.nc", show_progress=False)
    # the sweep's value at one grid point is the channel mean that evaluate gives at the fixed focus
    d = Design(s=-0.7, Q_back=-3.0, focus_shift_um=-250.0)
    ref = evaluate(cfg.camera, d, [27.6], numerics=cfg.numerics, rho0=PAPER_RHO0)
    got = float(ds["mse_r"].sel(s=-0.7, Q_back=-3.0, snr=27.6))
    assert got == pytest.approx(float(ref["mse_r"].reshape(-1)[0]), rel=1e-9)
    # and the focus matters: at the d-line focus the value differs
    at0 = evaluate(cfg.camera, Design(s=-0.7, Q_back=-3.0), [27.6], numerics=cfg.numerics, rho0=PAPER_RHO0)
    assert abs(float(at0["mse_r"].reshape(-1)[0]) - got) > 1e-3


@pytest.mark.parametrize("bad, match", [({"focus_shift_um": 1.0, "s": 0.0}, "both fixed and gridded"),
                                        ({"focus_shift_um": float("nan")}, "finite")])
def test_fixed_parameters_are_checked(bad, match):
    with pytest.raises(ValueError, match=match):
        SweepConfig(grid={"s": (-1, 0, 0.5)}, fixed=bad)


def test_the_trade_off_refuses_a_sweep_whose_fixed_parameters_add_cost(tmp_path):
    from lenssim_studies.tradeoff import tradeoff

    cfg = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 10.0)), PAPER_CAMERA.sensor, PAPER_SPECTRUM),
                      grid={"s": (-1.0, -0.5, 0.25), "Q_back": (-2.0, 0.0, 1.0)}, snr_db=(27.6,), numerics=FAST,
                      fixed={"Q_front": -1.0})
    ds = run_sweep(cfg, tmp_path / "q.nc", show_progress=False)
    with pytest.raises(ValueError, match="Q_front"):
        tradeoff(ds)


def test_the_back_conic_is_solved_for_the_summed_cost_of_both_aspheres():
    from lenssim_studies.study import _solve_q_back

    lens = PAPER_CAMERA.lens
    for s, qf, level in ((-0.3, -1.0, 8e-4), (-0.775, 0.7, 5e-4)):
        qb = _solve_q_back(lens, s, qf, level)
        assert qb is not None and qb <= 0
        total = float(slope_departure_cost(lens, Design(s=s, Q_front=qf, Q_back=qb)))
        assert total == pytest.approx(level, rel=1e-9)
    # a front asphere that alone costs more than the level leaves no back conic
    assert _solve_q_back(lens, 0.8, -30.0, 1e-5) is None


def test_the_white_light_study_refines_the_grid_optima_and_writes_its_report(tmp_path):
    from lenssim_studies.study import WhiteLightStudy, white_light_study

    study = WhiteLightStudy(glasses=("paper",), grid={"s": (-1.0, -0.5, 0.25), "Q_back": (-4.0, 0.0, 2.0)},
                            snr_db=(27.6,), max_evaluations=6, q_front=False,
                            levels=(0.0, 4e-4, 8e-4))
    logged = []
    report = white_light_study(tmp_path / "st", study, log=logged.append, show_progress=False)
    summary = json.loads((tmp_path / "st" / "summary.json").read_text())
    r = summary["results"][0]
    grid_best = min(row["mse_r"] for row in r["table1_at_z0"])
    opt = r["optima_focus_free"]
    # the refined optimum starts at the grid optimum (at z0) and can only improve on it (the sweep evaluates the
    # grid in one batch, the search one design at a time: their float32 OTFs agree to ~1e-8)
    assert opt["mse_r"]["value"] <= grid_best * (1 + 1e-6)
    assert opt["mse_r"]["mse_r_relative"] == pytest.approx(1.0)
    # each refined design's reported MSE_R is the model's at that design
    d = opt["mse_s"]["design"]
    ref = evaluate(PAPER_CAMERA, Design(d), [27.6], numerics=study.numerics, rho0=PAPER_RHO0)
    assert opt["mse_s"]["mse_r"] == pytest.approx(float(ref["mse_r"].reshape(-1)[0]), rel=1e-9)
    text = report.read_text()
    assert "MSE_R (end-to-end)" in text and "paper" in text
    for f in ("fig4_landscapes.png", "fig6_performance_vs_cost.png", "table1.md", "sweep.nc", "tradeoff.nc"):
        assert (tmp_path / "st" / "paper" / f).exists()
    assert any("z0" in m for m in logged)


def test_the_study_refuses_an_unknown_glass_before_any_work(tmp_path):
    from lenssim_studies.study import WhiteLightStudy, white_light_study

    with pytest.raises(ValueError, match="not in the catalogue"):
        white_light_study(tmp_path / "x", WhiteLightStudy(glasses=("paper", "unobtainium")), show_progress=False)
    assert not (tmp_path / "x" / "paper").exists()


def test_exact_and_third_order_trade_off_agree_within_two_percent_at_the_paper_aperture():
    """The third-order optimum lies on the iso-cost curve, its MSE_R is the model's, and the exact wavefront
    moves MSE_R by about 1.5% (docs/white-light.md) and the optimum little."""
    from lenssim_studies.study import exact_along_tradeoff

    (row,) = exact_along_tradeoff(levels=(6e-4,), exact_points=3, s_step=0.05, log=lambda m: None)
    t = row["third_order"]
    cost = float(slope_departure_cost(PAPER_CAMERA.lens, Design(s=t["s"], Q_back=t["Q_back"])))
    assert cost == pytest.approx(6e-4, rel=1e-8)
    direct = float(evaluate(PAPER_CAMERA, Design(s=t["s"], Q_back=t["Q_back"]), [27.6], numerics=FAST, rho0=PAPER_RHO0)["mse_r"][0])
    assert t["mse_r"] == pytest.approx(direct, rel=2e-3)  # parabolic estimate vs the model
    assert abs(row["exact_at_third_order"] / direct - 1) < 0.02
    assert abs(row["exact"]["s"] - t["s"]) < 0.1
