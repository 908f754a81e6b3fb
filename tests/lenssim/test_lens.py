import math

import pytest

from lenssim_studies.config import paper_lens_with, paper_sensor_with
import torch

from lenssim import Camera, Design, LensError, Spectrum

from lenssim_studies.paper import PAPER_CAMERA, PAPER_LENS, PAPER_SENSOR
import dataclasses
from lenssim_studies.paper import PAPER_SPECTRUM


def test_paper_lens_derived_quantities():
    assert PAPER_LENS.f_number == 6.25
    assert PAPER_SENSOR.pixel_pitch_um == pytest.approx(1.5625)
    assert PAPER_LENS.nyquist_pitch_um(0.5) == pytest.approx(PAPER_SENSOR.pixel_pitch_um)
    assert PAPER_LENS.image_distance_mm == pytest.approx(25.0)
    c1, c2 = PAPER_LENS.curvatures(-0.775)
    assert (c1 + c2) / (c1 - c2) == pytest.approx(-0.775)
    # lensmaker: 1/f = (n - 1)(c1 - c2)
    assert (PAPER_LENS.refractive_index - 1) * (c1 - c2) == pytest.approx(1 / 25)


def test_6000x4000_sensor_spans_12p7_degrees():
    half_diag_mm = math.hypot(3000, 2000) * PAPER_SENSOR.pixel_pitch_um * 1e-3
    assert float(PAPER_CAMERA.geometry.field_angle_deg(half_diag_mm, 0.0)) == pytest.approx(12.7, abs=0.05)
    assert PAPER_CAMERA.geometry.max_field_angle_deg(PAPER_SENSOR.shape) == pytest.approx(12.7, abs=0.05)


def test_the_sensor_pitch_does_not_move_with_the_wavelength():
    for lam in (0.45, 0.5, 0.65):
        assert Camera(spectrum=Spectrum.monochromatic(lam), lens=PAPER_LENS, sensor=PAPER_SENSOR).pixel_pitch_um == 1.5625
    with pytest.warns(UserWarning, match="undersample wavelengths below 0.5 um"):
        Camera(spectrum=Spectrum.monochromatic(0.45), lens=PAPER_LENS, sensor=PAPER_SENSOR).pupil_radius_px(256, 0.45)
    assert Camera(sensor=dataclasses.replace(PAPER_SENSOR, pixel_pitch_um=1.0), lens=PAPER_LENS, spectrum=PAPER_SPECTRUM).pupil_radius_px(256, 0.5) == pytest.approx(256 * 1.0 / 6.25)


@pytest.mark.parametrize(
    "kw, name",
    [
        ({"refractive_index": 1.0}, "refractive_index"),
        ({"refractive_index": 0.8}, "refractive_index"),
        ({"focal_length_mm": 0.0}, "focal_length_mm"),
        ({"focal_length_mm": -25.0}, "focal_length_mm"),
        ({"pupil_radius_mm": 0.0}, "pupil_radius_mm"),
        ({"pupil_radius_mm": 30.0}, "pupil_radius_mm"),
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
        paper_lens_with(kw)  # the paper's lens with one value changed


@pytest.mark.parametrize("kw, name", [({"pixel_pitch_um": 0.0}, "pixel_pitch_um"), ({"width_px": 0}, "width_px"),
                                      ({"read_noise_e": -1.0}, "read_noise_e"), ({"bit_depth": 0}, "bit_depth"),
                                      ({"full_well_e": ((100, -5.0),)}, "full_well_e")])
def test_unphysical_sensor_is_refused_with_its_name(kw, name):
    with pytest.raises(ValueError, match=name):
        paper_sensor_with(kw)


def test_spectrum_normalises_weights_and_refuses_nonsense():
    sp = Spectrum((0.45, 0.55, 0.65), (1.0, 2.0, 1.0))
    assert sp.weights == (0.25, 0.5, 0.25) and sp.reference_um == pytest.approx(0.55)
    for bad in (((0.5,), (1.0, 1.0)), ((-0.5,), (1.0,)), ((0.5,), (0.0,)), ((), ())):
        with pytest.raises(ValueError):
            Spectrum(*bad)


def test_undefined_conic_is_refused():
    # s = -2: c2 = -0.12 /mm, y = 2 mm -> (1 + Q) c2^2 y^2 < 1 needs Q < 16.36
    from lenssim.validate import ModelValidityWarning

    with pytest.warns(ModelValidityWarning, match="third-order"):  # defined, but near its limit: (1+Q) c^2 y^2 = 0.98
        PAPER_LENS.check_design(Design(s=-2.0, Q_back=16.0))
    with pytest.raises(LensError, match=r"Q_back=17\.0 .*undefined.*Q_back must be < 16\.36"):
        PAPER_LENS.check_design(Design(s=-2.0, Q=17.0))
    with pytest.raises(LensError, match="s=nan"):
        PAPER_LENS.check_design(Design(s=float("nan"), Q_back=0.0))
    with pytest.raises(LensError, match="surface 1 .spherical. is smaller than"):
        PAPER_LENS.check_design(Design(s=40.0, Q_back=-10.0))
    PAPER_LENS.check_design(Design(s=torch.linspace(-2, 1, 7), Q_back=torch.tensor(-10.0)))


def test_the_blur_check_makes_its_tensors_on_the_designs_device():
    """Issue 43: every `--device cuda` command stopped at `Lens._check_blur`, whose field angle was a CPU tensor
    stacked with the design's CUDA tensors. CI has no GPU: with the default device set to another one (meta), a
    tensor made without the design's device lands there and mixing it with the design's CPU tensors fails."""
    from lenssim_studies.paper import PAPER

    design = PAPER.designs["end_to_end_paper"]
    torch.set_default_device("meta")
    try:
        PAPER.camera.lens._check_blur(design)  # raises "Tensor on device meta is not on the expected device cpu"
    finally:
        torch.set_default_device(None)
