"""A lens with its stop inside (issue 44): the real-ray wavefront against an independent tracer, and the cause of the
3.8% a new user measured against Optiland (how the entrance pupil sizes the stop that real rays are aimed at).

The lens is ``tests/data/lenses/cooke_stop_inside.toml``: a Cooke triplet whose stop is surface 4, the back of the
negative element (the Zemax sample "Cooke 40 degree field"; EPD 10 mm, 0/14/20 deg; model glasses). Its front group
images the stop with spherical aberration of the pupil: the real axial ray entering at the entrance pupil's rim meets
the stop 1.5% above the paraxial marginal ray. The optical-design programs size the stop one way or the other (Zemax:
"paraxial" ray aiming, its default, or "aberrated"; Optiland's real aiming: the real ray), and the RMS OPD at 20 deg
differs by 2.7% between the two; the prescription names its choice (``[aperture] stop_size``).

Reference numbers: Optiland 0.6.3 (an independent tracer: its own intersection, refraction, aiming and OPD), run by
``benchmarks/crosscheck_optiland.py --lens tests/data/lenses/cooke_stop_inside.toml`` (the same 64 x 64 pupil grid
given to it as a custom distribution, our glass indices, the file's semi-diameters as radial apertures; OPD about the
real chief ray's image point, the mean removed from Optiland's before its RMS; for ``stop_size = "real"`` Optiland's
own EPD aperture and "robust" real aiming, for ``"paraxial"`` its "float by stop size" at its paraxial stop radius),
printed to 6 significant digits on 2026-11-27. The second case narrows surface 5 to a semi-diameter of 6.6 mm, so
that the 20 deg beam is vignetted.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from lenssim.io.prescription_file import prescription_from_dict, read_prescription_toml
from lenssim.model.prescription import PrescriptionError
from lenssim.optics.sequential import SequentialLens, pupil_grid

LENS = Path(__file__).parents[1] / "data" / "lenses" / "cooke_stop_inside.toml"

# (case, stop size, field deg): Optiland 0.6.3's RMS OPD (waves), RMS spot (um), vignetted (% of the grid's points)
OPTILAND = {
    ("file", "paraxial", 0.0): (0.192102, 4.29055, 0.0),
    ("file", "paraxial", 14.0): (0.661633, 15.02576, 0.0),
    ("file", "paraxial", 20.0): (0.488883, 12.75694, 0.0),
    ("file", "real", 0.0): (0.190476, 4.27211, 0.0),
    ("file", "real", 14.0): (0.687700, 15.46249, 0.0),
    ("file", "real", 20.0): (0.502112, 13.24947, 0.0),
    ("clipped", "paraxial", 20.0): (0.487893, 12.61576, 1.6109),
    ("clipped", "real", 20.0): (0.501170, 13.02881, 2.2924),
}
RTOL = 1e-4
"""Our figures against Optiland's (printed to 6 digits; the two traces agree to ~1e-6): far inside the issue's 1.5%."""


def _lens(case: str, stop_size: str) -> SequentialLens:
    p = read_prescription_toml(LENS)
    if case == "clipped":
        p = replace(p, surfaces=p.surfaces[:4] + (replace(p.surfaces[4], semi_diameter_mm=6.6),) + p.surfaces[5:])
    return SequentialLens(replace(p, stop_size=stop_size))


@pytest.fixture(scope="module")
def grid():
    return pupil_grid(64)


@pytest.mark.parametrize("case, stop_size, field", list(OPTILAND))
def test_the_stop_inside_agrees_with_an_independent_tracer(case, stop_size, field, grid):
    w = _lens(case, stop_size).wavefront(field, *grid)
    rms, spot, vignetted = OPTILAND[case, stop_size, field]
    assert w.rms_waves() == pytest.approx(rms, rel=RTOL)
    assert w.rms_spot_mm() * 1e3 == pytest.approx(spot, rel=RTOL)
    n = grid[0].numel()
    assert round(w.vignetted_fraction * n) == round(vignetted / 100 * n)  # the same rays vignetted


def test_the_two_stop_sizes_are_different_pupils(grid):
    """The cause of the difference: at 20 deg the two conventions differ by more than the issue's 1.5%, so comparing
    across them is not like with like."""
    a = _lens("file", "paraxial").wavefront(20.0, *grid).rms_waves()
    b = _lens("file", "real").wavefront(20.0, *grid).rms_waves()
    assert abs(b - a) / b > 0.02


def test_a_real_stop_size_makes_the_axial_beam_the_entrance_pupil():
    """Closed form: with ``stop_size = "real"`` the axial ray aimed at the stop's rim enters at the entrance pupil's
    radius (parallel to the axis); with the paraxial size it enters lower, by the pupil's spherical aberration."""
    one = torch.ones(1, dtype=torch.float64)
    for stop_size, close in (("real", True), ("paraxial", False)):
        seq = _lens("file", stop_size)
        P, d, _ = seq.aim(0.0, 0 * one, one)
        r_ep = seq.prescription.entrance_pupil_diameter_mm / 2
        assert float(d[0, 1]) == 0.0
        assert (abs(float(P[0, 1]) - r_ep) < 1e-8) is close
    par = _lens("file", "paraxial").paraxial()
    real_r = _lens("file", "real").aimed_stop_radius_mm()
    assert real_r / par.stop_radius_mm == pytest.approx(1.0149, abs=1e-4)


def test_the_stop_size_is_read_written_and_checked(tmp_path):
    p = read_prescription_toml(LENS)
    assert p.stop_size == "paraxial"
    d = replace(p, stop_size="real").to_dict()
    assert d["aperture"]["stop_size"] == "real"
    assert prescription_from_dict(d).stop_size == "real"
    d["aperture"]["stop_size"] = "marginal"
    with pytest.raises(PrescriptionError, match=r"stop_size = 'marginal' is not allowed: one of paraxial, real"):
        prescription_from_dict(d)
    assert math.isfinite(SequentialLens(prescription_from_dict({**d, "aperture": {
        "entrance_pupil_diameter_mm": 10.0, "stop_size": "real"}})).aimed_stop_radius_mm())
