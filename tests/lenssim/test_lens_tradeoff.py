"""The trade-off of any lens (issue 30, item 4): a grid of a prescription's free parameters, each design scored as
``evaluate_sequential`` scores it alone, priced by its aspheres, the optima per cost level by brute force, invalid
designs kept with their reason, a killed sweep resumed to the same file, and the command's one-line refusals."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from lenssim.io.prescription_file import read_lens
from lenssim.model.numerics import Numerics
from lenssim.optics.lens_solves import solve_design
from lenssim.optics.sequential import SequentialLens
from lenssim.metrics import evaluate_sequential, evaluation_angles
from lenssim_cli.design import parse_vary
from lenssim_cli.main import main
from lenssim_studies.tradeoff import (LensTradeoffRun, front, run_lens_tradeoff, sequential_provider,
                                           tradeoff_json)

LENS_FILE = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")
SMALL = Numerics(min_size=64, oversample=1)
SNR = (21.6, 33.6)


def _run(vary, **kw):
    p = read_lens(LENS_FILE)
    return LensTradeoffRun(p, LENS_FILE, tuple(vary), SNR, 0.937, 5.0, "area", SMALL, image="paraxial", levels=4,
                           angles=2, **kw)


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    # S1.curvature 0.11 with a sphere makes the surfaces cross within their 8 mm semi-diameters: an invalid design
    run = _run((("S1.conic", (-1.0, -0.5, 0.0)), ("S1.curvature", (0.0387, 0.11))))
    ds = run_lens_tradeoff(run, tmp_path_factory.mktemp("t") / "t.nc", show_progress=False)
    return run, ds


@pytest.mark.parametrize("text, expect", [("S7.conic=-2:0:0.5", ("S7.conic", (-2.0, -1.5, -1.0, -0.5, 0.0))),
                                          ("E1.bending=1,2", ("E1.bending", (1.0, 2.0))),
                                          ("focus_um=-10:10", ("focus_um", tuple(np.linspace(-10, 10, 9))))])
def test_vary_ranges_are_inclusive(text, expect):
    name, values = parse_vary(text)
    assert name == expect[0] and np.allclose(values, expect[1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("text, match", [("S7.conic", "NAME=LO:HI"), ("S7.conic=0:1:0.3", "whole number of STEPs"),
                                         ("S7.conic=1:0:0.5", "LO <= HI"), ("S7.conic=a:b", "with numbers"),
                                         ("S7.conic=0,inf", "finite")])
def test_vary_refuses(text, match):
    with pytest.raises(ValueError, match=match):
        parse_vary(text)


def test_each_design_is_scored_as_it_would_be_alone(swept):
    run, ds = swept
    assert dict(ds.sizes) == {"S1.conic": 3, "S1.curvature": 2, "snr": 2}
    for i in range(run.size):
        d = run.design(i)
        idx = {"S1.conic": [-1.0, -0.5, 0.0].index(d["S1.conic"]),
               "S1.curvature": [0.0387, 0.11].index(d["S1.curvature"])}
        valid = bool(ds["valid"].isel(idx))
        c, k = d["S1.curvature"], d["S1.conic"]
        sag = c * 64 / (1 + math.sqrt(1 - (1 + k) * c * c * 64))  # at the 8 mm semi-diameter; the plate is 4 mm
        if sag >= 4.0:  # crossing surfaces: kept, marked, never scored
            assert not valid and "crosses" in str(ds["reason"].isel(idx).values)
            assert math.isnan(float(ds["mse_s"].isel(idx)[0]))
            continue
        assert valid
        q, shift = solve_design(run.prescription, {run.parameter(k): v for k, v in d.items()}, image="paraxial")
        psf = sequential_provider(q, SequentialLens(q, image_shift_mm=shift), pitch_um=5.0, sampling="area",
                                  max_field_deg=3.0, numerics=SMALL, coarse=True)
        r = evaluate_sequential(psf, SNR, rho0=0.937, numerics=SMALL, angles_deg=evaluation_angles(3.0, 2),
                                criteria=("mse_r", "rms_w", "cost"))
        assert np.allclose(ds["mse_r"].isel(idx).values, r["mse_r"].numpy(), rtol=1e-12, atol=0)
        assert float(ds["rms_w"].isel(idx)) == pytest.approx(float(r["rms_w"]), rel=1e-12)
        assert float(ds["cost"].isel(idx)) == pytest.approx(float(r["cost"]), rel=1e-12)
        assert (float(ds["cost"].isel(idx)) == 0) == (d["S1.conic"] == 0)  # a sphere costs nothing


def test_the_optima_per_cost_level_are_the_brute_force_ones(swept):
    run, ds = swept
    res = front(ds, 4)
    cost = ds["cost"].values.reshape(-1)
    valid = ds["valid"].values.reshape(-1)
    v = ds["mse_r"].values[..., 0].reshape(-1)
    assert res["levels"][0] == 0 and res["levels"][-1] == pytest.approx(cost[valid].max())
    for level, best in zip(res["levels"], res["optima"]["mse_r"]):
        ok = valid & (cost <= level * (1 + 1e-12) + 1e-15)
        assert best["value"] == pytest.approx(v[ok].min(), rel=0) and best["cost"] <= level * (1 + 1e-12) + 1e-15
    s = ds["strehl"].values.reshape(-1)
    assert res["unconstrained"]["strehl"]["value"] == pytest.approx(s[valid].max(), rel=0)  # higher is better
    assert "mse_r@33.6" in res["optima"] and "mse_r@21.6" not in res["optima"]  # the first SNR's is 'mse_r'
    out = tradeoff_json(ds, 4)
    assert out["invalid_designs"] == [{"design": {"S1.conic": 0.0, "S1.curvature": 0.11},
                                       "reason": out["invalid_designs"][0]["reason"]}]
    assert "crosses" in out["invalid_designs"][0]["reason"]
    json.dumps(out, allow_nan=False)  # no NaN anywhere


def test_a_killed_sweep_resumes_to_the_same_file(swept, tmp_path):
    run, ds = swept
    out = tmp_path / "t.nc"
    assert run_lens_tradeoff(run, out, show_progress=False, max_chunks=0) is None
    chunk = run_lens_tradeoff.__globals__["_compute_chunk"](run, 0, lambda k: None)
    run_lens_tradeoff.__globals__["_write_chunk"](tmp_path / "t.nc.partial" / "chunk_00000.npz", chunk, run, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = run_lens_tradeoff(run, out, show_progress=False)
    for k in ds.data_vars:
        a, b = again[k].values, ds[k].values
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), k


def test_the_command_writes_its_outputs_and_refuses_in_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=-1:0:1", "--image", "paraxial", "--pixel-pitch", "5",
            "--snr", "27.6", "--levels", "3", "--quiet", "--out", str(out)]
    assert main(argv) == 0
    assert {"tradeoff.nc", "tradeoff.json", "tradeoff.png", "tradeoff.svg", "index.html"} <= {f.name for f in
                                                                                           out.iterdir()}
    res = json.loads((out / "tradeoff.json").read_text())
    assert res["parameters"] == ["S1.conic"] and len(res["levels"]) == 3 and res["levels"] == sorted(res["levels"])
    for name in ("mse_r", "rms_w", "mse_s"):
        assert {"cost", "value", "design"} <= set(res["unconstrained"][name])
        assert all(o is None or math.isfinite(o["value"]) for o in res["optima"][name])
    f = out / res["design_files"]["mse_r"]  # each optimum as a lens file: --lens on every command
    q = read_lens(str(f))
    assert q.surfaces[0].conic == res["unconstrained"]["mse_r"]["design"]["S1.conic"]
    assert SequentialLens(q).paraxial().image_z_mm == pytest.approx(q.image_z_mm, abs=1e-9)  # --image paraxial
    assert main(["inspect", str(f), "--json"]) == 0
    capsys.readouterr()
    for extra, match in ((["--vary", "S9.conic=0:1"], "not a parameter of this lens"),
                         (["--vary", "S1.curvature=0.03:0.04", "--hold", "efl"], "surface 1 holds the focal length"),
                         (["--vary", "S1.conic=0:1", "--hold", "bfl"], "--hold 'bfl' is not allowed"),
                         (["--vary", "S1.A4=0:1e-5"], "surface 1 is not an even asphere"),
                         (["--vary", "S1.conic=0:1", "--levels", "1"], "--levels 1 is not allowed")):
        bad = tmp_path / "bad"
        assert main(["tradeoff", "--lens", LENS_FILE, *extra, "--out", str(bad)]) == 2
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1 and not bad.exists()
    assert torch.get_default_dtype() == torch.float32


def test_the_end_to_end_gain_is_brute_force():
    """end_to_end_gain on a random grid with invalid designs: the RMS_W optimum, the best mse_r at most its cost, the
    cheapest design restoring at least as well, each found again by a plain loop."""
    import numpy as np
    import xarray as xr

    from lenssim_studies.tradeoff import end_to_end_gain

    rng = np.random.default_rng(3)
    shape, snr = (6, 7), [21.6, 27.6]
    data = {k: (("a", "b"), rng.random(shape)) for k in ("rms_w", "strehl", "mtf50", "cost")}
    data |= {k: (("a", "b", "snr"), rng.random(shape + (2,))) for k in ("mse_s", "mse_r")}
    valid = rng.random(shape) > 0.2
    data["valid"] = (("a", "b"), valid)
    ds = xr.Dataset(data, coords={"a": np.arange(6.0), "b": np.arange(7.0) / 10, "snr": snr})
    got = end_to_end_gain(ds)
    assert set(got) == {"mse_r", "mse_r@27.6"}
    cells = [(i, j) for i in range(6) for j in range(7) if valid[i, j]]
    w = min(cells, key=lambda c: ds["rms_w"].values[c])
    for k, name in enumerate(("mse_r", "mse_r@27.6")):
        v = ds["mse_r"].values[..., k]
        c = ds["cost"].values
        e = min((x for x in cells if c[x] <= c[w]), key=lambda x: v[x])
        q = min((x for x in cells if v[x] <= v[w]), key=lambda x: c[x])
        g = got[name]
        assert g["rms_w_optimum"]["design"] == {"a": float(w[0]), "b": w[1] / 10}
        assert g["equal_cost"]["design"] == {"a": float(e[0]), "b": e[1] / 10} and g["mse_r_ratio"] == v[e] / v[w]
        assert g["equal_quality"]["design"] == {"a": float(q[0]), "b": q[1] / 10}
        assert g["cost_saving"] == pytest.approx(1 - c[q] / c[w], rel=1e-15)
        assert g["mse_r_ratio"] <= 1 and g["cost_saving"] >= 0  # the RMS_W optimum is a candidate of both
