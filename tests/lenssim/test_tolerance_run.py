"""``lenssim tolerance`` (issue 19, item 3): seeded, chunked, resumable and verified, byte-identical on dask, and its
command line with its errors."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import xarray as xr

from lenssim import Design
from lenssim.model.tolerances import GRADES
from lenssim.validate import ResumeWarning
from lenssim_cli.main import main
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0
from lenssim_studies.tolerance import ToleranceRun, parse_yield, run_tolerance, summarise

RUN = ToleranceRun(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), GRADES["commercial"], (21.6, 27.6), PAPER_RHO0,
                   n_lenses=11, seed=3, field_angles_deg=(0.0, 10.0), chunk_lenses=4)


@pytest.fixture(scope="module")
def serial_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("tol") / "serial.nc"
    run_tolerance(RUN, out, device="cpu", show_progress=False)
    return out


def test_the_dataset_holds_every_lens_criterion_and_the_sampled_errors(serial_file):
    ds = xr.load_dataset(serial_file, engine="scipy")
    assert ds.sizes["lens"] == 11 and list(ds["snr"].values) == [21.6, 27.6]
    assert ds["mse_r_nominal"].dims == ("lens", "snr") and ds["rms_w"].dims == ("lens",)
    assert "asphere_decentre_x_um" in ds and ds["asphere_decentre_x_um"].attrs["units"] == "um"
    assert bool((ds["mse_r_nominal"] >= ds["mse_r"] * (1 - 1e-6)).all())
    # the same lenses as drawing them directly: the chunks slice one seeded sample
    lenses = RUN.tolerances.sample(11, seed=3)
    np.testing.assert_array_equal(ds["despace_um"].values, lenses.despace_mm.numpy() * 1e3)


def test_an_interrupted_run_resumes_verifies_its_chunks_and_writes_the_same_file(serial_file, tmp_path):
    out = tmp_path / "resumed.nc"
    assert run_tolerance(RUN, out, device="cpu", show_progress=False, max_chunks=2) is None
    chunks = sorted((tmp_path / "resumed.nc.partial").glob("chunk_*.npz"))
    assert len(chunks) == 2
    chunks[1].write_bytes(chunks[1].read_bytes()[:-40])  # a truncated chunk
    with pytest.warns(ResumeWarning, match="chunk_00001.npz.*computing it again"):
        run_tolerance(RUN, out, device="cpu", show_progress=False)
    assert out.read_bytes() == serial_file.read_bytes()
    assert not (tmp_path / "resumed.nc.partial").exists()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = run_tolerance(RUN, out, device="cpu", show_progress=False)  # finished: read back, nothing recomputed
    assert again.attrs["config_digest"] == RUN.digest()
    other = dataclasses.replace(RUN, seed=4)
    with pytest.raises(FileExistsError, match="not the finished result of this tolerance run"):
        run_tolerance(other, out, device="cpu", show_progress=False)


def test_two_local_workers_write_the_single_process_file_byte_for_byte(serial_file, tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "cluster.nc"
    run_tolerance(RUN, out, device="cpu", show_progress=False, workers=2)
    assert out.read_bytes() == serial_file.read_bytes()


def test_summary_statistics_and_yields(serial_file):
    ds = xr.load_dataset(serial_file, engine="scipy")
    s = summarise(ds, {k: 0.0 for k in ("mse_s", "mse_r", "mse_r_nominal", "mtf50", "strehl", "rms_w", "cost")},
                  27.6, [parse_yield("mse_r_nominal<=0.05"), parse_yield("strehl>=0.1")])
    v = ds["mse_r_nominal"].sel(snr=27.6).values
    assert s["criteria"]["mse_r_nominal"]["p90"] == pytest.approx(float(np.percentile(v, 90)))
    assert s["criteria"]["strehl"]["p90"] == pytest.approx(float(np.percentile(ds["strehl"].values, 10)))  # to maximise
    assert s["yields"][0]["fraction"] == pytest.approx(float((v <= 0.05).mean()))
    with pytest.raises(ValueError, match="criterion 'mse_q' is not allowed"):
        parse_yield("mse_q<=1")
    with pytest.raises(ValueError, match="CRITERION<=VALUE"):
        parse_yield("mse_r=1")


def test_the_command_writes_its_report_dataset_and_figures(tmp_path, capsys):
    out = tmp_path / "tol"
    rc = main(["tolerance", "--design", "end_to_end_paper", "-n", "6", "--angles", "0", "7", "--sensitivity-lenses",
               "3", "--yield", "mse_r_nominal<=0.05", "--out", str(out), "--quiet", "--grade", "precision"])
    assert rc == 0
    for f in ("tolerance.nc", "report.md", "summary.json", "histogram.png", "histogram.svg", "cdf.png", "cdf.svg"):
        assert (out / f).is_file(), f
    text = capsys.readouterr().out
    assert "MSE_R nominal (mse_r_nominal)" in text and "Sensitivity" in text and "Yield:" in text


@pytest.mark.parametrize("argv, message", [
    (["--off", "radius"], "--off 'radius' is not allowed: one of radius_front_pct"),
    (["--yield", "mse_r<0.1"], "CRITERION<=VALUE"),
    (["--yield", "mse_r<=nan"], "not a finite number"),
    (["-n", "0"], "number of lenses=0 is not allowed"),
    (["--reference-snr", "30"], "--reference-snr 30 is not allowed"),
    (["--wavefront", "exact"], "--wavefront exact is not allowed here"),
    (["--sensitivity-lenses", "-1"], "--sensitivity-lenses -1 is not allowed"),
])
def test_bad_arguments_are_one_line_errors_before_any_work(tmp_path, capsys, argv, message):
    out = tmp_path / "o"
    rc = main(["tolerance", "--design", "end_to_end_paper", "--out", str(out), "--quiet", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_a_tolerances_file_with_a_typo_is_refused(tmp_path, capsys):
    f = tmp_path / "t.toml"
    f.write_text("[tolerances]\ngrade = \"precision\"\ndespace_mu = 3\n")
    rc = main(["tolerance", "--design", "end_to_end_paper", "--tolerances", str(f), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "unknown key(s) despace_mu" in err
