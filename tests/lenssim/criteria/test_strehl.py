"""The Strehl ratio criterion against closed forms (defocus) and a quadrature (spherical aberration)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import integrate

from lenssim_studies.paper import PAPER_CAMERA
from lenssim.optics.aberrations import COEFFICIENT_NAMES
from lenssim.metrics import otf_criteria_bank
from lenssim_studies.paper import PAPER_RHO0


def _strehl(coeffs: dict, n: int = 256) -> float:
    c = torch.zeros(1, 1, len(COEFFICIENT_NAMES), dtype=torch.float64)
    for k, v in coeffs.items():
        c[0, 0, COEFFICIENT_NAMES.index(k)] = v
    out = otf_criteria_bank(PAPER_CAMERA, c, torch.tensor([n]), [27.6], criteria=("strehl",), rho0=PAPER_RHO0)
    return float(out["strehl"][0])


def test_an_aberration_free_lens_has_strehl_one():
    assert _strehl({}) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("w020", [0.1, 0.25, 0.5, 0.8])
def test_defocus_gives_the_closed_form_sinc_squared(w020):
    """W = W020 rho^2: the centre amplitude is int_0^1 exp(i 2 pi W020 u) du, so S = sinc^2(W020)."""
    closed = (math.sin(math.pi * w020) / (math.pi * w020)) ** 2
    assert _strehl({"W220": w020}) == pytest.approx(closed, abs=2e-3)


@pytest.mark.parametrize("w040", [0.1, 0.3])
def test_spherical_aberration_matches_a_quadrature_of_the_pupil(w040):
    """W = W040 rho^4 at the Gaussian focus: S = |int_0^1 exp(i 2 pi W040 u^2) du|^2 (u = rho^2)."""
    re = integrate.quad(lambda u: np.cos(2 * np.pi * w040 * u * u), 0, 1, epsabs=1e-13)[0]
    im = integrate.quad(lambda u: np.sin(2 * np.pi * w040 * u * u), 0, 1, epsabs=1e-13)[0]
    assert _strehl({"W040": w040}) == pytest.approx(re * re + im * im, abs=2e-3)


def test_the_strehl_ratio_does_not_depend_on_the_fft_size():
    """The sum rule holds for any sampling: 256 and 512 samples agree to the pupil's sampling error."""
    assert _strehl({"W040": 0.3, "W131": 0.2}, 256) == pytest.approx(_strehl({"W040": 0.3, "W131": 0.2}, 512), abs=2e-3)
