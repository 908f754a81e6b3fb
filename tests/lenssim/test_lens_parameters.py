"""Free parameters of any prescription by name, and the solves that hold the focal length, the F-number and the
image plane (issue 30, items 1-2): checked against the paper's thin-lens closed forms (the bending at constant power,
today's ``Lens`` curvatures), a brute-force root of the focal length, and the paraxial trace."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from scipy.optimize import brentq

from lenssim.io.prescription_file import read_lens
from lenssim.model.lens_parameters import (FOCUS_PARAMETER, apply_parameters, lens_parameters, parameter_values,
                                           parse_parameter)
from lenssim.model.prescription import PrescriptionError
from lenssim.optics.lens_solves import SolveError, default_solve_surface, solve_design
from lenssim.optics.sequential import SequentialLens
from lenssim_studies.paper import PAPER_LENS


@pytest.fixture(scope="module")
def cooke():
    return read_lens("cooke_triplet")


def test_every_name_of_a_lens(cooke):
    names = lens_parameters(cooke)
    assert len(names) == 7 * 4 + 3 + 1  # curvature, radius, conic, thickness per surface; 3 elements; focus
    assert "E3.bending" in names and FOCUS_PARAMETER in names and "S3.A4" not in names
    asph = read_lens("aspheric_singlet")
    k = next(i + 1 for i, s in enumerate(asph.surfaces) if s.is_aspheric)
    assert {f"S{k}.A{o}" for o in (4, 6, 8, 10, 12, 14, 16)} <= set(lens_parameters(asph))
    assert parse_parameter(cooke, "s3.CONIC").name == "S3.conic"
    assert parse_parameter(cooke, "S3.A6", aspherize=(3,)).kind == "A6"


@pytest.mark.parametrize("name, match", [
    ("S9.conic", "not a parameter of this lens; valid: S1..S7.curvature|radius|conic|thickness"),
    ("S3.A4", "surface 3 is not an even asphere in the file"),
    ("E4.bending", "E1..E3.bending"),
    ("shape", "not a parameter of this lens"),
])
def test_unknown_names_list_the_valid_ones(cooke, name, match):
    with pytest.raises(ValueError, match=match.replace("|", r"\|").replace(".", r"\.")):
        parse_parameter(cooke, name)


def test_the_files_values_give_back_the_file(cooke):
    params = [q for q in lens_parameters(cooke).values() if q.kind not in ("radius",)]
    vals = parameter_values(cooke, params)
    q, shift = apply_parameters(cooke, dict(zip(params, vals.values())))
    assert shift == 0.0
    for a, b in zip(q.surfaces, cooke.surfaces):
        assert a.curvature_per_mm == pytest.approx(b.curvature_per_mm, rel=1e-14, abs=1e-17)
        assert (a.conic, a.thickness_mm) == (b.conic, b.thickness_mm)


def test_bending_the_paper_singlet_is_todays_shape_factor():
    """The paper's thin singlet as a prescription: E1.bending = s gives c1 = (s + 1) / (2 f (n - 1)) and
    c2 = (s - 1) / (2 f (n - 1)) (today's Lens), at the same focal length."""
    p = read_lens("paper_singlet")
    f0 = SequentialLens(p).paraxial().efl_mm
    for s in (-1.5, -0.775, 0.0, 0.3, 1.7):
        q, _ = apply_parameters(p, {"E1.bending": s})
        c1, c2 = PAPER_LENS.curvatures(torch.tensor(s, dtype=torch.float64))
        assert q.surfaces[0].curvature_per_mm == pytest.approx(float(c1), rel=1e-12)
        assert q.surfaces[1].curvature_per_mm == pytest.approx(float(c2), rel=1e-12)
        assert SequentialLens(q).paraxial().efl_mm == pytest.approx(f0, rel=1e-12)
        assert parameter_values(q, [parse_parameter(q, "E1.bending")])["E1.bending"] == pytest.approx(s, abs=1e-12)


def test_a_cemented_element_bends_as_one(cooke):
    g = read_lens("double_gauss")
    b = parameter_values(g, [parse_parameter(g, "E2.bending")])["E2.bending"]
    q, _ = apply_parameters(g, {"E2.bending": b + 0.05})  # surfaces 3-5: every curvature shifted alike
    d = [q.surfaces[k].curvature_per_mm - g.surfaces[k].curvature_per_mm for k in (2, 3, 4)]
    assert d[0] == pytest.approx(d[1], rel=1e-12) and d[1] == pytest.approx(d[2], rel=1e-12) and d[0] != 0


def test_the_focal_length_is_held_exactly(cooke):
    """S1's curvature 2% steeper, element 2 bent: the last surface's curvature restores f, equal to a brute-force
    root of f(c7) = f0 (the solve's affine step is exact)."""
    values = {"S1.curvature": cooke.surfaces[0].curvature_per_mm * 1.02, "E2.bending": 0.1}
    params = {parse_parameter(cooke, k): v for k, v in values.items()}
    q, _ = solve_design(cooke, params, hold=("efl",))
    f0 = SequentialLens(cooke).paraxial().efl_mm
    assert SequentialLens(q).paraxial().efl_mm == pytest.approx(f0, rel=1e-12)
    moved, _ = apply_parameters(cooke, params)
    k = default_solve_surface(cooke)
    assert k == 6

    def f_minus(c):
        surfs = list(moved.surfaces)
        surfs[k] = replace(surfs[k], curvature_per_mm=c)
        return SequentialLens(replace(moved, surfaces=tuple(surfs))).paraxial().efl_mm - f0

    c = brentq(f_minus, -0.03, -0.02, xtol=1e-16)
    assert q.surfaces[k].curvature_per_mm == pytest.approx(c, rel=1e-10)


def test_the_f_number_and_the_image_plane_are_held(cooke):
    params = {parse_parameter(cooke, "S1.curvature"): cooke.surfaces[0].curvature_per_mm * 0.98}
    q, shift = solve_design(cooke, params, hold=("fnum",), image="paraxial")
    a, b = SequentialLens(cooke).paraxial(), SequentialLens(q).paraxial()
    assert b.efl_mm != pytest.approx(a.efl_mm, rel=1e-3)  # the focal length moved...
    assert b.f_number == pytest.approx(a.f_number, rel=1e-13)  # ...and the entrance pupil with it
    assert SequentialLens(q, image_shift_mm=shift).image_z_mm == pytest.approx(b.image_z_mm, abs=1e-12)
    q2, shift2 = solve_design(cooke, {**params, parse_parameter(cooke, FOCUS_PARAMETER): 25.0}, image="paraxial")
    assert shift2 == pytest.approx(shift + 0.025, abs=1e-12) and q2.entrance_pupil_diameter_mm == 29.2


def test_what_a_solve_cannot_hold_is_said(cooke):
    with pytest.raises(ValueError, match="surface 7 holds the focal length"):
        solve_design(cooke, {parse_parameter(cooke, "S7.radius"): -40.0}, hold=("efl",))
    q, _ = solve_design(cooke, {parse_parameter(cooke, "S7.conic"): -0.5}, hold=("efl",))  # no power: allowed
    assert q.surfaces[6].conic == -0.5 and q.surfaces[6].curvature_per_mm == pytest.approx(
        cooke.surfaces[6].curvature_per_mm, rel=1e-12)
    with pytest.raises(ValueError, match="surface 7 holds the focal length"):  # E3: surfaces 6-7
        solve_design(cooke, {parse_parameter(cooke, "E3.bending"): 0.2}, hold=("efl",))
    plate = replace(cooke, surfaces=tuple(replace(s, curvature_per_mm=0.0) for s in cooke.surfaces))
    with pytest.raises(SolveError, match="no curved surface"):
        solve_design(plate, {}, hold=("efl",))
    with pytest.raises(PrescriptionError, match="crosses"):
        apply_parameters(cooke, {"S1.curvature": 0.05})
    with pytest.raises(ValueError, match="curvature and radius"):
        apply_parameters(cooke, {"S1.curvature": 0.02, "S1.radius": 50.0})
    with pytest.raises(ValueError, match="hold 'bfl' is not allowed"):
        solve_design(cooke, {}, hold=("bfl",))


def test_the_best_focus_solve_is_the_least_mean_wavefront_error(cooke):
    """image="best": the plane where the RMS wavefront averaged over the file's fields is least (a local minimum to
    the search's 1e-6 mm), the same plane `inspect --refocus best` uses."""
    from lenssim.optics.lens_solves import best_focus_shift
    from lenssim.optics.sequential import pupil_grid
    from lenssim_cli.lens import refocused_lens

    params = {parse_parameter(cooke, "S7.conic"): -0.5}
    q, shift = solve_design(cooke, params, image="best")
    px, py = pupil_grid(24)

    def mean_rms(dz):
        seq = SequentialLens(q, image_shift_mm=shift + dz)
        return sum(seq.wavefront(f, px, py).rms_waves() for f in q.fields) / len(q.fields)

    assert mean_rms(0.0) < mean_rms(0.02) and mean_rms(0.0) < mean_rms(-0.02)
    assert shift == refocused_lens(q, "best")[1]  # inspect's route: best_focus_shift of the solved lens
    # the file's own Cooke triplet focuses best 0.35 mm before its plane, beyond the first search's 10 focal depths
    # about the paraxial focus (0.28 mm): the search widens instead of returning its edge
    q, shift = cooke, best_focus_shift(cooke)
    assert shift == pytest.approx(-0.3524, abs=1e-3)
    assert mean_rms(0.0) < mean_rms(0.02) and mean_rms(0.0) < mean_rms(-0.02)
