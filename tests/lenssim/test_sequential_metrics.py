"""The paper's criteria for any lens (lenssim.metrics.evaluate_sequential), checked against closed forms and against today's
exact (ray-traced) criteria of the thin singlet."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from lenssim import Design
from lenssim.model.prescription import Prescription
from lenssim.model.prescription import PrescriptionSurface as S
from lenssim.model.sensor import Sensor
from lenssim.model.spectrum import Spectrum
from lenssim.optics.image_model import image_psd, noise_variance
from lenssim.optics.sequential import SequentialLens
from lenssim.optics.psf_provider import SequentialPSF
from lenssim.metrics import evaluate_sequential, evaluation_angles

LAM = 0.55
N_GLASS = 1.5
RHO0 = 0.97


def _perfect(f=50.0, epd=5.0, shift_mm=0.0):
    """A plano-hyperbolic singlet (flat side to the object, back conic -n^2): no aberration on axis (Cartesian oval)."""
    p = Prescription((S(0.0, 3.0, (N_GLASS, 0.0)), S(-1 / ((N_GLASS - 1) * f), f, "air", conic=-N_GLASS**2)), 1, epd,
                     fields=(0.0, 0.5), wavelengths_um=(LAM,), primary_wavelength_um=LAM)
    return SequentialLens(p, image_shift_mm=shift_mm)


def _provider(seq, pitch_um, sampling="point", max_field_deg=None):
    return SequentialPSF(seq, Sensor(pixel_pitch_um=pitch_um, width_px=1000, height_px=1000),
                         Spectrum.monochromatic(LAM), sampling=sampling, max_field_deg=max_field_deg)


def _circular_otf(x):
    x = x.clamp(max=1.0)
    return 2 / math.pi * (torch.acos(x) - x * torch.sqrt(1 - x**2))


def test_a_perfect_lens_gives_the_closed_form_criteria():
    """Point samples at the Nyquist pitch lambda N / 2: the pixel OTF is the circular pupil's OTF (cut-off at 1/2
    cycle per pixel, nothing aliases), so MSE_S, MSE_R and MTF50 follow from it in closed form; Strehl 1, RMS_W 0."""
    seq = _perfect()
    N = seq.paraxial().working_f_number
    prov = _provider(seq, LAM * N / 2)
    snr = [21.6, 33.6]
    r = evaluate_sequential(prov, snr, rho0=RHO0, angles_deg=[0.0])
    n = r["psf_grid_px"]
    m = 2 * n  # DEFAULT_NUMERICS.oversample
    k = torch.fft.fftfreq(m, dtype=torch.float64)
    H = _circular_otf(torch.hypot(k[:, None], k[None, :]) / 0.5)
    P = image_psd(m, RHO0, dtype=torch.float64)
    s2 = noise_variance(snr).to(torch.float64)
    mse_r = torch.stack([(v * P / (H**2 * P + v)).mean() for v in s2])
    mse_s = torch.stack([v + ((1 - H) ** 2 * P).mean() for v in s2])
    assert r["mse_r"].tolist() == pytest.approx(mse_r.tolist(), rel=0.01)
    assert r["mse_s"].tolist() == pytest.approx(mse_s.tolist(), rel=0.01)
    # the circular pupil's MTF is 0.5 at 0.4040 of the cut-off 1 / (lambda N) (cycles/mm)
    assert float(r["mtf50"]) == pytest.approx(0.4040 / (LAM * 1e-3 * N), rel=0.01)
    assert float(r["strehl"]) == pytest.approx(1.0, abs=1e-9)
    assert float(r["rms_w"]) < 1e-5


def test_defocus_gives_the_closed_form_rms_wavefront():
    """A perfect lens (focus f) with its image plane moved by dz: the reference sphere's radius is f + dz, the wave's
    f, so W = W20 rho^2 with W20 = (h^2 / 2) (1/f - 1/(f + dz)) (h the pupil's radius; small aperture); the RMS over
    the pupil is W20 / sqrt(3) referred to the chief ray (no piston removal), W20 / sqrt(12) about the mean."""
    f, epd, dz = 50.0, 2.5, 1.0  # mm, F/20
    seq = _perfect(f=f, epd=epd, shift_mm=dz)
    N = seq.paraxial().working_f_number
    w20 = (epd / 2) ** 2 / 2 * (1 / f - 1 / (f + dz)) / (LAM * 1e-3)  # waves
    assert w20 > 0.5  # a real defocus: the check is not empty
    r = evaluate_sequential(_provider(seq, LAM * N / 2), [27.6], rho0=RHO0, angles_deg=[0.0], criteria=["rms_w"])
    assert float(r["rms_w"]) == pytest.approx(w20 / math.sqrt(3), rel=0.01)
    assert float(r["rms_w_piston_removed"]) == pytest.approx(w20 / math.sqrt(12), rel=0.01)


@pytest.fixture(scope="module")
def singlet_pair():
    from lenssim_studies.paper import PAPER_CAMERA

    angles = (0.0, 7.0, 13.0)
    cam = dataclasses.replace(PAPER_CAMERA, lens=dataclasses.replace(PAPER_CAMERA.lens, field_angles_deg=angles))
    lens = cam.lens
    d = Design(s=-0.775, Q_back=-2.4).to(torch.float64)
    s1, s2 = lens.surfaces(d)
    lam = cam.spectrum.wavelengths_um[0]
    p = Prescription((S(float(s1.curvature), 0.0, (lens.refractive_index, 0.0)),
                      S(float(s2.curvature), lens.image_distance_mm, "air", conic=float(s2.conic))), 1,
                     2 * lens.pupil_radius_mm, fields=angles, wavelengths_um=(lam,), primary_wavelength_um=lam)
    seq = SequentialPSF(SequentialLens(p), cam.sensor, cam.spectrum, sampling="point")
    return cam, d, seq, angles


def test_the_singlet_as_a_prescription_gives_todays_exact_criteria(singlet_pair):
    """The thin singlet read as a prescription, about the paraxial image point as today's model: every OTF criterion
    per field angle equals today's exact (ray-traced) criteria (:func:`lenssim.metrics.exact_criteria`: the OPD fitted
    by polynomials on an anti-aliased circular pupil; ours interpolated from a traced table on the FFT's samples)."""
    from lenssim.metrics import exact_criteria
    from lenssim_studies.paper import PAPER_RHO0

    cam, d, seq, angles = singlet_pair
    snr = [21.6, 33.6]
    ref = exact_criteria(cam, d, snr, rho0=PAPER_RHO0)
    ours = evaluate_sequential(seq, snr, rho0=PAPER_RHO0, angles_deg=angles, registered=False)
    assert ours["mse_r_alpha"][-1, 0] > 2 * ours["mse_r_alpha"][0, 0]  # the field matters: the check is not empty
    for name, rel in (("mse_r", 0.02), ("mse_s", 0.02), ("mtf50", 0.03), ("strehl", 0.03)):
        a, b = ours[f"{name}_alpha"], ref[f"{name}_alpha"]
        assert a.reshape(-1).tolist() == pytest.approx(b.reshape(-1).tolist(), rel=rel, abs=1e-3), name


def test_registering_the_image_removes_only_the_shift():
    """About the chief ray's point, the shift-invariant criteria (MSE_R, MTF50) are unchanged and MSE_S (which scores
    a shifted image as error) falls; the RMS wavefront loses the distortion's tilt (the Cooke triplet at 10 deg: its
    distortion moves the image by several pixels)."""
    from lenssim.io.prescription_file import read_lens

    seq = SequentialLens(read_lens("cooke_triplet"))
    prov = _provider(seq, 6.0, sampling="area", max_field_deg=10.0)
    assert abs(float(prov.table().distortion_at(torch.tensor([10.0], dtype=torch.float64)))) * 1e3 > 2 * 6.0
    a = evaluate_sequential(prov, [27.6], rho0=RHO0, angles_deg=[10.0], registered=False)
    b = evaluate_sequential(prov, [27.6], rho0=RHO0, angles_deg=[10.0])
    # a sub-pixel shift changes what the pixels alias, a little
    assert float(b["mse_r"]) == pytest.approx(float(a["mse_r"]), rel=0.005)
    assert float(b["mtf50"]) == pytest.approx(float(a["mtf50"]), rel=0.005)
    assert float(b["mse_s"]) < 0.9 * float(a["mse_s"])
    assert float(b["rms_w"]) < float(a["rms_w"])
    assert float(b["rms_w_piston_removed"]) < float(a["rms_w_piston_removed"])
    assert float(b["strehl"]) > float(a["strehl"])


def test_evaluation_angles_and_refusals():
    assert evaluation_angles(14.0) == tuple(float(v) for v in range(15))
    assert evaluation_angles(0.0) == (0.0,)
    prov = _provider(_perfect(), 2.0, sampling="area", max_field_deg=0.5)
    with pytest.raises(ValueError, match="field angle 3 deg is not allowed"):
        evaluate_sequential(prov, [27.6], rho0=RHO0, angles_deg=[3.0])
