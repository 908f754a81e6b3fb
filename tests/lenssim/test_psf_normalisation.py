"""PSF normalisation consistent with the metrics' OTF (issue 19, section 0).

The metrics divide the pupil's autocorrelation by the pupil area (``H(0) = 1``, the O(1/R^2)-accurate MTF). The
PSFs of the image pipeline are ``|DFT(field)|^2 / (area n^2)`` plus a uniform pedestal holding the light the
anti-aliased rim leaves out (``1 - c``, ``c = sum(amp^2) / sum(amp)``), so their DFT *is* the metrics' OTF. Before,
they were normalised to unit sum: their MTF was ``1 / c`` too high at every frequency (0.53% at n = 256, 0.26% at
n = 512) and blurred images differed from metric-consistent ones by 57-66 dB on the built-in scene. These tests fail
on that normalisation.
"""

from __future__ import annotations

import cmath
import dataclasses
import math

import pytest
import torch

from lenssim import DEFAULT_NUMERICS, LensPSF
from lenssim.model.tolerances import GRADES
from lenssim.optics.as_built import AS_BUILT_TERMS, as_built_coefficients
from lenssim.optics.psf_bank import (_radius, otf, otf_quarter_pair, otf_quarter_spectrum, pedestal_fraction, psf,
                                     spectral_coefficients)
from lenssim.optics.psf_provider import AsBuiltPSF
from lenssim.model.spectrum import Spectrum
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline.blur import WindowScheme, blur_windowed

D = torch.float64
E2E_DESIGN = PAPER_DESIGNS["end_to_end_paper"].to(D)


@pytest.mark.parametrize("n", [128, 256, 512])
def test_the_rim_loss_is_a_third_of_a_sample_over_the_radius(n):
    """Closed form: a straight edge crossing a unit sample with area fraction ``a`` uniform in [0, 1] loses
    ``integral a (1 - a) da = 1/6`` of a sample per unit length of rim, so ``1 - c = 2 pi R / 6 / (pi R^2) = 1/(3R)``
    (to the rim's curvature and the edge's angle: 4% at R = 32 samples, 1.4% at 128)."""
    R = _radius(PAPER_CAMERA, n, 0.5)
    assert pedestal_fraction(PAPER_CAMERA, n) == pytest.approx(1 / (3 * R), rel=0.05)


@pytest.mark.parametrize("n", [256, 512])
@pytest.mark.parametrize("angle", [0.0, 5.0, 14.0])
def test_the_psf_dft_is_the_metrics_otf(n, angle):
    """One wavelength and a three-wavelength spectrum (each wavelength its own pupil scale and rim loss): the DFT of
    the unit-sum PSF equals the area-normalised OTF, by the reference path and the metrics' quarter-plane path."""
    spectrum = Spectrum((0.5, 0.55, 0.6), (0.2, 0.5, 0.3), "three lines")
    for camera in (PAPER_CAMERA, dataclasses.replace(PAPER_CAMERA, spectrum=spectrum)):
        co = spectral_coefficients(camera, E2E_DESIGN, [angle])
        p = psf(camera, co, n, centered=False)[0]
        assert float(p.sum()) == pytest.approx(1.0, abs=1e-13)
        Hp = torch.fft.fft2(p)
        torch.testing.assert_close(Hp, otf(camera, co, n)[0], rtol=0, atol=1e-13)
        Hq = otf_quarter_spectrum(camera, co, n)[0]
        torch.testing.assert_close(Hp[: n // 2 + 1, : n // 2 + 1], Hq, rtol=0, atol=1e-13)


def test_an_as_built_psf_dft_is_the_metrics_non_symmetric_otf():
    """A decentred lens (no mirror symmetry): the PSF's DFT equals the two quarter planes of the metrics."""
    lens = GRADES["commercial"].sample(1, seed=3)
    co = as_built_coefficients(PAPER_CAMERA, E2E_DESIGN, lens, [7.0], [90.0])[:, 0]  # (1, K, 6), field along +y
    n = 256
    Hp = torch.fft.fft2(psf(PAPER_CAMERA, co, n, centered=False, terms=AS_BUILT_TERMS)[0])
    pair = otf_quarter_pair(PAPER_CAMERA, co, n, terms=AS_BUILT_TERMS)[0]  # (2, n/2+1, n/2+1): fx >= 0, fx <= 0
    h = n // 2
    torch.testing.assert_close(Hp[: h + 1, : h + 1], pair[0], rtol=0, atol=1e-12)
    neg = (-torch.arange(h + 1)) % n
    torch.testing.assert_close(Hp[: h + 1][:, neg], pair[1], rtol=0, atol=1e-12)
    assert float((pair[0] - pair[1]).abs().max()) > 1e-3  # not mirror-symmetric
    provider = AsBuiltPSF(PAPER_CAMERA, E2E_DESIGN, lens)
    assert provider.pedestal_fractions(512) == (pedestal_fraction(PAPER_CAMERA, 512),)


def _response(provider, center, k, axis, fit):
    """The windowed blur's response at pixel (512, 512) to ``exp(2 pi i k t / 512)`` along ``axis`` (0: rows): from
    a cosine and a sine image, divided by the phase at the pixel (the PSF's OTF there, if the blur is right)."""
    N = 1024
    ph = 2 * math.pi * k * torch.arange(N, dtype=D) / 512
    out = []
    for f in (torch.cos, torch.sin):
        v = f(ph)
        img = (v[:, None].expand(N, N) if axis == 0 else v[None, :].expand(N, N)).contiguous()[None, None]
        b = blur_windowed(img, provider, scheme=WindowScheme(fit=fit), optical_center=center,
                          region=(512, 513, 512, 513))
        out.append(float(b[0, 0, 512, 512]))
    return complex(out[0], out[1]) * cmath.exp(-2j * math.pi * k)


@pytest.mark.parametrize("rows_off_axis", [0, 32 * 88])  # on the axis and 10 deg off it, on a window's position
def test_the_windowed_blur_has_the_metrics_otf(rows_off_axis):
    """A sinusoid of ``k / 512`` cycles/pixel through the camera pipeline's blur, at a window's own position: its
    gain and phase are the metrics' OTF at that field angle, to rounding with 512 px windows, and to 1e-3 with
    windows fitted to the PSF (the PSF's far tail beyond the fitted window wraps; the pedestal is convolved over the
    full 512 px). The unit-sum PSF was 2.6e-3 off."""
    E2E = LensPSF(PAPER_CAMERA, E2E_DESIGN)
    g = PAPER_CAMERA.geometry
    alpha = float(g.field_angle_deg(torch.tensor(0.0, dtype=D), torch.tensor(rows_off_axis * g.pitch_mm, dtype=D)))
    H = otf(PAPER_CAMERA, spectral_coefficients(PAPER_CAMERA, E2E_DESIGN, [alpha]), 512)[0]  # field along +y (rows)
    center = (512.0 - rows_off_axis, 512.0)
    for k in (1, 3):
        for axis in (0, 1):
            want = complex(H[k, 0] if axis == 0 else H[0, k])
            assert abs(_response(E2E, center, k, axis, fit=False) - want) < 1e-12
            assert abs(_response(E2E, center, k, axis, fit=True) - want) < 1e-3


def test_the_pedestal_does_not_depend_on_the_design():
    """The rim loss is a property of the sampled pupil (wavelength, grid), not of the aberrations."""
    other = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["rms_w_paper"])
    assert other.pedestal_fractions(512) == LensPSF(PAPER_CAMERA, E2E_DESIGN).pedestal_fractions(512)
    assert DEFAULT_NUMERICS.supersample > 1
