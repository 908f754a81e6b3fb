"""Properties of every registered wavefront model (lenssim.optics.wavefront_models), never a frozen list of names."""

from __future__ import annotations

import pytest
import torch

from lenssim import Design, FAST_NUMERICS, LensPSF
from lenssim.criteria import lens_criteria
from lenssim.optics.wavefront_models import WAVEFRONT_MODELS, validate_wavefront_model
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0

E2E = Design(s=-0.775, Q_back=-2.4)


@pytest.mark.parametrize("name", list(WAVEFRONT_MODELS))
def test_every_model_gives_unit_sum_psfs_and_every_criterion(name):
    m = WAVEFRONT_MODELS[name]
    assert m.label and m.support_factor >= 1
    p = LensPSF(PAPER_CAMERA, E2E, wavefront=name)
    psfs = p.psf_at_pixels(torch.tensor([0.0, 300.0]), torch.tensor([0.0, 400.0]), (0.0, 0.0), 128)
    assert psfs.shape == (2, 128, 128) and bool(torch.isfinite(psfs).all())
    torch.testing.assert_close(psfs.sum(dim=(-2, -1)).double(), torch.ones(2, dtype=torch.float64), rtol=0, atol=1e-5)
    r = m.evaluate(PAPER_CAMERA, E2E, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    for k in lens_criteria():
        assert bool(torch.isfinite(r[k]).all()), k


def test_the_exact_model_takes_every_otf_criterion_from_the_exact_wavefront():
    from lenssim.metrics import exact_criteria

    third = WAVEFRONT_MODELS["third_order"].evaluate(PAPER_CAMERA, E2E, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    exact = WAVEFRONT_MODELS["exact"].evaluate(PAPER_CAMERA, E2E, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    ref = exact_criteria(PAPER_CAMERA, E2E, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    for k, c in lens_criteria().items():
        if c.from_otf is not None or k == "rms_w":  # RMS_W: the exact wavefront's too (a fit of its own: lstsq's
            # last bit varies between calls)
            torch.testing.assert_close(exact[k], ref[k].to(exact[k].dtype), rtol=0 if k != "rms_w" else 1e-12, atol=0)
            assert not torch.equal(exact[k], third[k])  # off axis the two wavefronts differ
        else:
            torch.testing.assert_close(exact[k], third[k], rtol=0, atol=0)


def test_unknown_models_and_unserved_cameras_are_refused():
    from lenssim.model.spectrum import channel_spectra

    with pytest.raises(ValueError, match="wavefront='fifth' is not allowed: one of third_order, exact"):
        validate_wavefront_model("fifth")
    colour = PAPER_CAMERA.__class__(PAPER_CAMERA.lens, PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum,
                                    channels=channel_spectra(per_channel=2))
    with pytest.raises(ValueError, match="one-wavelength camera"):
        LensPSF(colour, E2E, wavefront="exact")
