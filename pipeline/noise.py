"""Sensor noise (paper Section 3.2-3.3): photon (Poisson) noise, and the sensor's further terms where it has them.

The blurred linear image's maximum is scaled to the full-well capacity (electrons), each pixel is
Poisson-sampled, and the result is scaled back. The paper's sensor
(:data:`lenssim_studies.paper.PAPER_SENSOR`): 3,200 e- at ISO 100 (the expected level, SNR ~27.6 dB), 800 at
ISO 400 and 12,800 at ISO 25, no read noise, no quantisation.

There is one forward model of the camera, :class:`pipeline.camera_chain.CameraChain`: :func:`expose` is the chain of the
given sensor (its stages on where the sensor sets their terms: read noise, ADC, dark current, PRNU, DSNU, ...; the
paper's sensor draws photon noise only), and the noise a restoration assumes is the chain's description of it
(:meth:`pipeline.camera_chain.CameraChain.noise_model`, a :class:`pipeline.camera_chain.NoiseModel`). Randomness comes only
from the explicit ``generator`` (or ``seed``), so results are reproducible.
"""

from __future__ import annotations

import torch

from lenssim import Sensor

from .camera_chain import CameraChain, NoiseModel
from .checks import check_full_well, check_image

__all__ = ["add_poisson_noise", "expose", "NoiseModel"]


def expose(image: torch.Tensor, electrons_per_unit: float, sensor: Sensor | CameraChain | None, full_well: float, *,
           generator: torch.Generator) -> torch.Tensor:
    """The sensor's reading of a linear image (any shape, >= 0): Poisson photo-electrons at ``electrons_per_unit`` per
    unit of the image, then ``sensor``'s further terms (``full_well`` electrons at the top of the ADC range), back in
    image units and dtype: :meth:`pipeline.camera_chain.CameraChain.expose` of ``CameraChain.of(sensor)`` (``None``: an
    ideal sensor, photon noise only)."""
    return CameraChain.of(sensor).expose(image, electrons_per_unit, full_well, generator=generator)


def add_poisson_noise(image: torch.Tensor, full_well: float, *, generator: torch.Generator | None = None,
                      seed: int | None = None, sensor: Sensor | CameraChain | None = None) -> torch.Tensor:
    """Poisson noise on a linear image ``(B, C, H, W)`` >= 0, with its maximum at ``full_well`` electrons,
    then ``sensor``'s further terms (``None``: an ideal sensor, photon noise only).

    Exactly one of ``generator`` and ``seed`` must be given. Returns the same shape, dtype and device.
    """
    if (generator is None) == (seed is None):
        raise ValueError("give exactly one of generator= or seed= (noise must be reproducible)")
    full_well = check_full_well(full_well)
    check_image(image, "image", nonnegative=True)
    chain = CameraChain.of(sensor)
    if generator is None:
        generator = torch.Generator(device=image.device).manual_seed(int(seed))
    peak = image.amax()
    if peak <= 0:
        return image.clone()
    return chain.expose(image, full_well / float(peak), full_well, generator=generator)
