"""The paper's numbers, named once (Optics Express 31(10) 16897, 2023).

Lens, sensor and spectrum (Section 3.1), the two designs of Fig. 8, the image model and noise
levels (Section 2.3, 3.2), the design grid (Section 3.1), the iso-cost levels (Section 2.4), the
field angles of Fig. 8 and the ISO table (Section 3.3). Everything else reads them from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.restoration.wiener import WIENER_RHO0

from lenssim.model.camera import Camera
from lenssim.model.design import Design, load_designs
from lenssim.model.glass import ConstantGlass
from lenssim.model.lens import Lens
from lenssim.model.sensor import Sensor
from lenssim.model.spectrum import Spectrum

__all__ = ["PAPER_LENS", "PAPER_SENSOR", "PAPER_SPECTRUM", "PAPER_CAMERA", "PAPER_DESIGNS", "PAPER_RHO0",
           "PAPER_SNR_DB", "REFERENCE_SNR_DB", "PAPER_GRID", "PAPER_COST_LEVELS", "PAPER_FIG8_ANGLES_DEG",
           "ISO_FULL_WELL", "ISO_FOR_SNR", "PAPER", "Scenario", "paper_designs"]

PAPER_LENS = Lens(focal_length_mm=25.0, pupil_radius_mm=2.0, glass=ConstantGlass(1.5),
                  field_angles_deg=tuple(float(a) for a in range(15)))
"""f = 25 mm, y = 2 mm (f/6.25), n = 1.5, object at infinity, field angles 0..14 deg."""

PAPER_SENSOR = Sensor(pixel_pitch_um=1.5625, width_px=6000, height_px=4000,
                      full_well_e=((25, 12800.0), (100, 3200.0), (400, 800.0)))
"""1.5625 um pixels (lambda f# / 2 at 0.5 um), 6000 x 4000, 12,800 / 3,200 / 800 e- at ISO 25 / 100 / 400."""

PAPER_SPECTRUM = Spectrum.monochromatic(0.5)
"""One wavelength, 0.5 um."""

PAPER_CAMERA = Camera(PAPER_LENS, PAPER_SENSOR, PAPER_SPECTRUM)

PAPER_DESIGNS = {
    "rms_w_paper": Design(s=-0.725, Q_back=-10.0, name="rms_w_paper",
                          description="paper's RMS_W optimum (conventional design, Fig. 8)"),
    "end_to_end_paper": Design(s=-0.775, Q_back=-2.4, name="end_to_end_paper",
                               description="paper's end-to-end (MSE_R at 27.6 dB) design (Fig. 8)"),
}

PAPER_RHO0 = WIENER_RHO0
"""Correlation coefficient per pixel of the image model ``rho0^|r|`` (0.97; the number is named once, as the
Wiener filter's prior, :data:`pipeline.restoration.wiener.WIENER_RHO0`)."""

PAPER_SNR_DB = (21.6, 27.6, 33.6)
"""SNR per pixel (dB): ISO 400 (low light), ISO 100 (expected), ISO 25 (high light)."""

REFERENCE_SNR_DB = PAPER_SNR_DB[1]
"""The expected noise level (27.6 dB, ISO 100): Fig. 4-6, Table 1 and the end-to-end design."""

ISO_FOR_SNR = dict(zip(PAPER_SNR_DB, (400, 100, 25)))

ISO_FULL_WELL = dict(PAPER_SENSOR.full_well_e)
"""Full-well capacity (electrons) per ISO."""

PAPER_GRID = {"s": (-2.0, 1.025, 0.025), "Q_back": (-10.0, 1.2, 0.1)}
"""The design grid: (start, stop inclusive, step) per parameter; 122 x 113 designs."""

PAPER_COST_LEVELS = np.linspace(0.0, 2e-3, 30)
"""30 iso-cost levels of C_a in [0, 2e-3] (slope units)."""

PAPER_FIG8_ANGLES_DEG = (1.3, 2.1, 7.1, 3.4, 4.8, 8.8)
"""Field angles (deg) of the crops of Fig. 8."""


def paper_designs(path=None) -> dict[str, Design]:
    """The named designs: the paper's two, those of the built-in ``configs/designs.toml``, and those of the TOML
    file ``path`` (if given)."""
    return load_designs(path, {**PAPER_DESIGNS, **load_designs()})


@dataclass(frozen=True)
class Scenario:
    """A study's givens, passed to the library's functions (which take none of them as defaults): the camera,
    the named designs, the noise levels and the reference one, the image model, the design grid, the iso-cost
    levels and the field angles of the Fig. 8 crops."""

    camera: Camera
    designs: dict
    snr_db: tuple[float, ...]
    reference_snr_db: float
    rho0: float
    grid: dict
    cost_levels: np.ndarray
    fig8_angles_deg: tuple[float, ...]


PAPER = Scenario(PAPER_CAMERA, PAPER_DESIGNS, PAPER_SNR_DB, REFERENCE_SNR_DB, PAPER_RHO0, PAPER_GRID, PAPER_COST_LEVELS,
                 PAPER_FIG8_ANGLES_DEG)
"""The paper (Optics Express 31(10), 16897, 2023) as a scenario."""
