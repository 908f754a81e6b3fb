"""The gradient route of the trade-off on any lens (lenssim.design_opt, lenssim_studies.tradeoff; issue 30):
its gradients against the paper model's full autograd, its iso-cost optima against a dense scan of the iso-cost
curve, and the command."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from lenssim import DEFAULT_NUMERICS, Camera, Design, slope_departure_cost
from lenssim.design_opt import DifferentiableCriterion, optimise_on_iso_cost
from lenssim.io.prescription_file import read_lens, write_prescription_toml
from lenssim.design_opt import LensThirdOrderCriterion
from lenssim.model.lens_parameters import parse_parameter
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM
from lenssim_studies.tradeoff import iso_cost_curve

ANGLES = (0.0, 7.0, 14.0)
CAM3 = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=ANGLES), PAPER_SENSOR, PAPER_SPECTRUM)
NUM = DEFAULT_NUMERICS.replace(min_size=128, oversample=1)


def _singlet():
    return dataclasses.replace(read_lens("paper_singlet"), fields=ANGLES)


def _criterion(p=None, names=("E1.bending", "S2.conic"), **kw):
    p = _singlet() if p is None else p
    return LensThirdOrderCriterion(p, [parse_parameter(p, n) for n in names], 27.6, "mse_r", rho0=PAPER_RHO0,
                                   pitch_um=PAPER_SENSOR.pixel_pitch_um, angles_deg=ANGLES, scale=[0.025, 0.1],
                                   numerics=NUM, **kw)


def test_the_gradient_is_the_paper_models_autograd_gradient():
    """The paper's singlet as a prescription with (E1.bending, S2.conic) free: MSE_R and C_a and their gradients (the
    paraxial part by central differences, the FFTs by autograd) equal the paper model's, differentiated by autograd
    end to end in (s, Q_back) (lenssim.design_opt.DifferentiableCriterion, lenssim.slope_departure_cost)."""
    f, ref = _criterion(), DifferentiableCriterion(CAM3, 27.6, "mse_r", numerics=NUM, rho0=PAPER_RHO0)
    x = torch.tensor([-0.8, -2.3], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(f(x), x)
    (g0,) = torch.autograd.grad(ref(x), x)
    with torch.no_grad():
        assert float(f(x)) == pytest.approx(float(ref(x)), rel=1e-12)
    assert g.tolist() == pytest.approx(g0.tolist(), rel=1e-6)
    (gc,) = torch.autograd.grad(f.cost(x, NUM.cost_points), x)
    xs = x.detach().clone().requires_grad_(True)
    c0 = slope_departure_cost(PAPER_LENS, Design(s=xs[0], Q_back=xs[1]), NUM.cost_points)
    (gc0,) = torch.autograd.grad(c0, xs)
    assert float(f.cost(x.detach(), NUM.cost_points)) == pytest.approx(float(c0.detach()), rel=1e-12)
    assert gc.tolist() == pytest.approx(gc0.tolist(), rel=1e-6)


def test_the_iso_cost_optimum_beats_a_dense_scan_of_its_curve():
    """The paper's descent on the prescription's criterion finds, on C_a = 5.5e-4, a design no point of a dense scan of
    the iso-cost curve around it beats (the curve from lenssim_studies.tradeoff.iso_cost_curve, the paper model's
    closed-form cost), and the design lies on the level."""
    level = 5.5e-4
    f = _criterion()
    r = optimise_on_iso_cost(f, (-0.9, -2.0), level, steps=12, cost_points=NUM.cost_points)
    assert r.cost == pytest.approx(level, rel=1e-8) and r.stopped in ("gradient", "step")
    s = np.linspace(r.design["E1.bending"] - 0.05, r.design["E1.bending"] + 0.05, 11)
    cs, cq, cb = iso_cost_curve(CAM3.lens, level, s)
    with torch.no_grad():  # on the optimiser's own FFT sizes (fixed at its start): its values compare to 1e-12
        vals = [float(f(torch.tensor([a, b], dtype=torch.float64))) for a, b in zip(cs[cb == -1], cq[cb == -1])]
    assert len(vals) > 5 and r.value <= min(vals) + 1e-9


def test_a_parameter_that_moves_the_psf_scale_needs_the_focal_length_held():
    p = _singlet()
    f = LensThirdOrderCriterion(p, [parse_parameter(p, "S1.curvature")], 27.6, "mse_r", rho0=PAPER_RHO0,
                                pitch_um=1.5625, angles_deg=ANGLES, scale=[1e-3], numerics=NUM)
    with pytest.raises(ValueError, match="hold the focal length"):
        f(torch.tensor([0.012], dtype=torch.float64))
    held = LensThirdOrderCriterion(p, [parse_parameter(p, "S1.curvature")], 27.6, "mse_r", rho0=PAPER_RHO0,
                                   pitch_um=1.5625, angles_deg=ANGLES, scale=[1e-3], numerics=NUM, hold=("efl",))
    assert np.isfinite(float(held(torch.tensor([0.012], dtype=torch.float64))))


def test_the_command_writes_the_front_resumes_and_refuses_in_one_line(tmp_path, capsys):
    from lenssim_cli.main import main

    lens = tmp_path / "singlet.toml"
    write_prescription_toml(dataclasses.replace(read_lens("paper_singlet"), fields=(0.0, 14.0)), lens)
    out = tmp_path / "g"
    argv = ["tradeoff", "--lens", str(lens), "--vary", "E1.bending=-1:-0.6", "--vary", "S2.conic=-4:-1",
            "--wavefront", "third_order", "--optimise", "mse_r", "--snr", "27.6", "21.6", "--levels", "2",
            "--starts", "2", "--steps", "3", "--quiet", "--out", str(out)]
    assert main(argv) == 0
    res = json.loads((out / "tradeoff.json").read_text())
    assert {"gradient.nc", "tradeoff.json", "tradeoff.png", "tradeoff.svg", "index.html"} <= {f.name for f in
                                                                                              out.iterdir()}
    assert res["parameters"] == ["E1.bending", "S2.conic"] and len(res["levels"]) == 2
    assert res["levels"] == sorted(res["levels"]) and len(res["convergence"]) == 3 * 2
    # a level none of whose descents could reach within the bounds (held by a bound above it) has no optimum: None
    front = [o for o in res["optima"]["mse_r"] if o is not None]
    u = res["unconstrained"]["mse_r"]
    assert front and all(o is None or o["cost"] <= lv * (1 + 1e-9) for o, lv in zip(res["optima"]["mse_r"],
                                                                                   res["levels"]))
    assert [o["value"] for o in front] == sorted([o["value"] for o in front], reverse=True)  # cheaper: never better
    assert u["value"] <= min(o["value"] for o in front)
    for o, sc in zip(res["optima"]["mse_r"] + [u], res["scores"]):  # every criterion at each optimum
        assert (o is None) == (sc is None)
        assert o is None or sc["mse_r"][0] == o["value"] and len(sc["mse_s"]) == 2
        assert o is None or o["descent_value"] == pytest.approx(o["value"], rel=1e-4)  # the descent's FFT sizes
    q = read_lens(str(out / res["design_files"]["unconstrained"]))
    assert q.surfaces[1].conic == pytest.approx(u["design"]["S2.conic"], rel=1e-12)
    stamp = (out / "gradient.nc").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv) == 0  # a second run finds the finished result: nothing computed again
    assert (out / "gradient.nc").stat().st_mtime_ns == stamp
    capsys.readouterr()
    for extra, match in ((["--vary", "S2.conic=-4:-1", "--optimise", "rms_w"], "--optimise rms_w is not allowed"),
                         (["--vary", "S2.conic=-4:-1", "--optimise", "rms_w", "--wavefront", "third_order"],
                          "--optimise rms_w is not allowed"),
                         (["--vary", "S2.conic=-2:-2:1", "--optimise", "mse_r", "--wavefront", "third_order"],
                          "needs a range LO:HI"),
                         (["--vary", "S2.conic=-4:-1", "--optimise", "mse_r", "--wavefront", "third_order",
                           "--starts", "0"], "starts 0 is not allowed"),
                         (["--vary", "S2.conic=-4:-1", "--optimise", "mse_r", "--wavefront", "third_order",
                           "--image", "best"], "best focus is a search")):
        bad = tmp_path / "bad"
        assert main(["tradeoff", "--lens", str(lens), *extra, "--out", str(bad)]) == 2
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1 and not bad.exists()
