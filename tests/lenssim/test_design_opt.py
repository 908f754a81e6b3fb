import numpy as np
import pytest
import torch

from lenssim import CRITERIA

from lenssim import DEFAULT_NUMERICS, Camera, Design

from lenssim_studies.paper import PAPER_LENS
from lenssim import slope_departure_cost as _cost
from lenssim.design_opt import DifferentiableCriterion, optimise_on_iso_cost
from lenssim_studies.tradeoff import iso_cost_curve
import dataclasses
from lenssim_studies.paper import PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM

CAM3 = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 7.0, 14.0)), PAPER_SENSOR, PAPER_SPECTRUM)
NUM = DEFAULT_NUMERICS.replace(min_size=128, oversample=1)


def slope_departure_cost(lens, s, Q):
    return _cost(lens, Design(s=s, Q_back=Q))


@pytest.mark.parametrize("criterion", ["mse_r", "mse_s"])
def test_autograd_through_the_whole_chain_matches_finite_differences(criterion):
    f = DifferentiableCriterion(CAM3, 27.6, criterion, numerics=NUM, rho0=PAPER_RHO0)
    x = torch.tensor([-0.8, -2.3], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(f(x), x)
    for i, h in enumerate((1e-5, 1e-4)):
        e = torch.zeros(2, dtype=torch.float64)
        e[i] = h
        with torch.no_grad():
            fd = (f(x + e) - f(x - e)) / (2 * h)
        assert float(g[i]) == pytest.approx(float(fd), rel=1e-6)


def test_cost_gradient_matches_finite_differences():
    x = torch.tensor([-0.8, -2.3], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(slope_departure_cost(PAPER_LENS, x[0], x[1]), x)
    for i, h in enumerate((1e-6, 1e-5)):
        e = torch.zeros(2, dtype=torch.float64)
        e[i] = h
        fd = (slope_departure_cost(PAPER_LENS, *(x + e).detach()) - slope_departure_cost(PAPER_LENS, *(x - e).detach())) / (2 * h)
        assert float(g[i]) == pytest.approx(float(fd), rel=1e-6)


class Quadratic:
    """A known quality landscape: minimum along any iso-cost curve where s is closest to s0."""

    evaluations = 0
    lens = PAPER_LENS
    names = ("s", "Q_back")

    def __init__(self, s0):
        self.s0 = s0

    def design(self, x):
        return Design(s=x[0], Q_back=x[1])

    def fix_sizes(self, x):
        pass

    def __call__(self, x):
        self.evaluations += 1
        return (x[0] - self.s0) ** 2 + 1.0

    objective = __call__  # a criterion to minimise (as DifferentiableCriterion.objective)
    criterion = CRITERIA["mse_r"]


def test_projected_descent_finds_a_known_iso_cost_optimum():
    level = 6e-4
    r = optimise_on_iso_cost(Quadratic(-0.55), (-1.2, -1.0), level)
    s, Q = r.design["s"], r.design["Q_back"]
    assert s == pytest.approx(-0.55, abs=2e-3)
    assert r.cost == pytest.approx(level, rel=1e-8)
    _, cq, _ = iso_cost_curve(PAPER_LENS, level, [s])
    assert Q == pytest.approx(float(cq[np.argmin(np.abs(cq - Q))]), abs=1e-6)


def test_projected_descent_agrees_with_a_dense_scan_of_the_real_model():
    level = 5.5e-4
    f = DifferentiableCriterion(CAM3, 27.6, "mse_r", numerics=NUM, rho0=PAPER_RHO0)
    r = optimise_on_iso_cost(f, (-1.0, -1.8), level)
    s = np.linspace(r.design["s"] - 0.05, r.design["s"] + 0.05, 11)
    cs, cq, cb = iso_cost_curve(CAM3.lens, level, s)
    neg = cb == -1
    with torch.no_grad():
        vals = [float(f(torch.tensor([a, b], dtype=torch.float64))) for a, b in zip(cs[neg], cq[neg])]
    assert r.value <= min(vals) + 1e-9  # nothing on the dense scan beats the optimiser
    assert r.evaluations < 80
