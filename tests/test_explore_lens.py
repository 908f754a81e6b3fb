"""The explorer on any lens (issue 32: ``lenssim explore --lens LENS --vary ...``): its numbers are the command line's
for the same design (criteria as ``tradeoff --lens`` computes them, the photo as ``simulate --lens`` does)."""

import json
import math
import shlex

import pytest
import torch

from lenssim.io.prescription_file import read_lens
from lenssim_studies.explore import LENS_EXPORT_FILE, Explorer, FreeParameter, PhotoControls, command_line

FREE = (FreeParameter("E1.bending", -1.0, 0.0, 0.025), FreeParameter("s2.conic", -10.0, 0.0, 0.1))


@pytest.fixture(scope="module")
def explorer():
    from lenssim_studies.paper import PAPER_CAMERA
    from pipeline.photo import open_photo

    return Explorer(photo=open_photo("skimage:astronaut", PAPER_CAMERA).load(), photo_source="astronaut",
                    prescription=read_lens("paper_singlet"), lens="paper_singlet", free=FREE, map_values=3)


def test_sliders_start_at_the_file_s_design(explorer):
    sl = explorer.sliders()
    assert [s.key for s in sl] == ["E1.bending", "S2.conic"]  # canonical names
    assert sl[1].label == "S2.conic"
    v = explorer.start.as_dict()
    p = read_lens("paper_singlet")
    c1, c2 = p.surfaces[0].curvature_per_mm, p.surfaces[1].curvature_per_mm
    assert v["E1.bending"] == pytest.approx((c1 + c2) / (c1 - c2), abs=1e-12)
    assert v["S2.conic"] == p.surfaces[1].conic
    assert explorer.is_file_design(explorer.start)


def test_criteria_are_the_real_ray_evaluation_at_the_tradeoff_s_sensor(explorer):
    """Built here by hand: the lens at the Nyquist pitch (point samples), fast numerics, the coarse table, five field
    angles from the axis to the largest."""
    from dataclasses import replace

    from lenssim.model.numerics import FAST_NUMERICS
    from lenssim.model.spectrum import Spectrum
    from lenssim.optics.sequential import SequentialLens
    from lenssim.optics.psf_bank import TABLE_INITIAL_NODES
    from lenssim.optics.psf_provider import SequentialPSF
    from lenssim.metrics import evaluate_sequential, evaluation_angles
    from lenssim_studies.paper import PAPER_CAMERA

    p = read_lens("paper_singlet")
    seq = SequentialLens(p)
    pitch = p.primary_wavelength_um * seq.paraxial().working_f_number / 2
    sensor = replace(PAPER_CAMERA.sensor, pixel_pitch_um=pitch, width_px=1, height_px=1)
    psf = SequentialPSF(seq, sensor, Spectrum(p.wavelengths_um, (1.0,) * len(p.wavelengths_um)), (),
                        max_field_deg=max(p.fields), sampling="point", numerics=FAST_NUMERICS,
                        table_max_nodes=TABLE_INITIAL_NODES)
    r = evaluate_sequential(psf, explorer.snr_db, rho0=explorer.rho0, numerics=FAST_NUMERICS,
                            angles_deg=evaluation_angles(max(p.fields), 5),
                            criteria=("rms_w", "mse_s", "mse_r", "strehl", "mtf50", "cost"))
    c = explorer.criteria(explorer.start)
    assert c["MSE_R at 27.6 dB"] == pytest.approx(float(r["mse_r"][1]), rel=1e-9)
    assert c["RMS_W [waves]"] == pytest.approx(float(r["rms_w"]), rel=1e-9)
    assert c["MTF50 [cycles/mm]"] == pytest.approx(float(r["mtf50"]), rel=1e-9)
    assert c["cost C_a"] == pytest.approx(float(r["cost"]), rel=1e-9) and c["cost C_a"] > 0
    assert c["EFL [mm]"] == pytest.approx(seq.paraxial().efl_mm, rel=1e-12)
    other = explorer.criteria(explorer.controls_from({"E1.bending": -0.5, "S2.conic": -5.0}))
    assert other["MSE_R at 27.6 dB"] != c["MSE_R at 27.6 dB"]


def test_a_design_that_cannot_be_made_is_a_one_line_error(explorer):
    with pytest.raises(ValueError, match="surface 1: the conic surface .* is not defined out to its semi-diameter") as e:
        explorer.criteria(explorer.controls_from({"E1.bending": -50.0, "S2.conic": -2.0}))  # a 0.5 mm front radius
    assert "\n" not in str(e.value)


def test_optics_figure_and_map(explorer):
    png = explorer.optics_figure(explorer.start)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    m = explorer.compute_map()
    assert m["mse_r"].shape == (3, 3, 3) and m["E1.bending"].tolist() == [-1.0, -0.5, 0.0]
    # each cell is the criteria of its design (a cell checked against the selected-design route)
    c = explorer.criteria(explorer.controls_from({"E1.bending": -0.5, "S2.conic": -5.0}))
    assert m["mse_r"][1, 1, 1] == pytest.approx(c["MSE_R at 27.6 dB"], rel=1e-9)
    layer = explorer.map_layer("cost", 0)
    assert (layer["x_name"], layer["y_name"]) == ("E1.bending", "S2.conic") and layer["z"].shape == (3, 3)
    assert explorer.cost_map("mse_r", 1, explorer.start)[:4] == b"\x89PNG"


def _run(cmd, tmp_path):
    from lenssim_cli.main import main

    argv = shlex.split(cmd)[1:]
    argv[argv.index("--out") + 1] = str(tmp_path / "run")
    assert main(argv) == 0
    return json.loads((tmp_path / "run" / "metrics.json").read_text())["crops"][0]


def test_the_command_line_reproduces_the_photo_panel(explorer, tmp_path, monkeypatch):
    """The file's design by the lens's name; a changed design by the lens file the page offers (its solves applied):
    the command's crop at the panel's field angle has the panel's scores."""
    pc = PhotoControls(iso=100, seed=5)
    r = explorer.photo_panel(explorer.start, pc)
    cmd = command_line("skimage:astronaut", explorer.start, pc, explorer)
    assert "--lens paper_singlet" in cmd
    crop = _run(cmd, tmp_path)
    assert crop["scores"]["wiener"]["psnr_db"] == pytest.approx(r["scores"]["restored"]["psnr_db"], abs=1e-9)

    changed = explorer.controls_from({"E1.bending": -0.5, "S2.conic": -5.0})
    pc = PhotoControls(center=(100, 400), iso=400, seed=2)
    r = explorer.photo_panel(changed, pc)
    assert r["field_deg"] > 5
    cmd = command_line("skimage:astronaut", changed, pc, explorer)
    assert f"--lens {LENS_EXPORT_FILE}" in cmd
    (tmp_path / LENS_EXPORT_FILE).write_text(explorer.lens_toml(changed))
    monkeypatch.chdir(tmp_path)
    crop = _run(cmd, tmp_path)
    assert crop["box_r0_r1_c0_c1"] == list(r["box"]) == [0, 256, 256, 512]
    assert crop["field_deg"] == pytest.approx(r["field_deg"], abs=1e-3)
    # the exported file folds the image plane into the last thickness: the same lens
    assert crop["scores"]["wiener"]["psnr_db"] == pytest.approx(r["scores"]["restored"]["psnr_db"], abs=1e-6)


def test_restoration_lab_on_a_centred_manufactured_copy(explorer):
    pc = PhotoControls(center=(256, 256))
    r = explorer.restoration_lab(explorer.start, pc, "wiener", "tikhonov:weight=0.003", "commercial", 1)
    assert set(r["scores"]) == {"a", "b", "nominal", "own"}
    assert all(math.isfinite(v["psnr_db"]) for v in r["scores"].values())
    # a copy of the "none" grade is the nominal lens: its own PSFs and the nominal ones restore alike
    same = explorer.restoration_lab(explorer.start, pc, "wiener", "wiener", "none", 0)
    assert same["scores"]["own"]["psnr_db"] == pytest.approx(same["scores"]["nominal"]["psnr_db"], abs=1e-9)
    with pytest.raises(ValueError, match="grade 'bad' is not known"):
        explorer.restoration_lab(explorer.start, pc, "wiener", "wiener", "bad", 0)


def test_the_page_on_a_lens_without_a_browser(explorer, tmp_path):
    pytest.importorskip("panel")
    from types import SimpleNamespace

    from lenssim_cli.explore import build_app

    app = build_app(explorer, "skimage:astronaut")
    assert {"E1.bending", "S2.conic"} <= set(app.widgets) and not app.widgets["glass"].visible
    fig = app.panes["map"]  # the axes: the ranges given by --vary
    assert (fig.x_range.start, fig.x_range.end, fig.y_range.start, fig.y_range.end) == (-1.0, 0.0, -10.0, 0.0)
    before = app.panes["criteria"].object
    assert "EFL [mm]" in before
    app.actions["map_tap"](SimpleNamespace(x=-0.51, y=-4.96))
    assert (app.widgets["E1.bending"].value, app.widgets["S2.conic"].value) == (-0.5, -5.0)
    assert app.panes["selected"].data == {"x": [-0.5], "y": [-5.0]}
    assert app.panes["criteria"].object != before
    assert f"--lens {LENS_EXPORT_FILE}" in app.panes["command"].object
    toml = app.exports[1]._callback().read().decode() if hasattr(app.exports[1], "_callback") else \
        app.exports[1].callback().read().decode()
    (tmp_path / "x.toml").write_text(toml)
    q = read_lens(str(tmp_path / "x.toml"))
    assert q.surfaces[1].conic == -5.0
    assert app.actions["design_png"]().read(8) == b"\x89PNG\r\n\x1a\n"
    app.actions["pick"](SimpleNamespace(new="skimage:coffee"))
    assert not app.panes["error"].visible and "skimage:coffee" in app.panes["command"].object


@pytest.mark.parametrize("argv, message", [
    (["explore", "--vary", "S2.conic=-2:0"], "--vary appl(ies) to --lens LENS"),
    (["explore", "--lens", "paper_singlet"], "--lens needs its free parameters"),
    (["explore", "--lens", "paper_singlet", "--vary", "S2.conic=-2:0", "--design", "end_to_end_paper"],
     "--design describe(s) the paper's singlet"),
    (["explore", "--lens", "paper_singlet", "--vary", "S2.conic"], "--vary 'S2.conic' is not allowed: NAME=LO:HI"),
    (["explore", "--lens", "paper_singlet", "--vary", "S2.conic=0:-2"], "finite LO < HI"),
    (["explore", "--lens", "paper_singlet", "--vary", "S9.conic=-2:0"], "is not a parameter of this lens; valid"),
    (["explore", "--lens", "no_such_lens", "--vary", "S2.conic=-2:0"], "no_such_lens"),
    (["explore", "--lens", "paper_singlet", "--vary", "S2.conic=-2:0", "--pixel-pitch", "-1"],
     "--pixel-pitch -1 is not allowed"),
    (["explore", "--photo", "skimage:brick"], "photo 'skimage:brick' is not offered"),
])
def test_bad_lens_arguments_are_refused(argv, message, capsys):
    pytest.importorskip("panel")
    from lenssim_cli.main import main

    assert main(argv + ["--port", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err


def test_the_photo_spans_the_lens_s_field_as_simulate_takes_it(explorer):
    """The photo's pitch puts the lens's largest field at its corners plus the blur windows' core beyond them (the
    simulate command's default, issue 43: no PSF asked for beyond the lens's field)."""
    import math as m

    from pipeline.blur import PAPER_SCHEME

    pitch, reach = explorer._photo_field()
    H, W = explorer.photo_shape[-2:]
    scale = explorer._provider(explorer.start).base.image_scale_mm
    reach_deg = m.degrees(m.atan((m.hypot(H - 1, W - 1) / 2 + PAPER_SCHEME.core) * pitch * 1e-3 / scale))
    assert reach_deg == pytest.approx(max(read_lens("paper_singlet").fields), abs=1e-9) == reach
    assert torch.is_tensor(explorer._ideal().load())
