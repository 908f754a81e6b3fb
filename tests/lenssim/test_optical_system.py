"""The optical-system protocol: the thin lens implements it, and its closed-form Seidel sums (the fast path)
equal the general surface-by-surface sums over its surfaces."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lenssim import Design, Lens
from lenssim.optics.optical_system import OpticalSystem, surface_seidel_sums
from lenssim_studies.paper import PAPER_LENS


def test_the_thin_lens_is_an_optical_system():
    assert isinstance(PAPER_LENS, OpticalSystem)
    surfs = PAPER_LENS.surfaces(Design(s=-0.775, Q_back=-2.4))
    assert PAPER_LENS.stop_index == 0 and len(surfs) == 2
    assert all(s.semi_aperture_mm == PAPER_LENS.pupil_radius_mm and s.thickness_after_mm == 0 for s in surfs)


@pytest.mark.parametrize("glass", [1.5, "N-BK7"])
def test_closed_form_seidel_sums_equal_the_surface_by_surface_route(glass):
    lens = dataclasses.replace(PAPER_LENS, glass=glass)
    s = torch.tensor([-2.0, -0.775, 0.0, 0.6], dtype=torch.float64)[:, None]
    q = torch.tensor([-10.0, -2.4, 0.0, 1.2], dtype=torch.float64)[None, :]
    design = Design(s=s.expand(4, 4), Q_back=q.expand(4, 4), Q_front=0.7 * q.expand(4, 4))
    alpha = torch.tensor([0.0, 5.0, 14.0], dtype=torch.float64)
    for lam in (None, 0.45, 0.65):
        if lam is not None and glass == 1.5:
            continue
        fast = lens.seidel_sums(design.unsqueeze(-1), alpha, lam)
        general = surface_seidel_sums(lens, design.unsqueeze(-1), alpha, lam)
        torch.testing.assert_close(fast, general, rtol=1e-12, atol=1e-15)


def test_the_general_route_refuses_a_stop_it_does_not_model():
    class Stopped(Lens):
        @property
        def stop_index(self):
            return 1

    lens = Stopped(**{f.name: getattr(PAPER_LENS, f.name) for f in dataclasses.fields(PAPER_LENS)})
    with pytest.raises(ValueError, match="stop at the first surface"):
        surface_seidel_sums(lens, Design(s=-0.775, Q_back=-2.4), 5.0)
