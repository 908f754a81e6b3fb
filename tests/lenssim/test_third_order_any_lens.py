"""The third-order route for any lens (lenssim.optics.seidel_wavefront, lenssim.metrics.evaluate_third_order; issue 30):
checked against the paper's closed-form thin-lens model, against real-ray wavefronts of a slow lens, and against a
numerical integration of the wavefront over the pupil."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch

from lenssim import Design
from lenssim.io.prescription_file import read_lens
from lenssim.metrics import evaluate, evaluate_third_order
from lenssim.model.numerics import FAST_NUMERICS
from lenssim.optics.aberrations import TERMS, rms_wavefront
from lenssim.optics.seidel_wavefront import SEIDEL_TERMS, equivalent_thin_lens, third_order_coefficients
from lenssim.optics.sequential import SequentialLens, pupil_grid
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0

SNR = [21.6, 27.6, 33.6]


def _singlet(s, q, shift_mm=0.0):
    """The paper's singlet at shape factor ``s`` and back conic ``q`` as a prescription (the shipped file re-bent)."""
    from lenssim.model.lens_parameters import apply_parameters, parse_parameter

    p = read_lens("paper_singlet")
    p, _ = apply_parameters(p, {parse_parameter(p, "E1.bending"): s, parse_parameter(p, "S2.conic"): q})
    return SequentialLens(p, image_shift_mm=shift_mm)


@pytest.mark.parametrize("s, q, shift_um", [(-0.775, -2.4, 0.0), (0.3, 0.5, 0.0), (-1.2, -6.0, 40.0)])
def test_the_paper_singlet_as_a_prescription_gives_the_papers_criteria(s, q, shift_um):
    """The paper's singlet read as a prescription, through its surfaces' Seidel sums, gives every criterion of the
    paper's closed-form thin-lens model (lenssim.metrics.evaluate) at its 15 field angles: the wavefront coefficients to
    1e-10 (focus shift included), the criteria to float32 rounding."""
    seq = _singlet(s, q, shift_um * 1e-3)
    lens = PAPER_CAMERA.lens
    d = Design(s=s, Q_back=q, focus_shift_um=shift_um)
    c = third_order_coefficients(seq, lens.field_angles_deg, [0.5])[:, 0]
    from lenssim.optics.aberrations import wavefront_coefficients

    ref_c = wavefront_coefficients(lens, d.to(torch.float64), wavelength_um=0.5)
    assert torch.allclose(c[:, :4], ref_c, rtol=1e-10, atol=1e-10) and bool((c[:, 4] == 0).all())
    ours = evaluate_third_order(seq, SNR, pitch_um=PAPER_CAMERA.sensor.pixel_pitch_um, rho0=PAPER_RHO0,
                                angles_deg=lens.field_angles_deg, numerics=FAST_NUMERICS)
    ref = evaluate(PAPER_CAMERA, d, SNR, rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    for name in ("mse_r", "mse_s", "strehl", "mtf50", "rms_w", "rms_w_piston_removed", "cost"):
        assert torch.as_tensor(ours[name]).tolist() == pytest.approx(torch.as_tensor(ref[name]).tolist(), rel=2e-6), name
    assert ours["fft_size"].tolist() == ref["fft_size"].reshape(-1).tolist()


def _third_order_residual(scale: float) -> float:
    """The largest over the wavelengths of the RMS difference between the real-ray OPD and the third-order wavefront,
    relative to the OPD's RMS, of the Cooke triplet stopped down to ``scale`` of its pupil at 16 ``scale`` deg."""
    from lenssim.optics.seidel_wavefront import _first_order

    p = read_lens("cooke_triplet")
    q = dataclasses.replace(p, entrance_pupil_diameter_mm=p.entrance_pupil_diameter_mm * scale)
    seq = SequentialLens(q)
    a = 16.0 * scale
    px, py = pupil_grid(16)
    lam0 = q.primary_wavelength_um
    c = third_order_coefficients(seq, [a], q.wavelengths_um)[0]  # (K, 5)
    # the primary wavelength's paraxial chief ray on the file's image plane: where W111 = 0 and W has no tilt
    y_ref = _first_order(seq, a, lam0)[2]
    r2, rr = px**2 + py**2, py  # rho_r points to the image point: +py in the tracer's pupil coordinates
    worst = 0.0
    for k, lam in enumerate(q.wavelengths_um):
        s5 = float(seq.seidel_surfaces(a, lam).sum(0)[4]) / (lam * 1e-3)
        w = seq.wavefront(a, px, py, lam, reference_mm=(0.0, y_ref), aim="paraxial")
        W = c[k, 0] * r2**2 + c[k, 1] * r2 * rr + c[k, 2] * rr**2 + c[k, 3] * r2 + c[k, 4] * rr + s5 / 2 * rr
        ok = ~torch.isnan(w.opd_waves)
        rms = float(w.opd_waves[ok].pow(2).mean().sqrt())
        err = float((w.opd_waves - W)[ok].pow(2).mean().sqrt())
        worst = max(worst, err / rms)
        if lam < lam0:  # the lateral-colour term matters: without it the blue wavefront is far off
            assert float((w.opd_waves - (W - c[k, 4] * rr))[ok].pow(2).mean().sqrt()) > 20 * err
    return worst


def test_a_slow_lens_third_order_wavefront_is_its_real_ray_wavefront():
    """The Cooke triplet stopped down (its entrance pupil x ``scale``) at a field of 16 ``scale`` deg: at each of its
    three wavelengths the real-ray OPD (traced, referred to the primary wavelength's paraxial image point on the
    file's image plane) equals the third-order wavefront (the Seidel terms, the defocus of the file's plane from each
    wavelength's focus, the lateral-colour tilt) plus the distortion's tilt ``S_V / 2``, to the higher-order residual:
    a few percent of the wavefront's RMS at a quarter of the pupil, and falling fast (at least 4x) when the aperture
    and field halve."""
    quarter, eighth = _third_order_residual(0.25), _third_order_residual(0.125)
    assert quarter < 0.04 and eighth < quarter / 4


def test_the_rms_of_five_terms_is_the_pupil_integral():
    """``rms_wavefront`` with the tilt term: the closed-form disc moments against a numerical integral over the unit
    disc (polar Gauss-Legendre in r, uniform in theta)."""
    coeffs = torch.tensor([[0.3, -1.2, 0.7, 0.4, 0.9], [0.0, 0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    import numpy as np

    x, wx = np.polynomial.legendre.leggauss(40)
    r = torch.tensor((x + 1) / 2)
    wr = torch.tensor(wx / 2) * r * 2  # the area element 2 r dr over [0, 1] (the disc's mean)
    th = torch.arange(64, dtype=torch.float64) * (2 * math.pi / 64)
    R, T = torch.meshgrid(r, th, indexing="ij")
    rho_r, r2 = R * torch.cos(T), R**2
    for c in coeffs:
        W = sum(ci * t(r2, rho_r) for ci, t in zip(c, SEIDEL_TERMS))
        m2 = float((W**2 * wr[:, None]).sum() / 64)
        m1 = float((W * wr[:, None]).sum() / 64)
        assert float(rms_wavefront(c, terms=SEIDEL_TERMS)) == pytest.approx(math.sqrt(m2), rel=1e-12)
        assert float(rms_wavefront(c, True, terms=SEIDEL_TERMS)) == pytest.approx(math.sqrt(m2 - m1**2), rel=1e-12)
    assert float(rms_wavefront(coeffs[0, :4])) == float(rms_wavefront(coeffs[0, :4], terms=TERMS))
    with pytest.raises(ValueError):  # the default table takes four terms
        rms_wavefront(coeffs[1])


def test_the_equivalent_lens_holds_the_working_f_number():
    """The camera's thin lens has the image-space working F-number of the prescription (the PSF's scale)."""
    seq = SequentialLens(read_lens("cooke_triplet"))
    lens = equivalent_thin_lens(seq, (0.0, 5.0))
    assert lens.f_number == pytest.approx(seq.paraxial().working_f_number, rel=1e-12)
    assert lens.pupil_radius_mm == pytest.approx(seq.prescription.entrance_pupil_diameter_mm / 2, rel=1e-15)


def test_tradeoff_third_order_finds_the_papers_end_to_end_design(tmp_path, capsys):
    """``lenssim tradeoff --wavefront third_order`` on the paper's singlet, a 3 x 3 grid about the paper's end-to-end
    design: the MSE_R optimum at 27.6 dB is the one today's sweep finds (s = -0.75, Q = -2.5,
    docs/reproduction.md), its value that of the paper's model at that design."""
    from lenssim_cli.main import main

    out = tmp_path / "t"
    assert main(["tradeoff", "--lens", "paper_singlet", "--vary", "E1.bending=-0.775:-0.725:0.025", "--vary",
                 "S2.conic=-2.6:-2.4:0.1", "--wavefront", "third_order", "--snr", "27.6", "--levels", "3", "--quiet",
                 "--out", str(out)]) == 0
    res = json.loads((out / "tradeoff.json").read_text())
    best = res["unconstrained"]["mse_r"]
    assert best["design"] == pytest.approx({"E1.bending": -0.75, "S2.conic": -2.5})
    ref = evaluate(PAPER_CAMERA, Design(s=-0.75, Q_back=-2.5), [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    assert best["value"] == pytest.approx(float(ref["mse_r"][0]), rel=2e-6)
    assert res["wavefront"] == "third_order" and len(res["angles_deg"]) == 15 and res["sampling"] == "point"


def test_tradeoff_third_order_refuses_a_parameter_third_order_does_not_see(tmp_path, capsys):
    from lenssim_cli.main import main

    assert main(["tradeoff", "--lens", "paper_singlet", "--aspherize", "S2", "--vary", "S2.A6=-1e-6,0",
                 "--wavefront", "third_order", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert "S2.A6 does not enter the third-order wavefront" in err and "Traceback" not in err
    assert not (tmp_path / "t").exists()
