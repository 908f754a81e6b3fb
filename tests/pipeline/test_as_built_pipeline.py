"""The camera pipeline on an as-built lens (issue 19, items 2 and 5): its PSF provider, and the windowed Wiener filter
run with the nominal lens's PSFs on an image blurred by the as-built lens, against ``mse_r_nominal``."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from lenssim import AsBuiltPSF, Camera, Design, LensPSF, image_psd
from lenssim.model.tolerances import GRADES, Tolerances
from lenssim.tolerancing import as_built_criteria
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0
from pipeline import NoiseModel, WindowScheme, blur_windowed, wiener_windowed
from pipeline.noise import expose

DESIGN = Design(s=-0.775, Q_back=-2.4)


def test_the_nominal_as_built_lens_has_the_lens_psfs():
    """The non-symmetric path (general monomials, one PSF per window) equals the symmetric one for a perfect lens."""
    rows, cols, oc = torch.tensor([0.0, 300.0, -200.0]), torch.tensor([0.0, 400.0, 900.0]), (0.0, 0.0)
    a = AsBuiltPSF(PAPER_CAMERA, DESIGN, Tolerances().sample(1, seed=0)).psf_at_pixels(rows, cols, oc, 256,
                                                                                      dtype=torch.float64)
    b = LensPSF(PAPER_CAMERA, DESIGN).psf_at_pixels(rows, cols, oc, 256, dtype=torch.float64)
    torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
    assert not AsBuiltPSF(PAPER_CAMERA, DESIGN, Tolerances().sample(1, seed=0)).mirror_symmetric
    with pytest.raises(ValueError, match="takes one lens"):
        AsBuiltPSF(PAPER_CAMERA, DESIGN, Tolerances().sample(2, seed=0))


def test_a_decentred_lens_psf_is_not_mirror_symmetric():
    lens = GRADES["commercial"].only("asphere_decentre_um").sample(1, seed=1)
    p = AsBuiltPSF(PAPER_CAMERA, DESIGN, lens).psf_at_pixels(torch.tensor([0.0]), torch.tensor([2000.0]), (0.0, 0.0),
                                                             256, dtype=torch.float64)[0]
    # the field lies along +x (columns): a centred lens's PSF is mirror-symmetric about that row, this one is not
    asym = float((p - p.flip(-2).roll(1, -2)).abs().sum())
    assert asym > 1e-3


def test_the_windowed_wiener_with_the_nominal_psf_costs_what_mse_r_nominal_predicts():
    """A correlated random image (the criteria's image model), blurred by an as-built lens at 5 degrees, Poisson
    noise at ~27.6 dB, restored by the adaptive windowed Wiener filter with the nominal lens's PSFs and with the
    lens's own: the measured errors, relative to the signal variance, against the criteria at that field point."""
    cam = Camera(dataclasses.replace(PAPER_CAMERA.lens, field_angles_deg=(5.0,)), PAPER_CAMERA.sensor,
                 PAPER_CAMERA.spectrum)
    lenses = GRADES["commercial"].sample(12, seed=5)
    r = as_built_criteria(cam, DESIGN, lenses, [27.6], rho0=PAPER_RHO0, azimuths_deg=(0.0,))
    ratio = r["mse_r_nominal"][:, 0] / r["mse_r"][:, 0]
    i = int(torch.argmax(ratio))
    assert float(ratio[i]) > 1.15  # a lens whose nominal restoration costs something
    n, var, mean = 512, 0.01, 0.5
    g = torch.Generator().manual_seed(0)
    P = image_psd(n, PAPER_RHO0, dtype=torch.float64)
    x = torch.fft.ifft2(torch.fft.fft2(torch.randn(n, n, generator=g, dtype=torch.float64)) * P.sqrt()).real
    x = (mean + math.sqrt(var) * x / x.std())[None, None].to(torch.float32)
    px = cam.geometry.pixel_pitch_um * 1e-3
    centre_px = cam.lens.focal_length_mm * math.tan(math.radians(5.0)) / px
    oc = ((n - 1) / 2, (n - 1) / 2 - centre_px)  # the image's centre at 5 degrees along +x
    scheme = WindowScheme(256, 32, 64)
    built = AsBuiltPSF(cam, DESIGN, lenses[i])
    nominal = LensPSF(cam, DESIGN)
    y = blur_windowed(x, built, scheme=scheme, optical_center=oc)
    e = mean / (var * 10 ** (-27.6 / 10))  # electrons per unit: noise variance mean / e at 27.6 dB
    obs = expose(y, e, None, e, generator=torch.Generator().manual_seed(1))
    inner = (slice(None), slice(None), slice(96, -96), slice(96, -96))
    measured = {}
    for name, prov in (("mse_r", built), ("mse_r_nominal", nominal)):
        xr = wiener_windowed(obs, prov, noise=NoiseModel(e), scheme=scheme, optical_center=oc)
        measured[name] = float(((xr - x)[inner] ** 2).mean()) / var
    pred = {k: float(r[k][i, 0]) for k in measured}
    # the adaptive filter estimates its signal variance locally and its window is finite: within 20% of the
    # stationary theory; the penalty of the nominal PSFs (the ratio) within 10%
    for k in measured:
        assert measured[k] == pytest.approx(pred[k], rel=0.2), (k, measured, pred)
    assert measured["mse_r_nominal"] / measured["mse_r"] == pytest.approx(pred["mse_r_nominal"] / pred["mse_r"],
                                                                          rel=0.1), (measured, pred)


def test_simulate_as_built_restores_with_the_nominal_and_the_calibrated_psfs(tmp_path, capsys):
    import json

    from lenssim_cli.main import main

    out = tmp_path / "sim"
    rc = main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--as-built", "3", "--angles", "0",
               "--crop", "128", "--scheme", "256", "32", "64", "--out", str(out)])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["as_built"]["seed"] == 3 and "asphere_decentre_x_um" in m["as_built"]["errors"]
    crop = m["crops"][0]
    assert {"wiener@nominal", "wiener@calibrated", "sensor"} <= set(crop["scores"])
    assert crop["psnr_restored_calibrated_db"] == crop["scores"]["wiener@calibrated"]["psnr_db"]
    for f in ("crop_0deg_restored_nominal.png", "crop_0deg_restored_calibrated.png", "mosaic.png", "index.html"):
        assert (out / f).is_file(), f
    assert "nominal PSFs" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--as-built", "-1"], "--as-built -1 is not allowed"),
    (["--as-built", "1", "--full-frame", "--restore", "wiener", "tikhonov"], "--full-frame restores with one method"),
    (["--as-built", "1", "--wavefront", "exact"], "--as-built takes the third-order wavefront"),
])
def test_simulate_as_built_bad_arguments(tmp_path, capsys, argv, message):
    from lenssim_cli.main import main

    rc = main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--out", str(tmp_path / "o"), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "o").exists()


def test_psnr_table_as_built_adds_the_calibrated_columns(tmp_path):
    from lenssim_cli.main import main

    out = tmp_path / "pt"
    rc = main(["psnr-table", "skimage:camera", "--designs", "end_to_end_paper", "--isos", "100", "--as-built", "2",
               "--angles", "0", "--crop", "128", "--out", str(out)])
    assert rc == 0
    head, row = (out / "psnr_table.csv").read_text().splitlines()[:2]
    cols = dict(zip(head.split(","), row.split(",")))
    assert cols["as_built_seed"] == "2" and float(cols["psnr_restored_calibrated_db"]) > 0
    assert "PSNR calibrated [dB]" in (out / "psnr_table.md").read_text()


def test_the_as_built_example_runs(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "examples" / "as_built_demo.py"
    r = subprocess.run([sys.executable, str(script), "skimage:camera", "--out", str(tmp_path / "demo")], cwd=tmp_path,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "restored with the nominal PSFs" in r.stdout and (tmp_path / "demo" / "as_built.png").is_file()
    assert "leaked" not in r.stderr
