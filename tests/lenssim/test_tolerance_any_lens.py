"""``lenssim tolerance --lens LENS`` (issue 29): a Monte Carlo of manufactured copies of any lens, tolerances per
surface (radius, thickness, conic, index, despace), each checked against something independent of the code under
test: the lensmaker's closed form, the matched Wiener filter's optimality, the draws' own bookkeeping."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from lenssim.io.prescription_file import read_lens
from lenssim.model.numerics import Numerics
from lenssim.model.misalignment import Misalignment
from lenssim.model.tolerances import (GRADES, SURFACE_GRADES, SurfaceTolerances, copy_misalignments, lens_elements,
                                      lens_surfaces, perturbed_prescription)
from lenssim.optics.sequential import SequentialLens
from lenssim.metrics import evaluate_sequential
from lenssim.tolerancing import copy_provider, manufactured_lens, run_lens_tolerance
from lenssim_cli.lens import lens_provider
from lenssim_cli.main import main

LENS_FILE = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")
SMALL = Numerics(min_size=64, oversample=1)
"""Small grids: the checks below compare lenses with each other on the same numerics."""
SNR = (21.6, 33.6)


@pytest.fixture(scope="module")
def singlet():
    p = read_lens(LENS_FILE)
    return p, SequentialLens(p)


def _provider(p, seq, max_field_deg=None):
    return lens_provider(argparse.Namespace(spectrum="paper"), p, seq, pitch_um=5.0, width_px=1, height_px=1,
                         max_field_deg=max(p.fields) if max_field_deg is None else max_field_deg)


@pytest.fixture(scope="module")
def commercial_run(singlet):
    p, seq = singlet
    return run_lens_tolerance(_provider(p, seq), SURFACE_GRADES["commercial"], 3, seed=1, snr_db=SNR, rho0=0.937,
                              angles_deg=(0.0, 3.0), numerics=SMALL)


def test_grades_reuse_the_singlet_grades_and_name_a_thickness():
    for name in ("commercial", "precision"):
        s, t = SURFACE_GRADES[name], GRADES[name]
        assert (s.radius_pct, s.conic_pct, s.index, s.despace_um) == (t.radius_front_pct, t.conic_pct, t.index,
                                                                     t.despace_um)
        assert s.thickness_um > 0
    assert SURFACE_GRADES["none"].terms() == ()
    assert SurfaceTolerances.from_dict({"grade": "precision", "index": 2e-4}) == replace(SURFACE_GRADES["precision"],
                                                                                        index=2e-4)


@pytest.mark.parametrize("d, match", [({"decentre_um": 10}, "unknown key(s) decentre_um"),
                                      ({"surface_tilt_arcmin": -1}, "surface_tilt_arcmin=-1 is not allowed"),
                                      ({"radius_front_pct": 1}, "unknown key(s) radius_front_pct"),
                                      ({"radius_pct": -1}, "radius_pct=-1 is not allowed"),
                                      ({"grade": "best"}, "grade 'best' is not known")])
def test_from_dict_refuses(d, match):
    with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        SurfaceTolerances.from_dict(d)


def test_zero_tolerances_give_the_nominal_lens(singlet):
    p, seq = singlet
    pert = SurfaceTolerances().sample(p, 2, seed=3)
    assert all(manufactured_lens(seq, pert, i).cache_key() == seq.cache_key() for i in range(2))
    ds = run_lens_tolerance(_provider(p, seq), SurfaceTolerances(), 2, seed=3, snr_db=SNR, rho0=0.937,
                            angles_deg=(0.0, 3.0), numerics=SMALL, compare_default=False)
    for k in ("mse_r", "mse_r_nominal", "mse_s"):  # the same table, the same numbers
        assert (ds[k].values == ds[f"nominal_{k}"].values[None, :]).all()
    assert (ds["rms_w"].values == float(ds["nominal_rms_w"])).all()
    assert ds["mse_r_nominal"].values == pytest.approx(ds["mse_r"].values, rel=1e-12)  # H = H0: the matched filter


def test_nominal_filter_never_beats_the_matched_one(commercial_run):
    ds = commercial_run
    r, rn = ds["mse_r"].values, ds["mse_r_nominal"].values
    assert (rn >= r * (1 - 1e-12)).all()  # the matched Wiener filter is the minimum-MSE linear filter
    assert (rn > r * (1 + 1e-6)).any()  # and a copy with errors is worse off with the nominal's filter
    assert (ds["mse_r"].values <= ds["mse_s"].values).all()
    for k in ("mse_r", "mse_r_nominal", "mse_s", "rms_w"):
        assert torch.isfinite(torch.as_tensor(ds[k].values)).all()
    # the coarse copies' table against the default one: the nominal lens at both, within 0.1% here
    assert float(ds["nominal_mse_r"][1]) == pytest.approx(float(ds["nominal_default_mse_r"][1]), rel=1e-3)


def test_reference_argument_leaves_results_unchanged_without_it(singlet):
    p, seq = singlet
    psf = _provider(p, seq, max_field_deg=0.0)
    a = evaluate_sequential(psf, SNR, rho0=0.937, numerics=SMALL, criteria=("mse_r", "mse_r_nominal"))
    b = evaluate_sequential(psf, SNR, rho0=0.937, numerics=SMALL, criteria=("mse_r", "mse_r_nominal"), reference=psf)
    assert torch.equal(a["mse_r"], b["mse_r"]) and torch.equal(a["mse_r_nominal"], a["mse_r"])
    assert torch.allclose(b["mse_r_nominal"], b["mse_r"], rtol=1e-12)


def test_radius_error_scales_the_focal_length(singlet):
    # plano-convex, curved face first: 1/f = (n - 1) / R exactly (the flat face has no power, so the thickness
    # does not enter), hence f is proportional to R
    p, seq = singlet
    pert = SurfaceTolerances(radius_pct=2.0).sample(p, 4, seed=5)
    f0 = seq.paraxial().efl_mm
    n = seq.index_after(0, 0.55)
    assert f0 == pytest.approx(p.surfaces[0].radius_mm / (n - 1), rel=1e-12)
    for i in range(4):
        e = float(pert.radius_rel[i, 0])
        assert e != 0
        f = manufactured_lens(seq, pert, i).paraxial().efl_mm
        assert f / f0 == pytest.approx(1 + e, rel=1e-12)


def test_index_error_changes_f_and_keeps_the_dispersion(singlet):
    p, seq = singlet
    pert = SurfaceTolerances(index=2e-3).sample(p, 3, seed=6)
    n0 = seq.index_after(0, 0.55)
    f0 = seq.paraxial().efl_mm
    for i in range(3):
        dn = float(pert.index[i, 0])
        copy = manufactured_lens(seq, pert, i)
        assert copy.prescription.surfaces[0].material == "N-BK7"  # still the catalogue glass
        assert copy.index_after(0, 0.55) - n0 == pytest.approx(dn, abs=1e-15)
        # dispersion kept: the same index difference between two wavelengths
        assert copy.index_after(0, 0.45) - copy.index_after(0, 0.65) == pytest.approx(
            seq.index_after(0, 0.45) - seq.index_after(0, 0.65), abs=1e-14)
        rel = copy.paraxial().efl_mm / f0 - 1
        assert rel == pytest.approx((n0 - 1) / (n0 - 1 + dn) - 1, rel=1e-9)  # exact: f = R / (n - 1)
        assert rel == pytest.approx(-dn / (n0 - 1), rel=5e-3)  # first order


def test_thickness_draw_lands_on_its_gap():
    p = read_lens("cooke_triplet")
    pert = SurfaceTolerances(thickness_um=25.0).sample(p, 2, seed=7)
    nonzero = [i for i, s in enumerate(p.surfaces[:-1]) if s.thickness_mm > 0]
    assert pert.thickness_at == tuple(nonzero)
    for i in range(2):
        q, offsets = perturbed_prescription(p, pert, i)
        assert offsets == {}
        for k, (s0, s1) in enumerate(zip(p.surfaces, q.surfaces)):
            want = s0.thickness_mm + (float(pert.thickness_mm[i, nonzero.index(k)]) if k in nonzero else 0.0)
            assert s1.thickness_mm == pytest.approx(want, abs=1e-15)
            assert (s1.curvature_per_mm, s1.conic) == (s0.curvature_per_mm, s0.conic)
        assert q.surfaces[-1].thickness_mm == p.surfaces[-1].thickness_mm  # the image distance is the focus's


def test_seed_reproduces_and_terms_are_independent(singlet):
    p = read_lens("cooke_triplet")
    t = SURFACE_GRADES["commercial"]
    a, b, c = t.sample(p, 5, seed=11), t.sample(p, 5, seed=11), t.sample(p, 5, seed=12)
    for name in ("radius_rel", "thickness_mm", "index", "despace_mm"):
        assert torch.equal(getattr(a, name), getattr(b, name))
        assert not torch.equal(getattr(a, name), getattr(c, name))
    off = replace(t, radius_pct=0.0).sample(p, 5, seed=11)  # common random numbers: the other draws unchanged
    assert (off.radius_rel == 0).all() and torch.equal(off.index, a.index) and torch.equal(off.despace_mm, a.despace_mm)
    assert set(a.variables()) >= {"radius_s1_pct", "thickness_s1_um", "index_s1", "despace_um"}


def test_focus_compensation(singlet):
    p, seq = singlet
    psf = _provider(p, seq, max_field_deg=0.0)  # the axis: a one-node table
    on = SurfaceTolerances(radius_pct=1.0)
    off = replace(on, focus_compensated=False)
    d0 = seq.image_z_mm - seq.paraxial().image_z_mm
    mse = {}
    for t in (on, off):
        pert = t.sample(p, 3, seed=2)
        vals = []
        for i in range(3):
            copy = manufactured_lens(seq, pert, i)
            if t.focus_compensated:  # focused at assembly: the nominal's distance from its own paraxial focus
                assert copy.image_z_mm - copy.paraxial().image_z_mm == pytest.approx(d0, abs=1e-9)
            else:  # the image plane where the nominal's is
                assert copy.image_z_mm == pytest.approx(seq.image_z_mm, abs=1e-12)
            r = evaluate_sequential(copy_provider(psf, copy), SNR, rho0=0.937, numerics=SMALL,
                                    criteria=("mse_r", "mse_r_nominal"), reference=psf)
            vals.append(float(r["mse_r"][1]))
        mse[t.focus_compensated] = sum(vals) / 3
    assert mse[False] > 1.5 * mse[True]  # a 1% radius error is ~0.5 mm of defocus at f = 50 mm, F/8


def test_table_cache_tells_index_offsets_apart(singlet):
    p, _ = singlet
    a = SequentialLens(p)
    b = SequentialLens(p, index_offsets={0: 1e-3})
    assert a.cache_key() != b.cache_key() and SequentialLens(p, index_offsets={0: 0.0}).cache_key() == a.cache_key()
    ta = _provider(p, a, max_field_deg=0.0).table()
    tb = _provider(p, b, max_field_deg=0.0).table()
    assert tb is not ta and not torch.allclose(ta.opd_waves, tb.opd_waves)
    assert _provider(p, SequentialLens(p), max_field_deg=0.0).table() is ta  # the same lens shares its table
    with pytest.raises(ValueError, match="needs a glass"):
        SequentialLens(p, index_offsets={1: 1e-3})


def _args(out, *extra):
    return ["tolerance", "--lens", LENS_FILE, "--pixel-pitch", "5", "--angles", "0", "3", "--out", str(out), *extra]


def test_cli_writes_three_files(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(_args(out, "-n", "3", "--quiet")) == 0
    assert sorted(f.name for f in out.iterdir()) == ["report.md", "summary.json", "tolerance.nc"]
    s = json.loads((out / "summary.json").read_text())
    assert s["run"]["lenses"] == 3 and s["summary"]["reference_snr_db"] == 27.6
    for k in ("mse_r", "mse_r_nominal"):
        for stat in ("mean", "median", "p90", "nominal"):
            assert math.isfinite(s["summary"][k][stat]) and s["summary"][k][stat] > 0
    import xarray as xr

    with xr.open_dataset(out / "tolerance.nc", engine="scipy") as ds:
        assert ds.sizes["lens"] == 3 and ds.sizes["snr"] == 3
        assert "error_radius_s1_pct" in ds and "error_index_s1" in ds
        assert (ds["mse_r_nominal"].values >= ds["mse_r"].values * (1 - 1e-12)).all()
    assert "mse_r_nominal" in (out / "report.md").read_text()


@pytest.mark.parametrize("extra, toml, match", [
    ((), "[tolerances]\ndecentre_um = 10\n", "unknown key(s) decentre_um"),
    ((), "[tolerances]\nradius_pct = 1\nwobble = 2\n", "unknown key(s) wobble"),
    (("--design", "end_to_end_paper"), None, "--design describe"),
    (("--yield", "mse_r<=0.1"), None, "--yield belong(s) to the paper's singlet"),
    (("--angles", "5"), None, "--angles 5 is not allowed"),
    (("-n", "0"), None, "-n/--lenses 0 is not allowed"),
    (("--off", "radius_front_pct"), None, "--off 'radius_front_pct' is not allowed with --lens"),
])
def test_cli_refuses_in_one_line(tmp_path, capsys, extra, toml, match):
    out = tmp_path / "run"
    argv = _args(out, *extra)
    if toml is not None:
        f = tmp_path / "tol.toml"
        f.write_text(toml)
        argv += ["--tolerances", str(f)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_an_interrupted_run_resumes_verifies_its_chunks_and_equals_one_run(singlet, tmp_path):
    import warnings

    import xarray as xr

    from lenssim.validate import ResumeWarning
    from lenssim_studies.tolerance import LensToleranceRun, run_tolerance

    p, seq = singlet
    psf = _provider(p, seq)
    tol = SURFACE_GRADES["commercial"]
    run = LensToleranceRun(psf, tol, 3, 1, SNR, 0.937, SMALL, angles_deg=(0.0, 3.0), chunk_copies=1)
    out = tmp_path / "t.nc"
    assert run_tolerance(run, out, show_progress=False, max_chunks=2) is None
    part = tmp_path / "t.nc.partial"
    chunks = sorted(part.glob("chunk_*.npz"))
    assert len(chunks) == 2 and not out.exists()
    chunks[1].write_bytes(chunks[1].read_bytes()[:-40])  # a chunk cut short by a crash
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = run_tolerance(run, out, show_progress=False)
    assert any(issubclass(w.category, ResumeWarning) for w in caught)
    assert out.exists() and not part.exists()
    one = run_lens_tolerance(psf, tol, 3, seed=1, snr_db=SNR, rho0=0.937, angles_deg=(0.0, 3.0), numerics=SMALL)
    for k in one.data_vars:
        assert (ds[k].values == one[k].values).all(), k
    with xr.open_dataset(out, engine="scipy") as back:
        assert back.attrs["config_digest"] == run.digest()
    other = LensToleranceRun(psf, tol, 3, 2, SNR, 0.937, SMALL, angles_deg=(0.0, 3.0), chunk_copies=1)
    with pytest.raises(FileExistsError, match="not the finished result"):
        run_tolerance(other, out, show_progress=False)


def test_two_local_workers_write_the_in_process_file_byte_for_byte(singlet, tmp_path):
    """The Monte Carlo of any lens as dask tasks on a local cluster of two processes (each evaluating the nominal lens
    for itself, at the process's torch threads per task): the file the run in this process writes, byte for byte."""
    pytest.importorskip("distributed")
    from lenssim_studies.tolerance import LensToleranceRun, run_tolerance

    p, seq = singlet
    run = LensToleranceRun(_provider(p, seq), SURFACE_GRADES["commercial"], 3, 5, SNR, 0.937, SMALL,
                           angles_deg=(0.0, 3.0), chunk_copies=1)
    here, there = tmp_path / "here.nc", tmp_path / "cluster.nc"
    run_tolerance(run, here, show_progress=False)
    ds = run_tolerance(run, there, show_progress=False, workers=2)
    assert there.read_bytes() == here.read_bytes()
    assert ds.sizes["lens"] == 3 and not (tmp_path / "cluster.nc.partial").exists()


def test_grades_take_the_singlets_decentres_and_tilts():
    for name, t in GRADES.items():
        s = SURFACE_GRADES[name]
        assert (s.surface_decentre_um, s.surface_tilt_arcmin, s.element_tilt_arcmin) == (
            t.asphere_decentre_um, t.asphere_tilt_arcmin, t.lens_tilt_arcmin)
    assert SURFACE_GRADES["commercial"].element_decentre_um == 25.0


def test_elements_are_runs_of_glass():
    cooke = read_lens("cooke_triplet")  # the stop (surface 5) in air between elements 2 and 3
    assert lens_elements(cooke) == ((0, 1), (2, 3), (5, 6)) and 4 not in lens_surfaces(cooke)
    gauss = read_lens("double_gauss")  # two cemented doublets: one element each
    assert lens_elements(gauss) == ((0, 1), (2, 4), (6, 8), (9, 10))


def test_copy_misalignments_compose_the_surface_and_element_motions():
    cooke = read_lens("cooke_triplet")
    only = SurfaceTolerances(surface_tilt_arcmin=3.0, element_decentre_um=25.0)
    pert = only.sample(cooke, 4, seed=3)
    m = copy_misalignments(cooke, pert, 2)
    assert set(m) == set(lens_surfaces(cooke))
    z = cooke.vertex_z_mm
    for e, (a, b) in enumerate(lens_elements(cooke)):
        dx, dy = (pert.element_decentre_mm[2, e] * 1.0).tolist()
        for k in range(a, b + 1):
            own, elem = m[k]
            assert own.pivot_z_mm is None and own.decentre_x_mm == 0 and own.tilt_deg > 0  # the surface's wedge
            assert (elem.decentre_x_mm, elem.decentre_y_mm, elem.pivot_z_mm) == (dx, dy, z[a]) and elem.tilt_deg == 0
    # the draws of the earlier terms are those of a run without the new ones (common random numbers)
    old = SurfaceTolerances(radius_pct=1.0).sample(cooke, 4, seed=3)
    new = replace(SURFACE_GRADES["commercial"], thickness_um=0.0, conic_pct=0.0, index=0.0, despace_um=0.0,
                  radius_pct=1.0).sample(cooke, 4, seed=3)
    assert torch.equal(old.radius_rel, new.radius_rel)


def test_a_singlet_decentred_with_its_stop_only_moves_the_image(singlet):
    """Lens and stop translated across a collimated beam: the image is translated by the same amount and nothing
    else changes, so every registered criterion is the nominal's; a tilt of the same lens is not a translation."""
    p, seq = singlet
    kw = dict(rho0=0.937, angles_deg=(0.0, 3.0), numerics=SMALL, criteria=("mse_s", "mse_r", "rms_w"))
    nominal = evaluate_sequential(_provider(p, seq), SNR, **kw)
    moved = SequentialLens(p, misalignments={0: Misalignment(decentre_x_mm=0.05, decentre_y_mm=-0.08),
                                             1: Misalignment(decentre_x_mm=0.05, decentre_y_mm=-0.08)})
    z = SequentialLens(p).wavefront(3.0, torch.zeros(1), torch.zeros(1)).chief_mm
    assert torch.allclose(moved.wavefront(3.0, torch.zeros(1), torch.zeros(1)).chief_mm,
                          z + torch.tensor([0.05, -0.08, 0.0], dtype=torch.float64), atol=1e-12)
    got = evaluate_sequential(_provider(p, moved), SNR, **kw)
    for k in ("mse_s", "mse_r", "rms_w"):
        assert torch.allclose(got[k], nominal[k], rtol=1e-7, atol=0), k
    tilted = SequentialLens(p, misalignments={0: Misalignment(tilt_x_deg=0.5), 1: Misalignment(tilt_x_deg=0.5,
                                                                                             pivot_z_mm=0.0)})
    off = evaluate_sequential(_provider(p, tilted), SNR, **kw)
    assert float(off["mse_s"][0]) > float(nominal["mse_s"][0]) * 1.01


def _full_plane_mse(psf_centered, m, rho0, sigma2, H_ref=None):
    """mse_s and mse_r_nominal by their definitions over the whole m x m DFT grid (no quarter-plane symmetry)."""
    from lenssim.optics.image_model import image_psd_quarter

    n = psf_centered.shape[-1]
    pad = torch.zeros(m, m, dtype=torch.float64)
    o = m // 2 - n // 2
    pad[o:o + n, o:o + n] = psf_centered
    H = torch.fft.fft2(torch.fft.ifftshift(pad))
    q = image_psd_quarter(m, rho0, dtype=torch.float64)
    k = torch.arange(m)
    fold = torch.minimum(k, m - k)
    P = q[fold[:, None], fold[None, :]]
    mse_s = sigma2 + ((1 - H).abs().square() * P).mean()
    G = H_ref.conj() * P / (H_ref.abs().square() * P + sigma2)
    mse_rn = ((1 - G * H).abs().square() * P + G.abs().square() * sigma2).mean()
    return float(mse_s), float(mse_rn)


def test_an_asymmetric_psf_is_scored_over_the_whole_frequency_plane():
    """A tilted back surface (a wedge) makes the PSF asymmetric about its meridian: evaluate_sequential's two
    quarters equal the definitions summed over the full DFT grid."""
    p = read_lens(LENS_FILE)
    wedge = SequentialLens(p, misalignments={1: Misalignment(tilt_x_deg=0.3, tilt_y_deg=0.4)})
    psf, ref = _provider(p, wedge), _provider(p, SequentialLens(p))
    snr = (27.6,)
    got = evaluate_sequential(psf, snr, rho0=0.937, angles_deg=(2.0,), numerics=SMALL, reference=ref,
                              criteria=("mse_s", "mse_r_nominal"))
    n = got["psf_grid_px"]
    m = n * SMALL.oversample
    a, phi = torch.tensor([2.0], dtype=torch.float64), torch.tensor([math.pi / 2], dtype=torch.float64)
    P = psf.psfs_at_angles(a, phi, n, n, distortion=False, complex_dtype=torch.complex128)[0, 0]
    assert not torch.allclose(P, P.flip(-1).roll(1, -1), atol=1e-4)  # not mirror-symmetric
    R = ref.psfs_at_angles(a, phi, n, n, distortion=False, complex_dtype=torch.complex128)[0, 0]
    pad = torch.zeros(m, m, dtype=torch.float64)
    o = m // 2 - n // 2
    pad[o:o + n, o:o + n] = R
    sigma2 = 10 ** (-27.6 / 10)
    mse_s, mse_rn = _full_plane_mse(P, m, 0.937, sigma2, torch.fft.fft2(torch.fft.ifftshift(pad)))
    assert float(got["mse_s"][0]) == pytest.approx(mse_s, rel=1e-10)
    assert float(got["mse_r_nominal"][0]) == pytest.approx(mse_rn, rel=1e-10)


def test_a_decentred_copy_is_averaged_over_four_azimuths(singlet):
    from lenssim.tolerancing import copy_criteria, nominal_criteria

    p, seq = singlet
    psf = _provider(p, seq)
    kw = dict(rho0=0.937, angles_deg=(0.0, 3.0), numerics=SMALL)
    nominal, _, _ = nominal_criteria(psf, SNR, **kw)
    pert = SurfaceTolerances(surface_tilt_arcmin=30.0).sample(p, 1, seed=0)
    row = copy_criteria(psf, nominal, pert, 0, SNR, **kw)
    lens = manufactured_lens(seq, pert, 0)
    assert not lens.is_centred
    each = [evaluate_sequential(copy_provider(psf, lens.rotated(a)), SNR, criteria=("mse_s", "mse_r_nominal"),
                                reference=nominal, **kw) for a in (0, 90, 180, 270)]
    assert torch.allclose(row["mse_s"], sum(e["mse_s"] for e in each) / 4, rtol=1e-12, atol=0)
    assert len({round(float(e["mse_s"][0]), 12) for e in each}) > 1  # the azimuths differ
    assert (row["mse_r_nominal"] >= row["mse_r"] * (1 - 1e-12)).all()
