"""``rms_w``: the paper's wavefront criterion ``RMS_W = sqrt(<RMS_w(alpha)^2>_alpha)`` (no piston removal).

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Sections 2.1-2.2, Eq. (2) (the wavefront), its RMS over the pupil.
"""

from __future__ import annotations

import torch

from . import Criterion, register, wavefront_rms_per_field


def rms_w(camera, design, coeffs, numerics) -> torch.Tensor:
    """Field RMS of the wavefront error ``(*)`` in waves, from coefficients ``(*, A, K, T)``."""
    return torch.sqrt((wavefront_rms_per_field(camera, coeffs) ** 2).mean(dim=-1))


register(Criterion("rms_w", "RMS_W", "field RMS of the wavefront error (no piston removal)", "waves", False,
                   from_design=rms_w))
