"""Properties every registered criterion has (never a frozen list of names): a new criterion file in
lenssim/criteria/ is checked here without a change to this file."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import CRITERIA, Design, FAST_NUMERICS, evaluate

from lenssim_studies.paper import PAPER_CAMERA
from lenssim.criteria import ROLES, SENSES, Criterion, lens_criteria, register
from lenssim_studies.paper import PAPER_RHO0

DESIGNS = Design(s=torch.tensor([-0.775, -0.2]), Q_back=torch.tensor([-2.4, -6.0]))


@pytest.fixture(scope="module")
def result():
    return evaluate(PAPER_CAMERA, DESIGNS, [21.6, 27.6], numerics=FAST_NUMERICS, rho0=PAPER_RHO0)


@pytest.mark.parametrize("name", list(lens_criteria()))
def test_every_criterion_is_finite_with_its_declared_shape_sense_and_role(result, name):
    c = CRITERIA[name]
    assert c.sense in SENSES and c.role in ROLES and c.units and c.label and c.description
    assert (c.from_otf is None) != (c.from_design is None)
    v = result[name]
    assert v.dtype == torch.float64 and v.shape == ((2, 2) if c.per_snr else (2,))
    assert bool(torch.isfinite(v).all())
    if c.from_otf is not None:  # the field average of the per-field values
        per_field = result[f"{name}_alpha"]
        assert per_field.shape == ((2, 15, 2) if c.per_snr else (2, 15))
        torch.testing.assert_close(per_field.mean(dim=1), v, rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", [k for k, c in lens_criteria().items() if c.role == "quality" and c.from_otf is not None])
def test_every_otf_quality_criterion_prefers_the_sharper_lens(name):
    """The paper's end-to-end design at 0 deg against the same lens at 10 deg (far more aberrated): every
    OTF quality criterion, read by its sense, prefers the axis."""
    c = CRITERIA[name]
    r = evaluate(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), [27.6], numerics=FAST_NUMERICS, rho0=PAPER_RHO0)
    axis, off = r[f"{name}_alpha"][0], r[f"{name}_alpha"][10]
    assert bool((c.sign * (off - axis) > 0).all())


def test_a_criterion_declares_one_way_of_computing_and_a_valid_sense_and_role():
    f = lambda ctx: ctx.H.real.mean(dim=(-2, -1))  # noqa: E731
    with pytest.raises(ValueError, match="exactly one of"):
        Criterion("x", "X", "x", "1", False)
    with pytest.raises(ValueError, match="sense='best'"):
        Criterion("x", "X", "x", "1", False, from_otf=f, sense="best")
    with pytest.raises(ValueError, match="role='price'"):
        Criterion("x", "X", "x", "1", False, from_otf=f, role="price")
    with pytest.raises(ValueError, match="registered already"):
        register(CRITERIA["mse_r"])
    assert CRITERIA["strehl"].sign == -1.0 and CRITERIA["mse_r"].sign == 1.0 and not math.isnan(CRITERIA["cost"].sign)


@pytest.mark.parametrize("name", [k for k, c in CRITERIA.items() if c.needs_reference])
def test_every_reference_criterion_is_finite_with_its_declared_shape_in_the_as_built_evaluation(name):
    """A criterion that compares a lens with a reference (the nominal lens) is computed by the as-built evaluation;
    for lenses equal to the nominal one it is finite, has its declared shape, and prefers the axis as the others."""
    import dataclasses

    from lenssim import Camera
    from lenssim.model.tolerances import Tolerances
    from lenssim.tolerancing import as_built_criteria

    c = CRITERIA[name]
    assert c.sense in SENSES and c.role in ROLES and c.from_otf is not None
    cam = Camera(dataclasses.replace(PAPER_CAMERA.lens, field_angles_deg=(0.0, 10.0)), PAPER_CAMERA.sensor,
                 PAPER_CAMERA.spectrum)
    r = as_built_criteria(cam, Design(s=-0.775, Q_back=-2.4), Tolerances().sample(2, seed=0), [21.6, 27.6],
                          numerics=FAST_NUMERICS, rho0=PAPER_RHO0)
    v = r[name]
    assert v.dtype == torch.float64 and v.shape == ((2, 2) if c.per_snr else (2,)) and bool(torch.isfinite(v).all())
    axis = as_built_criteria(dataclasses.replace(cam, lens=dataclasses.replace(cam.lens, field_angles_deg=(0.0,))),
                             Design(s=-0.775, Q_back=-2.4), Tolerances().sample(1, seed=0), [27.6],
                             numerics=FAST_NUMERICS, rho0=PAPER_RHO0)[name]
    off = as_built_criteria(dataclasses.replace(cam, lens=dataclasses.replace(cam.lens, field_angles_deg=(10.0,))),
                            Design(s=-0.775, Q_back=-2.4), Tolerances().sample(1, seed=0), [27.6],
                            numerics=FAST_NUMERICS, rho0=PAPER_RHO0)[name]
    assert bool((c.sign * (off - axis) > 0).all())
