"""``strehl``: the Strehl ratio at the Gaussian image point, field average (maximised).

The PSF at the paraxial (Gaussian) image point relative to the aberration-free PSF's peak. By the
sampling theorem's sum rule, the mean of the OTF over the full DFT grid is the PSF at the origin
sample (aliasing included), so ``S = <Re H> / <H_0>`` with ``H_0`` the diffraction-limited OTF of the same
camera (spectrum, pupil, sampling) on the same grid: no peak search, and exact for a PSF sampled at any
pitch. The reference point is the Gaussian image point (the wavefront has no tilt term), so coma's
shift of the peak lowers this Strehl ratio; it is not maximised over the image position.

References
----------
.. [1] V. N. Mahajan, "Strehl ratio for primary aberrations in terms of their aberration variance",
   J. Opt. Soc. Am. 73(6), 860-861 (1983).
.. [2] L. N. Thibos, X. Hong, A. Bradley, R. A. Applegate, "Accuracy and precision of objective
   refraction from wavefront aberrations", J. Vision 4(4), 329-351 (2004): the OTF-based Strehl ratio.

Examples
--------
>>> from lenssim import CRITERIA, FAST_NUMERICS, Camera, ConstantGlass, Design, Lens, Sensor, Spectrum, evaluate
>>> lens = Lens(focal_length_mm=25.0, pupil_radius_mm=2.0, glass=ConstantGlass(1.5), field_angles_deg=(0.0, 5.0))
>>> camera = Camera(lens, Sensor(pixel_pitch_um=1.5625, width_px=6000, height_px=4000), Spectrum.monochromatic(0.5))
>>> r = evaluate(camera, Design(s=-0.775, Q_back=-2.4), [27.6], rho0=0.97, numerics=FAST_NUMERICS)
>>> CRITERIA["strehl"].sense, [round(float(v), 3) for v in r["strehl_alpha"]]
('max', [0.918, 0.084])
"""

from __future__ import annotations

import torch

from . import Criterion, OTFContext, register


def strehl(ctx: OTFContext) -> torch.Tensor:
    """Strehl ratio ``(B,)`` of each PSF at its Gaussian image point (1 for an aberration-free lens)."""
    return ctx.integrate(ctx.H.real) / ctx.integrate(ctx.diffraction_limited().real)


register(Criterion("strehl", "Strehl", "Strehl ratio at the Gaussian image point, field average", "1", False,
                   from_otf=strehl, sense="max"))
