import json

import numpy as np
import pytest
import torch
import xarray as xr

from lenssim import Camera, Design, Numerics

from lenssim_studies.paper import PAPER_LENS
from lenssim import slope_departure_cost as _cost
from lenssim_studies.figures import all_figures, table1
from lenssim_studies.report import reproduce
from lenssim_studies.sweep import SweepConfig
from lenssim_studies.tradeoff import iso_cost_curve, min_cost_for_quality, tradeoff
import dataclasses
from lenssim_studies.paper import PAPER_SENSOR, PAPER_SPECTRUM


def slope_departure_cost(lens, s, Q):
    return _cost(lens, Design(s=s, Q_back=Q))


def synthetic_sweep(metric):
    """A sweep-shaped dataset whose criteria are a known function of (s, Q); cost from the real model."""
    s = np.round(np.arange(-1.0, 1.0 + 1e-9, 0.05), 6)
    Q = np.round(np.arange(-10.0, 1.2 + 1e-9, 0.2), 6)
    S, QQ = np.meshgrid(s, Q, indexing="ij")
    m = metric(S, QQ)
    snr = np.array([21.6, 27.6, 33.6])
    cost = slope_departure_cost(PAPER_LENS, torch.from_numpy(S), torch.from_numpy(QQ)).numpy()
    three = np.repeat(m[..., None], 3, axis=-1)
    dims = ("s", "Q_back")
    ds = xr.Dataset({"rms_w": (dims, m), "mse_s": (dims + ("snr",), three), "mse_r": (dims + ("snr",), three),
                     "cost": (dims, cost)}, coords={"s": s, "Q_back": Q, "snr": snr, "alpha": np.arange(15.0)})
    ds.attrs["config"] = json.dumps(SweepConfig().to_dict())
    ds.attrs["design_parameters"] = "s Q_back"
    return ds


def test_iso_cost_curves_are_located_exactly():
    s = np.linspace(-2, 0.9, 40)
    for level in (1e-4, 7e-4, 2e-3):
        cs, cq, cb = iso_cost_curve(PAPER_LENS, level, s)
        assert len(cs) > 0 and set(np.unique(cb)) <= {-1, 1}
        c = slope_departure_cost(PAPER_LENS, torch.from_numpy(cs), torch.from_numpy(cq)).numpy()
        np.testing.assert_allclose(c, level, rtol=1e-9)
        assert np.all((cq >= -10) & (cq <= 1.2))
    cs, cq, _ = iso_cost_curve(PAPER_LENS, 0.0, s)
    assert np.all(cq == 0)


def test_tradeoff_finds_a_known_optimum_to_sub_grid_precision():
    s0 = 0.3137  # between grid points (step 0.05)
    ds = synthetic_sweep(lambda S, Q: (S - s0) ** 2 + 1.0)
    levels = np.array([0.0, 5e-5, 1e-4])
    t = tradeoff(ds, levels=levels)
    for lvl in levels[1:]:
        row = t.sel(criterion="mse_r@27.6", level=lvl)
        assert float(row["s"]) == pytest.approx(s0, abs=1e-4)
        assert float(row["value"]) == pytest.approx(1.0, abs=1e-7)
        assert float(row["cost"]) == pytest.approx(lvl, rel=1e-6)
    # the "minimal cost for a given quality" view reads the same curves
    assert min_cost_for_quality(t, "rms_w", 1.0 + 1e-6) == 0.0 or min_cost_for_quality(t, "rms_w", 1.0 + 1e-6) == 5e-5


def test_tradeoff_prefers_lower_quality_values_along_the_curve():
    # quality improves towards large |Q|: on each level the optimum sits at the most negative Q reachable
    ds = synthetic_sweep(lambda S, Q: 1.0 + 0.01 * Q)
    t = tradeoff(ds, levels=np.array([2e-4, 1e-3]))
    for lvl in (2e-4, 1e-3):
        cs, cq, _ = iso_cost_curve(PAPER_LENS, lvl, np.arange(-1.0, 1.0 + 1e-9, 0.002))
        assert float(t.sel(criterion="rms_w", level=lvl)["Q_back"]) == pytest.approx(cq.min(), abs=1e-6)


def test_figures_and_table_render_headless(tmp_path):
    ds = synthetic_sweep(lambda S, Q: (S + 0.5) ** 2 + 0.01 * (Q + 3) ** 2 + 0.1)
    ds["mse_s"] = ds["mse_s"] * 1.5
    t = tradeoff(ds, levels=np.linspace(0, 1e-3, 6))
    paths = all_figures(ds, t, tmp_path)
    for p in paths:
        assert p.exists() and p.stat().st_size > 10_000
        assert p.with_suffix(".svg").exists()
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    csv, md, rows = table1(ds, tmp_path)
    assert [r["design"] for r in rows] == ["RMS_W", "MSE_S", "MSE_R"]
    assert rows[2]["mse_r_relative"] == 1.0
    assert "relative to best" in md.read_text() and csv.read_text().count("\n") == 4


def test_reproduce_reuses_its_outputs(tmp_path):
    cfg = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 7.0, 14.0)), PAPER_SENSOR, PAPER_SPECTRUM),
                      grid={"s": (-1.0, -0.5, 0.25), "Q": (-4.0, 0.0, 1.0)}, numerics=Numerics(min_size=128, oversample=1))
    report = reproduce(tmp_path, cfg, show_progress=False)
    text = report.read_text()
    assert "| RMS_W optimum | s = -0.725, Q_back = -10 |" in text and "NOT the paper grid" in text
    stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "sweep.nc", tmp_path / "tradeoff.nc")}
    reproduce(tmp_path, cfg, show_progress=False)
    assert stamps == {p.name: p.stat().st_mtime_ns for p in (tmp_path / "sweep.nc", tmp_path / "tradeoff.nc")}


def test_a_criterion_to_maximise_is_maximised_along_the_curves_and_in_the_grid():
    """The trade-off, the grid optimum and the minimal-cost view read a criterion's sense: a Strehl-like
    landscape (maximised) peaks where its mirror image (minimised) bottoms out."""
    s0 = 0.3137
    ds = synthetic_sweep(lambda S, Q: (S - s0) ** 2 + 1.0)
    ds["strehl"] = 2.0 - ds["rms_w"]  # best where rms_w is best
    levels = np.array([5e-5, 1e-4])
    t = tradeoff(ds, levels=levels, criteria=("rms_w", "strehl"))
    for lvl in levels:
        best, mirror = t.sel(criterion="strehl", level=lvl), t.sel(criterion="rms_w", level=lvl)
        assert float(best["s"]) == pytest.approx(float(mirror["s"]), abs=1e-9)
        assert float(best["value"]) == pytest.approx(2.0 - float(mirror["value"]), abs=1e-9)
    assert min_cost_for_quality(t, "strehl", 1.0 - 1e-6) == 5e-5  # "at least" for a criterion to maximise
    from lenssim_studies.tradeoff import find_optimum

    assert find_optimum(ds, "strehl")["value"] == pytest.approx(float(ds["strehl"].max()))
    assert find_optimum(ds, "strehl")["design"] == find_optimum(ds, "rms_w")["design"]
    with pytest.raises(ValueError, match="is a cost"):
        tradeoff(ds, levels=levels, criteria=("cost",))
