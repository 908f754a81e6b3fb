"""The paper's conclusion under each restoration (issue 45, item 4): lenssim_studies.restoration_ranking and
``lenssim rank-designs``."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from lenssim.model.design import Design
from lenssim.model.numerics import FAST_NUMERICS
from lenssim.metrics import evaluate
from lenssim.optics.cost import slope_departure_cost
from lenssim_cli.main import main
from lenssim_studies import restoration_ranking as rr
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_RHO0
from pipeline.restoration import parse_restoration


def test_the_iso_cost_optima_lie_on_their_level_and_beat_every_sample_of_it():
    """Each optimum costs its level (the cost model, recomputed here), and no design of a brute-force scan along the
    curve (independent: twice as fine in s) is better by its own criterion than the optimum by more than the parabola's
    interpolation error; the MSE_R optimum has the lower MSE_R and the RMS_W optimum the lower RMS_W."""
    from lenssim_studies.tradeoff import iso_cost_curve

    from lenssim.model.camera import Camera
    from lenssim.model.lens import Lens

    lens = Lens.from_dict({**PAPER_CAMERA.lens.to_dict(), "field_angles_deg": [0.0, 7.0, 14.0]})  # 3 angles: fast
    camera = Camera(lens, PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum)
    level, snr = 6e-4, 27.6
    found = rr.iso_cost_optima(camera, [level], ["mse_r", "rms_w"], snr, PAPER_RHO0, s_range=(-1.0, -0.3),
                               s_step=0.1, Q_range=(-10.0, 1.2), numerics=FAST_NUMERICS)
    assert set(found) == {"mse_r@0.0006", "rms_w@0.0006"}
    for d in found.values():
        assert float(slope_departure_cost(camera.lens, d)) == pytest.approx(level, rel=1e-9)
        assert float(d["Q_back"]) < 0
    both = {k: evaluate(camera, d, [snr], numerics=FAST_NUMERICS, rho0=PAPER_RHO0) for k, d in found.items()}
    cs, cq, cb = iso_cost_curve(camera.lens, level, np.arange(-1.0, -0.3 + 1e-9, 0.05))
    scan = evaluate(camera, Design(s=torch.from_numpy(cs[cb < 0]), Q_back=torch.from_numpy(cq[cb < 0])), [snr],
                    numerics=FAST_NUMERICS, rho0=PAPER_RHO0)
    for crit in ("mse_r", "rms_w"):
        best = float(both[f"{crit}@0.0006"][crit].reshape(-1)[0])
        assert best <= float(scan[crit].reshape(len(cs[cb < 0]), -1)[:, 0].min()) * (1 + 2e-3)
    assert float(both["mse_r@0.0006"]["mse_r"].reshape(-1)[0]) < float(both["rms_w@0.0006"]["mse_r"].reshape(-1)[0])
    assert float(both["rms_w@0.0006"]["rms_w"].reshape(-1)[0]) < float(both["mse_r@0.0006"]["rms_w"].reshape(-1)[0])
    with pytest.raises(ValueError, match="cost level 0.5"):  # beyond every design of the range
        rr.iso_cost_optima(camera, [0.5], ["mse_r"], snr, PAPER_RHO0, s_range=(-1.0, -0.3), s_step=0.05,
                           Q_range=(-10.0, 1.2), numerics=FAST_NUMERICS)


def test_kendall_tau_is_scipys_without_ties():
    from scipy.stats import kendalltau

    g = np.random.default_rng(4)
    for n in (2, 3, 7):
        a, b = g.permutation(n), g.permutation(n)
        names = [f"d{i}" for i in range(n)]
        got = rr._kendall_tau(dict(zip(names, a + 1)), dict(zip(names, b + 1)))
        assert got == pytest.approx(kendalltau(a, b).statistic, abs=1e-12)
    assert rr._ranks({"a": 3.0, "b": 1.0, "c": 2.0}, -1) == {"a": 1, "c": 2, "b": 3}


def _study(**kw):
    d = {"sharp": PAPER_DESIGNS["end_to_end_paper"], "other": PAPER_DESIGNS["rms_w_paper"]}
    base = dict(camera=PAPER_CAMERA, designs=d, methods=(parse_restoration("wiener"),), isos=(100,),
                full_wells=(3200.0,), snr_db=(27.6,), angles_deg=(0.0,), crop_px=32, seed=0, rho0=PAPER_RHO0,
                numerics=FAST_NUMERICS, pairs=(("p", "sharp", "other"),))
    return rr.RankingStudy(**{**base, **kw})


def test_a_stopped_ranking_resumes_its_finished_designs_and_refuses_another_runs_folder(tmp_path, monkeypatch):
    """Each design's crops land in OUT.partial/ as they finish; a rerun takes them from there (computing only the
    rest), writes the tables and removes the folder; a partial folder of other settings is refused."""
    photos = [("scene", torch.rand(1, 1, 64, 64))]
    calls = []

    def fake(study, name, photos_, angles, progress=None):  # synthetic scores: the first design better
        calls.append(name)
        if name == "other" and len(calls) == 2:
            raise KeyboardInterrupt
        v = 30.0 if name == "sharp" else 25.0
        return [{"design": name, "photo": "scene", "angle_deg": 0.0, "iso": 100, "method": m, "psnr_db": v,
                 "ssim": v / 40, "nmse": 10 ** (-v / 10)} for m in ("sensor", "wiener")]

    monkeypatch.setattr(rr, "_design_unit", fake)
    monkeypatch.setattr(rr, "closed_form", lambda camera, designs, snrs, rho0, numerics: {  # the same order
        k: {"cost": 1e-3, "rms_w": 1.0, "mse_r": {27.6: 0.04 * (1 + i)}, "mse_s": {27.6: 0.3 * (1 + i)},
            "alpha_deg": [0.0, 1.0], "mse_r_alpha": {27.6: [0.03 * (1 + i), 9.0]},
            "mse_s_alpha": {27.6: [0.2 * (1 + i), 9.0]}}
        for i, k in enumerate(designs)})
    out, log = tmp_path / "r", []
    with pytest.raises(KeyboardInterrupt):
        rr.rank_designs(_study(), photos, out, log=log.append)
    assert (tmp_path / "r.partial" / "design_000.chunk").exists() and not out.exists()
    with pytest.raises(FileExistsError, match="another ranking"):
        rr.rank_designs(_study(seed=1), photos, out, log=log.append)
    tables = rr.rank_designs(_study(), photos, out, log=log.append)
    assert calls == ["sharp", "other", "other"] and any("resumed from design_000.chunk" in m for m in log)
    assert not (tmp_path / "r.partial").exists()
    (p,) = [p for p in tables["pairs"] if p["method"] == "wiener"]
    assert p["psnr_a_minus_b_db"] == pytest.approx(5.0) and p["nmse_a_over_b"] == pytest.approx(10 ** -0.5)
    rows = list(csv.DictReader((out / "ranking.csv").read_text().splitlines()))
    assert {(r["design"], r["method"], r["rank_psnr"]) for r in rows} >= {("sharp", "wiener", "1"), ("other", "wiener", "2")}
    assert "| sharp |" in (out / "ranking.md").read_text()
    assert all(a["tau_psnr"] == 1.0 == a["tau_psnr_at_crops"] for a in tables["agreement"])
    (sharp,) = [r for r in tables["means"] if r["design"] == "sharp" and r["method"] == "wiener"]
    assert sharp["closed_form_at_crops"] == pytest.approx(0.03)  # the crop at 0 deg: the first field angle's


def test_a_defocused_design_ranks_below_the_sharp_one_under_every_restoration_and_the_closed_form(tmp_path, capsys):
    """A constructed case whose ranking is known: the paper's end-to-end design and the same lens 150 um out of focus
    (a blur far wider than the sharp design's), on a generated scene; every method, the sensor image and the closed
    form put the sharp design first (Kendall's tau 1), and the outputs say so."""
    designs = tmp_path / "d.toml"
    designs.write_text("[defocused]\ns = -0.775\nQ_back = -2.4\nfocus_shift_um = 150.0\n")
    out = tmp_path / "rank"
    assert main(["rank-designs", "skimage:camera", "--designs", "end_to_end_paper", "defocused", "--designs-file",
                 str(designs), "--restore", "wiener", "richardson_lucy:iterations=4", "--isos", "100", "--angles", "0",
                 "--crop", "32", "--out", str(out)]) == 0
    agree = list(csv.DictReader((out / "agreement.csv").read_text().splitlines()))
    assert {a["method"] for a in agree} == {"sensor", "wiener", "richardson_lucy"}
    for a in agree:
        assert float(a["tau_psnr"]) == 1.0 and float(a["tau_nmse"]) == 1.0
        assert a["best_psnr"] == a["best_closed_form"] == a["best_closed_form_at_crops"] == "end_to_end_paper"
        assert float(a["tau_psnr_at_crops"]) == 1.0
    rows = list(csv.DictReader((out / "ranking.csv").read_text().splitlines()))
    by = {(r["design"], r["method"]): r for r in rows}
    assert float(by[("end_to_end_paper", "wiener")]["psnr_db"]) > float(by[("defocused", "wiener")]["psnr_db"]) + 1
    crops = list(csv.DictReader((out / "ranking_crops.csv").read_text().splitlines()))
    assert len(crops) == 2 * 3  # designs x (sensor + 2 methods) x 1 crop x 1 ISO
    md = (out / "ranking.md").read_text()
    assert "### ISO 100 (closed form at 27.6 dB)" in md and "Richardson-Lucy (iterations=4)" in md
    assert not (tmp_path / "rank.partial").exists()


@pytest.mark.parametrize("argv, words", [
    (["--designs", "nope"], "design 'nope' is not known"),
    (["--designs", "rms_w_paper"], "give 2 to"),
    (["--cost-levels", "-1e-4"], "--cost-levels -0.0001 is not allowed"),
    (["--optimise", "cost"], "--optimise 'cost' is not allowed"),
    (["--isos", "800"], "ISO 800 is not allowed"),
    (["--restore", "nope"], "nope"),
    (["--angles", "0", "0"], "--angles holds 0 more than once"),
])
def test_rank_designs_refuses_bad_input_in_one_line_before_any_work(tmp_path, capsys, argv, words):
    out = tmp_path / "o"
    assert main(["rank-designs", "skimage:camera", "--crop", "32", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lenssim rank-designs: error:") and words in err and err.count("\n") == 1
    assert not out.exists() and not (tmp_path / "o.partial").exists()


def test_parabola_minimum_finds_a_parabolas_vertex_and_keeps_an_end_sample():
    from lenssim_studies.study import parabola_minimum

    x = np.arange(0.0, 1.0001, 0.25)
    xv, yv = parabola_minimum(x, 3.0 * (x - 0.33) ** 2 + 1.0)  # exact for a parabola, off the samples
    assert xv == pytest.approx(0.33, abs=1e-12) and yv == pytest.approx(1.0, abs=1e-12)
    assert parabola_minimum(x, -x) == (1.0, -1.0)  # the least sample at an end: itself


def test_ranking_angles_keep_the_asked_angles_that_fit_and_bound_the_crops():
    """Only asked angles, never the evenly spaced fallback of fitting_angles: a photo that reaches fewer than two of
    them is cropped where it reaches (here: on the axis); more crops than MAX_RANKING_CROPS are refused."""
    g = PAPER_CAMERA.geometry
    big, small = (1, 3, 4000, 6000), (1, 3, 1000, 1000)
    got = rr.ranking_angles([("big", big), ("small", small)], 128, g, (0.0, 5.0, 10.0))
    assert got == {"big": (0.0, 5.0, 10.0), "small": (0.0,)}
    with pytest.raises(ValueError, match="72 crops per design"):
        rr.ranking_angles([(f"p{i}", big) for i in range(8)], 128, g, tuple(float(a) for a in range(9)))
