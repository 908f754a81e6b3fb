"""Wavefront models, as a registry: how a design's wavefront at a field point is obtained.

* ``third_order``: the paper's Seidel (third-order) wavefront of the thin lens, in closed form
  (:func:`lenssim.optics.aberrations.wavefront_coefficients`; any spectrum);
* ``exact``: the optical path difference of an exact ray trace through the real surfaces at each field angle
  (:mod:`lenssim.optics.exact_wavefront`; one-wavelength cameras).

A model gives the PSFs of a :class:`lenssim.LensPSF` at image points (:attr:`WavefrontModel.psfs`), the cameras it
serves and the factor by which its PSF support may exceed third order's. Its criteria
(:attr:`WavefrontModel.evaluate`: every registered criterion of designs, the OTF criteria from its wavefront) belong
to the evaluation layer above the optics: :mod:`lenssim.metrics` registers them here (:func:`register_evaluator`)
when it is imported, which ``import lenssim`` does, so that this module never imports the criteria. The PSF
provider, ``lenssim evaluate --wavefront`` and ``lenssim simulate --wavefront`` read this table; a new model
(e.g. a measured wavefront) is one entry here and its evaluator in :mod:`lenssim.metrics`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

__all__ = ["WavefrontModel", "WAVEFRONT_MODELS", "validate_wavefront_model", "register_evaluator"]


@dataclass(frozen=True)
class WavefrontModel:
    """``psfs(provider, x_mm, y_mm, n, centered, dtype) -> (P, n, n)`` or ``(P, C, n, n)``; ``check(camera)``
    raises ``ValueError`` for a camera the model cannot serve; ``support_factor``: how much wider than third
    order's geometric support its PSFs may be. :attr:`evaluate` is the evaluator registered for the model from
    above (:func:`register_evaluator`)."""

    name: str
    label: str
    psfs: Callable
    check: Callable | None = None
    support_factor: float = 1.0

    @property
    def evaluate(self) -> Callable:
        """``evaluate(camera, design, snr_db, *, rho0, numerics, device) -> {criterion: tensor}`` (as
        :func:`lenssim.metrics.evaluate`), registered by the evaluation layer (:mod:`lenssim.metrics`)."""
        try:
            return _EVALUATORS[self.name]
        except KeyError:
            raise LookupError(f"wavefront model {self.name!r} has no evaluator: the evaluation layer registers one "
                              "(lenssim.optics.wavefront_models.register_evaluator)") from None


_EVALUATORS: dict[str, Callable] = {}
"""Each model's evaluator by model name, filled from above by :func:`register_evaluator`."""


def register_evaluator(name: str, evaluate: Callable) -> Callable:
    """Register ``evaluate`` as the criteria of the wavefront model ``name`` (:attr:`WavefrontModel.evaluate`);
    called by the evaluation layer, which may import the optics (this module never imports it). Returns
    ``evaluate``."""
    validate_wavefront_model(name)
    _EVALUATORS[name] = evaluate
    return evaluate


def _third_order_psfs(provider, x_mm, y_mm, n, centered, dtype):
    from .psf_bank import psf_at

    d = provider.design.map(lambda v: torch.full_like(y_mm, float(v.reshape(()))))
    camera = provider.camera.with_quadrature(provider.numerics.spectral_tol)
    if camera.shared_channels:  # each wavelength once for every channel
        nodes, weights = camera.node_camera()
        return psf_at(nodes, d, x_mm, y_mm, n=n, centered=centered, dtype=dtype, numerics=provider.numerics,
                      channel_weights=weights)[0]
    ps = [psf_at(cam, d, x_mm, y_mm, n=n, centered=centered, dtype=dtype, numerics=provider.numerics)[0]
          for cam in camera.channel_cameras()]
    return ps[0] if not provider.camera.channels else torch.stack(ps, dim=1)


def _one_wavelength(camera):
    if camera.channels or len(camera.spectrum) != 1:
        raise ValueError("wavefront='exact' takes a one-wavelength camera (no colour channels)")


def _exact_psfs(provider, x_mm, y_mm, n, centered, dtype):
    from .exact_wavefront import EXACT_TERMS, exact_wavefront_coefficients
    from .psf_bank import psf

    alpha = provider.geometry.field_angle_deg(x_mm, y_mm).cpu()
    c = torch.stack([exact_wavefront_coefficients(provider.camera, provider.design, float(a)) for a in alpha])
    az = torch.rad2deg(torch.atan2(y_mm, x_mm)).flatten()
    return psf(provider.camera, c[:, None].to(x_mm.device), n, azimuth_deg=az, centered=centered, dtype=dtype,
               numerics=provider.numerics, terms=EXACT_TERMS)


WAVEFRONT_MODELS: dict[str, WavefrontModel] = {m.name: m for m in (
    WavefrontModel("third_order", "third order (Seidel, closed form)", _third_order_psfs),
    WavefrontModel("exact", "exact (the OPD of a real ray trace; RMS_W stays third order)", _exact_psfs,
                   check=_one_wavelength, support_factor=1.25),  # fifth and higher orders: 25% more support
)}
"""The registry: name -> :class:`WavefrontModel`."""


def validate_wavefront_model(name: str) -> WavefrontModel:
    """The registered model ``name``; ``ValueError`` listing the valid names otherwise."""
    if name not in WAVEFRONT_MODELS:
        raise ValueError(f"wavefront={name!r} is not allowed: one of {', '.join(WAVEFRONT_MODELS)}")
    return WAVEFRONT_MODELS[name]
