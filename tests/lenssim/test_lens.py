import math

import pytest
import torch

from lenssim import PAPER_LENS, LensError, ThinLens


def test_paper_lens_derived_quantities():
    assert PAPER_LENS.f_number == 6.25
    assert PAPER_LENS.pixel_pitch_um == pytest.approx(1.5625)
    assert PAPER_LENS.image_distance_mm == pytest.approx(25.0)
    c1, c2 = PAPER_LENS.curvatures(-0.775)
    assert (c1 + c2) / (c1 - c2) == pytest.approx(-0.775)
    # lensmaker: 1/f = (n - 1)(c1 - c2)
    assert (PAPER_LENS.refractive_index - 1) * (c1 - c2) == pytest.approx(1 / 25)


def test_6000x4000_sensor_spans_12p7_degrees():
    half_diag_mm = math.hypot(3000, 2000) * PAPER_LENS.pixel_pitch_um * 1e-3
    assert float(PAPER_LENS.field_angle_deg(half_diag_mm, 0.0)) == pytest.approx(12.7, abs=0.05)


@pytest.mark.parametrize(
    "kw, name",
    [
        ({"refractive_index": 1.0}, "refractive_index"),
        ({"refractive_index": 0.8}, "refractive_index"),
        ({"focal_length_mm": 0.0}, "focal_length_mm"),
        ({"focal_length_mm": -25.0}, "focal_length_mm"),
        ({"pupil_radius_mm": 0.0}, "pupil_radius_mm"),
        ({"pupil_radius_mm": 30.0}, "pupil_radius_mm"),
        ({"wavelength_um": 0.0}, "wavelength_um"),
        ({"position_factor": 1.0}, "position_factor"),
        ({"focal_length_mm": float("nan")}, "focal_length_mm"),
        ({"field_angles_deg": (0.0, 90.0)}, "field angle"),
        ({"field_angles_deg": (-1.0,)}, "field angle"),
        ({"field_angles_deg": ()}, "field_angles_deg"),
        ({"refractive_index": "glass"}, "refractive_index"),
    ],
)
def test_unphysical_lens_is_refused_with_its_name(kw, name):
    with pytest.raises(LensError, match=name):
        ThinLens(**kw)


def test_undefined_conic_is_refused():
    # s = -2: c2 = -0.12 /mm, y = 2 mm -> (1 + Q) c2^2 y^2 < 1 needs Q < 16.36
    PAPER_LENS.check_design(-2.0, 16.0)
    with pytest.raises(LensError, match=r"Q=17\.0 .*undefined.*Q must be < 16\.36"):
        PAPER_LENS.check_design(-2.0, 17.0)
    with pytest.raises(LensError, match="s=nan"):
        PAPER_LENS.check_design(float("nan"), 0.0)
    with pytest.raises(LensError, match="front sphere"):
        PAPER_LENS.check_design(40.0, -10.0)
    PAPER_LENS.check_design(torch.linspace(-2, 1, 7), torch.tensor(-10.0))
