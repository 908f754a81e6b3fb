"""Robustness on the trade-off front of any lens (issue 30, item 5): the as-built Monte Carlo at each distinct optimum,
each design's summary against a direct in-memory Monte Carlo of its lens, the robust optimum per cost level against
brute force, a design repeated across levels computed once, a second call resumed without computing, the nominal
lens given back by a Monte Carlo without errors, and one-line refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from lenssim.io.prescription_file import read_lens
from lenssim.model.numerics import Numerics
from lenssim.model.tolerances import SurfaceTolerances
from lenssim.optics.sequential import SequentialLens
from lenssim.metrics import evaluation_angles
from lenssim.tolerancing import run_lens_tolerance
from lenssim_studies.lens_robustness import robust_front, robustness_figure
from lenssim_studies.tradeoff import (LensTradeoffRun, design_prescription, run_lens_tradeoff,
                                           sequential_provider, tradeoff_json)

LENS_FILE = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")
SMALL = Numerics(min_size=64, oversample=1)
SNR = (21.6, 33.6)
CONICS = (-1.0, -0.5)
"""Two aspheric designs (the same error terms drawn: common random numbers); with 6 cost levels the cheaper is the
optimum at two of them and the first three levels reach no design."""
TOL = SurfaceTolerances(radius_pct=1.0, thickness_um=25.0, conic_pct=2.0, index=1e-3, despace_um=10.0)
"""The commercial grade's centred terms (a centred copy is scored at one azimuth: a quick test)."""
COPIES, SEED = 3, 1


@pytest.fixture(scope="module")
def traded(tmp_path_factory):
    p = read_lens(LENS_FILE)
    run = LensTradeoffRun(p, LENS_FILE, (("S1.conic", CONICS),), SNR, 0.937, 5.0, "area", SMALL, image="paraxial",
                          levels=6, angles=2)
    ds = run_lens_tradeoff(run, tmp_path_factory.mktemp("t") / "t.nc", show_progress=False)
    return run, ds, tradeoff_json(ds, run.levels)


@pytest.fixture(scope="module")
def robust(traded, tmp_path_factory):
    run, _, res = traded
    out = tmp_path_factory.mktemp("r")
    return out, robust_front(run, res, TOL, copies=COPIES, seed=SEED, out_dir=out, show_progress=False)


@pytest.fixture(scope="module")
def direct(traded):
    """Each grid design's Monte Carlo in memory (lenssim.tolerancing), on its design_prescription lens."""
    run, _, _ = traded
    out = {}
    for k in CONICS:
        q = design_prescription(run, {"S1.conic": k})
        psf = sequential_provider(q, SequentialLens(q), pitch_um=5.0, sampling="area", max_field_deg=3.0,
                                  numerics=SMALL, coarse=True)
        out[k] = run_lens_tolerance(psf, TOL, COPIES, seed=SEED, snr_db=SNR, rho0=0.937,
                                    angles_deg=evaluation_angles(3.0, 2), numerics=SMALL, compare_default=False)
    return out


def test_each_design_equals_its_own_monte_carlo(traded, robust, direct):
    run, ds, res = traded
    out, r = robust
    distinct = {o["design"]["S1.conic"] for o in res["optima"]["mse_r"] if o is not None}
    assert [d["design"]["S1.conic"] for d in r["designs"]] == sorted(distinct, key=lambda k: abs(k))  # ascending cost
    assert [d["cost"] for d in r["designs"]] == sorted(d["cost"] for d in r["designs"])
    assert r["snr_db"] == SNR[0] and r["seed"] == SEED and r["copies"] == COPIES
    for d in r["designs"]:
        k = d["design"]["S1.conic"]
        mc = direct[k]
        v = mc["mse_r"].values[:, 0]
        vn = mc["mse_r_nominal"].values[:, 0]
        expect = {"nominal": float(mc["nominal_mse_r"].values[0]), "mean": v.mean(), "p90": np.quantile(v, 0.9),
                  "max": v.max(), "nominal_restoration_mean": vn.mean(), "nominal_restoration_p90": np.quantile(vn, 0.9)}
        for key, e in expect.items():
            assert d[key] == pytest.approx(float(e), rel=1e-12, abs=0), (k, key)
        # the design as the trade-off scored it (its image shift folded into the last thickness)
        front_value = float(ds["mse_r"].sel({"S1.conic": k}).values[0])
        assert d["nominal"] == pytest.approx(front_value, rel=1e-12)
        assert d["cost"] == pytest.approx(float(ds["cost"].sel({"S1.conic": k})), rel=1e-12)
        assert d["nominal_restoration_mean"] >= d["mean"] * (1 - 1e-12)  # the matched filter is the least MSE
    json.dumps(r, allow_nan=False)


def test_a_design_repeated_across_levels_is_computed_once(traded, robust):
    _, _, res = traded
    out, r = robust
    keys = [o["design"]["S1.conic"] for o in res["optima"]["mse_r"] if o is not None]
    assert len(keys) > len(set(keys))  # the fixture's front does repeat a design
    assert sorted(f.name for f in out.glob("*.nc")) == [f"design_{k:02d}.nc" for k in range(len(set(keys)))]
    assert [d["file"] for d in r["designs"]] == [f"design_{k:02d}.nc" for k in range(len(set(keys)))]
    for lv, o in zip(r["levels"], res["optima"]["mse_r"]):
        if o is None:  # no design costs this little
            assert lv["nominal_optimum"] is None and lv["robust_optimum"] is None
        else:
            assert r["designs"][lv["nominal_optimum"]]["design"] == o["design"]
    assert sum(lv["nominal_optimum"] is None for lv in r["levels"]) == 3


def test_common_random_numbers_across_designs(robust):
    out, r = robust
    a, b = (xr.load_dataset(out / d["file"], engine="scipy") for d in r["designs"])
    errs = [v for v in a.data_vars if v.startswith("error_")]
    assert "error_conic_s1_pct" in errs and all(np.array_equal(a[v].values, b[v].values) for v in errs)


def test_the_robust_optimum_per_level_is_the_brute_force_one(traded, robust, direct):
    _, ds, res = traded
    _, r = robust
    conics = [d["design"]["S1.conic"] for d in r["designs"]]
    cost = {k: float(ds["cost"].sel({"S1.conic": k})) for k in conics}
    p90 = {k: np.quantile(direct[k]["mse_r"].values[:, 0], 0.9) for k in conics}
    for level, lv in zip(res["levels"], r["levels"]):
        within = [k for k in conics if cost[k] <= level * (1 + 1e-9) + 1e-15]
        assert lv["cost"] == level
        if not within:
            assert lv["robust_optimum"] is None
            continue
        assert conics[lv["robust_optimum"]] == min(within, key=lambda k: p90[k])
    assert conics[r["robust_optimum"]] == min(conics, key=lambda k: p90[k])
    assert r["nominal_optimum"] == r["levels"][-1]["nominal_optimum"]


def test_a_second_call_resumes_and_computes_nothing(traded, robust, monkeypatch):
    import lenssim.tolerancing as lt

    run, _, res = traded
    out, r = robust

    def refuse(*a, **k):
        raise AssertionError("recomputed")

    monkeypatch.setattr(lt, "copy_criteria", refuse)
    monkeypatch.setattr(lt, "nominal_criteria", refuse)
    assert robust_front(run, res, TOL, copies=COPIES, seed=SEED, out_dir=out, show_progress=False) == r
    with pytest.raises(FileExistsError, match="design_00.nc"):  # another run's files: refused before any work
        robust_front(run, res, TOL, copies=COPIES, seed=SEED + 1, out_dir=out, show_progress=False)
    png = robustness_figure(r, out, "test singlet")
    assert png.exists() and png.with_suffix(".svg").exists()


def test_without_errors_as_built_is_the_design(traded, tmp_path):
    run, _, res = traded
    first = {"levels": res["levels"][:5], "optima": {"mse_r": res["optima"]["mse_r"][:5]}}  # the cheaper design
    r = robust_front(run, first, SurfaceTolerances(), copies=1, seed=SEED, out_dir=tmp_path, show_progress=False)
    (d,) = r["designs"]
    for key in ("mean", "p90", "max"):  # the same lens, the same table, the same numbers
        assert d[key] == d["nominal"], key
    for key in ("nominal_restoration_mean", "nominal_restoration_p90"):  # its own filter by another path: rounding
        assert d[key] == pytest.approx(d["nominal"], rel=1e-14, abs=0), key


def test_bad_arguments_are_refused_in_one_line(traded, tmp_path):
    run, _, res = traded
    none = {"levels": res["levels"], "optima": {"mse_r": [None] * len(res["levels"])}}
    other = {"levels": res["levels"][:1], "optima": {"mse_r": [{"cost": 0.0, "value": 1.0, "design": {"S1.A4": 0.0}}]}}
    for kw, match in ((dict(copies=0), "copies=0 is not allowed"), (dict(copies=10_001), "copies=10001"),
                      (dict(copies=True), "copies=True"), (dict(copies=2.0), "copies=2.0"),
                      (dict(criterion="psnr"), "criterion 'psnr' is not allowed"),
                      (dict(res=none), "no optimum of 'mse_r'"), (dict(res=other), "res must be tradeoff_json()"),
                      (dict(tolerances="commercial"), "a SurfaceTolerances"), (dict(seed=1.5), "seed=1.5")):
        args = dict(res=res, tolerances=TOL, copies=2, seed=0, criterion="mse_r") | kw
        with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)")) as exc:
            robust_front(run, args.pop("res"), args.pop("tolerances"), out_dir=tmp_path / "x", show_progress=False,
                         **args)
        assert "\n" not in str(exc.value)
    assert not (tmp_path / "x").exists()


def test_the_command_runs_the_monte_carlo_along_the_front(tmp_path, capsys):
    """``tradeoff --robust COPIES``: tradeoff.json's ``robustness`` holds each optimum's Monte Carlo, whose nominal
    mse_r is the trade-off's own value of that design (the same real-ray criteria on the design's lens file), the figure
    and the page are written; --grade without --robust, --robust 0 and --robust with --optimise are refused in one
    line before any work."""
    import json

    from lenssim_cli.main import main

    out = tmp_path / "t"
    argv = ["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=-1,-0.5", "--image", "paraxial", "--pixel-pitch",
            "5", "--snr", "21.6", "--levels", "3", "--robust", "1", "--grade", "commercial", "--quiet",
            "--out", str(out)]
    assert main(argv) == 0
    res = json.loads((out / "tradeoff.json").read_text())
    rob = res["robustness"]
    assert rob["copies"] == 1 and rob["designs"] and (out / "robustness.png").exists()
    assert "As built" in (out / "index.html").read_text()
    for d in rob["designs"]:
        o = next(o for o in res["optima"]["mse_r"] if o is not None and o["design"] == d["design"])
        assert d["nominal"] == pytest.approx(o["value"], rel=1e-6)
        assert (out / "robust" / d["file"]).exists()
    capsys.readouterr()
    for extra, match in ((["--grade", "precision"], "give --robust too"), (["--robust", "0"], "--robust 0 is not"),
                         (["--robust", "2", "--optimise", "mse_r", "--wavefront", "third_order"],
                          "--robust takes a grid trade-off")):
        bad = tmp_path / "bad"
        assert main(["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=-1:-0.5", *extra, "--out", str(bad)]) == 2
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1 and not bad.exists()
