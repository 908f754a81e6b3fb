"""`lenssim optimum` on a trade-off of any lens (issue 30): the best valid design per criterion and per cost limit equals
brute force over the dataset, invalid designs are never chosen, the design files are named when they hold the chosen
design, --write-lens writes it as a lens file that reads back with its solves, the run rebuilds from the file's config
to its digest, and every bad input is one line with status 2. The paper singlet's sweep still goes the old way."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from lenssim.io.prescription_file import read_lens
from lenssim.model.numerics import Numerics
from lenssim.optics.sequential import SequentialLens
from lenssim_cli.main import main
from lenssim_studies.chunks import stamp_result
from lenssim_studies.tradeoff import find_lens_optimum, rebuild_run, tradeoff_run_from_dict
from lenssim_studies.tradeoff import LensTradeoffRun, front, run_lens_tradeoff, tradeoff_json, write_design_files

LENS_FILE = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")
SMALL = Numerics(min_size=64, oversample=1)
SNR = (21.6, 33.6)
CONIC = (-1.0, -0.5, 0.0)
FOCUS = (0.0, 20.0)
SENSE = {"rms_w": "min", "mse_s": "min", "mse_r": "min", "strehl": "max", "mtf50": "max", "cost": "min"}


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A trade-off folder as `lenssim tradeoff` writes it (tradeoff.nc, designs/*.toml): 3 conics x 2 focus shifts
    of the test singlet, each at its paraxial focus plus the shift, scored on the axis (a few seconds)."""
    run = LensTradeoffRun(read_lens(LENS_FILE), LENS_FILE, (("S1.conic", CONIC), ("focus_um", FOCUS)), SNR, 0.937, 5.0,
                          "area", SMALL, image="paraxial", levels=4, angles=1)
    out = tmp_path_factory.mktemp("opt") / "run"
    ds = run_lens_tradeoff(run, out / "tradeoff.nc", show_progress=False)
    write_design_files(run, tradeoff_json(ds, run.levels), out / "designs")
    return run, out, xr.load_dataset(out / "tradeoff.nc", engine="scipy")


def _brute(ds, var, snr_index=None, *, max_cost=None):
    """(design, value) of the best valid design, by numpy alone: the first one in the grid's C order."""
    dims = ds["valid"].dims
    v = ds[var].transpose(*dims, ...).values
    v = (v[..., snr_index] if snr_index is not None else v).reshape(-1)
    cost = ds["cost"].transpose(*dims).values.reshape(-1)
    ok = ds["valid"].values.astype(bool).reshape(-1) & np.isfinite(v)
    if max_cost is not None:
        ok &= cost <= max_cost
    score = np.where(ok, v if SENSE[var] == "min" else -v, np.inf)
    i = int(np.argmin(score))
    assert ok[i]
    grids = np.meshgrid(*(ds[d].values for d in dims), indexing="ij")
    return {d: float(g.reshape(-1)[i]) for d, g in zip(dims, grids)}, float(v[i])


def _cases(ds):
    for var in SENSE:
        if "snr" in ds[var].dims:
            for j, s in enumerate(ds["snr"].values):
                yield var, j, float(s)
        else:
            yield var, None, None


def _scrambled(ds, seed):
    """A copy on a finer grid (4 focus shifts) with every criterion and cost drawn at random (invalid designs too) and
    some designs invalid."""
    rng = np.random.default_rng(seed)
    out = ds.reindex({"focus_um": [0.0, 5.0, 10.0, 20.0]}, method="nearest").copy(deep=True)
    for k in SENSE:
        out[k].values[...] = rng.uniform(0.1, 1.0, out[k].shape)
    valid = rng.uniform(size=out["valid"].shape) < 0.6
    valid.reshape(-1)[rng.integers(valid.size)] = True
    out["valid"].values[...] = valid
    return out


def test_the_optimum_is_the_brute_force_one(made):
    _, _, ds = made
    res = front(ds, 4)
    for var, j, s in _cases(ds):
        r = find_lens_optimum(ds, var, s)
        design, value = _brute(ds, var, j)
        assert r["design"] == design and r["value"] == value, var
        name = var if not j else f"{var}@{s:g}"
        assert r["name"] == name
        if name in res["unconstrained"]:  # the optimum tradeoff.json lists (and designs/NAME.toml holds)
            assert res["unconstrained"][name]["design"] == design
            for level, o in zip(res["levels"], res["optima"][name]):  # and its optima per cost level
                assert find_lens_optimum(ds, var, s, max_cost=level)["design"] == o["design"]
    assert find_lens_optimum(ds, "mse_r")["snr_db"] == SNR[0]  # the run's first SNR, not 27.6
    assert find_lens_optimum(ds, "mse_r@33.6")["design"] == find_lens_optimum(ds, "mse_r", 33.6)["design"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_landscapes_invalid_designs_and_cost_limits_match_brute_force(made, seed):
    _, _, ds = made
    ds = _scrambled(ds, seed)
    cost = np.sort(ds["cost"].values[ds["valid"].values.astype(bool)])
    limits = [cost[0], *(0.5 * (cost[:-1] + cost[1:])), cost[len(cost) // 2], 10.0]
    for var, j, s in _cases(ds):
        r = find_lens_optimum(ds, var, s)
        assert (r["design"], r["value"]) == _brute(ds, var, j), var
        assert find_lens_optimum(ds, var, s, max_cost=10.0)["design"] == r["design"]  # a large C: unconstrained
        for c in limits:
            rc = find_lens_optimum(ds, var, s, max_cost=float(c))
            assert (rc["design"], rc["value"]) == _brute(ds, var, j, max_cost=c), (var, c)
            assert rc["cost"] <= c
    with pytest.raises(ValueError, match=f"cheapest valid design costs {float(cost[0])!r}"):
        find_lens_optimum(ds, "mse_r", max_cost=float(cost[0]) * 0.5)


def test_an_invalid_design_is_never_chosen(made):
    _, _, ds = made
    for var, j, s in _cases(ds):
        best = find_lens_optimum(ds, var, s)["design"]
        copy = ds.copy(deep=True)
        copy["valid"].loc[best] = False  # its numbers stay finite: only 'valid' keeps it out
        r = find_lens_optimum(copy, var, s)
        assert r["design"] != best and (r["design"], r["value"]) == _brute(copy, var, j)
    none = ds.copy(deep=True)
    none["valid"].values[...] = False
    with pytest.raises(ValueError, match="no valid design"):
        find_lens_optimum(none, "rms_w")


def test_the_grid_boundary_is_flagged(made):
    _, _, ds = made
    r = find_lens_optimum(ds, "mse_r", SNR[1])
    idx = {d: list(ds[d].values).index(v) for d, v in r["design"].items()}
    edge = [d for d, i in idx.items() if i in (0, ds.sizes[d] - 1)]
    assert r["on_grid_boundary"] == bool(edge) and r["boundary_parameters"] == edge
    copy = _scrambled(ds, 3)
    copy["rms_w"].values[...] = 1.0
    copy["rms_w"].loc[{"S1.conic": -0.5, "focus_um": 10.0}] = 0.5
    copy["valid"].loc[{"S1.conic": -0.5, "focus_um": 10.0}] = True
    inner = find_lens_optimum(copy, "rms_w")
    assert inner["design"] == {"S1.conic": -0.5, "focus_um": 10.0} and not inner["on_grid_boundary"]
    copy["rms_w"].loc[{"S1.conic": -0.5, "focus_um": 20.0}] = 0.25
    copy["valid"].loc[{"S1.conic": -0.5, "focus_um": 20.0}] = True
    edge = find_lens_optimum(copy, "rms_w")
    assert edge["on_grid_boundary"] and edge["boundary_parameters"] == ["focus_um"]
    one = copy.isel({"focus_um": [2]})  # a parameter with one value is fixed: never on a boundary
    assert find_lens_optimum(one, "rms_w")["boundary_parameters"] == []


def test_the_run_rebuilds_from_its_config_to_its_digest(made):
    run, _, ds = made
    assert rebuild_run(ds).digest() == ds.attrs["config_digest"] == run.digest()
    for lens, vary, kw in (("cooke_triplet", (("S7.conic", (-1.0, 0.0)), ("S7.A4", (0.0, 1e-6))),
                            {"aspherize": (7,), "hold": ("efl",)}),
                           ("double_gauss", (("S1.conic", (-0.5, 0.0)),), {"image": "best", "coarse": False})):
        r = LensTradeoffRun(read_lens(lens), lens, vary, (27.6,), 0.937, 1.5, "point", Numerics(), levels=5, **kw)
        again = tradeoff_run_from_dict(json.loads(json.dumps(r.to_dict())))
        assert again.digest() == r.digest() and again.prescription == r.prescription
    # a curvature whose radius does not give it back (a solved one, from a design file): the config records the
    # radius alone, so one of the same radius (1 ulp away) comes back, with the same digest
    c = next(x for x in np.linspace(0.030, 0.031, 1001) if 1.0 / (1.0 / x) != x)
    p = read_lens(LENS_FILE)
    p = dataclasses.replace(p, surfaces=(dataclasses.replace(p.surfaces[0], curvature_per_mm=float(c)),
                                         *p.surfaces[1:]))
    r = LensTradeoffRun(p, LENS_FILE, (("S1.conic", (-1.0, 0.0)),), SNR, 0.937, 5.0, "area", SMALL)
    again = tradeoff_run_from_dict(json.loads(json.dumps(r.to_dict())))
    back = again.prescription.surfaces[0].curvature_per_mm
    assert 1.0 / back == 1.0 / c and abs(back - c) <= np.spacing(c) and again.digest() == r.digest()
    other = ds.copy()
    cfg = json.loads(ds.attrs["config"])
    other.attrs["config"] = json.dumps(cfg | {"rho0": 0.5})
    with pytest.raises(ValueError, match="different version or config"):
        rebuild_run(other)
    other.attrs["config"] = json.dumps(cfg | {"lenssim_version": "0.0.1"})
    with pytest.raises(ValueError, match="written by lenssim 0.0.1"):
        rebuild_run(other)


def test_the_command_reads_a_tradeoff_folder_or_file(made, capsys):
    _, out, ds = made
    assert main(["optimum", str(out), "--criterion", "mse_r", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    design, value = _brute(ds, "mse_r", 0)
    assert r["design"] == design and r["value"] == value and r["snr_db"] == SNR[0]
    assert r["lens_file"] == str(out / "designs" / "mse_r.toml")
    idx = {d: list(ds[d].values).index(v) for d, v in design.items()}
    assert r["on_grid_boundary"] == any(i in (0, ds.sizes[d] - 1) for d, i in idx.items())
    assert set(SENSE) <= set(r) and set(r["mse_s"]) == {"21.6", "33.6"}
    assert main(["optimum", str(out / "tradeoff.nc"), "--criterion", "mse_r", "--snr", "33.6", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["design"] == _brute(ds, "mse_r", 1)[0] and r["lens_file"] == str(out / "designs" / "mse_r_at_33.6.toml")
    assert main(["optimum", str(out), "--criterion", "cost", "--json"]) == 0  # no design file for the cost
    assert json.loads(capsys.readouterr().out)["lens_file"] is None
    # a cost limit below the unconstrained optimum's cost: another design, no design file
    best = find_lens_optimum(ds, "mse_r")
    limit = float(ds["cost"].values[ds["cost"].values < best["cost"]].max())
    assert main(["optimum", str(out), "--criterion", "mse_r", "--max-cost", repr(limit), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert (r["design"], r["value"]) == _brute(ds, "mse_r", 0, max_cost=limit) and r["cost"] <= limit
    assert r["lens_file"] is None and r["max_cost"] == limit
    assert main(["optimum", str(out), "--criterion", "mse_r", "--max-cost", "1"]) == 0  # C large: the optimum, its file
    text = capsys.readouterr().out
    where = ", ".join(f"{k} = {v:g}" for k, v in best["design"].items())
    assert text.startswith(f"best mse_r at 21.6 dB at cost <= 1: {where}  (value {best['value']:#.3g}, cost "
                           f"{best['cost']:#.3g})")
    assert ("[on the grid boundary]" in text) == best["on_grid_boundary"]
    assert "MSE_R:" in text and "@ 33.6 dB" in text and "C_a:" in text and "Strehl:" in text
    assert f"lens file {out / 'designs' / 'mse_r.toml'}" in text


def test_write_lens_writes_the_design_with_its_solves(made, tmp_path, capsys):
    run, out, ds = made
    f = tmp_path / "best.toml"
    assert main(["optimum", str(out), "--criterion", "mtf50", "--write-lens", str(f), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["lens_written"] == str(f)
    q = read_lens(str(f))
    assert q.surfaces[0].conic == r["design"]["S1.conic"]
    focus = SequentialLens(q).paraxial().image_z_mm  # --image paraxial, plus focus_um
    assert q.image_z_mm - focus == pytest.approx(r["design"]["focus_um"] * 1e-3, abs=1e-9)
    assert f.read_text() == (out / "designs" / "mtf50.toml").read_text()  # the unconstrained optimum's file
    before = f.read_text()
    assert main(["optimum", str(out), "--criterion", "rms_w", "--write-lens", str(f)]) == 2  # never overwritten
    err = capsys.readouterr().err
    assert "exists" in err and err.count("\n") == 1 and f.read_text() == before
    # a design under a cost limit, which no design file holds
    g = tmp_path / "cheap.toml"
    assert main(["optimum", str(out), "--criterion", "mse_r", "--max-cost", "0", "--write-lens", str(g), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["cost"] == 0 and read_lens(str(g)).surfaces[0].conic == r["design"]["S1.conic"] == 0


def _refused(argv, match, capsys):
    assert main(argv) == 2
    cap = capsys.readouterr()
    assert match in cap.err and cap.err.count("\n") == 1 and cap.err.startswith("lenssim optimum: error: "), cap.err
    assert "Traceback" not in cap.err and not cap.out


def test_bad_inputs_are_one_line(made, tmp_path, capsys):
    _, out, ds = made
    o = str(out)
    _refused(["optimum", o, "--criterion", "sharpness"], "criterion 'sharpness' is not in this trade-off", capsys)
    _refused(["optimum", o, "--criterion", "mse_r", "--snr", "27.6"], "SNR 27.6 dB is not in this trade-off; it holds "
             "21.6, 33.6 dB", capsys)
    _refused(["optimum", o, "--criterion", "mse_r@30"], "SNR 30 dB is not in this trade-off", capsys)
    cheapest = float(ds["cost"].values[ds["valid"].values].min())
    _refused(["optimum", o, "--criterion", "mse_r", "--max-cost", "-1"],
             f"below every valid design's cost: the cheapest valid design costs {cheapest!r}", capsys)
    _refused(["optimum", o, "--criterion", "mse_r", "--max-cost", "nan"], "a finite asphere cost", capsys)
    _refused(["optimum", o, "--criterion", "rms_w", "--snr", "21.6"], "rms_w does not depend on the SNR", capsys)
    _refused(["optimum", o, "--criterion", "mse_r", "--write-lens", str(tmp_path / "x.txt")], "*.toml", capsys)
    _refused(["optimum", str(tmp_path), "--criterion", "mse_r"], "holds no tradeoff.nc", capsys)
    (tmp_path / "afile.nc").write_text("not a NetCDF file\n")
    _refused(["optimum", str(tmp_path / "afile.nc"), "--criterion", "mse_r"], "is not a sweep file or a trade-off",
             capsys)
    foreign = ds.copy()
    foreign.attrs = {"title": "something else"}
    foreign.to_netcdf(tmp_path / "foreign.nc", engine="scipy")
    _refused(["optimum", str(tmp_path / "foreign.nc"), "--criterion", "mse_r"], "not a lenssim sweep", capsys)
    edited = ds.copy()
    edited.attrs = dict(ds.attrs, config=json.dumps(json.loads(ds.attrs["config"]) | {"rho0": 0.5}))
    edited.to_netcdf(tmp_path / "edited.nc", engine="scipy")
    _refused(["optimum", str(tmp_path / "edited.nc"), "--criterion", "mse_r", "--write-lens",
              str(tmp_path / "e.toml")], "its run record (config) was modified", capsys)
    assert not (tmp_path / "e.toml").exists()
    none = ds.copy(deep=True)  # a trade-off whose every design is invalid, as a run would write it
    none["valid"].values[...] = False
    none["reason"].values[...] = "the surfaces cross"
    none["reason"].encoding = {}  # the read file's string width does not hold the reason
    for k in ("rms_w", "mse_s", "mse_r", "strehl", "mtf50", "cost", "efl_mm"):
        none[k].values[...] = np.nan
    none["mtf50_capped"].values[...] = 0
    stamp_result(none).to_netcdf(tmp_path / "none.nc", engine="scipy")
    _refused(["optimum", str(tmp_path / "none.nc"), "--criterion", "mse_r"], "no valid design", capsys)


def test_a_sweep_file_still_goes_the_old_way_and_takes_a_cost_limit(tmp_path, capsys):
    from lenssim_studies.sweep import load_config, run_sweep
    from lenssim_studies.tradeoff import find_optimum

    p = tmp_path / "tiny.toml"
    p.write_text("[lens]\nfield_angles_deg = [0]\n[grid]\ns = [-1.0, -0.5, 0.25]\nQ = [-4.0, 0.0, 2.0]\n"
                 "snr_db = [21.6, 27.6]\n[numerics]\nmin_size = 64\n")
    path = tmp_path / "a.nc"
    ds = run_sweep(load_config(p), path, show_progress=False)
    assert main(["optimum", str(path), "--criterion", "mse_r", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    old = find_optimum(ds, "mse_r")
    assert r["design"] == old["design"] and r["value"] == old["value"] and r["snr_db"] == 27.6
    cost = ds["cost"].values
    limit = float(np.sort(np.unique(cost))[1])
    assert main(["optimum", str(path), "--criterion", "mse_r", "--max-cost", repr(limit), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    v = np.where(cost <= limit, ds["mse_r"].sel(snr=27.6).transpose("s", "Q_back").values, np.inf)
    i, k = np.unravel_index(int(np.argmin(v)), v.shape)
    assert r["design"] == {"s": float(ds["s"].values[i]), "Q_back": float(ds["Q_back"].values[k])}
    assert r["value"] == float(v[i, k]) and r["cost"] <= limit
    _refused(["optimum", str(path), "--criterion", "mse_r", "--max-cost", "-1"], "the cheapest design costs 0.0", capsys)
    _refused(["optimum", str(path), "--criterion", "mse_r", "--write-lens", str(tmp_path / "w.toml")],
             "--write-lens takes a trade-off of any lens", capsys)
