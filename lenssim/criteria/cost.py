"""``cost``: the industrial cost ``C_a``, the RMS slope departure of the aspheres (:mod:`lenssim.optics.cost`).

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Section 2.2, Eq. (3).
"""

from __future__ import annotations

from ..optics.cost import slope_departure_cost
from . import Criterion, register


def cost(camera, design, coeffs, numerics):
    """``C_a`` ``(*)`` (slope units) of the design's aspheres."""
    return slope_departure_cost(camera.lens, design, numerics.cost_points)


register(Criterion("cost", "C_a", "industrial cost: RMS slope departure of the aspheres", "1 (slope)", False,
                   from_design=cost, role="cost"))
