"""The MTF50 criterion against the diffraction-limited MTF's closed form and an interpolation check."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import optimize

from lenssim_studies.paper import PAPER_CAMERA
from lenssim.optics.aberrations import COEFFICIENT_NAMES
from lenssim.criteria.mtf50 import first_crossing
from lenssim.metrics import otf_criteria_bank
from lenssim_studies.paper import PAPER_RHO0


def _mtf50(coeffs: dict, n: int = 256) -> float:
    c = torch.zeros(1, 1, len(COEFFICIENT_NAMES), dtype=torch.float64)
    for k, v in coeffs.items():
        c[0, 0, COEFFICIENT_NAMES.index(k)] = v
    return float(otf_criteria_bank(PAPER_CAMERA, c, torch.tensor([n]), [27.6], criteria=("mtf50",), rho0=PAPER_RHO0)["mtf50"][0])


def test_an_aberration_free_lens_meets_the_closed_form():
    """MTF(nu) = (2/pi)(acos x - x sqrt(1 - x^2)), x = nu lambda N: 0.5 at x = 0.4040 (cycles/mm)."""
    lens = PAPER_CAMERA.lens
    f_number = lens.focal_length_mm / (2 * lens.pupil_radius_mm)
    cutoff = 1 / (PAPER_CAMERA.spectrum.wavelengths_um[0] * 1e-3 * f_number)  # 320 cycles/mm
    x = optimize.brentq(lambda x: 2 / math.pi * (math.acos(x) - x * math.sqrt(1 - x * x)) - 0.5, 0, 1, xtol=1e-14)
    assert _mtf50({}) == pytest.approx(x * cutoff, rel=5e-3)


def test_blur_lowers_it_and_the_nyquist_bounds_it():
    assert _mtf50({"W220": 0.5}) < _mtf50({"W220": 0.25}) < _mtf50({})
    nyquist = 1 / (2 * PAPER_CAMERA.sensor.pixel_pitch_um * 1e-3)
    assert _mtf50({}) < nyquist


def test_first_crossing_interpolates_and_caps():
    f = torch.linspace(0, 1, 11, dtype=torch.float64)
    lines = torch.stack([1 - f, torch.ones_like(f), torch.where(f < 0.35, torch.tensor(1.0, dtype=torch.float64), torch.tensor(0.2, dtype=torch.float64))])
    got = first_crossing(lines, f).numpy()
    # 1 - f crosses at 0.5; a flat MTF never does (capped at the last frequency); a step between 0.3 and 0.4
    np.testing.assert_allclose(got, [0.5, 1.0, 0.3 + 0.1 * (1 - 0.5) / (1 - 0.2)], rtol=1e-12)


def test_an_mtf50_beyond_nyquist_is_counted_there_and_said():
    """Not silently clamped: an MTF above 0.5 up to Nyquist gives the Nyquist frequency with a warning."""
    from lenssim.criteria import OTFContext
    from lenssim.criteria.mtf50 import mtf50
    from lenssim.validate import ModelValidityWarning

    H = torch.ones(1, 9, 9, dtype=torch.complex64)
    ctx = OTFContext(H, H.real.square(), H.real, H.real, H.real, torch.ones(1), 16, PAPER_CAMERA)
    with pytest.warns(ModelValidityWarning, match="stays above 0.5 up to the sensor's Nyquist"):
        v = mtf50(ctx)
    assert float(v[0]) == pytest.approx(1 / (2 * PAPER_CAMERA.sensor.pixel_pitch_um * 1e-3))
