"""Any lens from a prescription (issue 29): paraxial data, Seidel sums, real rays and the exact wavefront, each against
something independent: today's thin singlet (its closed-form Seidel sums and its exact OPD: its own beam and sphere), Cartesian ovals
(closed form: zero OPD), the third-order limit of the real OPD, the area a semi-diameter leaves, thin-lens optics."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import Design
from lenssim.model.prescription import Prescription, PrescriptionError
from lenssim.model.prescription import PrescriptionSurface as S
from lenssim.optics.exact_wavefront import opd
from lenssim.optics.sequential import RayTraceError, SequentialLens, pupil_grid
from lenssim_studies.paper import PAPER_CAMERA

N_GLASS = 1.5
MODEL = (N_GLASS, 0.0)  # a model glass without dispersion


def _paper_singlet(s=-0.775, q=-2.4):
    lens = PAPER_CAMERA.lens
    d = Design(s=s, Q_back=q).to(torch.float64)
    lam = PAPER_CAMERA.spectrum.wavelengths_um[0]
    return SequentialLens(lens.prescription(d, (lam,))), lens, d, lam


def test_the_singlets_named_design_is_its_shipped_prescription():
    """One lens, two names: ``Lens.prescription`` of the paper's end-to-end design is
    ``configs/lenses/paper_singlet.toml`` (transcribed from the paper independently), and the prescription's free
    parameters read back the design's values under their lens names."""
    from dataclasses import replace

    from lenssim.io.prescription_file import read_lens
    from lenssim.model.design import PARAMETERS
    from lenssim.model.lens_parameters import parameter_values, parse_parameter

    d = Design(s=-0.775, Q_back=-2.4, Q_front=0.3, focus_shift_um=12.0)
    p = PAPER_CAMERA.lens.prescription(d, (0.5,))
    shipped = read_lens("paper_singlet")
    made = PAPER_CAMERA.lens.prescription(Design(s=-0.775, Q_back=-2.4), (0.5,))
    strip = lambda q: replace(q, surfaces=tuple(replace(x, comment="") for x in q.surfaces), name="", source="",  # noqa: E731
                              notes="", extra={})
    assert strip(made) == strip(shipped)
    shape = [par for par in PARAMETERS.values() if par.lens_name != "focus_um"]
    values = parameter_values(p, [parse_parameter(p, par.lens_name) for par in shape])
    assert values == pytest.approx({par.lens_name: float(d[par.name]) for par in shape}, rel=1e-12)
    # the focus shift is in the image distance (focus_um moves the image plane from there)
    assert (p.image_z_mm - made.image_z_mm) * 1e3 == pytest.approx(12.0, rel=1e-9)
    assert float(Design(**{"E1.bending": 0.5, "S2.conic": -1.0})["Q_back"]) == -1.0
    with pytest.raises(ValueError, match="one lens"):
        PAPER_CAMERA.lens.prescription(Design(s=torch.tensor([0.1, 0.2])), (0.5,))


@pytest.mark.parametrize("alpha", [0.0, 7.0, 14.0])
def test_the_thin_singlet_as_a_prescription_is_todays_lens(alpha):
    seq, lens, d, lam = _paper_singlet()
    par = seq.paraxial()
    assert par.efl_mm == pytest.approx(lens.focal_length_mm, rel=1e-12)
    assert par.bfl_mm == pytest.approx(lens.image_distance_mm, rel=1e-12)
    assert par.entrance_pupil_z_mm == 0 and par.exit_pupil_z_mm == pytest.approx(0, abs=1e-12)
    a = torch.tensor(alpha, dtype=torch.float64)
    assert torch.allclose(seq.seidel_surfaces(alpha).sum(0)[:4], lens.seidel_sums(d, a), rtol=1e-10, atol=1e-15)
    px, py = pupil_grid(12)
    w = seq.wavefront(alpha, px, py, aim="paraxial")  # the same rays as the singlet's trace: its plane pupil
    ref, _ = opd(lens, d, alpha, py, px, wavelength_um=lam)
    assert torch.allclose(w.opd_waves, ref / (lam * 1e-3), atol=1e-9, rtol=0)
    # real aiming puts the pupil on the (curved) stop surface: the same wavefront within a small fraction of it
    real = seq.wavefront(alpha, px, py)
    assert real.rms_waves() == pytest.approx(w.rms_waves(), rel=0.01, abs=1e-3)


def test_a_plano_hyperbolic_singlet_focuses_a_collimated_beam_perfectly():
    f = 50.0
    c2 = -1 / ((N_GLASS - 1) * f)  # flat side to the object, back radius -(n - 1) f
    p = Prescription((S(0.0, 5.0, MODEL), S(c2, f, "air", conic=-N_GLASS**2)), 1, 20.0)
    seq = SequentialLens(p)
    assert seq.paraxial().bfl_mm == pytest.approx(f, rel=1e-12)
    px, py = pupil_grid(24)
    w = seq.wavefront(0.0, px, py)
    assert w.valid.all() and w.pv_waves() < 1e-6 and w.rms_spot_mm() < 1e-9
    spherical = SequentialLens(Prescription((S(0.0, 5.0, MODEL), S(c2, f, "air")), 1, 20.0))
    assert spherical.wavefront(0.0, px, py).pv_waves() > 10  # the conic does the work (F/2.5)


def test_a_refracting_ellipsoid_focuses_inside_the_glass():
    r = 20.0
    image = N_GLASS * r / (N_GLASS - 1)  # the paraxial focus in the glass
    p = Prescription((S(1 / r, image, MODEL, conic=-1 / N_GLASS**2),), 1, 16.0)
    seq = SequentialLens(p)
    assert seq.paraxial().image_z_mm == pytest.approx(image, rel=1e-12)
    px, py = pupil_grid(24)
    w = seq.wavefront(0.0, px, py)
    assert w.pv_waves() < 1e-6
    assert SequentialLens(Prescription((S(1 / r, image, MODEL),), 1, 16.0)).wavefront(0.0, px, py).pv_waves() > 1


def _thick_singlet(epd, stop_gap=0.0, a4=0.0):
    """A biconvex spherical singlet (n = 1.5, R = +-50 mm, 5 mm thick), its stop ``stop_gap`` mm before it (a flat
    surface) or on its first surface, the image plane at the paraxial focus."""
    lens = (S(1 / 50, 5.0, MODEL, aspheric_coefficients=(a4,)), S(-1 / 50, 1.0, "air"))
    surfs = ((S(0.0, stop_gap, "air"),) if stop_gap else ()) + lens
    p = Prescription(surfs, 1, epd, fields=(0.0, 0.5))
    seq = SequentialLens(p)
    return SequentialLens(p.with_image_distance(seq.paraxial().bfl_mm))


@pytest.mark.parametrize("stop_gap, a4", [(0.0, 0.0), (15.0, 0.0), (15.0, 2e-6)])
def test_the_real_wavefront_tends_to_the_seidel_sums(stop_gap, a4):
    """At F/50 and half a degree: spherical aberration at the rim is S_I / 8, coma across the pupil S_II (Welford's
    W = S_I/8 rho^4 + S_II/2 rho^3 cos + ...), the stop on the lens or 15 mm before it (stop shift), with an A4."""
    seq = _thick_singlet(2.0, stop_gap, a4)
    lam = seq.primary_wavelength_um
    sums = seq.seidel_surfaces(0.5).sum(0) / (lam * 1e-3)  # waves
    one = torch.tensor([1.0], dtype=torch.float64)
    zero = torch.zeros(1, dtype=torch.float64)
    w_axis = seq.wavefront(0.0, zero, one).opd_waves[0]
    assert float(w_axis) == pytest.approx(float(sums[0]) / 8, rel=0.02)
    up = seq.wavefront(0.5, zero, one).opd_waves[0]
    down = seq.wavefront(0.5, zero, -one).opd_waves[0]
    assert float(up - down) == pytest.approx(float(sums[1]), rel=0.05)


def test_a_semi_diameter_vignettes_the_area_it_leaves():
    clip = 0.5  # a flat aperture before the lens, half the beam's radius
    surfs = (S(0.0, 2.0, "air", semi_diameter_mm=clip * 5.0), S(1 / 50, 5.0, MODEL), S(-1 / 50, 48.0, "air"))
    seq = SequentialLens(Prescription(surfs, 2, 10.0))
    px, py = pupil_grid(64)
    w = seq.wavefront(0.0, px, py)
    assert 1 - w.vignetted_fraction == pytest.approx(clip**2, abs=0.01)
    assert torch.isnan(w.opd_waves[~w.valid]).all() and torch.isfinite(w.opd_waves[w.valid]).all()


def test_ray_aiming_meets_the_stop_where_it_aims():
    surfs = (S(1 / 40, 4.0, MODEL), S(-1 / 200, 8.0, "air"), S(0.0, 8.0, "air"), S(1 / 60, 4.0, MODEL),
             S(-1 / 40, 40.0, "air"))
    seq = SequentialLens(Prescription(surfs, 3, 10.0, fields=(0.0, 20.0)))
    px, py = pupil_grid(8)
    P, d, o = seq.aim(20.0, px, py)
    at_stop = seq.trace(P, d, upto=2, opl_start=o, vignette=False).points[:, :2]
    r = seq.paraxial().stop_radius_mm
    assert torch.allclose(at_stop, torch.stack([px, py], -1) * r, atol=1e-8 * r, rtol=0)
    P, d, o = seq.aim(20.0, px, py, method="paraxial")  # the paraxial pupil misses the target off axis
    off = (seq.trace(P, d, upto=2, opl_start=o, vignette=False).points[:, :2] - torch.stack([px, py], -1) * r)
    assert off.abs().max() > 1e-3 * r


def test_a_finite_object_images_where_thin_lens_optics_says():
    f, u = 50.0, 150.0  # a thin lens (zero thickness): 1/v = 1/f - 1/u
    c = 1 / ((N_GLASS - 1) * 2 * f)
    p = Prescription((S(c, 0.0, MODEL), S(-c, 60.0, "air")), 1, 5.0, fields=(0.0, 2.0), object_distance_mm=u)
    par = SequentialLens(p).paraxial()
    v = 1 / (1 / f - 1 / u)
    assert par.image_z_mm == pytest.approx(v, rel=1e-12)
    assert par.image_heights_mm[1] == pytest.approx(2.0 * v / u, rel=1e-12)  # magnification v/u (object at -y)


def test_a_chief_ray_that_does_not_pass_is_reported_with_its_field():
    surfs = (S(0.0, 20.0, "air"), S(1 / 50, 5.0, MODEL, semi_diameter_mm=3.0), S(-1 / 50, 48.0, "air"))
    seq = SequentialLens(Prescription(surfs, 1, 4.0, fields=(0.0, 30.0)))
    with pytest.raises(RayTraceError, match=r"field 30: the chief ray does not pass \(stopped at surface 2"):
        seq.wavefront(30.0, *pupil_grid(4))


def test_prescription_errors_name_the_surface():
    with pytest.raises(PrescriptionError, match=r"surface 2: thickness \(mm\) = nan"):
        Prescription((S(0.0, 1.0, "air"), S(0.0, float("nan"), "air")), 1, 4.0)
    with pytest.raises(PrescriptionError, match="surface 1: thickness .* >= 0"):
        Prescription((S(0.0, -1.0, "air"), S(0.0, 10.0, "air")), 1, 4.0)
    with pytest.raises(PrescriptionError, match="stop surface 3 is not allowed: a surface number from 1 to 2"):
        Prescription((S(0.0, 1.0, "air"), S(0.0, 10.0, "air")), 3, 4.0)
    with pytest.raises(PrescriptionError, match="surface 1: the conic surface .* semi-diameter"):
        Prescription((S(1 / 5, 1.0, MODEL, semi_diameter_mm=6.0), S(0.0, 10.0, "air")), 1, 4.0)


def test_a_perfect_lens_has_strehl_one_and_the_diffraction_limited_mtf():
    from lenssim.optics.lens_report import field_quality

    f = 50.0
    seq = SequentialLens(Prescription((S(0.0, 5.0, MODEL), S(-1 / ((N_GLASS - 1) * f), f, "air", conic=-N_GLASS**2)),
                                      1, 10.0))
    lam_mm = seq.primary_wavelength_um * 1e-3
    cutoff = 1 / (lam_mm * seq.paraxial().working_f_number)
    nus = [0.1 * cutoff, 0.3 * cutoff, 0.6 * cutoff]
    q = field_quality(seq, 0.0, nus, grid=96)
    assert q["strehl"] == pytest.approx(1.0, abs=1e-9) and q["rms_opd_waves"] < 1e-6
    for nu, s_, t_ in zip(nus, q["mtf_sagittal"], q["mtf_tangential"]):
        x = nu / cutoff
        closed = 2 / math.pi * (math.acos(x) - x * math.sqrt(1 - x * x))  # a circular pupil's MTF
        assert s_ == pytest.approx(closed, abs=0.01) and t_ == pytest.approx(closed, abs=0.01)


def test_the_strehl_ratio_of_a_small_defocus_follows_marechal():
    from lenssim.optics.lens_report import field_quality

    f = 50.0
    p = Prescription((S(0.0, 5.0, MODEL), S(-1 / ((N_GLASS - 1) * f), f, "air", conic=-N_GLASS**2)), 1, 10.0)
    seq = SequentialLens(p, image_shift_mm=0.01)  # 10 um of defocus at F/5: about 0.05 wave RMS
    q = field_quality(seq, 0.0, (10.0,), grid=96)
    sigma = q["rms_opd_waves"]
    assert 0.02 < sigma < 0.1
    assert q["strehl"] == pytest.approx(math.exp(-(2 * math.pi * sigma) ** 2), abs=0.01)


def test_surfaces_that_cross_within_their_semi_diameters_are_refused():
    # a strong biconvex element 1 mm thick at the centre: its edge at 8 mm is negative (sags 1.34 mm and -1.34 mm)
    surfs = (S(1 / 25, 1.0, MODEL, semi_diameter_mm=8.0), S(-1 / 25, 40.0, "air", semi_diameter_mm=8.0))
    with pytest.raises(PrescriptionError, match=r"surface 2 crosses surface 1 within their semi-diameters: the gap "
                                                r"between them is -1\.\d+ mm at a height of 8 mm"):
        Prescription(surfs, 1, 4.0)
    Prescription((surfs[0].__class__(1 / 25, 3.0, MODEL, semi_diameter_mm=8.0), surfs[1]), 1, 4.0)  # 3 mm: an edge


def test_an_axial_beam_that_cannot_pass_is_refused_naming_the_surface():
    """check_aperture: the axial beam's rim at the entrance-pupil diameter. A ray from glass (n = 1.5) meeting a sphere
    of radius 3 mm at 2.5 mm height is incident at asin(2.5/3) = 56 deg, beyond the critical angle asin(1/1.5) = 42
    deg: total internal reflection at surface 2; a sphere of radius 2 mm cannot be met at 2.5 mm; a stop of
    semi-diameter 2 mm cannot pass a 5 mm entrance pupil on it."""
    def lens(r2, epd=5.0, stop_sd=None):
        return SequentialLens(Prescription((S(0.0, 3.0, MODEL, semi_diameter_mm=stop_sd), S(-1 / r2, 20.0, "air")),
                                           1, epd))

    with pytest.raises(PrescriptionError, match=r"^surface 2: the axial beam's rim .* is totally internally reflected$"):
        lens(3.0).check_aperture()
    lens(3.0, epd=3.5).check_aperture()  # asin(1.75 / 3) = 36 deg: it passes
    with pytest.raises(PrescriptionError, match=r"^surface 2: the axial beam's rim .* misses the surface$"):
        lens(2.0).check_aperture()
    with pytest.raises(PrescriptionError, match=r"^surface 1 \(the stop\): .* stop radius of 2.5 mm .* semi-diameter 2 mm"):
        lens(30.0, stop_sd=2.0).check_aperture()
    lens(30.0, stop_sd=2.5).check_aperture()


@pytest.mark.parametrize("name", ["paper_singlet", "cooke_triplet", "double_gauss", "aspheric_singlet"])
def test_the_shipped_lenses_pass_their_axial_beam(name):
    from lenssim.io.prescription_file import read_lens

    SequentialLens(read_lens(name)).check_aperture()


def test_aiming_that_does_not_converge_beyond_the_pupil_leaves_the_ray_untraced(monkeypatch):
    """The double Gauss at 6.205 deg: two rays of a wavefront table's margin (pupil radius 1.05, far outside a
    semi-diameter) need more than 20 Newton steps (once a RayTraceError that stopped every PSF of this lens). Cut
    short, a point beyond the unit disc is left untraced (NaN, not valid), and a point within it is still an error."""
    import lenssim.optics.sequential as seq_mod

    from lenssim.io.prescription_file import read_lens

    lens = SequentialLens(read_lens("double_gauss"))
    px = torch.tensor([-0.21945074326026714, 0.21945074326026714, 0.0], dtype=torch.float64)
    py = torch.tensor([1.0297304106827916, 1.0297304106827916, 0.5], dtype=torch.float64)
    w = lens.wavefront(6.205, px, py, vignette=False)  # no error, whatever the margin's rays do
    assert torch.isfinite(w.opd_waves[2]) and bool(w.valid[2])
    # where an unconverged iterate stops (its aperture ratio, 2.3 to 9 across hosts) depends on the host's rounding:
    # only what the code promises is tested, a ray either traced (finite) or left untraced (NaN, not valid)
    assert all(bool(torch.isfinite(w.opd_waves[i])) == bool(w.valid[i]) for i in range(2))
    monkeypatch.setattr(seq_mod, "AIM_ITERATIONS", 20)
    w20 = lens.wavefront(6.205, px, py, vignette=False)
    assert torch.isnan(w20.opd_waves[:2]).all() and not w20.valid[:2].any()
    assert w20.opd_waves[2] == w.opd_waves[2]
    monkeypatch.setattr(seq_mod, "AIM_ITERATIONS", 1)
    with pytest.raises(seq_mod.RayTraceError, match="did not converge"):
        lens.wavefront(6.205, px[2:] * 1.9, py[2:] * 1.9)


@pytest.mark.parametrize("name", ["cooke_triplet", "double_gauss"])
def test_through_focus_is_the_refocused_lens_s_wavefront_bit_for_bit(name):
    """SequentialLens.through_focus (the rays traced once, the reference sphere moved per plane) against a lens built
    with its image plane moved (SequentialLens(image_shift_mm=...).wavefront, every ray traced again): the same
    numbers, bit for bit, at several planes, fields and a reference point; the best-focus search rests on it."""
    from lenssim.io.prescription_file import read_lens

    p = read_lens(name)
    px, py = pupil_grid(12)
    lens = SequentialLens(p)
    for field in (0.0, max(p.fields)):
        at = lens.through_focus(field, px, py)
        for shift in (0.0, -0.35, 0.0123, 1.5):
            want = SequentialLens(p, image_shift_mm=shift).wavefront(field, px, py)
            got = at(shift)
            assert torch.equal(got.opd_waves.nan_to_num(7.0), want.opd_waves.nan_to_num(7.0))
            assert torch.equal(got.valid, want.valid) and torch.equal(got.image_mm, want.image_mm)
            assert got.reference_radius_mm == want.reference_radius_mm and torch.equal(got.chief_mm, want.chief_mm)
            assert not torch.equal(got.opd_waves.nan_to_num(7.0), at(shift + 0.1).opd_waves.nan_to_num(7.0))
        ref = SequentialLens(p, image_shift_mm=0.2).wavefront(field, px, py, reference_mm=(0.01, 0.3))
        assert torch.equal(at(0.2, reference_mm=(0.01, 0.3)).opd_waves.nan_to_num(7.0), ref.opd_waves.nan_to_num(7.0))


def _maps_equal(got, want) -> bool:
    return (torch.equal(got.opd_waves.nan_to_num(7.0), want.opd_waves.nan_to_num(7.0))
            and torch.equal(got.valid, want.valid)
            and torch.equal(got.image_mm.nan_to_num(7.0), want.image_mm.nan_to_num(7.0))
            and torch.equal(got.chief_mm, want.chief_mm) and float(got.reference_radius_mm) == want.reference_radius_mm
            and torch.equal(got.aperture_ratio.nan_to_num(7.0), want.aperture_ratio.nan_to_num(7.0)))


def _one(w, f):
    """Field ``f`` of a map of several fields, as a single field's map."""
    from dataclasses import replace

    return replace(w, opd_waves=w.opd_waves[f], valid=w.valid[f], chief_mm=w.chief_mm[f], image_mm=w.image_mm[f],
                   reference_radius_mm=float(w.reference_radius_mm[f]), aperture_ratio=w.aperture_ratio[f])


def _misaligned_copy(name):
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.tolerances import SurfaceTolerances
    from lenssim.tolerancing import manufactured_lens

    nominal = SequentialLens(read_lens(name))
    tol = SurfaceTolerances.grade("commercial")
    return manufactured_lens(nominal, tol.sample(nominal.prescription, 2, seed=0), 1).rotated(90.0)


@pytest.mark.parametrize("name, misaligned", [("cooke_triplet", False), ("cooke_triplet", True),
                                              ("double_gauss", True), ("finite", False)])
def test_several_fields_at_once_are_each_field_traced_alone_bit_for_bit(name, misaligned):
    """SequentialLens.wavefront of a Fields (every field's rays in one bundle, each field's aiming stopping where its
    own rays have converged) against one call per field: the same numbers, bit for bit, with and without a reference
    point per field, vignetted or not, for a centred lens, decentred and tilted copies and a finite object."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.sequential import Fields

    if name == "finite":
        c = 1 / ((N_GLASS - 1) * 2 * 50.0)
        lens = SequentialLens(Prescription((S(0.0, 2.0, "air"), S(c, 4.0, MODEL), S(-c, 60.0, "air")), 1, 5.0,
                                           fields=(0.0, 3.0), object_distance_mm=150.0))
    else:
        lens = _misaligned_copy(name) if misaligned else SequentialLens(read_lens(name))
        assert lens.is_centred is not misaligned
    amax = max(lens.prescription.fields)
    fields = [0.0, 0.37 * amax, 0.81 * amax, amax]
    px, py = pupil_grid(14)
    px, py = 1.04 * px, 1.04 * py  # a table's margin beyond the rim too
    ref = ([0.001 * i for i in range(4)], [0.25 * amax * i / 10 for i in range(4)])
    for kw in ({}, {"vignette": False}, {"vignette": False, "reference_mm": ref}):
        many = lens.wavefront(Fields(fields), px, py, lens.primary_wavelength_um, **kw)
        assert many.opd_waves.shape == (4, px.numel()) and many.chief_mm.shape == (4, 3)
        for f, a in enumerate(fields):
            one = dict(kw, reference_mm=(ref[0][f], ref[1][f])) if "reference_mm" in kw else kw
            assert _maps_equal(_one(many, f), lens.wavefront(a, px, py, lens.primary_wavelength_um, **one)), (a, kw)


def test_several_fields_stop_aiming_each_on_its_own_and_name_the_one_that_fails(monkeypatch):
    """The double Gauss's margin rays at 6.205 deg that need more than 20 Newton steps
    (test_aiming_that_does_not_converge_beyond_the_pupil_leaves_the_ray_untraced), beside the axis: cut short, that
    field's rays are left untraced as alone, the axis's are untouched, and a point within the disc that cannot be
    aimed is an error naming its field. A batch of designs refuses several fields."""
    from dataclasses import replace

    import lenssim.optics.sequential as seq_mod
    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.sequential import Fields

    lens = SequentialLens(read_lens("double_gauss"))
    px = torch.tensor([-0.21945074326026714, 0.21945074326026714, 0.0], dtype=torch.float64)
    py = torch.tensor([1.0297304106827916, 1.0297304106827916, 0.5], dtype=torch.float64)
    monkeypatch.setattr(seq_mod, "AIM_ITERATIONS", 20)
    many = lens.wavefront(Fields([0.0, 6.205]), px, py, vignette=False)
    for f, a in enumerate((0.0, 6.205)):
        assert _maps_equal(_one(many, f), lens.wavefront(a, px, py, vignette=False))
    assert torch.isnan(many.opd_waves[1, :2]).all() and torch.isfinite(many.opd_waves[0]).all()
    monkeypatch.setattr(seq_mod, "AIM_ITERATIONS", 1)
    with pytest.raises(RayTraceError, match=r"^field 6.205: ray aiming at the stop .* for 1 of 1 pupil points"):
        lens.wavefront(Fields([0.0, 6.205]), px[2:] * 1.9, py[2:] * 1.9)
    surfs = (S(0.0, 20.0, "air"), S(1 / 50, 5.0, MODEL, semi_diameter_mm=3.0), S(-1 / 50, 48.0, "air"))
    vignetting = SequentialLens(Prescription(surfs, 1, 4.0, fields=(0.0, 30.0)))
    with pytest.raises(RayTraceError, match=r"^field 30: the chief ray does not pass \(stopped at surface 2"):
        vignetting.wavefront(Fields([0.0, 30.0, 31.0]), *pupil_grid(4))
    batch = SequentialLens(lens.prescription, numbers=tuple(
        replace(s, thickness_mm=torch.full((2, 1), s.thickness_mm, dtype=torch.float64))
        for s in lens.prescription.surfaces))
    with pytest.raises(ValueError, match="several fields at once are traced through a lens of floats"):
        batch.wavefront(Fields([0.0, 1.0]), px, py)
