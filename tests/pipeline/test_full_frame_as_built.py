"""``lenssim simulate --full-frame --as-built SEED`` (issue 28): one manufactured lens through the whole-frame path,
blurred and exposed once, the one noisy frame restored with the nominal lens's PSFs and with the lens's own
(calibrated); its crops, its scores, and its checkpoint (the stamp names the lens)."""

from __future__ import annotations

import contextlib
import io
import json
import math

import pytest
import torch

import pipeline.simulate
from lenssim import AsBuiltPSF, LensPSF
from lenssim.model.tolerances import GRADES, Tolerances
from lenssim_cli.main import main
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_SENSOR
from pipeline.blur import WindowScheme
from pipeline.io import read_image, write_image
from pipeline.simulate import crops_from_frame, frame_memory_bytes, simulate_frame

DESIGN = PAPER_DESIGNS["end_to_end_paper"]
SCHEME = ["--scheme", "256", "32", "64"]
WELL = 3200.0  # ISO 100, the command's default


def _photo(path, h=288, w=320):
    """A small grey photo: the camera man cut down, with gamma so it is not flat."""
    from skimage import data

    cam = torch.from_numpy(data.camera()[:h, 96:96 + w].astype("float32") / 255.0)
    write_image(path, cam[None, None])
    return path


def _argv(photo, out, *extra):
    return ["simulate", str(photo), "--design", "end_to_end_paper", "--full-frame", *SCHEME, "--angles", "0", "0.2",
            "--crop", "64", "--out", str(out), *extra]


def _spy(monkeypatch):
    """Record what the command passes to ``simulate_frame`` and what it returns."""
    seen = {}
    real = pipeline.simulate.simulate_frame

    def spy(ideal, psf, full_well, **kw):
        frame = real(ideal, psf, full_well, **kw)
        seen.update(ideal=ideal, psf=psf, full_well=full_well, frame=frame, **kw)
        return frame

    monkeypatch.setattr(pipeline.simulate, "simulate_frame", spy)
    return seen


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One ``--full-frame --as-built 3 --exr`` run on a 320 x 288 photo, with what it gave ``simulate_frame``."""
    tmp = tmp_path_factory.mktemp("ffab")
    photo = _photo(tmp / "camera.png")
    out = tmp / "out"
    text = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(text):
        seen = _spy(mp)
        rc = main(_argv(photo, out, "--as-built", "3", "--exr"))
    assert rc == 0
    return {"out": out, "photo": photo, "seen": seen, "metrics": json.loads((out / "metrics.json").read_text()),
            "stdout": text.getvalue()}


def test_the_run_writes_both_restored_frames_and_their_scores(run):
    out, m = run["out"], run["metrics"]
    assert "whole frame: PSNR sensor" in run["stdout"] and "restored, adaptive Wiener (nominal PSFs)" in run["stdout"]
    assert "sensor -> adaptive Wiener (nominal PSFs), adaptive Wiener (the lens's own PSFs)" in run["stdout"]
    for f in ("sensor.png", "restored_nominal.png", "restored_calibrated.png", "sensor_linear.exr",
              "restored_nominal_linear.exr", "restored_calibrated_linear.exr", "field_psnr.png", "field_psnr.svg",
              "mosaic.png", "index.html", "crop_0deg_restored_nominal.png", "crop_0.2deg_restored_calibrated.png"):
        assert (out / f).is_file(), f
    assert not (out / "restored.png").exists() and not (out / ".checkpoint").exists()
    f = m["full_frame"]
    assert f["shape_c_h_w"] == [1, 288, 320] and not f["resumed"] and f["method"] == "wiener"
    for k in ("psnr_sensor_db", "psnr_restored_nominal_db", "psnr_restored_calibrated_db", "ssim_restored_nominal",
              "ssim_restored_calibrated"):
        assert math.isfinite(f[k]), k
    assert "psnr_restored_db" not in f  # no ambiguous key: each restoration says whose PSFs it used
    assert f["psnr_restored_nominal_db"] > f["psnr_sensor_db"] and f["psnr_restored_calibrated_db"] > f["psnr_sensor_db"]
    assert set(f["field_psnr_256px_tiles"]) == {"sensor_db", "restored_nominal_db", "restored_calibrated_db", "field_deg"}
    assert m["as_built"]["seed"] == 3 and "asphere_decentre_x_um" in m["as_built"]["errors"]
    for c in m["crops"]:
        assert {"sensor", "wiener@nominal", "wiener@calibrated"} == set(c["scores"])
        assert c["psnr_restored_db"] == c["scores"]["wiener@nominal"]["psnr_db"]
        assert c["psnr_restored_calibrated_db"] == c["scores"]["wiener@calibrated"]["psnr_db"]
    page = (out / "index.html").read_text()
    assert "Whole frame" in page and "(nominal PSFs)" in page and "(the lens&#x27;s own PSFs)" in page
    # one blur and one noise draw: the command blurred with the lens and restored with both providers
    seen = run["seen"]
    assert isinstance(seen["psf"], AsBuiltPSF) and list(seen["restoration_psf"]) == ["nominal", "calibrated"]
    assert isinstance(seen["restoration_psf"]["nominal"], LensPSF) and seen["restoration_psf"]["calibrated"] is seen["psf"]
    lin, _ = read_image(out / "restored_calibrated_linear.exr")
    assert torch.equal(lin, seen["frame"].restorations["calibrated"])


def test_the_crops_cut_from_the_frame_are_its_pixels(run):
    out, m, frame = run["out"], run["metrics"], run["seen"]["frame"]
    ideal = run["seen"]["ideal"]
    boxes = [tuple(c["box_r0_r1_c0_c1"]) for c in m["crops"]]
    cut = crops_from_frame(ideal, frame, boxes, PAPER_CAMERA.geometry)
    for c, r, box in zip(m["crops"], cut, boxes):
        r0, r1, c0, c1 = box
        for tag in ("nominal", "calibrated"):
            assert torch.equal(r.images[f"wiener@{tag}"], frame.restorations[tag][..., r0:r1, c0:c1])
            assert r.scores[f"wiener@{tag}"] == pytest.approx(c["scores"][f"wiener@{tag}"], rel=1e-12)
            # the crop's PNG holds the frame PNG's pixels (both 8-bit sRGB of the same linear values)
            crop_png, _ = read_image(out / f"crop_{c['requested_deg']:g}deg_restored_{tag}.png")
            frame_png, _ = read_image(out / f"restored_{tag}.png")
            torch.testing.assert_close(crop_png, frame_png[..., r0:r1, c0:c1], rtol=0, atol=1.01 / 255)
        assert torch.equal(r.images["sensor"], frame.sensor[..., r0:r1, c0:c1])


def test_each_restoration_equals_a_run_with_its_provider_alone(run):
    """The nominal restoration is ``simulate_frame`` blurred by the lens and restored with ``LensPSF(nominal)``; the
    calibrated one ``simulate_frame`` with the as-built provider alone: the same seed gives the same images."""
    seen = run["seen"]
    ideal = seen["ideal"]
    built = AsBuiltPSF(PAPER_CAMERA, DESIGN, GRADES["commercial"].sample(1, seed=3))  # --as-built 3, default grade
    assert built.fingerprint() == seen["psf"].fingerprint()
    scheme = WindowScheme(256, 32, 64)
    nominal = simulate_frame(ideal, built, WELL, seed=0, scheme=scheme, sensor=PAPER_SENSOR,
                             restoration_psf=LensPSF(PAPER_CAMERA, DESIGN))
    calibrated = simulate_frame(ideal, built, WELL, seed=0, scheme=scheme, sensor=PAPER_SENSOR)
    frame = seen["frame"]
    torch.testing.assert_close(frame.sensor, nominal.sensor, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(frame.restorations["nominal"], nominal.restored, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(frame.restorations["calibrated"], calibrated.restored, rtol=1e-5, atol=1e-6)
    assert frame.restored is frame.restorations["nominal"]
    # and the files hold them
    lin, _ = read_image(run["out"] / "restored_nominal_linear.exr")
    torch.testing.assert_close(lin, nominal.restored, rtol=1e-5, atol=1e-6)
    # the two differ: the lens is not the nominal one
    assert float((frame.restorations["nominal"] - frame.restorations["calibrated"]).abs().max()) > 1e-3


def test_a_perfect_lens_restores_alike_with_the_nominal_and_its_own_psfs(tmp_path):
    out = tmp_path / "perfect"
    rc = main(_argv(_photo(tmp_path / "camera.png"), out, "--as-built", "0", "--grade", "none", "--exr"))
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["as_built"]["tolerances"] == Tolerances().to_dict()
    # every error zero (the figure's weights are drawn always and scaled by a zero slope)
    assert all(v == 0 for k, v in m["as_built"]["errors"].items() if not k.startswith("figure_"))
    f = m["full_frame"]
    # the general (non-symmetric) PSF path equals the symmetric one for a perfect lens (3e-7 measured)
    assert f["psnr_restored_nominal_db"] == pytest.approx(f["psnr_restored_calibrated_db"], abs=1e-4)
    assert f["ssim_restored_nominal"] == pytest.approx(f["ssim_restored_calibrated"], abs=1e-6)
    a, _ = read_image(out / "restored_nominal_linear.exr")
    b, _ = read_image(out / "restored_calibrated_linear.exr")
    torch.testing.assert_close(a, b, rtol=0, atol=1e-5)
    for c in m["crops"]:
        assert c["psnr_restored_db"] == pytest.approx(c["psnr_restored_calibrated_db"], abs=1e-4)


def test_the_checkpoint_is_resumed_only_for_the_same_lens_and_seed(tmp_path, monkeypatch):
    from skimage import data

    ideal = (torch.from_numpy(data.camera()[:192, 96:320].astype("float32") / 255.0) ** 2.2)[None, None]
    scheme = WindowScheme(256, 32, 64)
    nominal = LensPSF(PAPER_CAMERA, DESIGN)
    lens = {s: AsBuiltPSF(PAPER_CAMERA, DESIGN, GRADES["commercial"].sample(1, seed=s)) for s in (3, 4)}
    assert len({lens[3].fingerprint(), lens[4].fingerprint(), nominal.fingerprint()}) == 3
    assert lens[3].fingerprint() == AsBuiltPSF(PAPER_CAMERA, DESIGN, GRADES["commercial"].sample(1, seed=3)).fingerprint()
    both = {"nominal": nominal, "calibrated": lens[3]}
    ck = tmp_path / "ck"
    run = lambda psf, seed=0, restoration_psf=None: simulate_frame(  # noqa: E731
        ideal, psf, WELL, seed=seed, scheme=scheme, sensor=PAPER_SENSOR, checkpoint=ck, restoration_psf=restoration_psf)
    first = run(lens[3], restoration_psf=both)
    assert not first.resumed
    again = run(lens[3], restoration_psf=both)
    assert again.resumed and "blur" not in again.seconds
    for tag in both:
        assert torch.equal(again.restorations[tag], first.restorations[tag])
    # the rest asks only whether the sensor image was resumed: the restorations are skipped
    monkeypatch.setattr(pipeline.simulate, "_restore_frame", lambda *a, resumed, **kw: resumed)
    assert not run(lens[4], restoration_psf={"nominal": nominal, "calibrated": lens[4]})  # another lens
    assert not run(nominal)  # a nominal run does not take lens 4's sensor image
    assert not run(lens[4])  # nor lens 4 the nominal one
    assert not run(lens[4], seed=1)  # another noise seed
    assert run(lens[4], seed=1)


def test_the_command_resumes_its_as_built_sensor_image_only_for_the_same_lens(tmp_path, monkeypatch):
    """Interrupted after the first pass (the sensor image saved), a rerun of the same command resumes from it; another
    lens, or the nominal lens, computes its own."""
    photo = _photo(tmp_path / "camera.png")
    out = tmp_path / "out"
    resumed = []
    real = pipeline.simulate._restore_frame

    def interrupt(*a, resumed: bool, **kw):  # stop where the restorations would start
        resumed_.append(resumed)
        raise KeyboardInterrupt

    resumed_ = resumed
    monkeypatch.setattr(pipeline.simulate, "_restore_frame", interrupt)
    for extra in (["--as-built", "3"], ["--as-built", "3"], ["--as-built", "4"], [], ["--as-built", "4"]):
        assert main(_argv(photo, out, *extra)) == 130
        assert (out / ".checkpoint" / "stamp.json").is_file()
    assert resumed == [False, True, False, False, False]  # lens 3 again: resumed; lens 4, nominal, lens 4: not
    monkeypatch.setattr(pipeline.simulate, "_restore_frame", real)
    assert main(_argv(photo, out, "--as-built", "4")) == 0  # lens 4's image is the one saved
    m = json.loads((out / "metrics.json").read_text())
    assert m["full_frame"]["resumed"] and m["as_built"]["seed"] == 4 and not (out / ".checkpoint").exists()


def test_the_memory_estimate_counts_every_restored_frame():
    shape = (1, 3, 4000, 6000)
    one, two = frame_memory_bytes(shape), frame_memory_bytes(shape, 2)
    assert two - one == 4 * math.prod(shape) and frame_memory_bytes(shape, 1) == one
    with pytest.raises(ValueError, match="restorations"):
        frame_memory_bytes(shape, 0)


def test_bad_restoration_provider_mappings_are_refused_before_any_work():
    ideal = torch.rand(1, 1, 64, 64)
    nominal = LensPSF(PAPER_CAMERA, DESIGN)
    for bad, msg in (({}, "empty mapping"), ({"a b": nominal}, "tag 'a b'"), ({"x": object()}, "restoration_psf\\['x'\\]")):
        with pytest.raises(ValueError, match=msg):
            simulate_frame(ideal, nominal, WELL, sensor=PAPER_SENSOR, restoration_psf=bad)
