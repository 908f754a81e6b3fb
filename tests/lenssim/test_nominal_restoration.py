"""Restoration built for the nominal lens, applied to an as-built one: the ``mse_r_nominal`` criterion (issue 19,
item 2), against an explicit filter on the full frequency grid, a Monte Carlo of correlated random images, and the
matched filter it can never beat."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from lenssim import Camera, Design, Numerics, image_psd, noise_variance
from lenssim.model.tolerances import GRADES, Tolerances
from lenssim.optics.as_built import AS_BUILT_TERMS, as_built_coefficients
from lenssim.optics.psf_bank import _field, _intensity, _pupil_box_cached, _radius
from lenssim.tolerancing import as_built_criteria
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0

D = torch.float64
DESIGN = Design(s=-0.775, Q_back=-2.4)
CAM = Camera(dataclasses.replace(PAPER_CAMERA.lens, field_angles_deg=(8.0,)), PAPER_CAMERA.sensor,
             PAPER_CAMERA.spectrum)
NUM = Numerics(oversample=1)


def full_otf(coeffs: torch.Tensor, n: int) -> torch.Tensor:
    """The full-plane OTF of a (non-symmetric) wavefront, field along +y: fft2 of the PSF over the pupil area."""
    R = _radius(CAM, n, 0.5)
    field = _field(coeffs[None], R, None, NUM.supersample, D, None, AS_BUILT_TERMS)
    amp, _ = _pupil_box_cached(float(R), int(NUM.supersample))
    H = torch.fft.fft2(_intensity(field, n))[0] / (float(amp.sum()) * n * n)
    H[0, 0] = 1
    return H


@pytest.fixture(scope="module")
def lens():
    """One commercial-grade lens, seen at 8 degrees along +y (azimuth 90)."""
    p = GRADES["commercial"].sample(8, seed=11)[3]
    r = as_built_criteria(CAM, DESIGN, p, [21.6, 27.6], rho0=PAPER_RHO0, numerics=NUM, azimuths_deg=(90.0,),
                          dtype=D)
    c = as_built_coefficients(CAM, DESIGN, p, [8.0], [90.0])[0, 0, 0]
    c0 = as_built_coefficients(CAM, DESIGN, Tolerances().sample(1, seed=0), [8.0], [90.0])[0, 0, 0]
    return r, c, c0


def test_it_is_the_explicit_nominal_filter_on_the_full_grid(lens):
    r, c, c0 = lens
    n = int(r["fft_size"][0, 0])
    H, H0 = full_otf(c, n), full_otf(c0, n)
    P = image_psd(n, dtype=D, rho0=PAPER_RHO0)
    for j, s2 in enumerate(noise_variance([21.6, 27.6]).tolist()):
        G0 = H0.conj() * P / (H0.abs() ** 2 * P + s2)
        err = ((1 - G0 * H).abs() ** 2 * P + G0.abs() ** 2 * s2).mean()
        assert float(r["mse_r_nominal"][0, j]) == pytest.approx(float(err), rel=1e-9)
        G = H.conj() * P / (H.abs() ** 2 * P + s2)  # the matched (calibrated) filter
        matched = ((1 - G * H).abs() ** 2 * P + G.abs() ** 2 * s2).mean()
        assert float(r["mse_r"][0, j]) == pytest.approx(float(matched), rel=1e-9)
        assert float(err) > float(matched)


def test_it_matches_monte_carlo_images(lens):
    """Correlated random images blurred by the as-built OTF, noised, restored with the nominal lens's Wiener filter."""
    r, c, c0 = lens
    n, reps = int(r["fft_size"][0, 0]), 60
    H, H0 = full_otf(c, n), full_otf(c0, n)
    P = image_psd(n, dtype=D, rho0=PAPER_RHO0)
    s2 = float(noise_variance(27.6))
    g = torch.Generator().manual_seed(5)
    X = torch.fft.fft2(torch.randn(reps, n, n, generator=g, dtype=D)) * P.sqrt()
    W = torch.fft.fft2(torch.randn(reps, n, n, generator=g, dtype=D)) * math.sqrt(s2)
    G0 = H0.conj() * P / (H0.abs() ** 2 * P + s2)
    x, xr = torch.fft.ifft2(X).real, torch.fft.ifft2(G0 * (H * X + W)).real
    assert float(((xr - x) ** 2).mean()) == pytest.approx(float(r["mse_r_nominal"][0, 1]), rel=0.03)


def test_it_equals_the_matched_error_for_the_nominal_lens_and_is_never_below_it():
    nominal = as_built_criteria(CAM, DESIGN, Tolerances().sample(1, seed=0), [27.6], rho0=PAPER_RHO0, numerics=NUM,
                                dtype=D)
    assert float(nominal["mse_r_nominal"][0, 0]) == pytest.approx(float(nominal["mse_r"][0, 0]), rel=1e-12)
    r = as_built_criteria(CAM, DESIGN, GRADES["precision"].sample(10, seed=2), [21.6, 33.6], rho0=PAPER_RHO0,
                          numerics=NUM)
    assert bool((r["mse_r_nominal"] >= r["mse_r"] * (1 - 1e-6)).all())
    assert float((r["mse_r_nominal"] / r["mse_r"]).max()) > 1.01  # tolerances do cost something


def test_rotationally_symmetric_lenses_take_the_fast_path_with_the_same_result(monkeypatch):
    """Radius, conic, index and despace errors only: one azimuth and the mirror-symmetric bank, chosen
    automatically; the same criteria as the general path over four azimuths (float32 rounding)."""
    from lenssim.model import tolerances as T

    t = dataclasses.replace(GRADES["commercial"], asphere_decentre_um=0.0, asphere_tilt_arcmin=0.0,
                            lens_tilt_arcmin=0.0, figure_floor=0.0, figure_per_cost=0.0)
    p = t.sample(4, seed=2)
    assert p.rotationally_symmetric and not GRADES["commercial"].sample(4, seed=2).rotationally_symmetric
    cam = Camera(dataclasses.replace(CAM.lens, field_angles_deg=(0.0, 7.0, 14.0)), CAM.sensor, CAM.spectrum)
    fast = as_built_criteria(cam, DESIGN, p, [27.6], rho0=PAPER_RHO0, numerics=NUM)
    assert fast["alpha_deg"].numel() == 3
    monkeypatch.setattr(T.Perturbations, "rotationally_symmetric", property(lambda self: False))
    general = as_built_criteria(cam, DESIGN, p, [27.6], rho0=PAPER_RHO0, numerics=NUM)
    assert general["alpha_deg"].numel() == 9
    for k in ("mse_s", "mse_r", "mse_r_nominal", "strehl", "mtf50", "rms_w"):
        torch.testing.assert_close(fast[k], general[k], rtol=1e-5, atol=0)


def test_the_two_quarter_planes_are_the_lens_and_its_mirror_image():
    """For a mirror-symmetric wavefront both quarters are the fast symmetric bank's; for a non-symmetric one the
    second quarter, H(fy, -fx), is the first quarter of the wavefront mirrored in x (odd rho_t terms negated)."""
    from lenssim.optics.psf_bank import otf_quarter_pair, otf_quarter_spectrum

    c = as_built_coefficients(CAM, DESIGN, GRADES["commercial"].sample(2, seed=4), [8.0], [90.0])[:, 0]  # (2, K, 6)
    c0 = as_built_coefficients(CAM, DESIGN, Tolerances().sample(1, seed=0), [8.0], [90.0])[:, 0]
    n = 384
    pair0 = otf_quarter_pair(CAM, c0, n, oversample=2, terms=AS_BUILT_TERMS)
    fast = otf_quarter_spectrum(CAM, c0, n, oversample=2, terms=AS_BUILT_TERMS)
    torch.testing.assert_close(pair0[:, 0], fast, rtol=0, atol=1e-12)
    torch.testing.assert_close(pair0[:, 1], fast, rtol=0, atol=1e-12)
    odd = torch.tensor([1.0 if t.c % 2 == 0 else -1.0 for t in AS_BUILT_TERMS], dtype=D)
    pair, mirrored = otf_quarter_pair(CAM, c, n, terms=AS_BUILT_TERMS), otf_quarter_pair(CAM, c * odd, n,
                                                                                         terms=AS_BUILT_TERMS)
    torch.testing.assert_close(pair[:, 1], mirrored[:, 0], rtol=0, atol=1e-12)
    assert float((pair[:, 0] - pair[:, 1]).abs().max()) > 1e-3  # the lens is not mirror-symmetric
