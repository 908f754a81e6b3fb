import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy import optimize

from lenssim import Design, LensError, best_fit_sphere_curvature

from lenssim_studies.paper import PAPER_LENS
from lenssim import slope_departure_cost as _cost
from lenssim import slope_departure_cost_third_order as _cost3

D = torch.float64


def slope_departure_cost(lens, s, Q, *n, **kw):
    return _cost(lens, Design(s=s, Q_back=Q), *n, **kw)


def slope_departure_cost_third_order(lens, s, Q):
    return _cost3(lens, Design(s=s, Q_back=Q))


def test_zero_cost_contour():
    s = torch.linspace(-2, 1, 13, dtype=D)
    assert torch.all(slope_departure_cost(PAPER_LENS, s, 0.0) < 1e-15)  # Q = 0: a sphere
    Q = torch.linspace(-10, 1.2, 12, dtype=D)
    assert torch.all(slope_departure_cost(PAPER_LENS, 1.0, Q) == 0)  # s = 1: flat back, any Q


def test_cost_grows_with_conicity_and_with_more_negative_shape_factor():
    Q = torch.linspace(-10, -0.1, 50, dtype=D)
    c = slope_departure_cost(PAPER_LENS, -0.775, Q)
    assert torch.all(c[:-1] > c[1:])
    s = torch.linspace(-2, 0.9, 50, dtype=D)
    c = slope_departure_cost(PAPER_LENS, s, -2.4)
    assert torch.all(c[:-1] > c[1:])
    assert slope_departure_cost(PAPER_LENS, -0.775, 1.0) > 0


def test_best_fit_sphere_matches_a_brute_force_fit():
    y, n = 2.0, 101
    r = np.linspace(0, y, n)
    for s, Q in [(-2.0, -10.0), (-0.775, -2.4), (0.5, 1.2)]:
        _, c = PAPER_LENS.curvatures(s)
        conic = c * r / np.sqrt(1 - (1 + Q) * c**2 * r**2)
        f = lambda k: np.mean((conic - k * r / np.sqrt(1 - k**2 * r**2)) ** 2)  # noqa: E731
        ref = optimize.minimize_scalar(f, bracket=(c * 0.9, c * 1.1), tol=1e-14)
        k = float(best_fit_sphere_curvature(torch.tensor(c, dtype=D), torch.tensor(Q, dtype=D), y, n))
        assert k == pytest.approx(ref.x, rel=1e-7)
        assert float(slope_departure_cost(PAPER_LENS, s, Q, n)) == pytest.approx(math.sqrt(ref.fun), rel=1e-6)


def test_third_order_limit_at_small_aperture():
    # next order is ~(1 + Q) c^2 y^2: 0.4 % at y = 0.2 mm, s = -2, Q = -10; 16x less at 0.05 mm
    lens = dataclasses.replace(PAPER_LENS, pupil_radius_mm=0.05)
    for s, Q in [(-2.0, -10.0), (-0.5, 1.0)]:
        exact = float(slope_departure_cost(lens, s, Q, n_points=4001))
        assert exact == pytest.approx(float(slope_departure_cost_third_order(lens, s, Q)), rel=1e-3)


def test_cost_converges_with_the_number_of_points():
    vals = [float(slope_departure_cost(PAPER_LENS, -0.775, -2.4, n)) for n in (11, 101, 1001, 10001)]
    assert abs(vals[1] - vals[3]) / vals[3] < 2e-2
    assert abs(vals[2] - vals[3]) < abs(vals[1] - vals[3]) < abs(vals[0] - vals[3])


def test_cost_errors_and_dtype():
    with pytest.raises(ValueError, match="n_points=1"):
        slope_departure_cost(PAPER_LENS, -0.5, -1.0, 1)
    with pytest.raises(LensError, match="Q_back=20"):
        slope_departure_cost(PAPER_LENS, -2.0, 20.0)
    assert slope_departure_cost(PAPER_LENS, torch.tensor([-0.5], dtype=torch.float32),
                                torch.tensor(-1.0, dtype=torch.float32)).dtype == torch.float32
    assert slope_departure_cost(PAPER_LENS, -0.5, -1.0).dtype == torch.float64  # Python numbers: float64


def test_the_cost_counts_every_aspheric_surface():
    """The cost sums over the surfaces whose conic is a design parameter (here the back one only)."""
    d = Design(s=-0.775, Q_back=-2.4)
    aspheres = [s for s in PAPER_LENS.surfaces(d) if s.aspheric]
    assert [s.conic_name for s in aspheres] == ["Q_back"]
    from lenssim.optics.cost import surface_cost

    c = torch.as_tensor(aspheres[0].curvature, dtype=D)
    assert float(_cost(PAPER_LENS, d)) == float(surface_cost(c, torch.as_tensor(-2.4, dtype=D), 2.0))


@pytest.mark.parametrize("Q", [48.0, 48.59, 48.5932])
def test_cost_near_the_conic_limit_matches_a_bounded_brute_force_fit(Q):
    """s = -0.775: the conic is defined for Q < 48.5933. The safeguarded Gauss-Newton (the plain one gave NaN
    here) must find the same best-fit sphere as a bounded scalar minimisation over |k| y < 1."""
    import warnings

    y, n = 2.0, 101
    r = np.linspace(0, y, n)
    _, c = PAPER_LENS.curvatures(-0.775)
    conic = c * r / np.sqrt(1 - (1 + Q) * c**2 * r**2)
    f = lambda k: np.mean((conic - k * r / np.sqrt(1 - k**2 * r**2)) ** 2)  # noqa: E731
    ref = optimize.minimize_scalar(f, bounds=(-0.4999999, 0.4999999), method="bounded", options={"xatol": 1e-14})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the third-order-validity warning of a conic this strong
        got = float(slope_departure_cost(PAPER_LENS, -0.775, Q, n))
    assert got == pytest.approx(math.sqrt(ref.fun), rel=1e-6)


def test_an_even_asphere_s_cost_is_its_definition_evaluated_directly():
    """Eq. (3) for an even asphere (conic + A4..A8), against a direct evaluation of the definition: the slopes by
    central differences of the sag (not the analytic slope), the best sphere by a bounded scalar search (not
    Gauss-Newton)."""
    from scipy.optimize import minimize_scalar

    from lenssim.model.prescription import PrescriptionSurface
    from lenssim.optics.cost import even_asphere_cost

    c, Q, coeffs, y, n = 1 / 30.0, -0.8, (2e-5, -3e-8, 4e-11), 9.0, 101
    surf = PrescriptionSurface(c, 1.0, "air", conic=Q, aspheric_coefficients=coeffs)
    r = np.linspace(0, y, n)
    h = 1e-5
    slope = np.array([(surf.sag_mm(v + h) - surf.sag_mm(v - h)) / (2 * h) for v in r])

    def rms(k):
        return np.sqrt(np.mean((slope - k * r / np.sqrt(1 - k**2 * r**2)) ** 2))

    best = minimize_scalar(rms, bounds=(c - 0.01, c + 0.01), method="bounded", options={"xatol": 1e-12})
    ours = even_asphere_cost(c, Q, coeffs, y, n)
    assert ours > 1e-3  # a real departure: the check is not empty
    assert ours == pytest.approx(best.fun, rel=1e-6)


def test_an_a4_asphere_tends_to_the_third_order_cost():
    """A sphere with A4 r^4 at a small aperture: the slope departure 4 A4 r^3 less the best line b r leaves an RMS of
    8 |A4| y^3 / sqrt(175) (the continuum; 2001 radii), as a conic's Q c^3 / 8 = A4."""
    from lenssim.optics.cost import even_asphere_cost

    a4, y = 1e-4, 1.0
    assert even_asphere_cost(1 / 500.0, 0.0, (a4,), y, 2001) == pytest.approx(8 * a4 * y**3 / 175**0.5, rel=2e-3)


def test_a_prescription_s_aspheres_cost_what_the_paper_s_singlet_costs():
    """The paper's singlet as a prescription: its one asphere (surface 2) costs today's C_a exactly; surfaces without
    a conic or coefficients cost nothing (not listed)."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.cost import prescription_costs
    from lenssim_studies.paper import PAPER_LENS

    costs = prescription_costs(read_lens("paper_singlet"))
    assert list(costs) == [2] and costs[2]["radius_mm"] == 2.0
    assert costs[2]["cost"] == float(_cost(PAPER_LENS, Design(s=-0.775, Q_back=-2.4)))
    assert prescription_costs(read_lens("cooke_triplet")) == {}
