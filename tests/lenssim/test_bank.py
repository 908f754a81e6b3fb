"""PSF and OTF banks carry their sampling: the frequency axes against closed forms."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import Design, FunctionPSF, LensPSF
from lenssim.optics.bank import PSFBank
from lenssim_studies.paper import PAPER_CAMERA


def test_the_otf_axes_of_a_gaussian_psf_meet_its_closed_form():
    """A Gaussian PSF of sigma px sampled on the pixel grid has the OTF sum_k exp(-2 pi^2 sigma^2 (f + k)^2) at f
    cycles/pixel (the continuous transform, periodised by the sampling: Poisson summation)."""
    n, sigma = 64, 1.7

    def gauss(x_mm, y_mm, m):
        k = torch.arange(m, dtype=torch.float64) - m // 2
        g = torch.exp(-(k[:, None] ** 2 + k[None, :] ** 2) / (2 * sigma**2))
        return (g / g.sum()).expand(len(x_mm), m, m)

    bank = FunctionPSF(gauss, PAPER_CAMERA.geometry).bank(torch.tensor([0.0]), torch.tensor([0.0]), (0.0, 0.0), n)
    otf = bank.otf()
    f = otf.freq_cycles_per_pixel
    closed = sum(torch.exp(-2 * math.pi**2 * sigma**2 * (f + k) ** 2) for k in range(-3, 4))
    torch.testing.assert_close(otf.otf[0, 0, :].real, closed, rtol=0, atol=1e-12)
    assert otf.freq_cycles_per_mm[1] == pytest.approx(1 / (n * 1.5625e-3)) and otf.nyquist_cycles_per_mm == pytest.approx(320.0)
    assert bank.coords_mm()[n // 2] == 0 and bank.coords_mm()[n // 2 + 1] == pytest.approx(1.5625e-3)


def test_the_lens_bank_carries_the_camera_s_pitch_and_spectrum_and_its_mtf_ends_at_the_cutoff():
    """On axis the end-to-end design is nearly diffraction-limited: its MTF vanishes beyond the optical cut-off
    1 / (lambda N) = 320 cycles/mm, which is the sensor's Nyquist frequency here."""
    p = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))
    bank = p.bank(torch.tensor([0.0]), torch.tensor([0.0]), (0.0, 0.0), 256)
    assert bank.pixel_pitch_um == 1.5625 and bank.wavelengths_um == (0.5,) and bank.weights == (1.0,)
    otf = bank.otf()
    assert float(otf.mtf()[0, 0, 0]) == pytest.approx(1.0, abs=1e-9)
    f = otf.freq_cycles_per_mm
    half = float(otf.mtf()[0, 0, (f.abs() > 0.5 * 320)].max())
    assert 0.05 < half < 0.5  # half the cut-off: a diffraction-limited MTF is 0.39 there
    with pytest.raises(ValueError, match="expected"):
        PSFBank(torch.zeros(4, 4), 1.0)
