"""PSF normalisation against the metrics' OTF (issue 19, section 0), measured: not yet consistent.

The metrics divide the pupil's autocorrelation by the pupil area (``H(0) = 1``, the O(1/R^2)-accurate MTF); the
PSFs of the image pipeline are normalised to unit sum. The two differ by exactly ``1 / c`` at every non-zero
frequency, ``c = sum(amp^2) / sum(amp)`` of the anti-aliased pupil (the light its smooth rim moves out of the grid:
0.53% at n = 256, 0.26% at n = 512). Blurring an image with the unit-sum PSF instead of the metric-consistent
``c p + (1 - c) / n^2`` changes it by 57-66 dB: below the pipeline's 70 dB standard, so simulated images are 0.3-0.5%
sharper at low frequency than the metrics assume. This test pins that measured state (docs/as-built.md says what a
fix would change); it fails if either side's normalisation changes.
"""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import DEFAULT_NUMERICS
from lenssim.optics.psf_bank import _pupil_box_cached, _radius, otf_quarter_spectrum, psf, spectral_coefficients
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS

D = torch.float64


@pytest.mark.parametrize("n, deficit", [(256, 0.0053078), (512, 0.0026412)])
def test_the_unit_sum_psf_is_sharper_than_the_metric_otf_by_exactly_one_over_c(n, deficit):
    R = _radius(PAPER_CAMERA, n, 0.5)
    amp, _ = _pupil_box_cached(float(R), DEFAULT_NUMERICS.supersample)
    c = float((amp**2).sum() / amp.sum())
    assert 1 - c == pytest.approx(deficit, rel=1e-4)
    co = spectral_coefficients(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"].to(D), [5.0])
    Hp = torch.fft.fft2(psf(PAPER_CAMERA, co, n, centered=False)[0])
    Hm = otf_quarter_spectrum(PAPER_CAMERA, co, n)[0]
    ratio = Hp[:4, :4] / Hm[:4, :4]
    torch.testing.assert_close(ratio[0, 1:].real, torch.full((3,), 1 / c, dtype=D), rtol=1e-9, atol=0)
    torch.testing.assert_close(ratio[1:, 0].real, torch.full((3,), 1 / c, dtype=D), rtol=1e-9, atol=0)
    # the built-in scene blurred both ways: they differ by (1 - c) (b - its mean), under 70 dB of the signal
    from pipeline.scene import resolution_scene

    img = resolution_scene(1024, 1024, geometry=PAPER_CAMERA.geometry)[0, 1, :n, :n].to(D)  # the built-in scene
    p = psf(PAPER_CAMERA, co, n, centered=False)[0]
    b1 = torch.fft.ifft2(torch.fft.fft2(img) * torch.fft.fft2(p)).real
    b2 = torch.fft.ifft2(torch.fft.fft2(img) * torch.fft.fft2(c * p + (1 - c) / n**2)).real
    db = 10 * math.log10(float((b1**2).mean() / ((b1 - b2) ** 2).mean()))
    assert 50 < db < 70
