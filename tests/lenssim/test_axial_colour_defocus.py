"""Axial-colour defocus against the exact ray trace (issue 19, section 0).

The third-order model's defocus term ``W020 = delta y^2 / (2 t_f t_img)`` is the rho^2 coefficient of the
wavefront fitted to an exact trace (the same image-plane scale, the reference sphere on the image plane):
at several wavelengths of N-BK7 and several focus shifts, at the paper's aperture and at a small one. The
former ``delta y^2 / (2 t_f^2)`` is off by ``t_img / t_f`` (1.1% for the F line in focus), which this test
fails.
"""

from __future__ import annotations

import dataclasses

import pytest

from lenssim import Camera, Design, Spectrum
from lenssim.optics.aberrations import wavefront_coefficients
from lenssim.optics.exact_wavefront import EXACT_TERMS, exact_wavefront_coefficients
from lenssim_studies.paper import PAPER_LENS, PAPER_SENSOR

RHO2 = [t.name for t in EXACT_TERMS].index("E10")  # the rho^2 monomial of the exact fit


@pytest.mark.parametrize("pupil_radius_mm", [2.0, 0.5])
@pytest.mark.parametrize("wavelength_um", [0.4861, 0.5876, 0.6563])  # F, d, C
@pytest.mark.parametrize("focus_shift_um", [0.0, -300.0, 200.0])
def test_defocus_is_the_exact_wavefront_s_rho2_term(pupil_radius_mm, wavelength_um, focus_shift_um):
    lens = dataclasses.replace(PAPER_LENS, glass="N-BK7", pupil_radius_mm=pupil_radius_mm)
    d = Design(s=-0.775, Q_back=-2.4, focus_shift_um=focus_shift_um)
    third = float(wavefront_coefficients(lens, d, [0.0], wavelength_um=wavelength_um)[0, 3])  # W220 on axis
    camera = Camera(lens, PAPER_SENSOR, Spectrum.monochromatic(wavelength_um))
    exact = float(exact_wavefront_coefficients(camera, d, 0.0, wavelength_um)[RHO2])
    # measured agreement: 1e-8 relative at 2 mm, 1e-13 at 0.5 mm; the old formula missed by up to 2%
    assert third == pytest.approx(exact, rel=1e-6, abs=1e-7)
