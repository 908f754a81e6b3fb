import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import optimize

from lenssim import Design, LensError, best_fit_sphere_curvature

from lenssim_studies.paper import PAPER_LENS
from lenssim.model.prescription import PrescriptionSurface
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
    from lenssim.optics.cost import asphere_cost

    c, Q, coeffs, y, n = 1 / 30.0, -0.8, (2e-5, -3e-8, 4e-11), 9.0, 101
    surf = PrescriptionSurface(c, 1.0, "air", conic=Q, aspheric_coefficients=coeffs)
    r = np.linspace(0, y, n)
    h = 1e-5
    slope = np.array([(surf.sag_mm(v + h) - surf.sag_mm(v - h)) / (2 * h) for v in r])

    def rms(k):
        return np.sqrt(np.mean((slope - k * r / np.sqrt(1 - k**2 * r**2)) ** 2))

    best = minimize_scalar(rms, bounds=(c - 0.01, c + 0.01), method="bounded", options={"xatol": 1e-12})
    ours = asphere_cost(surf, y, n)
    assert ours > 1e-3  # a real departure: the check is not empty
    assert ours == pytest.approx(best.fun, rel=1e-6)


def test_an_a4_asphere_tends_to_the_third_order_cost():
    """A sphere with A4 r^4 at a small aperture: the slope departure 4 A4 r^3 less the best line b r leaves an RMS of
    8 |A4| y^3 / sqrt(175) (the continuum; 2001 radii), as a conic's Q c^3 / 8 = A4."""
    from lenssim.optics.cost import asphere_cost

    a4, y = 1e-4, 1.0
    got = asphere_cost(PrescriptionSurface(1 / 500.0, aspheric_coefficients=(a4,)), y, 2001)
    assert got == pytest.approx(8 * a4 * y**3 / 175**0.5, rel=2e-3)


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


# --- Any asphere against a brute-force Eq. (3) (issue 43) -------------------------------------------------------------
# A phone lens's strongly hyperbolic last surfaces were priced at ~96.5 (the sphere fit, iterating in the curvature from
# a third-order start beyond the hemisphere, stayed at the hemisphere's edge). The reference below shares nothing with
# the library but the definition: slopes by a complex step of the sag (not the analytic slope), every sphere that exists
# over the aperture by its rim half-angle (k y = sin(theta)) densely searched and then refined by a bounded scalar
# minimiser (not Newton in the rim slope), the RMS over the paper's n equally spaced radii by numpy.

PHONE_LENS = Path(__file__).parents[1] / "data" / "lenses" / "phone_4element.toml"
REFERENCE_ANGLES = 20001
"""Spheres of the reference's dense search: rim half-angles equally spaced over (-90, 90) deg (0.009 deg apart)."""


def _sag(c, Q, coeffs, r):
    """An even asphere's sag (mm) at radius ``r`` (numpy; real or complex)."""
    return c * r**2 / (1 + np.sqrt(1 - (1 + Q) * c**2 * r**2)) + sum(a * r ** (2 * j + 4) for j, a in enumerate(coeffs))


def _reference_cost(c, Q, coeffs, y, n=101):
    """(C_a, best sphere's curvature) of Eq. (3) by brute force."""
    r = np.linspace(0, y, n)
    h = 1e-30
    slope = _sag(c, Q, coeffs, r + 1j * h).imag / h  # complex step: the sag's derivative to rounding

    def rms(theta):
        k = np.sin(np.asarray(theta))[..., None] / y
        return np.sqrt(np.mean((slope - k * r / np.sqrt(1 - (k * r) ** 2)) ** 2, axis=-1))

    grid = np.linspace(-np.pi / 2, np.pi / 2, REFERENCE_ANGLES)[1:-1]
    i = int(np.argmin(rms(grid)))
    best = optimize.minimize_scalar(lambda t: float(rms(t)), bounds=(grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]),
                                    method="bounded", options={"xatol": 1e-14})
    return float(best.fun), math.sin(best.x) / y


ANY_ASPHERES = {  # (c 1/mm, Q, (A4, A6, ...), y mm)
    "hyperbola Q -25, no terms": (1 / 1.5, -25.0, (), 2.5),
    "hyperbola Q -6.5 + A4..A10, inflection (a phone lens's last surface)": (1 / 1.05, -6.5, (-0.08, 0.025, -0.005, 4e-4), 2.0),
    "hyperbola Q -20 + A4..A10, sag turning back": (1 / 2.2, -20.0, (-0.09, 0.02, -0.003, 2e-4), 2.6),
    "concave hyperbola Q -6 + A4..A10": (-1 / 1.8, -6.0, (-0.1, 0.03, -0.005, 3e-4), 2.4),
    "oblate Q 3": (1 / 4, 3.0, (), 1.8),
    "oblate Q 0.8 + A4, A6": (-1 / 3, 0.8, (0.01, -0.002), 2.0),
    "flat base, A4..A10 only (inflection)": (0.0, 0.0, (0.05, -0.02, 0.003, -2e-4), 2.5),
    "near-flat paraboloid + A4": (1 / 5000, -1.0, (1e-7,), 3.0),
    "best sphere 0.3% short of the hemisphere": (0.4, -10.0, (-0.1, 0.05, -0.01, 0.001), 2.5),
    "two local minima, the least near the hemisphere": (0.27428920077943236, 1.0411692667699284,
                                                         (0.256517895355879, -0.10216382071025419, -0.001909390603070043,
                                                          0.0016585017726759993), 2.5117334447057678),
}


@pytest.mark.parametrize("name", list(ANY_ASPHERES))
def test_any_asphere_costs_what_a_brute_force_eq3_gives(name):
    """The cost and the best sphere agree with the brute force: the cost to 1e-9 relative (both are minima, where the
    value is flat), the curvature to 1e-6 (a minimum's abscissa is known to ~sqrt(float64 epsilon) of its scale)."""
    from lenssim.optics.cost import _fit_sphere, asphere_cost

    c, Q, coeffs, y = ANY_ASPHERES[name]
    ref, k_ref = _reference_cost(c, Q, coeffs, y)
    surf = PrescriptionSurface(c, conic=Q, aspheric_coefficients=coeffs)
    got = asphere_cost(surf, y)
    assert got == pytest.approx(ref, rel=1e-9)
    r = torch.linspace(0, y, 101, dtype=D)
    k = float(_fit_sphere(surf.surface_kind.slope(surf, r), r, y))
    assert abs(k - k_ref) <= 1e-6 * max(abs(k_ref), 1 / y)
    assert abs(k) * y < 1  # a sphere that exists over the aperture


def test_a_phone_lens_s_aspheres_cost_what_a_brute_force_eq3_gives():
    """A hand-written 4-element phone lens (even aspheres to A10 on every surface, the last three strongly hyperbolic):
    each surface's cost over its semi-diameter is the brute force's (its last three were ~96.5 each), and none is
    absurd (a slope departure of a moulded phone-lens surface is a fraction of a unit)."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.cost import prescription_costs

    p = read_lens(str(PHONE_LENS))
    costs = prescription_costs(p)
    assert list(costs) == list(range(1, 9))
    for i, s in enumerate(p.surfaces, start=1):
        ref, _ = _reference_cost(s.curvature_per_mm, s.conic, s.aspheric_coefficients, s.semi_diameter_mm)
        assert costs[i]["radius_mm"] == s.semi_diameter_mm
        assert costs[i]["cost"] == pytest.approx(ref, rel=1e-9), i
        assert 1e-3 < costs[i]["cost"] < 0.3, i


def test_the_fit_is_the_same_for_a_surface_alone_or_in_a_batch():
    """Each element iterates to its own fixed point: its sphere does not depend on the others in the batch."""
    s = torch.tensor([-2.0, -0.775, 0.5, 1.0, -0.3], dtype=D)
    Q = torch.tensor([-10.0, -2.4, 1.2, -3.0, 0.0], dtype=D)
    c = torch.stack([torch.as_tensor(PAPER_LENS.curvatures(v)[1], dtype=D) for v in s.tolist()])
    batch = best_fit_sphere_curvature(c, Q, 2.0)
    for i in range(len(s)):
        assert torch.equal(batch[i], best_fit_sphere_curvature(c[i], Q[i], 2.0))
    assert float(batch[-1]) == float(c[-1])  # Q = 0: the surface's own sphere, exactly (its cost exactly 0)


@pytest.mark.parametrize("s0, q0", [(-0.775, -2.4), (-2.0, -10.0), (0.5, 1.2), (-0.775, 48.5)])
def test_the_cost_s_gradient_is_its_finite_difference(s0, q0):
    """The gradient (one Newton step at the converged sphere, with the graph: the implicit-function derivative)
    agrees with central differences of the cost itself, near the conic's limit (Q = 48.5) too."""
    import warnings

    s = torch.tensor(s0, dtype=D, requires_grad=True)
    Q = torch.tensor(q0, dtype=D, requires_grad=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the third-order-validity warning of the strong conic
        slope_departure_cost(PAPER_LENS, s, Q).backward()
        h = 1e-6
        f = lambda a, b: float(slope_departure_cost(PAPER_LENS, a, b))  # noqa: E731
        fd_s = (f(s0 + h, q0) - f(s0 - h, q0)) / (2 * h)
        fd_q = (f(s0, q0 + h) - f(s0, q0 - h)) / (2 * h)
    assert float(s.grad) == pytest.approx(fd_s, rel=1e-6)
    assert float(Q.grad) == pytest.approx(fd_q, rel=1e-6)


def test_a_sphere_fit_that_does_not_converge_is_one_line_not_a_number(monkeypatch):
    """A fit stopped before its fixed point returns NaN, and the prescription's cost says so in one line (not that the
    conic is at its limit, which it is not)."""
    import lenssim.optics.cost as cost
    from lenssim.io.prescription_file import read_lens

    monkeypatch.setattr(cost, "SPHERE_FIT_ITERATIONS", 1)
    surf = PrescriptionSurface(1 / 1.05, conic=-6.5, aspheric_coefficients=(-0.08, 0.025, -0.005, 4e-4))
    assert math.isnan(cost.asphere_cost(surf, 2.0))
    with pytest.raises(LensError, match=r"surface 1: .*\(its best-fit sphere did not converge within 1 Newton iterations\)"):
        cost.prescription_costs(read_lens(str(PHONE_LENS)))
