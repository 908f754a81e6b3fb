"""A prescription's numbers as tensors (issue 44, item 3): a batch of designs traced at once, on the numbers' device,
differentiable through the solves, the real aiming, the trace, the OPD, its fit and the asphere cost.

Checked against the float route, which is independent of the batch's code where it matters: each design made by
:func:`lenssim.optics.lens_solves.solve_design` (the prescription's own checks, floats) and traced alone; the
gradients against central differences of the float route's results (no autograd there); the cost against
:func:`lenssim.optics.cost.prescription_costs`. The lens is the Cooke triplet, its stop inside the lens (surface 5),
so the real aiming's implicit derivative is exercised."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lenssim.io.prescription_file import read_lens
from lenssim.model.lens_parameters import parameter_values, parse_parameter
from lenssim.optics.cost import lens_cost, prescription_costs
from lenssim.optics.exact_wavefront import lens_exact_coefficients
from lenssim.optics.lens_solves import solve_design, solve_numbers
from lenssim.optics.sequential import SequentialLens, pupil_grid

NAMES = ("E1.bending", "E2.bending", "S6.conic", "S6.A4", "focus_um")
STEPS = (0.05, 0.05, 0.2, 2e-6, 5.0)
"""The free parameters and a typical step of each (bendings, conic, A4 in mm^-3, um of focus)."""
HOLD = ("efl",)
COST_POINTS = 64


@pytest.fixture(scope="module")
def cooke():
    p = read_lens("cooke_triplet")
    p = dataclasses.replace(p, wavelengths_um=(p.primary_wavelength_um,), fields=(0.0, 6.0))
    pars = [parse_parameter(p, n, aspherize=(6,)) for n in NAMES]
    x0 = torch.tensor([v if v == v else 0.0 for v in parameter_values(p, pars).values()], dtype=torch.float64)
    steps = torch.tensor(STEPS, dtype=torch.float64)
    designs = torch.stack([x0 + steps * torch.tensor(o, dtype=torch.float64)
                           for o in ((0.0, 0, 0, 0, 0), (1.0, -1, -2, 1, 2), (-1.0, 0.5, 1, -1, -3))])
    return p, pars, designs, steps


def _float_coefficients(p, pars, x):
    q, shift = solve_design(p, dict(zip(pars, x.tolist())), hold=HOLD)
    return lens_exact_coefficients(SequentialLens(q, image_shift_mm=shift), p.fields, p.wavelengths_um)


def _float_cost(p, pars, x):
    q, _ = solve_design(p, dict(zip(pars, x.tolist())), hold=HOLD)
    return sum(v["cost"] for v in prescription_costs(q, COST_POINTS).values())


def test_a_batch_traces_each_design_as_the_float_route_does(cooke):
    p, pars, designs, _ = cooke
    seq = solve_numbers(p, pars, designs, hold=HOLD)
    assert seq.batched and seq.batch_size == 3
    c = lens_exact_coefficients(seq, p.fields, p.wavelengths_um)
    ref = torch.stack([_float_coefficients(p, pars, x) for x in designs])
    assert c.shape == ref.shape == (3, 2, 1, ref.shape[-1])
    assert float((c - ref).abs().max()) < 1e-7 * float(ref.abs().max())  # the aiming's tolerance, 1e-9 of the stop
    assert float((ref[1] - ref[0]).abs().max()) > 1e-3 * float(ref.abs().max())  # the designs differ

    # the vignetted wavefront map too: OPD, validity and image points of every design
    px, py = pupil_grid(12)
    w = seq.wavefront(6.0, px, py)
    for b, x in enumerate(designs):
        q, shift = solve_design(p, dict(zip(pars, x.tolist())), hold=HOLD)
        one = SequentialLens(q, image_shift_mm=shift).wavefront(6.0, px, py)
        assert torch.equal(w.valid[b], one.valid)
        assert torch.allclose(w.opd_waves[b][one.valid], one.opd_waves[one.valid], rtol=0, atol=1e-7)
        assert torch.allclose(w.image_mm[b][one.valid], one.image_mm[one.valid], rtol=0, atol=1e-9)
        assert float(w.reference_radius_mm[b]) == pytest.approx(one.reference_radius_mm, rel=1e-12)


def test_the_real_ray_coefficients_gradient_is_the_float_routes_central_differences(cooke):
    """Autograd through the efl solve, the real aiming (stop inside the lens), the trace, the OPD and its fit, against
    central differences of the float route (each design made, checked and traced alone)."""
    p, pars, designs, steps = cooke
    x = designs[1].clone().requires_grad_(True)
    c = lens_exact_coefficients(solve_numbers(p, pars, x, hold=HOLD), p.fields, p.wavelengths_um)[0]
    weights = torch.linspace(1, 2, c.numel(), dtype=torch.float64).reshape(c.shape)  # every coefficient counts
    (g,) = torch.autograd.grad((c * weights).sum(), x)
    h = steps * 1e-3
    fd = []
    for i in range(len(pars)):
        e = torch.zeros(len(pars), dtype=torch.float64)
        e[i] = h[i]
        plus = _float_coefficients(p, pars, designs[1] + e)
        minus = _float_coefficients(p, pars, designs[1] - e)
        fd.append(float(((plus - minus) * weights).sum() / (2 * h[i])))
    assert g.tolist() == pytest.approx(fd, rel=1e-4)
    assert all(abs(v) > 0 for v in fd)


def test_the_batchs_asphere_cost_is_the_prescriptions_and_its_gradient_the_central_differences(cooke):
    p, pars, designs, steps = cooke
    x = designs.clone().requires_grad_(True)
    cost = lens_cost(solve_numbers(p, pars, x, hold=HOLD), COST_POINTS)
    ref = [_float_cost(p, pars, d) for d in designs]
    assert cost.tolist() == pytest.approx(ref, rel=1e-10, abs=1e-15)
    assert ref[0] == 0 and ref[1] > 0  # the file's sphere costs nothing; an asphere does
    (g,) = torch.autograd.grad(cost[1], x)
    h = steps * 1e-4
    fd = []
    for i in range(len(pars)):
        e = torch.zeros(len(pars), dtype=torch.float64)
        e[i] = h[i]
        fd.append((_float_cost(p, pars, designs[1] + e) - _float_cost(p, pars, designs[1] - e)) / (2 * float(h[i])))
    assert g[1].tolist() == pytest.approx(fd, rel=1e-5, abs=1e-12)
    assert abs(fd[2]) > 0 and abs(fd[3]) > 0  # the conic and A4 price the asphere
    assert torch.equal(g[0], torch.zeros_like(g[0]))  # the sphere's kink: 0, as the central differences give


def test_a_batch_follows_its_numbers_device(cooke, device_dtype):
    device, dtype = device_dtype
    p, pars, designs, _ = cooke
    x = designs.to(device=device, dtype=dtype)
    if dtype != torch.float64:
        with pytest.raises(ValueError, match="must be float64"):
            solve_numbers(p, pars, x, hold=HOLD)
        return
    c = lens_exact_coefficients(solve_numbers(p, pars, x, hold=HOLD), p.fields, p.wavelengths_um)
    assert c.device.type == device.type
    ref = lens_exact_coefficients(solve_numbers(p, pars, designs, hold=HOLD), p.fields, p.wavelengths_um)
    assert torch.allclose(c.cpu(), ref, rtol=0, atol=1e-9 * float(ref.abs().max()))


def test_what_a_batch_cannot_hold_is_refused(cooke):
    p, pars, designs, _ = cooke
    with pytest.raises(ValueError, match="holds the entrance pupil"):
        solve_numbers(p, pars, designs, hold=("efl", "fnum"))
    with pytest.raises(ValueError, match="image 'best' is not allowed"):
        solve_numbers(p, pars, designs, hold=HOLD, image="best")
    surfs = list(p.surfaces)
    surfs[5] = dataclasses.replace(surfs[5], conic=torch.zeros(2, 1, dtype=torch.float32))
    with pytest.raises(ValueError, match="float64 of shape"):
        SequentialLens(p, numbers=surfs)
    steep = designs.clone()
    steep[1, 2] = 400.0  # S6's conic beyond its limit over the semi-diameter: (1 + k) c^2 y^2 >= 1
    with pytest.raises(ValueError, match="surface 6: its asphere cost is not finite over the radius 11.6 mm"):
        lens_cost(solve_numbers(p, pars, steep, hold=HOLD), COST_POINTS)
    bare = dataclasses.replace(p, surfaces=tuple(dataclasses.replace(s, semi_diameter_mm=None) for s in p.surfaces))
    with pytest.raises(ValueError, match="surface 6: a batch's asphere cost needs the surface's semi-diameter"):
        lens_cost(solve_numbers(bare, pars, designs, hold=HOLD), COST_POINTS)
