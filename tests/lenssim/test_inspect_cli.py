"""``lenssim inspect LENS`` (issue 29): the JSON keys the issue names, their meaning checked against the library,
refusals in one line."""

from __future__ import annotations

import json
import math

import pytest

from lenssim.io.prescription_file import read_lens
from lenssim.optics.sequential import SequentialLens
from lenssim_cli.main import main


def test_inspect_json_has_the_issues_keys_and_they_mean_what_they_say(capsys):
    assert main(["inspect", "cooke_triplet", "--json", "--angles", "0", "10"]) == 0
    rep = json.loads(capsys.readouterr().out)
    for key in ("efl_mm", "bfl_mm", "epd_mm", "f_number", "field_angles_deg", "rms_opd_waves", "pv_opd_waves",
                "rms_spot_um", "strehl", "mtf_sagittal", "mtf_tangential"):
        assert key in rep, key
    par = SequentialLens(read_lens("cooke_triplet")).paraxial()
    assert rep["efl_mm"] == pytest.approx(par.efl_mm) and rep["f_number"] == pytest.approx(par.efl_mm / rep["epd_mm"])
    assert rep["field_angles_deg"] == [0.0, 10.0] and len(rep["rms_opd_waves"]) == 2
    assert all(math.isfinite(v) and v >= 0 for v in rep["rms_opd_waves"] + rep["rms_spot_um"])
    assert all(p >= r for p, r in zip(rep["pv_opd_waves"], rep["rms_opd_waves"]))


def test_refocusing_at_the_best_focus_lowers_the_mean_wavefront_error(capsys):
    main(["inspect", "cooke_triplet", "--json", "--angles", "0"])
    at_file = json.loads(capsys.readouterr().out)
    main(["inspect", "cooke_triplet", "--json", "--angles", "0", "--refocus", "best"])
    best = json.loads(capsys.readouterr().out)
    assert best["rms_opd_waves"][0] < 0.8 * at_file["rms_opd_waves"][0]
    assert best["image_shift_mm"] != 0


def test_inspect_prints_the_surfaces_numbered_as_in_the_file(capsys):
    assert main(["inspect", "aspheric_singlet"]) == 0
    out = capsys.readouterr().out
    assert "1 (stop)" in out and "EFL" in out and "RMS OPD waves" in out


@pytest.mark.parametrize("argv, match", [
    (["inspect", "no_such_lens"], "no_such_lens"),
    (["inspect", "cooke_triplet", "--angles", "95"], "fields: 95 is not allowed"),
    (["inspect", "cooke_triplet", "--mtf", "0"], "--mtf 0 is not allowed"),
])
def test_inspect_refuses_in_one_line(capsys, argv, match):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err


def test_inspect_refuses_a_lens_whose_axial_beam_is_totally_reflected(tmp_path, capsys):
    path = tmp_path / "tir.toml"
    path.write_text('stop_surface = 1\n[aperture]\nentrance_pupil_diameter_mm = 5.0\n[object]\ndistance_mm = "inf"\n'
                    '[fields]\nangles_deg = [0.0]\n[wavelengths]\num = [0.55]\nprimary_um = 0.55\n'
                    '[[surfaces]]\ncurvature_per_mm = 0.0\nthickness_mm = 3.0\nmaterial = [1.5, 0.0]\n'
                    '[[surfaces]]\nradius_mm = -3.0\nthickness_mm = 20.0\nmaterial = "air"\n')
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert "surface 2: the axial beam's rim" in err and "totally internally reflected" in err
    assert len(err.strip().splitlines()) == 1


def test_inspect_reports_the_cost_of_every_asphere(capsys):
    """The paper's singlet as a prescription: its back conic costs today's C_a (lenssim.optics.cost)."""
    from lenssim import Design, slope_departure_cost
    from lenssim_studies.paper import PAPER_LENS

    assert main(["inspect", "paper_singlet", "--json", "--angles", "0"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert list(rep["asphere_cost"]) == ["2"]
    assert rep["cost"] == pytest.approx(float(slope_departure_cost(PAPER_LENS, Design(s=-0.775, Q_back=-2.4))),
                                        rel=1e-12)


def test_the_any_lens_gallery_example_writes_its_page(tmp_path):
    """examples/any_lens_gallery.py on the tests' small singlet: its figures table, its mosaic and the PSNR table."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).parents[2]
    lens = root / "tests" / "data" / "lenses" / "test_singlet.toml"
    r = subprocess.run([sys.executable, str(root / "examples" / "any_lens_gallery.py"), "--lenses", str(lens), "--out",
                        str(tmp_path / "g")], capture_output=True, text=True, timeout=900, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    md = (tmp_path / "g" / "gallery.md").read_text()
    assert "| field (deg) | RMS OPD (waves)" in md and "## PSNR (dB)" in md
    table = md[md.index("## PSNR (dB)"):]
    assert table.count("\n|") >= 4  # header, rule, and a row per lens and ISO beside the paper's design
    assert (tmp_path / "g" / "test_singlet" / "lens_mosaic.png").stat().st_size > 0


def _singlet(tmp_path, back_curvature=None, image_mm=None):
    """The paper's singlet as a file, with its back curvature (1/mm) or its image distance (mm) changed."""
    from dataclasses import replace

    from lenssim.io.prescription_file import write_prescription_toml

    p = read_lens("paper_singlet")
    s = list(p.surfaces)
    if back_curvature is not None:
        s[1] = replace(s[1], curvature_per_mm=back_curvature)
    if image_mm is not None:
        s[1] = replace(s[1], thickness_mm=image_mm)
    path = tmp_path / "singlet.toml"
    write_prescription_toml(replace(p, surfaces=tuple(s)), path)
    return path


def test_a_blur_the_psf_grid_cannot_hold_prints_no_strehl_or_mtf_and_says_why(tmp_path, capsys):
    """Issue 43: a lens ~21 mm out of focus (RMS OPD ~150 waves, a blur of millimetres) printed MTFs of 0.84 / 0.53 /
    0.22: its pupil phase jumps by hundreds of waves between samples, so the sampled PSF wraps round its grid. The ray
    figures stay (exact); the Strehl ratio and the MTF are refused, marked, with the reason."""
    lens = _singlet(tmp_path, back_curvature=-0.4878)
    assert main(["inspect", str(lens), "--json", "--angles", "0", "5"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["strehl"] == [None, None] and rep["mtf_sagittal"] == [[None] * 3] * 2
    assert all("waves between neighbouring samples" in why for why in rep["psf_not_sampled"])
    assert all(v > 100 for v in rep["rms_opd_waves"]) and all(v > 1000 for v in rep["rms_spot_um"])
    assert main(["inspect", str(lens), "--angles", "0"]) == 0
    out = capsys.readouterr().out
    assert "n/a *" in out and "* field 0 deg: the wavefront changes by up to" in out


def test_the_mtf_of_a_defocused_lens_matches_a_brute_force_pupil_autocorrelation(tmp_path):
    """The paper's singlet 1.5 mm behind its focus (W020 ~ 9.6 waves): on the default 64 x 64 pupil grid its phase
    steps by more than half a wave between samples, so the report refines the grid. Its MTF is checked against the
    OTF as the overlap integral of the pupil function with itself shifted, summed directly on a 512 x 512 grid of
    the traced wavefront (no FFT); on the 64 grid (the old route) the MTF is far off."""
    import torch

    from lenssim.optics.lens_report import _pupil_phase, field_quality

    seq = SequentialLens(read_lens(str(_singlet(tmp_path, image_mm=26.5))))
    lam = seq.primary_wavelength_um
    cutoff = 1 / (lam * 1e-3 * seq.paraxial(lam).working_f_number)
    G = 512
    shifts = (4, 12, 20)  # pupil samples of the 512 grid (half samples of the 64 grid): frequencies shift / G of the cutoff
    freqs = [k / G * cutoff for k in shifts]
    _, _, _, step64 = _pupil_phase(seq, 0.0, lam, 64)
    assert step64 > 0.5
    fq = field_quality(seq, 0.0, freqs)
    assert fq["pupil_grid"] > 64 and fq["psf_not_sampled"] is None

    def direct(grid, ks):  # |sum P(x) P*(x - k)| / sum |P|^2 along x (sagittal), shifts of k samples of the grid
        _, amp, phase, _ = _pupil_phase(seq, 0.0, lam, grid)
        P = amp * torch.exp(2j * math.pi * phase)
        return [1.0 if k == 0 else float((P[:, k:] * P[:, :-k].conj()).sum().abs() / (amp**2).sum()) for k in ks]

    ref = direct(G, shifts)
    assert fq["mtf_sagittal"] == pytest.approx(ref, abs=0.01)
    # the 64 grid (the old route): its MTF samples lie 5 c/mm apart, coarser than the blur's ~4 c/mm scale, and
    # interpolating between them is far off
    at = direct(64, range(4))
    old = [(at[k // 8] + at[k // 8 + 1]) / 2 for k in shifts]
    assert max(abs(a - b) for a, b in zip(old, ref)) > 0.05
