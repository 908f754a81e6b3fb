"""Sensor noise (paper Section 3.2-3.3): photon (Poisson) noise, optional read noise and ADC.

The blurred linear image's maximum is scaled to the full-well capacity (electrons), each pixel is
Poisson-sampled, and the result is scaled back. The paper's sensor
(:data:`lenssim_studies.paper.PAPER_SENSOR`): 3,200 e- at ISO 100 (the expected level, SNR ~27.6 dB), 800 at
ISO 400 and 12,800 at ISO 25, no read noise, no quantisation. A :class:`lenssim.Sensor` with ``read_noise_e > 0`` adds Gaussian
read noise (electrons RMS) and with ``bit_depth`` quantises the electrons to ``2^bits - 1`` levels
over the full well. Randomness comes only from the explicit ``generator`` (or ``seed``), so
results are reproducible.
"""

from __future__ import annotations

import torch

from lenssim import Sensor

from .checks import check_full_well, check_image

__all__ = ["add_poisson_noise", "expose", "read_out", "read_noise_variance"]


def read_out(electrons: torch.Tensor, sensor: Sensor | None, full_well: float, *, generator: torch.Generator) -> torch.Tensor:
    """Read noise and ADC quantisation of ``sensor`` applied to photo-electron counts (any shape).

    Gaussian read noise of ``sensor.read_noise_e`` electrons RMS (drawn from ``generator``), then,
    with ``sensor.bit_depth``, rounding to ``2^bits - 1`` levels over ``[0, full_well]``. The paper's
    sensor has neither: the counts come back unchanged (and no random number is drawn).
    """
    out = electrons
    if sensor is None:  # an ideal sensor: photon noise only
        return out
    owned = False  # whether ``out`` is this function's own buffer (``electrons`` is never changed)
    if sensor.read_noise_e > 0:
        noise = torch.randn(out.shape, generator=generator, dtype=out.dtype, device=out.device)
        out, owned = noise.mul_(sensor.read_noise_e).add_(out), True  # electrons + read noise, in the noise's buffer
    if sensor.bit_depth is not None:
        levels = 2**sensor.bit_depth - 1
        gain = full_well / levels  # electrons per digital number
        out = (out.div_(gain) if owned else out / gain).round_().clamp_(0, levels).mul_(gain)
    return out


def read_noise_variance(sensor: Sensor | None, electrons_per_unit: float) -> float:
    """Variance (squared linear image units) of the read noise and ADC rounding, for the Wiener filter."""
    var_e = 0.0 if sensor is None else sensor.read_noise_e**2
    return var_e / electrons_per_unit**2 if electrons_per_unit != float("inf") else 0.0


def expose(image: torch.Tensor, electrons_per_unit: float, sensor: Sensor | None, full_well: float, *,
           generator: torch.Generator) -> torch.Tensor:
    """The sensor's reading of a linear image (any shape, >= 0): Poisson photo-electrons at
    ``electrons_per_unit`` per unit of the image, then ``sensor``'s read noise and quantisation (``full_well``
    electrons at the top of the ADC range), back in image units and dtype.

    The one noise path of crops and frames. The rate is formed in float64 from the image, so a float64 run
    draws the same counts on any CPU (a float32 rate that moves by one rounding between hosts can flip a count).
    """
    rate = (image.to(torch.float64) * electrons_per_unit).clamp_min_(0)
    counts = torch.poisson(rate, generator=generator)
    del rate  # float64 frames: at most two alive at a time (a 24 MP colour frame's is 580 MB)
    electrons = read_out(counts, sensor, full_well, generator=generator)
    del counts
    return electrons.div_(electrons_per_unit).to(image.dtype)


def add_poisson_noise(image: torch.Tensor, full_well: float, *, generator: torch.Generator | None = None,
                      seed: int | None = None, sensor: Sensor | None = None) -> torch.Tensor:
    """Poisson noise on a linear image ``(B, C, H, W)`` >= 0, with its maximum at ``full_well`` electrons,
    then ``sensor``'s read noise and quantisation (``None``: an ideal sensor, photon noise only).

    Exactly one of ``generator`` and ``seed`` must be given. Returns the same shape, dtype and device.
    """
    if (generator is None) == (seed is None):
        raise ValueError("give exactly one of generator= or seed= (noise must be reproducible)")
    full_well = check_full_well(full_well)
    check_image(image, "image", nonnegative=True)
    if generator is None:
        generator = torch.Generator(device=image.device).manual_seed(int(seed))
    peak = image.amax()
    if peak <= 0:
        return image.clone()
    return expose(image, full_well / float(peak), sensor, full_well, generator=generator)
