import dataclasses
import math

import pytest
import torch

from lenssim import TERMS, Design, field_rms_wavefront, rms_wavefront, seidel_sums, wavefront, wavefront_coefficients, wavefront_gradient

from lenssim_studies.paper import PAPER_LENS
from lenssim.optics.paraxial import Surface, seidel_surface_sums
from lenssim.optics.exact_wavefront import transverse_aberration

D = torch.float64
LAMBDA_UM = 0.5
DESIGNS = [(-0.725, -10.0), (-0.775, -2.4), (0.7, 0.0), (-2.0, 1.2), (1.025, -3.0), (0.0, -1.0)]


def design(s, Q):
    return Design(s=torch.as_tensor(s, dtype=D), Q_back=torch.as_tensor(Q, dtype=D))


def surface_sums(lens, s, Q, alpha_deg, u_marginal=0.0):
    t = lambda v: torch.tensor(float(v), dtype=D)  # noqa: E731
    return seidel_surface_sums(lens.surfaces(design(s, Q)), t(lens.pupil_radius_mm), t(u_marginal),
                               t(0.0), t(math.tan(math.radians(alpha_deg))))


@pytest.mark.parametrize("s,Q", DESIGNS)
@pytest.mark.parametrize("alpha", [0.0, 5.0, 14.0])
def test_closed_form_matches_surface_by_surface_seidel_sums(s, Q, alpha):
    closed = seidel_sums(PAPER_LENS, design(s, Q), [alpha])[0]
    ref = surface_sums(PAPER_LENS, s, Q, alpha)
    torch.testing.assert_close(closed, ref[:4], rtol=1e-12, atol=1e-15)
    assert abs(ref[4]) < 1e-15  # thin lens, stop at the lens: no distortion


@pytest.mark.parametrize("p", [-0.5, 0.3])
def test_closed_form_matches_surface_sums_at_finite_conjugates(p):
    lens = dataclasses.replace(PAPER_LENS, position_factor=p)
    t_img = lens.image_distance_mm  # marginal ray leaves the lens towards the axial image point
    y = lens.pupil_radius_mm
    u_in = -y / t_img + y / lens.focal_length_mm  # thin lens: u' = u - y/f
    for s, Q in DESIGNS:
        closed = seidel_sums(lens, design(s, Q), [7.0])[0]
        ref = surface_sums(lens, s, Q, 7.0, u_marginal=u_in)
        torch.testing.assert_close(closed, ref[:4], rtol=1e-10, atol=1e-15)


def test_conic_term_sign_single_surface_cartesian_oval():
    # A refracting conic from air into glass n with Q = -1/n^2 images infinity perfectly: S_I = 0.
    n, c, y = 1.5, 0.05, 2.0
    t = lambda v: torch.tensor(v, dtype=D)  # noqa: E731
    S = seidel_surface_sums([Surface(t(c), t(-1 / n**2), n, 0.0)], t(y), t(0.0), t(0.0), t(0.0))
    assert abs(S[0]) < 1e-15
    S0 = seidel_surface_sums([Surface(t(c), t(0.0), n, 0.0)], t(y), t(0.0), t(0.0), t(0.0))
    assert S0[0] > 1e-6  # the sphere alone is under-corrected


@pytest.mark.parametrize("s,Q", [(-0.725, -10.0), (0.7, 0.0), (-2.0, 1.2), (-0.775, -2.4)])
def test_third_order_matches_exact_ray_trace_at_small_aperture(s, Q):
    """Transverse aberrations of a real ray trace agree with -(f/y) grad W to third order."""
    alpha = 2.0
    r = torch.linspace(-1, 1, 21, dtype=D)
    R, T = torch.meshgrid(r, r, indexing="ij")
    m = R**2 + T**2 <= 1
    R, T = R[m], T[m]
    errs = []
    for y in (0.2, 0.05):
        lens = dataclasses.replace(PAPER_LENS, pupil_radius_mm=y)
        eps_r, eps_t = transverse_aberration(lens, design(s, Q), alpha, R, T)
        c = wavefront_coefficients(lens, design(s, Q), [alpha], wavelength_um=LAMBDA_UM)[0]
        g_r, g_t = wavefront_gradient(c * LAMBDA_UM * 1e-3, R, T)
        k = -lens.focal_length_mm / y
        scale = max(eps_r.abs().max(), eps_t.abs().max())
        errs.append(max((eps_r - k * g_r).abs().max(), (eps_t - k * g_t).abs().max()) / scale)
    assert errs[1] < 4e-3  # residual: fifth order in field and aperture
    assert errs[1] <= errs[0] * 1.05


def test_ray_trace_coma_sign_flips_with_the_conventions_of_the_notes():
    """The coma of NOTES.md (-S_II) belongs to a meridional axis pointing away from the image."""
    lens = dataclasses.replace(PAPER_LENS, pupil_radius_mm=0.1)
    s, Q, alpha = -0.725, -10.0, 2.0
    R = torch.tensor([1.0, -1.0], dtype=D)
    eps_r, _ = transverse_aberration(lens, design(s, Q), alpha, R, torch.zeros(2, dtype=D))
    S = seidel_sums(lens, design(s, Q), [alpha])[0]
    # sagittal-free meridional coma: eps_r(+1) + eps_r(-1) = -(f/y) * 2 * (3 W131) for W131 = S_II/2
    coma_from_trace = (eps_r[0] + eps_r[1]) / 2
    predicted = -(lens.focal_length_mm / lens.pupil_radius_mm) * 3 * S[1] / 2
    assert coma_from_trace * predicted > 0
    assert coma_from_trace == pytest.approx(float(predicted), rel=0.02)


def test_rms_closed_form_matches_pupil_quadrature():
    g = torch.Generator().manual_seed(0)
    coeffs = torch.randn(5, 4, generator=g, dtype=D)
    n = 801
    x = torch.linspace(-1, 1, n, dtype=D)
    Y, X = torch.meshgrid(x, x, indexing="ij")
    m = (X**2 + Y**2) <= 1
    W = wavefront(coeffs, Y[m], X[m])
    torch.testing.assert_close(rms_wavefront(coeffs), W.square().mean(-1).sqrt(), rtol=3e-3, atol=0)
    torch.testing.assert_close(rms_wavefront(coeffs, piston_removed=True), W.std(-1, correction=0), rtol=3e-3, atol=0)


def test_wavefront_gradient_matches_autograd():
    coeffs = torch.tensor([[0.3, -1.2, 2.0, 0.7]], dtype=D)
    r = torch.tensor([0.3, -0.5, 0.1], dtype=D, requires_grad=True)
    t = torch.tensor([0.2, 0.4, -0.8], dtype=D, requires_grad=True)
    gr, gt = torch.autograd.grad(wavefront(coeffs, r, t).sum(), (r, t))
    ar, at = wavefront_gradient(coeffs, r, t)
    torch.testing.assert_close(ar[0], gr)
    torch.testing.assert_close(at[0], gt)


def test_field_terms_match_notes_magnitudes():
    # NOTES.md: at 14 degrees astigmatism plus field curvature alone are ~18 waves.
    c = wavefront_coefficients(PAPER_LENS, Design(s=0.0, Q_back=0.0), [14.0], wavelength_um=LAMBDA_UM)[0]
    assert float(c[2] + c[3]) == pytest.approx(18.2, abs=0.1)
    # and at s = -2, Q = -10 the conic's spherical term reaches ~35 waves
    _, c2 = PAPER_LENS.curvatures(-2.0)
    conic = (1 - 1.5) * -10 * c2**3 * 2**4 / 8 / (LAMBDA_UM * 1e-3)
    assert abs(conic) == pytest.approx(34.56, abs=0.01)


def test_rms_w_grid_optimum_is_the_papers():
    """Paper: the RMS_W optimum of the grid is s = -0.725, Q = -10 (the bound)."""
    s = torch.round((torch.arange(122, dtype=D) * 0.025 - 2) * 1e6) / 1e6
    Q = torch.round((torch.arange(113, dtype=D) * 0.1 - 10) * 1e6) / 1e6
    S, QQ = torch.meshgrid(s, Q, indexing="ij")
    rms = field_rms_wavefront(wavefront_coefficients(PAPER_LENS, Design(s=S, Q_back=QQ), wavelength_um=LAMBDA_UM))
    i, j = divmod(int(torch.argmin(rms)), rms.shape[1])
    assert float(s[i]) == pytest.approx(-0.725)
    assert float(Q[j]) == pytest.approx(-10.0)


def test_dtype_and_device_follow_inputs():
    for dt in (torch.float32, torch.float64):
        d = Design(s=torch.tensor([0.1, 0.2], dtype=dt), Q_back=torch.tensor(-1.0, dtype=dt))
        c = wavefront_coefficients(PAPER_LENS, d, wavelength_um=LAMBDA_UM)
        assert c.dtype == dt and c.shape == (2, 15, len(TERMS))


def test_bad_coefficient_shape_is_refused():
    with pytest.raises(ValueError, match=r"expected a floating tensor of shape \(\*, 4\)"):
        rms_wavefront(torch.zeros(3, 5))


def test_rms_moment_matrix_is_the_closed_form_of_the_four_terms():
    """The generic disc moments of the term table reproduce the paper's four-term closed form."""
    g = torch.Generator().manual_seed(1)
    a, b, c, d = torch.randn(4, 6, generator=g, dtype=D)
    m2 = a * a / 5 + a * c / 4 + a * d / 2 + b * b / 8 + c * c / 8 + c * d / 3 + d * d / 3
    m1 = a / 3 + c / 4 + d / 2
    coeffs = torch.stack([a, b, c, d], dim=-1)
    torch.testing.assert_close(rms_wavefront(coeffs), m2.sqrt(), rtol=1e-14, atol=0)
    torch.testing.assert_close(rms_wavefront(coeffs, piston_removed=True), (m2 - m1 * m1).sqrt(), rtol=1e-13, atol=0)


def test_coefficients_scale_with_the_wavelength():
    """The wavefront in mm does not depend on the wavelength (non-dispersive glass): waves scale as 1/lambda."""
    d = design(-0.775, -2.4)
    c5 = wavefront_coefficients(PAPER_LENS, d, wavelength_um=0.5)
    c6 = wavefront_coefficients(PAPER_LENS, d, wavelength_um=0.6)
    torch.testing.assert_close(c6 * 0.6, c5 * 0.5, rtol=1e-14, atol=0)
