"""The gradient route on real rays (issue 44, item 3): ``tradeoff --optimise CRITERION --wavefront exact``.

The exact route's coefficients are the real-ray OPD fitted on :data:`lenssim.optics.exact_wavefront.EXACT_TERMS`:
checked against the paper singlet's own exact route (:func:`lenssim.optics.exact_wavefront.opd`, its own pupil), its
gradient against central differences of the whole criterion on the Cooke triplet with four free parameters, and one
descent step lowering the criterion."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lenssim import DEFAULT_NUMERICS, Design
from lenssim.io.prescription_file import read_lens
from lenssim.design_opt import LensExactCriterion
from lenssim.model.lens_parameters import parameter_values, parse_parameter
from lenssim.optics.exact_wavefront import EXACT_TERMS, exact_wavefront_coefficients, lens_exact_coefficients
from lenssim.optics.sequential import SequentialLens
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0

NUM = DEFAULT_NUMERICS.replace(min_size=64, oversample=1)
NAMES = ("E1.bending", "E2.bending", "S6.conic", "focus_um")
SCALE = (0.05, 0.05, 0.2, 5.0)


def test_the_lens_fit_is_the_singlets_exact_wavefront_on_axis():
    """On axis both routes trace the same rays through the same pupil: the fits agree to 1e-9 wave (off axis the
    singlet's pupil is the plane at its vertex, the prescription's the curved stop surface: the pupil points differ
    by the sag times the field's tangent, 0.8% of the largest coefficient at 14 deg)."""
    seq = SequentialLens(read_lens("paper_singlet"))
    c = lens_exact_coefficients(seq, [0.0], [0.5])[0, 0]
    ref = exact_wavefront_coefficients(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), 0.0)
    assert c.shape == (len(EXACT_TERMS),)
    assert float((c - ref).abs().max()) < 1e-9 < float(ref.abs().max())


@pytest.fixture(scope="module")
def cooke():
    p = read_lens("cooke_triplet")
    p = dataclasses.replace(p, wavelengths_um=(p.primary_wavelength_um,), fields=(0.0, 4.0))
    pars = [parse_parameter(p, n, aspherize=(6,)) for n in NAMES]
    f = LensExactCriterion(p, pars, 27.6, "mse_r", rho0=PAPER_RHO0, pitch_um=1.0, angles_deg=p.fields, scale=SCALE,
                           hold=("efl",), numerics=NUM)
    x0 = torch.tensor([v if v == v else 0.0 for v in parameter_values(p, pars).values()], dtype=torch.float64)
    return f, x0


def test_the_exact_routes_gradient_is_the_criterions_central_differences(cooke):
    f, x0 = cooke
    x = x0.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(f(x), x)
    h = torch.tensor(SCALE, dtype=torch.float64) * 1e-3
    with torch.no_grad():
        fd = [float((f(x0 + h[i] * e) - f(x0 - h[i] * e)) / (2 * h[i])) for i, e in enumerate(torch.eye(4,
                                                                                         dtype=torch.float64))]
    assert g.tolist() == pytest.approx(fd, rel=2e-3)
    assert all(abs(v) > 0 for v in fd)  # every parameter moves the criterion


def test_a_step_against_the_gradient_lowers_the_real_ray_criterion(cooke):
    f, x0 = cooke
    x = x0.clone().requires_grad_(True)
    v0 = f(x)
    (g,) = torch.autograd.grad(v0, x)
    scale = torch.tensor(SCALE, dtype=torch.float64)
    step = -(g * scale**2) / float((g * scale).norm()) * 0.05  # 5% of a typical step, along -gradient (scaled)
    with torch.no_grad():
        assert float(f(x0 + step)) < float(v0)
