"""Surface kinds (``lenssim.model.surface_kinds``): every registered kind against references written here.

Each kind has an example surface in :data:`EXAMPLES` (a new kind without one fails
:func:`test_every_registered_kind_has_an_example`), on which the generic checks run: the sag's derivative against
central differences of the sag, the slope, the normal and the intersection against the sag equation, the paraxial
curvature and the Seidel ``r^4`` term against a fit of the sag near the vertex, autograd through the sag, and the
TOML and ``.zmx`` round trips. Then each kind against an independent reference: the conic and the even asphere
against their formulas written in numpy; Qbfs against Forbes's published polynomials, his slope orthogonality (by
Gauss-Chebyshev quadrature of the departure's slope, the departure found geometrically normal to the best-fit
sphere), and against the even asphere its coefficients convert to exactly (a flat best-fit sphere): the same sag,
paraxial data, Seidel sums, cost and traced wavefront.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from lenssim.io.prescription_file import prescription_toml, read_lens, prescription_from_dict
from lenssim.io.zemax import prescription_zmx, read_zmx, write_zmx
from lenssim.model.prescription import Prescription, PrescriptionError, PrescriptionSurface
from lenssim.model.surface_kinds import SURFACE_KINDS
from lenssim.model.surface_kinds.qbfs import QBFS_MAX_TERMS, qbfs_polynomials
from lenssim.optics.cost import prescription_costs
from lenssim.optics.sequential import SequentialLens, pupil_grid

D = torch.float64
GLASS = (1.5168, 64.17)

EXAMPLES = {
    "standard": PrescriptionSurface(1 / 40.0, 4.0, GLASS, conic=-0.7, semi_diameter_mm=9.0),
    "even_asphere": PrescriptionSurface(1 / 30.0, 4.0, GLASS, conic=-1.2, aspheric_coefficients=(2e-5, -3e-8, 4e-11),
                                        semi_diameter_mm=9.0),
    "qbfs": PrescriptionSurface(1 / 60.0, 4.0, GLASS, aspheric_coefficients=(3e-3, -1e-3, 4e-4, -1e-4),
                                semi_diameter_mm=10.0, kind="qbfs",
                                shape_parameters={"normalization_radius_mm": 10.0}).check(1),
}
"""One surface of each kind (semi-diameters of 9-10 mm, the glass after it)."""


def _singlet(front: PrescriptionSurface, back: PrescriptionSurface | None = None, *, image_mm: float = 80.0,
             epd_mm: float = 14.0) -> Prescription:
    """A singlet with ``front`` as surface 1 (the stop) and a sphere of radius -200 mm (or ``back``) behind."""
    back = back or PrescriptionSurface(-1 / 200.0, image_mm, "air", semi_diameter_mm=10.0)
    return Prescription(surfaces=(replace(front, material=GLASS), replace(back, thickness_mm=image_mm)),
                        stop_surface=1, entrance_pupil_diameter_mm=epd_mm, fields=(0.0, 4.0),
                        wavelengths_um=(0.5875618,), name="kind test")


def _sag(s, r):
    """The sag (mm) of ``s`` at radii ``r`` (mm)."""
    return s.surface_kind.sag(s, torch.as_tensor(r, dtype=D) ** 2)[0]


def test_every_registered_kind_has_an_example():
    assert set(EXAMPLES) == set(SURFACE_KINDS)
    assert all(s.surface_kind.name == name for name, s in EXAMPLES.items())


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_the_sag_s_derivatives_are_its_finite_differences(name):
    s = EXAMPLES[name]
    kind = s.surface_kind
    rho = torch.linspace(0.5, 81.0, 40, dtype=D)
    h = 1e-5
    z, dz = kind.sag(s, rho)
    fd = (kind.sag(s, rho + h)[0] - kind.sag(s, rho - h)[0]) / (2 * h)
    torch.testing.assert_close(dz, fd, rtol=1e-7, atol=1e-12)
    r = torch.sqrt(rho)
    fd_r = (kind.sag(s, (r + h) ** 2)[0] - kind.sag(s, (r - h) ** 2)[0]) / (2 * h)
    torch.testing.assert_close(kind.slope(s, r), fd_r, rtol=1e-7, atol=1e-12)
    # autograd through the sag gives the same derivative (the shape is a torch function of its input)
    x = rho.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(kind.sag(s, x)[0].sum(), x)
    torch.testing.assert_close(g, dz, rtol=1e-12, atol=1e-15)
    assert float(kind.sag(s, torch.zeros(1, dtype=D))[0]) == 0.0  # the vertex at the origin


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_rays_meet_the_surface_on_its_sag_with_its_normal(name):
    """Rays from a plane before the vertex at various angles: the point is on the ray and on the sag, the normal is
    the gradient of ``sag(x^2 + y^2) - z`` by central differences."""
    s = EXAMPLES[name]
    kind = s.surface_kind
    g = torch.Generator().manual_seed(1)
    n = 200
    P = torch.cat([(torch.rand(n, 2, generator=g, dtype=D) - 0.5) * 14, torch.full((n, 1), -3.0, dtype=D)], -1)
    d = torch.cat([(torch.rand(n, 2, generator=g, dtype=D) - 0.5) * 0.4, torch.ones(n, 1, dtype=D)], -1)
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
    X, N, t, ok, rho = kind.intersect(s, P, d, torch.ones(n, dtype=torch.bool))
    assert bool(ok.all())
    torch.testing.assert_close(X, P + t[:, None] * d, rtol=0, atol=1e-12)
    z, _ = kind.sag(s, X[:, 0] ** 2 + X[:, 1] ** 2)
    assert float((z - X[:, 2]).abs().max()) < 1e-10
    h = 1e-6
    F = lambda x, y: kind.sag(s, x * x + y * y)[0]  # noqa: E731
    gx = (F(X[:, 0] + h, X[:, 1]) - F(X[:, 0] - h, X[:, 1])) / (2 * h)
    gy = (F(X[:, 0], X[:, 1] + h) - F(X[:, 0], X[:, 1] - h)) / (2 * h)
    ref = torch.stack([gx, gy, -torch.ones_like(gx)], -1)
    torch.testing.assert_close(N, ref / torch.linalg.norm(ref, dim=-1, keepdim=True), rtol=0, atol=1e-8)


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_the_intersection_takes_tensor_numbers_batched_and_differentiable(name):
    """A surface whose curvature is a tensor: autograd through the intersection (Newton's steps included) gives the
    central difference of the distance, and a batch of curvatures ``(2, 1)`` traces each as it traces alone."""
    s = EXAMPLES[name]
    kind = s.surface_kind
    g = torch.Generator().manual_seed(2)
    P = torch.cat([(torch.rand(50, 2, generator=g, dtype=D) - 0.5) * 14, torch.full((50, 1), -3.0, dtype=D)], -1)
    d = torch.tensor([0.0, 0.1, 1.0], dtype=D).expand(50, 3)
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
    every = torch.ones(50, dtype=torch.bool)
    t_of = lambda c: kind.intersect(replace(s, curvature_per_mm=c), P, d, every)[2]  # noqa: E731
    c = torch.tensor(s.curvature_per_mm, dtype=D, requires_grad=True)
    (grad,) = torch.autograd.grad(t_of(c).sum(), c)
    h = 1e-7
    fd = float(t_of(s.curvature_per_mm + h).sum() - t_of(s.curvature_per_mm - h).sum()) / (2 * h)
    assert float(grad) == pytest.approx(fd, rel=1e-7)
    batch = t_of(torch.tensor([[s.curvature_per_mm], [0.9 * s.curvature_per_mm]], dtype=D))
    assert batch.shape == (2, 50) and torch.equal(batch[1], t_of(0.9 * s.curvature_per_mm))


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_the_paraxial_curvature_and_seidel_r4_term_are_the_sag_s_expansion(name):
    """A polynomial in ``r^2`` fitted to the sag near the vertex (numpy least squares on r < 0.3 mm): its ``r^2``
    coefficient is ``c / 2`` and its ``r^4`` coefficient ``(1 + k) c^3 / 8 + A4`` of the kind's Seidel terms."""
    s = EXAMPLES[name]
    kind = s.surface_kind
    r = np.linspace(0.02, 0.3, 60)
    z = _sag(s, torch.tensor(r)).numpy()
    x = r * r
    fit = np.linalg.lstsq(np.stack([x, x**2, x**3, x**4], -1), z, rcond=None)[0]
    c, k, a4 = (float(v) for v in kind.seidel_terms(s))
    assert c == pytest.approx(float(kind.paraxial_curvature(s)), rel=1e-14)
    assert fit[0] == pytest.approx(c / 2, rel=1e-10)
    assert fit[1] == pytest.approx((1 + k) * c**3 / 8 + a4, rel=1e-8)  # the fit's own error: 3e-10


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_a_lens_with_the_kind_reads_back_equal_from_toml_and_zmx(name, tmp_path):
    p = _singlet(EXAMPLES[name])
    text = prescription_toml(p)
    (tmp_path / "lens.toml").write_text(text)
    assert read_lens(str(tmp_path / "lens.toml")) == p
    if SURFACE_KINDS[name].zemax_type is None:
        with pytest.raises(PrescriptionError, match=rf"^surface 1: a {name} surface .* cannot be written to a \.zmx "
                                                    "file: .*write the lens as TOML$"):
            write_zmx(p, tmp_path / "lens.zmx")
        assert not (tmp_path / "lens.zmx").exists()
    else:
        write_zmx(p, tmp_path / "lens.zmx")
        assert f"TYPE {SURFACE_KINDS[name].zemax_type}" in prescription_zmx(p)
        q = read_zmx(tmp_path / "lens.zmx")
        assert q == replace(p, source=q.source)


def test_the_shipped_lenses_read_back_equal_from_zmx(tmp_path):
    for name in ("cooke_triplet", "double_gauss", "aspheric_singlet", "paper_singlet"):
        p = read_lens(name)
        write_zmx(p, tmp_path / f"{name}.zmx")
        q = read_zmx(tmp_path / f"{name}.zmx")
        assert q == replace(p, source=q.source, notes=q.notes), name
    with pytest.raises(PrescriptionError, match="^stop_size 'real' cannot be written to a .zmx file"):
        write_zmx(replace(p, stop_size="real"), tmp_path / "real.zmx")  # the reader would take it as paraxial
    assert not (tmp_path / "real.zmx").exists()


# -- the standard surface and the even asphere against their formulas ------------------------------------------------
def _even_sag_numpy(c, k, coeffs, r):
    return c * r**2 / (1 + np.sqrt(1 - (1 + k) * c**2 * r**2)) + sum(a * r ** (2 * j + 4) for j, a in enumerate(coeffs))


@pytest.mark.parametrize("name", ["standard", "even_asphere"])
def test_the_conic_and_even_asphere_sags_are_their_formulas(name):
    s = EXAMPLES[name]
    r = np.linspace(0, 9, 31)
    ref = _even_sag_numpy(s.curvature_per_mm, s.conic, s.aspheric_coefficients, r)
    np.testing.assert_allclose(_sag(s, torch.tensor(r)).numpy(), ref, rtol=1e-14, atol=1e-16)
    assert s.is_aspheric and not replace(s, conic=0.0, aspheric_coefficients=()).is_aspheric


# -- Qbfs --------------------------------------------------------------------------------------------------------------
def _forbes_q(x):
    """The first five Qbfs polynomials as Forbes printed them (Opt. Express 15, 5218 (2007))."""
    return [1 + 0 * x, (13 - 16 * x) / math.sqrt(19), math.sqrt(2 / 95) * (29 - 4 * x * (25 - 19 * x)),
            math.sqrt(2 / 2545) * (207 - 4 * x * (315 - x * (577 - 320 * x))),
            (7737 - 16 * x * (4653 - 2 * x * (7381 - 8 * x * (1168 - 509 * x)))) / (3 * math.sqrt(131831))]


def test_the_qbfs_polynomials_are_forbes_s_published_ones():
    x = torch.linspace(0, 1, 101, dtype=D)
    ours = qbfs_polynomials(x, 5)
    for (q, dq), ref in zip(ours, _forbes_q(x)):
        torch.testing.assert_close(q, ref, rtol=0, atol=1e-13)
    h = 1e-6  # the recurrence's derivative too
    for (_, dq), hi, lo in zip(ours, _forbes_q(x + h), _forbes_q(x - h)):
        torch.testing.assert_close(dq, (hi - lo) / (2 * h), rtol=0, atol=1e-7)


def _chebyshev_mean_square_slope(departure, rn: float, n: int = 64) -> float:
    """Forbes's mean square slope ``<(d departure / du)^2>`` (weight ``1 / sqrt(1 - u^2)`` over the aperture) by
    Gauss-Chebyshev quadrature (nodes on ``u`` in (-1, 1), the integrand even), slopes by central differences."""
    u = np.cos((2 * np.arange(1, n + 1) - 1) * np.pi / (2 * n))
    h = 1e-6
    slope = (departure((u + h) * rn) - departure((u - h) * rn)) / (2 * h)
    return float(np.mean(slope**2))


@pytest.mark.parametrize("c", [0.0, 1 / 60.0, -1 / 25.0])
def test_qbfs_coefficients_measure_the_slope_departure_from_the_best_fit_sphere(c):
    """Forbes's orthogonality: the mean square of the slope (per unit ``u``) of the departure measured normal to the
    best-fit sphere is ``sum a_m^2``. The departure is found geometrically (each sag point's distance to the sphere
    of curvature ``c``); for a flat sphere it is the sag itself, exactly. Curved: exact to the departure's second
    order (``~ a^2 c``: 7e-8 and 1.2e-6 of it here, measured)."""
    rn = 10.0
    a = (2e-3, -1.5e-3, 8e-4, 5e-4, -3e-4, 1e-4)
    s = PrescriptionSurface(c, kind="qbfs", aspheric_coefficients=a, shape_parameters={"normalization_radius_mm": rn})

    def normal_departure(r):
        z = _sag(s, torch.tensor(np.abs(r))).numpy()
        if c == 0:
            return z
        R = 1 / c  # the sphere's centre on the axis at z = R; a point's distance to it less |R|, towards the sphere
        return np.sign(R) * (abs(R) - np.sqrt(r**2 + (z - R) ** 2))

    got = _chebyshev_mean_square_slope(normal_departure, rn)
    assert got == pytest.approx(sum(v * v for v in a), rel=1e-9 if c == 0 else 1e-5)
    # one term alone: its slope has unit mean square (orthonormal), and two terms' slopes are orthogonal
    for m in (0, 3):
        one = replace(s, curvature_per_mm=0.0, aspheric_coefficients=(0.0,) * m + (1e-3,))
        assert _chebyshev_mean_square_slope(lambda r: _sag(one, torch.tensor(np.abs(r))).numpy(), rn) == \
            pytest.approx(1e-6, rel=1e-9)


def test_all_qbfs_terms_have_orthonormal_slopes():
    """The Gram matrix of the slopes ``d/du [u^2 (1 - u^2) Q_m(u^2)]`` of every term a surface may have, by
    Gauss-Chebyshev quadrature (exact for these polynomials), is the identity: the recurrence holds to the last."""
    n = 200
    u = torch.cos((2 * torch.arange(1, n + 1, dtype=D) - 1) * math.pi / (2 * n))
    x = u * u
    slopes = torch.stack([2 * u * ((1 - 2 * x) * q + x * (1 - x) * dq) for q, dq in qbfs_polynomials(x, QBFS_MAX_TERMS)])
    torch.testing.assert_close(slopes @ slopes.T / n, torch.eye(QBFS_MAX_TERMS, dtype=D), rtol=0, atol=1e-13)


def _qbfs_as_even_asphere(rn: float, a) -> tuple[float, tuple[float, ...]]:
    """A flat-based Qbfs as a paraboloid plus ``A4 ... A16``: ``u^2 (1 - u^2) sum a_m Q_m(u^2)`` expanded in
    ``x = u^2`` with Forbes's published polynomials (numpy), ``p_1 x`` the paraboloid ``c r^2 / 2``."""
    P = np.polynomial.Polynomial
    x = P([0.0, 1.0])
    bracket = x * (1 - x) * sum(am * q for am, q in zip(a, _forbes_q(x)))
    p = bracket.coef
    return 2 * p[1] / rn**2, tuple(p[j] / rn ** (2 * j) for j in range(2, len(p)))


def test_a_qbfs_surface_is_the_even_asphere_its_coefficients_convert_to():
    """A plano-convex lens whose flat side is a Qbfs asphere (flat best-fit sphere): converted exactly to a
    paraboloid with A4..A12, both give the same sag, paraxial data, Seidel sums, asphere cost and traced wavefront."""
    rn, a = 10.0, (2e-3, -1.5e-3, 8e-4, 5e-4)
    q = PrescriptionSurface(0.0, 80.0, "air", kind="qbfs", aspheric_coefficients=a, semi_diameter_mm=10.0,
                            shape_parameters={"normalization_radius_mm": rn})
    c, A = _qbfs_as_even_asphere(rn, a)
    assert len(A) == 4 and c != 0
    e = PrescriptionSurface(c, 80.0, "air", conic=-1.0, aspheric_coefficients=A, semi_diameter_mm=10.0)
    r = torch.linspace(0, 10, 41, dtype=D)
    torch.testing.assert_close(_sag(q, r), _sag(e, r), rtol=1e-12, atol=1e-15)
    front = PrescriptionSurface(1 / 50.0, 6.0, GLASS, semi_diameter_mm=10.0)
    pq, pe = (Prescription(surfaces=(front, s), stop_surface=1, entrance_pupil_diameter_mm=16.0, fields=(0.0, 5.0),
                           wavelengths_um=(0.5875618,)) for s in (q, e))
    sq, se = SequentialLens(pq), SequentialLens(pe)
    assert sq.paraxial().efl_mm == pytest.approx(se.paraxial().efl_mm, rel=1e-13)
    torch.testing.assert_close(sq.seidel_surfaces(5.0), se.seidel_surfaces(5.0), rtol=1e-10, atol=1e-15)
    cq, ce = prescription_costs(pq), prescription_costs(pe)
    assert list(cq) == list(ce) == [2] and cq[2]["cost"] == pytest.approx(ce[2]["cost"], rel=1e-9)
    px, py = pupil_grid(24)
    for field in (0.0, 5.0):
        wq, we = sq.wavefront(field, px, py), se.wavefront(field, px, py)
        assert wq.rms_waves() > 0.1  # an aberrated lens: the comparison is not of zeros
        assert bool(torch.equal(wq.valid, we.valid))
        torch.testing.assert_close(wq.opd_waves[wq.valid], we.opd_waves[we.valid], rtol=0, atol=1e-9)


def test_qbfs_surfaces_are_refused_in_one_line():
    base = {"radius_mm": 60.0, "thickness_mm": 4.0, "material": list(GLASS), "kind": "qbfs",
            "normalization_radius_mm": 10.0, "aspheric_coefficients": [1e-3]}
    lens = {"stop_surface": 1, "aperture": {"entrance_pupil_diameter_mm": 10.0},
            "surfaces": [base, {"radius_mm": "inf", "thickness_mm": 90.0}]}
    assert prescription_from_dict(lens).surfaces[0].surface_kind.name == "qbfs"
    bad = {"conic": (-1.0, r"surface 1: conic = -1.0 is not allowed on a qbfs surface"),
           "normalization_radius_mm": (0.0, r"surface 1: normalization_radius_mm = 0.0 is not allowed: a radius > 0"),
           "kind": ("qbsf", r"surface 1: kind 'qbsf' is not known; valid: qbfs"),
           "aspheric_coefficients": ([1e-3] * 21, r"surface 1: 21 aspheric coefficients given; at most 20")}
    for key, (value, message) in bad.items():
        d = dict(lens, surfaces=[dict(base, **{key: value}), lens["surfaces"][1]])
        with pytest.raises(PrescriptionError, match="^" + message) as exc:
            prescription_from_dict(d)
        assert "\n" not in str(exc.value)
    d = dict(lens, surfaces=[{k: v for k, v in base.items() if k != "normalization_radius_mm"}, lens["surfaces"][1]])
    with pytest.raises(PrescriptionError, match="^surface 1: a qbfs surface needs normalization_radius_mm$"):
        prescription_from_dict(d)
    d = dict(lens, surfaces=[dict(base, kind="standard", normalization_radius_mm=1.0), lens["surfaces"][1]])
    with pytest.raises(PrescriptionError, match="^surface 1: unknown key 'normalization_radius_mm'"):
        prescription_from_dict(d)
