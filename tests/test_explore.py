"""The explorer (issue 32): its update functions without a browser (tests/test_explore_browser.py drives the page)."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import evaluate
from lenssim_studies.explore import MAP_CRITERIA, DesignControls, Explorer, PhotoControls, command_line
from lenssim_studies.paper import PAPER, PAPER_CAMERA, PAPER_DESIGNS


@pytest.fixture(scope="module")
def explorer():
    import skimage.data

    from pipeline import srgb_to_linear

    img = srgb_to_linear(torch.from_numpy(skimage.data.astronaut()).permute(2, 0, 1)[None].float() / 255)
    return Explorer(photo=img, photo_source="skimage:astronaut")


def test_criteria_are_evaluate_s(explorer):
    c = explorer.criteria(DesignControls())
    r = evaluate(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"], PAPER.snr_db, rho0=PAPER.rho0)
    assert c["MSE_R at 27.6 dB"] == pytest.approx(float(r["mse_r"][1]), rel=1e-9)
    assert c["cost C_a"] == pytest.approx(float(r["cost"]), rel=1e-9)
    assert c["MTF50 [cycles/mm]"] == pytest.approx(float(r["mtf50"]), rel=1e-9)
    assert explorer.criteria(DesignControls()) is c  # cached
    other = explorer.criteria(DesignControls(Q_back=-5.0))
    assert other["MSE_R at 27.6 dB"] != c["MSE_R at 27.6 dB"]


def test_the_singlet_s_parameters_are_its_free_parameters_by_either_name():
    """The singlet's sliders are its Design parameters; their lens names (E1.bending, S2.conic) name the same ones, and
    the design they select is the Design of those values."""
    from lenssim_studies.explore import FreeParameter

    ex = Explorer(free=(FreeParameter("E1.bending", -1.0, 0.0, 0.05), FreeParameter("S2.conic", -5.0, 0.0, 0.1)))
    assert [sl.key for sl in ex.sliders()] == ["s", "Q_back"] and ex.map_axes == ("Q_back", "s")
    c = ex.controls_from({"s": -0.5, "Q_back": -3.0})
    assert ex.check(c).floats() == {"s": -0.5, "Q_back": -3.0}
    assert [sl.key for sl in Explorer().sliders()] == ["s", "Q_back", "Q_front", "focus_shift_um"]
    with pytest.raises(ValueError, match="design parameter 'S9.conic' is not known"):
        Explorer(free=(FreeParameter("S9.conic", -1.0, 0.0, 0.1),))


def test_a_design_the_lens_refuses_is_a_one_line_error(explorer):
    with pytest.raises(ValueError) as e:
        explorer.criteria(DesignControls(Q_front=-1e308))
    assert "\n" not in str(e.value)


def test_optics_figure_and_cost_map_are_pngs(explorer):
    png = explorer.optics_figure(DesignControls())
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    note = explorer.cost_map("mse_r", 1, DesignControls())
    assert note[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="criterion 'nope' is not allowed: one of mse_r"):
        explorer.cost_map("nope", 0, DesignControls())


def test_a_sweep_s_dataset_is_the_map(explorer):
    import numpy as np
    import xarray as xr

    s, q = np.array([-1.0, -0.5, 0.0]), np.array([-4.0, -2.0])
    ds = xr.Dataset({k: (("s", "Q_back"), np.random.default_rng(0).random((3, 2))) for k in MAP_CRITERIA
                     if k not in ("mse_r", "mse_s")},
                    coords={"s": s, "Q_back": q})
    ds["mse_r"] = (("s", "Q_back", "snr"), np.ones((3, 2, 3)))
    ex = Explorer(photo=explorer.photo, photo_source="x")
    ex.load_map(ds)
    assert ex.map_data["mse_r"].shape == (3, 2, 3)
    a = ex.cost_map("mse_r", 0, DesignControls())
    b = ex.cost_map("cost", 0, DesignControls())
    assert a != b and a[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="needs s and Q_back"):
        ex.load_map(ds.rename({"s": "t"}))


def test_photo_panel_is_simulate_crops_and_caches(explorer):
    from pipeline.simulate import simulate_crops

    pc = PhotoControls(center=(200, 300), iso=400, seed=3)
    r = explorer.photo_panel(DesignControls(), pc)
    assert r["box"] == (72, 328, 172, 428)
    prov = explorer._provider(DesignControls())
    (ref,) = simulate_crops(explorer.photo, prov.base, 800.0, [r["box"]], seed=3, sensor=PAPER_CAMERA.sensor,
                            blur_zones="auto")
    assert r["scores"]["restored"] == ref.scores["wiener"]
    assert r["scores"]["restored"]["psnr_db"] > r["scores"]["sensor"]["psnr_db"]
    assert explorer.photo_panel(DesignControls(), pc) is r
    # the crop follows a click, clamped inside the photo
    assert explorer.crop_box((0, 0)) == (0, 256, 0, 256)
    assert explorer.crop_box((511, 511)) == (256, 512, 256, 512)
    chain = explorer.photo_panel(DesignControls(), PhotoControls(center=(200, 300), cfa="RGGB"))
    assert chain["scores"]["restored"] != explorer.photo_panel(DesignControls(), PhotoControls(center=(200, 300)))[
        "scores"]["restored"]


def test_the_command_line_reproduces_the_photo_panel(explorer, tmp_path, capsys):
    """At the frame's centre the panel's crop is the command's crop at 0 deg: the same scores."""
    import json
    import shlex

    from lenssim_cli.main import main

    pc = PhotoControls(iso=100, seed=5)
    r = explorer.photo_panel(DesignControls(), pc)
    cmd = command_line("skimage:astronaut", DesignControls(), pc, explorer)
    argv = shlex.split(cmd)[1:]
    argv[argv.index("--out") + 1] = str(tmp_path / "run")
    assert main(argv) == 0
    crop = json.loads((tmp_path / "run" / "metrics.json").read_text())["crops"][0]
    assert crop["scores"]["wiener"]["psnr_db"] == pytest.approx(r["scores"]["restored"]["psnr_db"], abs=1e-9)


def test_restoration_lab_two_methods_and_an_as_built_lens(explorer):
    pc = PhotoControls(center=(256, 256))
    r = explorer.restoration_lab(DesignControls(), pc, "wiener", "tikhonov:weight=0.003", "commercial", 1)
    assert set(r["png"]) == {"a", "b", "nominal", "own"}
    assert all(math.isfinite(v["psnr_db"]) for v in r["scores"].values())
    assert r["scores"]["a"] == explorer.photo_panel(DesignControls(), pc)["scores"]["restored"]
    same = explorer.restoration_lab(DesignControls(), pc, "wiener", "wiener:rho0=0.5", "none", 0)
    assert same["scores"]["a"] != same["scores"]["b"]
    # with no tolerances the as-built lens is the nominal one: the same restoration either way
    assert same["scores"]["nominal"] == pytest.approx(same["scores"]["own"])
    with pytest.raises(ValueError, match="grade 'bad' is not allowed"):
        explorer.restoration_lab(DesignControls(), pc, "wiener", "wiener", "bad", 0)


def test_uploads_are_checked_like_photo_files(tmp_path, monkeypatch):
    from lenssim_cli.explore import _read_upload
    from pipeline.io import write_image

    made = tmp_path / "made"
    made.mkdir()
    write_image(made / "a.png", torch.full((1, 3, 64, 80), 0.5))
    png = (made / "a.png").read_bytes()
    img = _read_upload(png, "../../etc/passwd.png", 1.0)
    assert img.shape == (1, 3, 64, 80)
    for data, name, message in ((b"", "a.png", "the upload is empty"),
                                (b"x" * 2_000_001, "a.png", "at most 2 MB"),
                                (png, "a.exe", "type '.exe' is not allowed"),
                                (b"not a png at all", "a.png", "cannot read photo")):
        with pytest.raises((ValueError, OSError)) as e:
            _read_upload(data, name, 2.0)
        assert message in str(e.value) and "\n" not in str(e.value)
    assert [p.name for p in tmp_path.iterdir()] == ["made"]  # nothing written beside it
    # a picture too large to keep is refused from its header, before a pixel is decoded
    import pipeline.photo

    def no_decoding(*a, **k):
        raise AssertionError("pixels decoded")

    monkeypatch.setattr(pipeline.photo, "PHOTO_KEEP_BYTES", 64 * 80 * 3 * 4 - 1)
    monkeypatch.setattr(pipeline.photo, "read_image", no_decoding)
    monkeypatch.setattr(pipeline.photo, "scan_image", no_decoding)
    with pytest.raises(ValueError, match=r"'big.png' is 80 x 64 px .*keeps its photo in memory"):
        _read_upload(png, "big.png", 1.0)


@pytest.mark.parametrize("argv, message", [
    (["explore", "--port", "70000"], "--port 70000 is not allowed"),
    (["explore", "--max-upload-mb", "0"], "--max-upload-mb 0 is not allowed"),
    (["explore", "--sweep", "missing.nc"], "missing.nc"),
    (["explore", "--design", "nope"], "--design 'nope' is not known; choose from"),
    (["explore", "--allow-origin", "*"], "--allow-origin '*' is not allowed: an origin"),
    (["explore", "--allow-origin", "http://friend.example:8080/page"], "no path, no wildcard"),
])
def test_bad_explore_arguments_are_refused(argv, message, capsys):
    from lenssim_cli.main import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_glass_changes_the_lens_and_the_command_line(explorer):
    from lenssim_cli.common import camera_from_args

    g = DesignControls(glass="N-SF5")
    c = explorer.criteria(g)
    args = type("A", (), {"glass": "N-SF5", "spectrum": "paper"})()
    r = evaluate(camera_from_args(args), PAPER_DESIGNS["end_to_end_paper"], PAPER.snr_db, rho0=PAPER.rho0)
    assert c["MSE_R at 27.6 dB"] == pytest.approx(float(r["mse_r"][1]), rel=1e-9)
    assert c["MSE_R at 27.6 dB"] != explorer.criteria(DesignControls())["MSE_R at 27.6 dB"]
    assert "--glass N-SF5" in command_line(None, g, PhotoControls(), explorer)
    # a full well in place of the ISO's: the same as that ISO's full well, and said so in the command
    fw = explorer.photo_panel(DesignControls(), PhotoControls(center=(256, 256), full_well=800.0))
    iso = explorer.photo_panel(DesignControls(), PhotoControls(center=(256, 256), iso=400))
    assert fw["scores"] == iso["scores"]
    assert "--full-well 800" in command_line(None, DesignControls(), PhotoControls(full_well=800.0), explorer)
    with pytest.raises(ValueError, match="full well"):
        explorer.photo_panel(DesignControls(), PhotoControls(full_well=-1.0))
    with pytest.raises(ValueError):
        explorer.criteria(DesignControls(glass="no-such-glass"))


def test_the_page_s_handlers_without_a_browser(explorer):
    """build_app's handlers as the page calls them: a tap on the photo, a tap on the map, a method's options, a bad
    upload (its error shown, the app still working)."""
    pytest.importorskip("panel")
    from types import SimpleNamespace

    from lenssim_cli.explore import build_app

    explorer.map_data = None
    explorer.map_progress = (0, 0)
    app = build_app(explorer)
    fig = app.panes["map"]  # the map not computed yet: its axes are the parameters' ranges all the same
    assert (fig.x_range.start, fig.x_range.end, fig.y_range.start, fig.y_range.end) == (-10.0, 1.2, -2.0, 1.0)
    assert app.panes["design_labels"].background_fill_color == "white"  # readable on every colour of the map
    assert "MSE_R at 27.6 dB" in app.panes["criteria"].object
    assert "crop (128, 384, 128, 384)" in app.panes["field"].object
    app.actions["tap"](SimpleNamespace(x=40.0, y=30.0))
    assert app.panes["images"]["restored"].object is not None
    assert "--at " in app.panes["command"].object
    before, before_optics = app.panes["criteria"].object, app.panes["optics"].object
    app.actions["map_tap"](SimpleNamespace(x=-6.04, y=-1.26))
    assert (app.widgets["Q_back"].value, app.widgets["s"].value) == (-6.0, -1.25)
    assert app.panes["selected"].data == {"x": [-6.0], "y": [-1.25]}  # the marker moved to the design clicked
    assert app.panes["criteria"].object != before and "s = -1.25, Q_back = -6," in app.panes["criteria"].object
    assert app.panes["optics"].object == explorer.optics_figure(DesignControls(-1.25, -6.0)) != before_optics
    assert "s = -1.25, Q_back = -6," in app.panes["field"].object  # the photo panel is the new design's
    assert not app.jobs.running and app.panes["busy"].object == ""
    assert app.specs["a"]() == "wiener" and app.specs["b"]() == "richardson_lucy"
    app.widgets["upload"].filename = "mine.png"
    app.widgets["upload"].value = b"not an image"
    assert app.panes["error"].visible and "cannot read photo 'mine.png'" in app.panes["error"].object
    app.widgets["glass"].value = "N-BK7"
    assert not app.panes["error"].visible


def test_another_photo_of_the_same_size_is_blurred_afresh():
    """A photo picked or uploaded after another of the same size: its crops are its own (the blurred regions kept for
    the previous photo are dropped), equal to a fresh explorer's."""
    g = torch.Generator().manual_seed(5)
    a, b = (torch.rand(1, 3, 320, 320, generator=g) for _ in range(2))
    pc = PhotoControls(seed=1)
    ex = Explorer(photo=a, photo_source="a")
    first = ex.photo_panel(DesignControls(), pc)["scores"]
    ex.set_photo(b, "b")
    again = ex.photo_panel(DesignControls(), pc)["scores"]
    assert again != first
    assert again == Explorer(photo=b, photo_source="b").photo_panel(DesignControls(), pc)["scores"]


def test_each_page_s_photo_has_its_own_results_and_a_cancelled_panel_keeps_nothing():
    """Two photos of the same size shown side by side (two pages): each panel is its photo's, equal to a fresh
    explorer's, whichever was computed first; the explorer's own photo is left as it was. A panel cancelled before it
    starts raises Cancelled and caches nothing."""
    import threading

    from lenssim_studies.explore import Cancelled

    g = torch.Generator().manual_seed(7)
    a, b = (torch.rand(1, 3, 300, 300, generator=g) for _ in range(2))
    pc = PhotoControls(seed=2)
    ex = Explorer(photo=a, photo_source="a")
    other = ex.new_photo(b, "b")
    from_b = ex.photo_panel(DesignControls(), pc, photo=other)["scores"]
    from_a = ex.photo_panel(DesignControls(), pc)["scores"]
    assert from_a != from_b
    assert from_b == Explorer(photo=b, photo_source="b").photo_panel(DesignControls(), pc)["scores"]
    assert ex.shown_photo.source == "a" and ex.photo_panel(DesignControls(), pc)["scores"] == from_a
    stop = threading.Event()
    stop.set()
    for run in (lambda: ex.photo_panel(DesignControls(), PhotoControls(seed=3), cancel=stop),
                lambda: ex.restoration_lab(DesignControls(), pc, "wiener", "wiener", "none", 0, cancel=stop)):
        with pytest.raises(Cancelled):
            run()
    assert len(ex._cache("photo")) == 2 and len(ex._cache("lab")) == 0


@pytest.mark.parametrize("sigma", [1.3, 4.0, 9.5])
def test_the_psf_window_holds_the_energy_the_gaussian_closed_form_gives(sigma):
    """A sampled Gaussian's square of half-width d holds erf((d + 1/2) / (sigma sqrt 2))^2 of its energy (each axis
    separately; the samples sum as the pixels' integrals do for sigma > 1): the smallest d holding 99% is found."""
    from lenssim_studies.explore import PSF_WINDOW_ENERGY, ensquared_half_width

    n = 160
    x = torch.arange(n, dtype=torch.float64) - n // 2
    g = torch.exp(-x**2 / (2 * sigma**2))
    psf = g[:, None] * g[None, :]
    held = [math.erf((d + 0.5) / (sigma * math.sqrt(2))) ** 2 for d in range(n // 2)]
    want = next(d for d, e in enumerate(held) if e >= PSF_WINDOW_ENERGY)
    assert held[want] - PSF_WINDOW_ENERGY > 1e-4 and PSF_WINDOW_ENERGY - held[want - 1] > 1e-4  # not a tie
    assert ensquared_half_width(psf / psf.sum(), PSF_WINDOW_ENERGY) == want
    # off the centre by 5 samples: the square about the centre must reach 5 further
    shifted = torch.roll(psf, 5, dims=1)
    assert ensquared_half_width(shifted, PSF_WINDOW_ENERGY) == next(
        d for d in range(n // 2) if math.erf((d + 0.5) / (sigma * math.sqrt(2)))
        * 0.5 * (math.erf((d + 5.5) / (sigma * math.sqrt(2))) + math.erf((d - 4.5) / (sigma * math.sqrt(2))))
        >= PSF_WINDOW_ENERGY)


def test_the_psf_panels_share_a_window_fitted_to_the_widest_psf():
    from lenssim_studies.explore import (PSF_WINDOW_ENERGY, PSF_WINDOW_MARGIN, PSF_WINDOW_MIN_PX, ensquared_half_width,
                                         psf_mtf_figure, psf_window_px)

    n = 128
    x = torch.arange(n, dtype=torch.float64) - n // 2
    gauss = lambda s: torch.exp(-(x[:, None]**2 + x[None, :]**2) / (2 * s**2))  # noqa: E731
    sharp, wide = torch.zeros(n, n, dtype=torch.float64), gauss(12.0)
    sharp[n // 2, n // 2] = 1.0
    assert psf_window_px([sharp]) == PSF_WINDOW_MIN_PX
    h = ensquared_half_width(wide, PSF_WINDOW_ENERGY)
    assert psf_window_px([sharp, wide]) == psf_window_px([wide]) == math.ceil(PSF_WINDOW_MARGIN * h) > 40
    assert psf_window_px([gauss(60.0)]) == (n - 1) // 2  # wider than the arrays: all of them
    png = psf_mtf_figure([sharp, wide], (0.0, 30.0), 1.5, "two PSFs")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_page_jobs_run_off_the_loop_newest_first_cancel_drops_results():
    """PageJobs with a stand-in event loop (a queue the test runs): a superseded job's result is dropped and it stops
    at its next step, Cancel drops a running job (its work sees the cancel), errors arrive as one line, and without a
    loop (tests) a job runs at once."""
    import queue
    import threading

    from lenssim_cli.explore import PageJobs
    from lenssim_studies.explore import Cancelled

    loop = queue.Queue()
    changes = []
    jobs = PageJobs(loop.put, on_change=lambda: changes.append(sorted(jobs.running)))
    shown, failed, gate = [], [], threading.Event()

    def job(value):
        def work(cancel):
            gate.wait(30)  # bounded: the test opens the gate
            if cancel.is_set():
                raise Cancelled()
            return value
        return work

    jobs.submit("photo", job(1), shown.append, failed.append)
    jobs.submit("photo", job(2), shown.append, failed.append)  # the first is superseded
    assert list(jobs.running) == ["photo"]
    gate.set()
    for _ in range(2):
        loop.get(timeout=30)()
    assert shown == [2] and not failed and not jobs.running and changes[-1] == []

    saw_cancel = []

    def long_lab(cancel):
        saw_cancel.append(cancel.wait(30))
        raise Cancelled()
    jobs.submit("lab", long_lab, shown.append, failed.append)
    jobs.cancel()
    assert jobs.cancelled == ("lab",) and not jobs.running
    loop.get(timeout=30)()
    assert saw_cancel == [True] and shown == [2] and not failed

    def bad(cancel):
        raise ValueError("grade 'x' is not allowed\nsecond line")
    jobs.submit("lab", bad, shown.append, failed.append)
    loop.get(timeout=30)()
    assert failed == ["grade 'x' is not allowed"]

    jobs.submit("lab", long_lab, shown.append, failed.append)
    told = len(changes)
    jobs.close()  # the page was closed: its job stops, the page is told nothing more
    loop.get(timeout=30)()
    assert saw_cancel == [True, True] and len(changes) == told and not jobs.running and shown == [2]

    inline = PageJobs()
    inline.submit("design", lambda cancel: 5, shown.append, failed.append)
    assert shown == [2, 5] and not inline.running


def test_who_may_connect():
    """The addresses a server answers to and accepts pages from: the one it was started for, at its port (loopback:
    all three names), and those --allow-origin adds; a foreign Host (DNS rebinding) or Origin is refused."""
    import socket

    from lenssim_cli.explore import allowed_addresses, parse_allowed_origin, refusal

    assert parse_allowed_origin("http://Friend.example:8080") == ("friend.example", 8080)
    assert parse_allowed_origin("https://friend.example") == ("friend.example", 443)
    assert parse_allowed_origin("http://friend.example/") == ("friend.example", 80)
    assert parse_allowed_origin("friend.example") == ("friend.example", None)
    assert parse_allowed_origin("[::1]:7000") == ("::1", 7000)
    for bad in ("*", "http://*.example", "ftp://friend.example", "http://friend.example/page", "friend:0",
                "friend:99999", "http://user@friend.example", "http://", "friend example"):
        with pytest.raises(ValueError, match="--allow-origin .* is not allowed: an origin"):
            parse_allowed_origin(bad)
    local = allowed_addresses("127.0.0.1", 5123)
    assert local == {("127.0.0.1", 5123), ("localhost", 5123), ("::1", 5123)}
    assert allowed_addresses("::1", 5123) == local
    assert allowed_addresses("192.168.1.5", 80, [("lab.example", None)]) == {("192.168.1.5", 80), ("lab.example", 80)}
    assert (socket.gethostname().lower(), 5123) in allowed_addresses("0.0.0.0", 5123)
    allowed = allowed_addresses("127.0.0.1", 5123, [parse_allowed_origin("http://friend.example:8080")])
    for host, origin in (("127.0.0.1:5123", None), ("localhost:5123", "http://localhost:5123"),
                         ("[::1]:5123", "http://[::1]:5123"), ("127.0.0.1:5123", "http://friend.example:8080")):
        assert refusal(host, origin, allowed) is None, (host, origin)
    for host, origin in (("evil.example:5123", None), ("evil.example", None), ("127.0.0.1:5124", None),
                         ("127.0.0.1", None), (None, None), ("127.0.0.1:5123/x", None),
                         ("127.0.0.1:5123", "http://evil.example"), ("127.0.0.1:5123", "http://localhost:5124"),
                         ("127.0.0.1:5123", "null"), ("127.0.0.1:5123", "file://"),
                         ("127.0.0.1:5123", "http://friend.example:8081")):
        assert refusal(host, origin, allowed) is not None, (host, origin)
