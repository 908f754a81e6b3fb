"""Decentred and tilted surfaces and elements in the sequential tracer (SequentialLens ``misalignments``), each checked
against something independent of the code under test: the tilted plane-parallel plate's closed-form displacement and
optical path, a sphere's invariance under rotations about its centre of curvature, paraxial magnification (the image of
a decentred lens moves by ``delta (1 - m)``), the mirror symmetries of the geometry, a whole lens tilted being the
same lens seen at another field, an aperture's projected shape, and the linear / quadratic growth of the aberrations a
decentre introduces."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim.io.prescription_file import read_lens
from lenssim.model.misalignment import Misalignment, element_misalignment
from lenssim.model.prescription import Prescription
from lenssim.model.prescription import PrescriptionSurface as S
from lenssim.optics.sequential import SequentialLens, pupil_grid

N_GLASS = 1.5
MODEL = (N_GLASS, 0.0)  # a model glass without dispersion
F64 = torch.float64


def _rays(x, y, z, direction):
    """Rays from the points ``(x, y, z)`` (tensors / floats) along one ``direction``."""
    x = torch.as_tensor(x, dtype=F64).reshape(-1)
    y = torch.as_tensor(y, dtype=F64).reshape(-1)
    P = torch.stack([x, y, torch.full_like(x, float(z))], -1)
    d = torch.tensor(direction, dtype=F64).expand_as(P)
    return P, d


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=F64)


def _triplet_misaligned():
    p = read_lens("cooke_triplet")
    m = element_misalignment(p, 2, 3, decentre_x_mm=0.03, decentre_y_mm=-0.02, tilt_x_deg=0.05, tilt_y_deg=-0.08)
    m[4] = Misalignment(decentre_x_mm=-0.04, tilt_y_deg=0.1)  # the stop too
    return p, m


# -- the model -----------------------------------------------------------------------------------------------------
def test_misalignment_validates_and_turns_with_the_frame():
    with pytest.raises(ValueError, match=r"^misalignment: decentre_y_mm=nan is not allowed: a finite number$"):
        Misalignment(decentre_y_mm=float("nan"))
    with pytest.raises(ValueError, match=r"^misalignment: tilt_x_deg=True is not allowed"):
        Misalignment(tilt_x_deg=True)
    with pytest.raises(ValueError, match=r"^misalignment: pivot_z_mm='a' is not allowed"):
        Misalignment(pivot_z_mm="a")
    with pytest.raises(ValueError, match=r"^misalignment: tilt_x_deg=60.0, tilt_y_deg=70.0 is not allowed"):
        Misalignment(tilt_x_deg=60, tilt_y_deg=70)
    assert Misalignment(pivot_z_mm=3.0).is_zero and not Misalignment(tilt_y_deg=1e-9).is_zero
    m = Misalignment(decentre_x_mm=0.1, decentre_y_mm=0.0, tilt_x_deg=0.0, tilt_y_deg=0.2, pivot_z_mm=4.0)
    q = m.rotated(90)  # the new frame's +y is the old +x, its +x the old -y
    assert (q.decentre_x_mm, q.decentre_y_mm, q.tilt_x_deg, q.tilt_y_deg, q.pivot_z_mm) == (0.0, 0.1, -0.2, 0.0, 4.0)
    r = m.rotated(30).rotated(45)
    assert r.decentre_x_mm == pytest.approx(m.rotated(75).decentre_x_mm, abs=1e-15)
    assert r.tilt_y_deg == pytest.approx(m.rotated(75).tilt_y_deg, abs=1e-15)
    assert m.rotated(360) == m
    # the rotation matrix: tilt_x alone is R_x (the axis turns toward -y), tilt_y alone R_y (toward +x), orthonormal
    a = math.radians(7.0)
    assert torch.allclose(torch.tensor(Misalignment(tilt_x_deg=7.0).rotation_matrix(), dtype=F64), _rx(a),
                          atol=1e-16, rtol=0)
    Ry = torch.tensor(Misalignment(tilt_y_deg=7.0).rotation_matrix(), dtype=F64)
    assert torch.allclose(Ry[:, 2], torch.tensor([math.sin(a), 0, math.cos(a)], dtype=F64), atol=1e-16, rtol=0)
    R = torch.tensor(Misalignment(tilt_x_deg=3.0, tilt_y_deg=-4.0).rotation_matrix(), dtype=F64)
    assert torch.allclose(R @ R.T, torch.eye(3, dtype=F64), atol=1e-15, rtol=0)
    assert float(torch.linalg.det(R)) == pytest.approx(1.0, abs=1e-15)
    axis = torch.tensor([3.0, -4.0, 0.0], dtype=F64) / 5  # the rotation's axis is the tilt vector; its angle 5 deg
    assert torch.allclose(R @ axis, axis, atol=1e-16, rtol=0)
    assert math.degrees(math.acos((float(torch.trace(R)) - 1) / 2)) == pytest.approx(5.0, rel=1e-9)


def test_an_element_misalignment_pivots_at_its_first_vertex_and_bad_input_is_named():
    p = read_lens("cooke_triplet")
    m = element_misalignment(p, 2, 3, decentre_y_mm=0.05, tilt_x_deg=0.1)
    assert set(m) == {2, 3} and m[2] == m[3] and m[2].pivot_z_mm == pytest.approx(5.90 + 12.93, abs=1e-12)
    with pytest.raises(ValueError, match=r"^element: last=7 is not allowed: a surface index from 0 to 6$"):
        element_misalignment(p, 2, 7)
    with pytest.raises(ValueError, match=r"^element: last=1 is not allowed: an index >= first=2$"):
        element_misalignment(p, 2, 1)
    with pytest.raises(ValueError, match=r"^misalignment at surface index 7 is not allowed: 0 to 6$"):
        SequentialLens(p, misalignments={7: Misalignment(decentre_x_mm=1.0)})
    with pytest.raises(ValueError, match=r"^surface 3: misalignment 0.1 is not allowed: a lenssim"):
        SequentialLens(p, misalignments={2: 0.1})


# -- 1. zero misalignment is the nominal lens, bit for bit ---------------------------------------------------------
def test_zero_misalignments_are_the_nominal_lens_exactly():
    p = read_lens("cooke_triplet")
    nominal = SequentialLens(p, index_offsets={0: 1e-3})
    zero = SequentialLens(p, index_offsets={0: 1e-3},
                          misalignments={i: Misalignment(pivot_z_mm=float(i)) for i in range(len(p.surfaces))})
    assert zero.misalignments == {} and zero.is_centred and zero.cache_key() == nominal.cache_key()
    turned = nominal.rotated(37.0)
    assert turned.cache_key() == nominal.cache_key()
    px, py = pupil_grid(12)
    for lens in (zero, turned):
        for f in (0.0, 11.86):
            a, b = lens.wavefront(f, px, py), nominal.wavefront(f, px, py)
            assert torch.equal(a.opd_waves.nan_to_num(-7.0), b.opd_waves.nan_to_num(-7.0)) and torch.equal(a.valid, b.valid)
            assert torch.equal(a.image_mm.nan_to_num(-7.0), b.image_mm.nan_to_num(-7.0))
        P, d, o = lens.aim(8.36, px, py)
        ra, rb = lens.trace(P, d, opl_start=o), nominal.trace(P, d, opl_start=o)
        assert torch.equal(ra.points, rb.points) and torch.equal(ra.directions, rb.directions)
        assert torch.equal(ra.opl, rb.opl) and torch.equal(ra.valid, rb.valid)
    moved = SequentialLens(p, index_offsets={0: 1e-3}, misalignments={2: Misalignment(decentre_y_mm=1e-6)})
    assert not moved.is_centred and moved.cache_key() != nominal.cache_key() and "misalignments" in moved.cache_key()


# -- 2. the tilted plane-parallel plate ----------------------------------------------------------------------------
@pytest.mark.parametrize("theta_deg", [5.0, 20.0, 40.0])
@pytest.mark.parametrize("axis", ["x", "y"])
def test_a_tilted_plate_displaces_a_collimated_beam_by_the_closed_form(theta_deg, axis):
    """A plate of thickness t and index n tilted by theta (an element, pivot at its first face) shifts a beam along
    the axis sideways by t sin(theta) (1 - cos(theta) / sqrt(n^2 - sin^2 theta)), away from where its normal turns
    (R_x: the normal turns toward -y, so the beam moves to -y; R_y: toward +x, the beam to +x), keeps its direction,
    and adds the optical path t (n cos theta' - cos theta) (Born & Wolf's plate, n cos theta' = sqrt(n^2 - sin^2))."""
    t, dn = 4.0, 0.012  # with an index offset: the melt's error is the plate's index
    n = N_GLASS + dn
    p = Prescription((S(0.0, t, MODEL), S(0.0, 20.0, "air")), 1, 10.0)
    tilt = {"tilt_x_deg": theta_deg} if axis == "x" else {"tilt_y_deg": theta_deg}
    seq = SequentialLens(p, index_offsets={0: dn}, misalignments=element_misalignment(p, 0, 1, **tilt))
    g = torch.linspace(-2, 2, 5, dtype=F64)
    X, Y = torch.meshgrid(g, g, indexing="ij")
    P, d = _rays(X, Y, -5.0, (0.0, 0.0, 1.0))
    b = seq.trace(P, d)
    assert b.valid.all()
    th = math.radians(theta_deg)
    root = math.sqrt(n * n - math.sin(th) ** 2)
    shift = t * math.sin(th) * (1 - math.cos(th) / root)
    moved = b.points[:, 1] - P[:, 1] if axis == "x" else b.points[:, 0] - P[:, 0]
    across = b.points[:, 0] - P[:, 0] if axis == "x" else b.points[:, 1] - P[:, 1]
    assert torch.allclose(moved, torch.full_like(moved, -shift if axis == "x" else shift), atol=1e-12, rtol=0)
    assert across.abs().max() < 1e-12
    assert torch.allclose(b.directions, d, atol=1e-14, rtol=0)
    z_ref = 30.0  # the optical path to a plane behind the plate, against air's
    opl = b.opl + (z_ref - b.points[:, 2])
    assert torch.allclose(opl - z_ref, torch.full_like(opl, t * (root - math.cos(th))), atol=1e-12, rtol=0)


# -- 3. a sphere is a sphere ----------------------------------------------------------------------------------------
def test_a_decentred_sphere_is_the_sphere_rotated_about_its_centre_of_curvature():
    """A sphere (radius R, vertex z_v) decentred by delta has its centre at (0, delta, z_v + R). The same point set is:
    (b) the sphere tilted about its own vertex by -asin(delta / R) (R_x moves the centre to (0, R sin, z_v + R cos))
    with the vertex moved back by R (1 - cos) along the axis; (c) the decentred sphere rotated by any angle about its
    centre of curvature; and (d) a rotation about the centre of curvature alone leaves the nominal sphere. Rays
    well inside the aperture meet the same surface: the same points, directions and optical paths (to rounding)."""
    R, delta, gap = 30.0, 0.6, 10.0
    z_c = gap + R
    theta = math.asin(delta / R)

    def lens(first_gap, m):
        p = Prescription((S(0.0, first_gap, "air"), S(1 / R, 20.0, MODEL)), 1, 10.0)
        return SequentialLens(p, misalignments={1: m})

    a = lens(gap, Misalignment(decentre_y_mm=delta))
    b = lens(gap + R * (1 - math.cos(theta)), Misalignment(tilt_x_deg=-math.degrees(theta)))
    c = lens(gap, Misalignment(decentre_y_mm=delta, tilt_x_deg=12.0, tilt_y_deg=-7.0, pivot_z_mm=z_c))
    nominal = lens(gap, Misalignment())
    d = lens(gap, Misalignment(tilt_x_deg=math.degrees(theta), tilt_y_deg=5.0, pivot_z_mm=z_c))
    g = torch.linspace(-5, 5, 7, dtype=F64)
    X, Y = torch.meshgrid(g, g, indexing="ij")
    for direction in ((0.0, 0.0, 1.0), (0.03, -0.05, 1.0)):
        P, dd = _rays(X, Y, -1.0, direction)
        ra, rb, rc = a.trace(P, dd), b.trace(P, dd), c.trace(P, dd)
        for r in (rb, rc):
            assert r.valid.all() and torch.allclose(r.points, ra.points, atol=1e-12, rtol=0)
            assert torch.allclose(r.directions, ra.directions, atol=1e-13, rtol=0)
            assert torch.allclose(r.opl, ra.opl, atol=1e-12, rtol=0)
        rn, rd = nominal.trace(P, dd), d.trace(P, dd)
        assert torch.allclose(rd.points, rn.points, atol=1e-12, rtol=0)
        assert torch.allclose(rd.directions, rn.directions, atol=1e-13, rtol=0)
        assert (ra.points - rn.points).abs().max() > 0.1  # the decentre does move the rays


# -- 4. the image of a decentred lens -------------------------------------------------------------------------------
@pytest.mark.parametrize("object_mm", [math.inf, 200.0])
def test_a_decentred_singlet_moves_the_image_by_delta_times_one_minus_m(object_mm):
    """A lens in air moved across the axis by delta: an object point on the axis sits at -delta from the lens's
    axis and is imaged at -m delta from it (m the lateral magnification), i.e. at delta (1 - m) from the axis; an
    object at infinity images at the moved rear focal point (the nodal point moves with the lens): delta. The
    chief ray passes a fixed stop 5 mm before the lens (the lens alone moved), traced to the paraxial image plane; m
    from the paraxial trace of the centred lens. Linear in delta to third order."""
    surfs = (S(0.0, 5.0, "air"), S(1 / 50, 3.0, MODEL), S(-1 / 50, 60.0, "air"))
    p = Prescription(surfs, 1, 6.0, fields=(0.0, 1.0), object_distance_mm=object_mm)
    seq = SequentialLens(p)
    p = p.with_image_distance(seq.paraxial().image_z_mm - p.vertex_z_mm[-1])
    if math.isinf(object_mm):
        m = 0.0
    else:
        m = -SequentialLens(p).paraxial().image_heights_mm[1] / 1.0  # the object height 1 mm sits at y = -1
        assert m == pytest.approx(-0.34, abs=0.02)  # ~ -v / u of a thin 50.5 mm lens at 200 mm
    zero = torch.zeros(1, dtype=F64)
    shifts = []
    for delta in (0.01, 0.02):
        lens = SequentialLens(p, misalignments=element_misalignment(p, 1, 2, decentre_y_mm=delta))
        chief = lens.wavefront(0.0, zero, zero).chief_mm
        assert float(chief[0]) == 0.0
        assert float(chief[1]) == pytest.approx(delta * (1 - m), rel=2e-6)  # measured 2.5e-7 at 0.02 mm
        shifts.append(float(chief[1]))
    assert shifts[1] / shifts[0] == pytest.approx(2.0, rel=1e-5)


# -- 5. symmetry -------------------------------------------------------------------------------------------------------
def test_decentres_keep_the_mirror_symmetries_of_the_geometry():
    """y -> -y maps a decentre dy to -dy, a field +a to -a and the pupil (px, py) to (px, -py), and keeps a decentre
    along x; x -> -x maps dx to -dx and (px, py) to (-px, py). The OPD maps with the pupil, the image points with
    the space."""
    p = read_lens("cooke_triplet")
    px, py = pupil_grid(10)

    def lens(dx=0.0, dy=0.0):
        return SequentialLens(p, misalignments=element_misalignment(p, 2, 3, decentre_x_mm=dx, decentre_y_mm=dy,
                                                                    tilt_x_deg=-20 * dy, tilt_y_deg=20 * dx))

    up, down = lens(dy=0.03), lens(dy=-0.03)
    a, b = up.wavefront(6.0, px, py), down.wavefront(-6.0, px, -py)
    assert torch.allclose(a.opd_waves, b.opd_waves, atol=1e-9, rtol=0, equal_nan=True)
    assert torch.allclose(a.image_mm[:, 1], -b.image_mm[:, 1], atol=1e-11, rtol=0, equal_nan=True)
    assert torch.allclose(a.image_mm[:, 0], b.image_mm[:, 0], atol=1e-11, rtol=0, equal_nan=True)
    # along x: the sagittal mirror (x -> -x) of one field is broken, restored by dx -> -dx; y -> -y is kept
    right, left = lens(dx=0.03), lens(dx=-0.03)
    a, b, c = right.wavefront(6.0, px, py), left.wavefront(6.0, -px, py), right.wavefront(6.0, -px, py)
    assert torch.allclose(a.opd_waves, b.opd_waves, atol=1e-9, rtol=0, equal_nan=True)
    assert torch.allclose(a.image_mm[:, 0], -b.image_mm[:, 0], atol=1e-11, rtol=0, equal_nan=True)
    assert (a.opd_waves - c.opd_waves).nan_to_num(0.0).abs().max() > 0.05  # broken by the decentre along x
    a, b = right.wavefront(6.0, px, py), right.wavefront(-6.0, px, -py)
    assert torch.allclose(a.opd_waves, b.opd_waves, atol=1e-9, rtol=0, equal_nan=True)
    assert torch.allclose(a.image_mm[:, 1], -b.image_mm[:, 1], atol=1e-11, rtol=0, equal_nan=True)
    # on the axis a decentre along y breaks y -> -y of the pupil and keeps x -> -x
    a, b, c = up.wavefront(0.0, px, py), up.wavefront(0.0, px, -py), up.wavefront(0.0, -px, py)
    assert (a.opd_waves - b.opd_waves).nan_to_num(0.0).abs().max() > 0.05
    assert torch.allclose(a.opd_waves, c.opd_waves, atol=1e-9, rtol=0, equal_nan=True)


@pytest.mark.parametrize("azimuth_deg", [90.0, 30.0])
def test_a_rotated_lens_at_its_y_field_is_the_lens_at_that_azimuth(azimuth_deg):
    """The lens (element 2 decentred and tilted, the stop decentred and tilted) at the field of image azimuth phi
    (from +y toward +x): built here with ``trace`` alone, from the rotated lens's aimed rays carried into the
    original's frame by the turn (x, y) -> (x c + y s, -x s + y c). The original's trace, turned back, is the rotated
    lens's; its chief ray crosses the (moved) stop at the stop's own centre."""
    p, m = _triplet_misaligned()
    lens = SequentialLens(p, misalignments=m)
    turned = lens.rotated(azimuth_deg)
    phi = math.radians(azimuth_deg)
    c, s = (0.0, 1.0) if azimuth_deg == 90.0 else (math.cos(phi), math.sin(phi))
    Q = torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=F64)  # original frame -> turned frame (row: v @ Q.T)
    a = math.radians(8.0)
    px, py = pupil_grid(8)
    px, py = torch.cat([torch.zeros(1, dtype=F64), px]), torch.cat([torch.zeros(1, dtype=F64), py])
    P, d, o = turned.aim(8.0, px, py)
    P0, d0 = P @ Q, d @ Q  # into the original frame: the field along azimuth phi
    assert torch.allclose(d0[0], torch.tensor([math.sin(a) * math.sin(phi), math.sin(a) * math.cos(phi),
                                               math.cos(a)], dtype=F64), atol=1e-15, rtol=0)
    ref = turned.trace(P, d, opl_start=o)
    got = lens.trace(P0, d0, opl_start=o)
    assert torch.equal(got.valid, ref.valid) and ref.valid[0]
    assert torch.allclose(got.points @ Q.T, ref.points, atol=1e-11, rtol=0, equal_nan=True)
    assert torch.allclose(got.directions @ Q.T, ref.directions, atol=1e-13, rtol=0)
    assert torch.allclose(got.opl, ref.opl, atol=1e-11, rtol=0, equal_nan=True)
    # the chief ray meets the stop at its moved centre (0 in the stop's frame, here a decentre and a tilt about y)
    at_stop = lens.trace(P0[:1], d0[:1], upto=4, opl_start=o[:1] if o is not None else None).points[0]
    st = m[4]
    Rs = torch.tensor(st.rotation_matrix(), dtype=F64)
    z4 = p.vertex_z_mm[4]
    local = Rs.T @ (at_stop - torch.tensor([st.decentre_x_mm, st.decentre_y_mm, z4], dtype=F64))
    assert local.abs().max() < 1e-9 and abs(float(at_stop[0]) - st.decentre_x_mm) < 1e-9


# -- 6. a tilted lens is the same lens at another field ------------------------------------------------------------
def test_a_whole_tilted_lens_at_field_zero_is_the_lens_at_the_tilt_as_field():
    """Every surface turned by R_x(eps) about one pivot: a beam along +z meets the lens as the untilted lens meets the
    beam along R_x(-eps) z = (0, sin eps, cos eps), the field +eps (this module's convention: tilt_x turns the axis to
    -y). The aimed rays are the same lines turned by R_x(eps) about the pivot; after the last surface (before the image
    plane, which does not turn) points and directions match, optical paths up to one constant."""
    p = read_lens("cooke_triplet")
    eps, pivot = 0.5, 14.0
    m = Misalignment(tilt_x_deg=eps, pivot_z_mm=pivot)
    tilted = SequentialLens(p, misalignments={i: m for i in range(len(p.surfaces))})
    plain = SequentialLens(p)
    px, py = pupil_grid(8)
    P, d, o = tilted.aim(0.0, px, py)
    rt = tilted.trace(P, d, opl_start=o)
    P, d, o = plain.aim(eps, px, py)
    ru = plain.trace(P, d, opl_start=o)
    R = _rx(math.radians(eps))
    piv = torch.tensor([0.0, 0.0, pivot], dtype=F64)
    assert torch.equal(rt.valid, ru.valid) and rt.valid.sum() > 40
    v = rt.valid
    assert torch.allclose(rt.points[v], (ru.points[v] - piv) @ R.T + piv, atol=1e-8, rtol=0)
    assert torch.allclose(rt.directions[v], ru.directions[v] @ R.T, atol=1e-10, rtol=0)
    dopl = rt.opl[v] - ru.opl[v]
    assert float(dopl.max() - dopl.min()) < 1e-8


# -- 7. the wavefront of a decentred Cooke triplet ------------------------------------------------------------------
def test_a_decentre_adds_axial_coma_linearly_and_symmetric_aberrations_quadratically():
    """Element 2 of the Cooke triplet decentred by delta along y, on the axis: the wavefront's part odd in py (zero
    for the centred lens) is fitted by py, py rho^2, py rho^4: its coma (py rho^2) and the rest grow linearly in
    delta (mirror symmetry: -delta flips them, so no delta^2 term); the even part's change is quadratic in delta."""
    p = read_lens("cooke_triplet")
    px, py = pupil_grid(20)
    r2 = px**2 + py**2
    A = torch.stack([py, py * r2, py * r2**2], -1)

    def parts(delta):
        lens = SequentialLens(p, misalignments=element_misalignment(p, 2, 3, decentre_y_mm=delta))
        w = lens.wavefront(0.0, torch.cat([px, px]), torch.cat([py, -py])).opd_waves
        a, b = w[:px.numel()], w[px.numel():]
        return torch.linalg.lstsq(A, ((a - b) / 2)[:, None]).solution[:, 0], (a + b) / 2

    c0, e0 = parts(0.0)
    c1, e1 = parts(0.01)
    c2, e2 = parts(0.02)
    assert c0.abs().max() < 1e-9
    assert abs(float(c1[1])) > 0.2  # ~0.47 waves of coma per 10 um: a sensitive element
    assert torch.allclose(c2 / c1, torch.full_like(c1, 2.0), rtol=1e-4, atol=0)  # measured 1.6e-5
    de1, de2 = e1 - e0, e2 - e0
    assert float(de1.abs().max()) > 1e-4  # 5.8e-4 waves
    assert torch.allclose(de2, 4 * de1, rtol=0, atol=1e-4 * float(de2.abs().max()))  # measured 1.7e-6


# -- aperture and aiming ----------------------------------------------------------------------------------------------
def test_a_moved_aperture_clips_in_its_own_frame():
    """A flat aperture (semi-diameter a) decentred by (dx, dy) passes the rays along z within a of its centre; tilted
    by theta about x (about its vertex) its projection on the xy plane is the ellipse x^2 + (y / cos theta)^2 <= a^2."""
    a = 2.0
    g = torch.linspace(-3, 3, 61, dtype=F64)
    X, Y = torch.meshgrid(g + 1e-3, g + 2e-3, indexing="ij")  # no ray on a rim
    P, d = _rays(X, Y, -1.0, (0.0, 0.0, 1.0))
    p = Prescription((S(0.0, 5.0, "air"), S(0.0, 5.0, "air", semi_diameter_mm=a), S(0.0, 5.0, "air")), 1, 4.0)
    b = SequentialLens(p, misalignments={1: Misalignment(decentre_x_mm=0.4, decentre_y_mm=-0.7)}).trace(P, d)
    assert torch.equal(b.valid, (P[:, 0] - 0.4) ** 2 + (P[:, 1] + 0.7) ** 2 <= a * a)
    assert torch.equal(b.clipped_at == 2, ~b.valid)
    th = math.radians(35.0)
    b = SequentialLens(p, misalignments={1: Misalignment(tilt_x_deg=35.0)}).trace(P, d)
    assert torch.equal(b.valid, P[:, 0] ** 2 + (P[:, 1] / math.cos(th)) ** 2 <= a * a)


def test_rays_are_aimed_at_the_moved_stop_in_its_own_frame():
    """A stop decentred (0.3, -0.2) mm and tilted: the pupil point (px, py) meets it at (px, py) times the stop's
    paraxial radius in its own frame (its motion undone with the rotation written out here)."""
    surfs = (S(1 / 40, 4.0, MODEL), S(-1 / 200, 8.0, "air"), S(0.0, 8.0, "air"), S(1 / 60, 4.0, MODEL),
             S(-1 / 40, 40.0, "air"))
    p = Prescription(surfs, 3, 10.0, fields=(0.0, 15.0))
    st = Misalignment(decentre_x_mm=0.3, decentre_y_mm=-0.2, tilt_x_deg=2.0)
    seq = SequentialLens(p, misalignments={2: st, 0: Misalignment(tilt_y_deg=0.5)})
    px, py = pupil_grid(6)
    P, d, o = seq.aim(15.0, px, py)
    at = seq.trace(P, d, upto=2, opl_start=o, vignette=False).points
    z = p.vertex_z_mm[2]
    local = (at - torch.tensor([0.3, -0.2, z], dtype=F64)) @ _rx(math.radians(2.0))  # R^T (X - pivot - decentre)
    r = seq.paraxial().stop_radius_mm
    assert torch.allclose(local[:, :2], torch.stack([px, py], -1) * r, atol=1e-8 * r, rtol=0)
    assert local[:, 2].abs().max() < 1e-12  # on the (flat) stop


def test_a_sequence_of_motions_is_applied_in_order():
    """A surface's own wedge, then its element's motion: a tuple of motions composes them in order. A tilt then a
    decentre (one Misalignment) equals the tuple (tilt, decentre); the reverse order differs by the tilt applied to
    the decentre (second order), and the key tells the two apart."""
    p = read_lens("cooke_triplet")
    tilt = Misalignment(tilt_x_deg=0.4, tilt_y_deg=-0.3)
    dec = Misalignment(decentre_x_mm=0.2, decentre_y_mm=-0.1)
    both = Misalignment(decentre_x_mm=0.2, decentre_y_mm=-0.1, tilt_x_deg=0.4, tilt_y_deg=-0.3)
    px, py = pupil_grid(16)
    one = SequentialLens(p, misalignments={2: both}).wavefront(5.0, px, py)
    seq = SequentialLens(p, misalignments={2: (tilt, dec)})
    two = seq.wavefront(5.0, px, py)
    ok = one.valid
    assert torch.allclose(one.image_mm[ok], two.image_mm[ok], atol=1e-12, rtol=0)
    assert torch.allclose(one.opd_waves[ok], two.opd_waves[ok], atol=1e-9, rtol=0)
    rev = SequentialLens(p, misalignments={2: (dec, tilt)})
    assert not torch.allclose(rev.wavefront(5.0, px, py).image_mm[ok], one.image_mm[ok], atol=1e-9, rtol=0)
    assert seq.cache_key() != SequentialLens(p, misalignments={2: both}).cache_key()
    turned = seq.rotated(90).misalignments[2]
    assert turned == (tilt.rotated(90), dec.rotated(90))
