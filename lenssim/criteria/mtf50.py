"""``mtf50``: the frequency (cycles/mm) at which the MTF falls to 0.5, field average (maximised).

Per PSF, the MTF ``|H|`` is read along the two axes of the frequency plane, which are the field point's
tangential and sagittal directions (the PSFs of the bank lie on one axis of the field); on each, the
first crossing of 0.5 is interpolated linearly between frequency samples, and the two are averaged.
An MTF that stays above 0.5 up to the sensor's Nyquist frequency (1/2 cycle per pixel) counts as the
Nyquist frequency: the sensor samples nothing finer (the value is then a lower bound, and a
:class:`lenssim.validate.ModelValidityWarning` says so; a camera sampled at the optics' Nyquist pitch or finer,
which :meth:`lenssim.Camera.check_sampling` requires, never reaches it: the MTF is 0 beyond the cut-off).

References
----------
.. [1] ISO 12233:2017, Photography -- Electronic still picture imaging -- Resolution and spatial
   frequency responses (MTF50 as a summary of the spatial frequency response).
"""

from __future__ import annotations

import torch

from . import Criterion, OTFContext, register

LEVEL = 0.5
"""The MTF level whose frequency is reported."""


def first_crossing(mtf: torch.Tensor, freq: torch.Tensor, level: float = LEVEL) -> torch.Tensor:
    """Frequency ``(B,)`` of the first fall of ``mtf`` ``(B, N)`` (sampled at ``freq`` ``(N,)``, increasing)
    below ``level``, interpolated linearly; ``freq[-1]`` where it never falls below."""
    mtf = mtf.to(torch.float64)
    below = mtf < level
    k = torch.argmax(below.to(torch.int8), dim=-1).clamp_min(1)  # first sample below (index 0 is H(0) = 1)
    a = mtf.gather(-1, (k - 1)[:, None])[:, 0]
    b = mtf.gather(-1, k[:, None])[:, 0]
    t = ((a - level) / (a - b).clamp_min(torch.finfo(torch.float64).tiny)).clamp(0, 1)
    f = freq[k - 1] + t * (freq[k] - freq[k - 1])
    return torch.where(below.any(dim=-1), f, freq[-1].expand_as(f))


def mtf50(ctx: OTFContext) -> torch.Tensor:
    """MTF50 ``(B,)`` in cycles/mm: the mean of the tangential and sagittal first crossings of 0.5."""
    mtf = ctx.H2.sqrt()
    f = ctx.freq_cycles_per_mm
    capped = (mtf[:, 0, :] >= LEVEL).all(dim=-1) | (mtf[:, :, 0] >= LEVEL).all(dim=-1)
    if bool(capped.any()):
        from ..validate import warn_model

        warn_model(f"MTF50: the MTF of {int(capped.sum())} PSF(s) stays above {LEVEL} up to the sensor's Nyquist "
                   f"frequency ({float(f[-1]):.4g} cycles/mm); their MTF50 is counted there (a lower bound)")
    return 0.5 * (first_crossing(mtf[:, 0, :], f) + first_crossing(mtf[:, :, 0], f))


register(Criterion("mtf50", "MTF50", "frequency where the MTF falls to 0.5 (tangential and sagittal mean), "
                   "field average", "cycles/mm", False, from_otf=mtf50, sense="max"))
