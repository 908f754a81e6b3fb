"""Gradient-based cost-aware design of any lens through its third-order wavefront (issue 30, item 4: more free
parameters than a grid can hold).

:class:`LensThirdOrderCriterion` is an OTF criterion of :mod:`lenssim.criteria` (field average at one SNR) of a
prescription as a differentiable function of ``x``, the values of its free parameters
(:mod:`lenssim.model.lens_parameters`), with the solves the designer holds (:mod:`lenssim.optics.lens_solves`).
The chain has two parts:

* ``x -> wavefront coefficients`` (the solves, the paraxial rays, the Seidel sums:
  :func:`lenssim.optics.seidel_wavefront.third_order_coefficients`): closed-form arithmetic on the prescription's
  numbers, milliseconds a design. Its Jacobian is taken by central differences (steps of
  :data:`FD_STEP` of each parameter's typical step; the sums are smooth rational functions of the parameters, so the
  truncation error is about ``FD_STEP^2`` relative and the rounding error about ``1e-16 / FD_STEP``);
* ``coefficients -> pupil -> PSF -> OTF -> criterion``: the FFTs, where the work is; differentiated by autograd, as
  the singlet's :class:`lenssim.design_opt.DifferentiableCriterion` (of which this is a subclass: the same code).

The cost ``C_a`` (:func:`lenssim.optics.cost.prescription_costs`, summed over the aspheric surfaces) is
differentiated by central differences likewise. :func:`lenssim.design_opt.optimise_on_iso_cost` then runs the
paper's iso-cost projected gradient descent on it, unchanged. The PSF's scale (the working F-number) must not move
with ``x``: a design that changes it is refused (hold the focal length: ``hold=("efl",)``).

:class:`LensExactCriterion` is the same chain on the real rays' wavefront (``tradeoff --optimise --wavefront exact``):
the first part is a real-ray trace and a degree-8 fit per field angle and wavelength (tenths of a second a design),
its Jacobian by central differences of whole traces (autograd through the aiming and the trace itself is not yet
there: a prescription's numbers are Python floats).
"""

from __future__ import annotations

import math

import torch

from .design_opt import DifferentiableCriterion
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .model.prescription import Prescription
from .optics.cost import prescription_costs
from .optics.exact_wavefront import EXACT_TERMS, lens_exact_coefficients
from .optics.lens_solves import solve_design
from .optics.seidel_wavefront import SEIDEL_TERMS, check_third_order_parameters, third_order_coefficients
from .optics.sequential import SequentialLens
from .metrics import third_order_camera
from .torch_utils import tensor_of

__all__ = ["LensThirdOrderCriterion", "LensExactCriterion", "GRADIENT_CRITERIA", "FD_STEP", "F_NUMBER_TOLERANCE"]

FD_STEP = 1e-4
"""Central-difference step of the paraxial part's Jacobian, in each parameter's typical step."""
F_NUMBER_TOLERANCE = 1e-9
"""Largest relative change of the working F-number (the PSF's scale) a design may make."""


class _Paraxial(torch.autograd.Function):
    """``y = f(x)`` for a float function ``f`` of the parameters (forward exact, backward by central differences)."""

    @staticmethod
    def forward(ctx, x, f, steps):
        ctx.f, ctx.steps = f, steps
        ctx.save_for_backward(x)
        return f(x.detach())

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        x = x.detach()
        out = torch.zeros_like(x)
        for i in range(x.numel()):
            e = torch.zeros_like(x)
            e[i] = ctx.steps[i]
            d = (ctx.f(x + e) - ctx.f(x - e)) / (2 * ctx.steps[i])
            out[i] = (grad.to(d.dtype) * d).sum()
        return out, None, None


class LensThirdOrderCriterion(DifferentiableCriterion):
    """The criterion ``criterion`` at ``snr_db`` (dB) of the lens ``prescription`` with the free ``parameters``
    (:class:`lenssim.model.lens_parameters.LensParameter` s), ``hold`` and ``image`` solves, pixels of ``pitch_um``
    (um, point samples), field angles ``angles_deg`` (deg), image model ``rho0``, as a differentiable function of
    ``x`` (see the module docstring). ``scale``: each parameter's typical step (its unit), the optimiser's
    coordinate scale. ``image`` is ``file`` or ``paraxial`` (best focus is a search: no gradient)."""

    terms = SEIDEL_TERMS

    def __init__(self, prescription: Prescription, parameters, snr_db: float, criterion: str, *, rho0: float,
                 pitch_um: float, angles_deg, scale, hold=(), image: str = "file", psd_model: str = "discrete",
                 numerics: Numerics = DEFAULT_NUMERICS.replace(oversample=1), dtype=torch.float64):
        parameters = tuple(parameters)
        self._check_parameters(parameters)
        if image not in ("file", "paraxial"):
            raise ValueError(f"image plane {image!r} is not allowed with the gradient route: file or paraxial (best "
                             "focus is a search, without a gradient)")
        self.prescription, self.parameters, self.hold, self.image = prescription, parameters, tuple(hold), image
        self.angles = tuple(float(a) for a in angles_deg)
        seq = SequentialLens(prescription)
        super().__init__(third_order_camera(seq, pitch_um, self.angles), snr_db, criterion, rho0=rho0,
                         psd_model=psd_model, names=(), numerics=numerics, dtype=dtype)
        self.names = tuple(p.name for p in parameters)
        self.scale = tensor_of(scale, torch.float64).reshape(-1)
        if self.scale.numel() != len(parameters) or not bool((self.scale > 0).all() & torch.isfinite(self.scale).all()):
            raise ValueError(f"scale must hold one typical step > 0 per free parameter ({len(parameters)})")
        self.steps = (self.scale * FD_STEP).tolist()
        self.f_number = seq.paraxial().working_f_number
        if self.terms is SEIDEL_TERMS and len(self.camera.spectrum) == 1:  # one wavelength: the paper's four terms
            # exactly (no lateral colour)
            self.terms = SEIDEL_TERMS[:4]

    def lens_at(self, x) -> SequentialLens:
        """The lens at design ``x`` (floats), its solves applied; a ``ValueError`` saying why a design cannot be made."""
        values = {p: float(v) for p, v in zip(self.parameters, tensor_of(x).tolist())}
        q, shift = solve_design(self.prescription, values, hold=self.hold, image=self.image)
        return SequentialLens(q, image_shift_mm=shift)

    def _check_parameters(self, parameters) -> None:
        check_third_order_parameters(parameters)

    def _checked_lens(self, x: torch.Tensor) -> SequentialLens:
        """The lens at ``x``; a ``ValueError`` if it moves the working F-number (the PSF's scale)."""
        seq = self.lens_at(x)
        n = seq.paraxial().working_f_number
        if not math.isclose(n, self.f_number, rel_tol=F_NUMBER_TOLERANCE):
            raise ValueError(f"the design {self.design(x)} changes the working F-number ({self.f_number:.6g} -> "
                             f"{n:.6g}), the PSF's scale: hold the focal length (hold efl)")
        return seq

    def _coefficients(self, x: torch.Tensor) -> torch.Tensor:
        seq = self._checked_lens(x)
        c = third_order_coefficients(seq, self.angles, self.camera.spectrum.wavelengths_um)
        return c[..., :len(self.terms)]

    def _cost(self, x: torch.Tensor, points: int) -> torch.Tensor:
        q = self.lens_at(x).prescription
        return torch.tensor(sum(v["cost"] for v in prescription_costs(q, points).values()), dtype=torch.float64,
                            device=x.device)

    def design(self, x) -> dict:
        return {n: float(v) for n, v in zip(self.names, tensor_of(x).reshape(-1).tolist())}

    def coefficients(self, x: torch.Tensor) -> torch.Tensor:
        return _Paraxial.apply(x.to(torch.float64), self._coefficients, self.steps)

    def cost(self, x: torch.Tensor, points: int) -> torch.Tensor:
        """``C_a`` at ``x`` (the sum over the aspheric surfaces of their RMS slope departure over ``points`` radii),
        differentiable (central differences)."""
        return _Paraxial.apply(x.to(torch.float64), lambda v: self._cost(v, int(points)), self.steps)


class LensExactCriterion(LensThirdOrderCriterion):
    """:class:`LensThirdOrderCriterion` on the real rays' wavefront: ``x -> coefficients`` is the real-ray OPD of the
    lens at ``x`` projected on :data:`lenssim.optics.exact_wavefront.EXACT_TERMS` (degree 8,
    :func:`lenssim.optics.exact_wavefront.lens_exact_coefficients`: rays aimed at the stop, the pupil the full disc,
    the PSF about the primary wavelength's chief ray), its Jacobian by central differences of whole real-ray traces
    (:data:`FD_STEP`), the rest (pupil -> PSF -> OTF -> criterion) by autograd, as the third-order route. Any free
    parameter of the lens may move (no third-order restriction); the working F-number must not."""

    terms = EXACT_TERMS

    def _check_parameters(self, parameters) -> None:
        pass

    def _coefficients(self, x: torch.Tensor) -> torch.Tensor:
        seq = self._checked_lens(x)
        return lens_exact_coefficients(seq, self.angles, self.camera.spectrum.wavelengths_um)


GRADIENT_CRITERIA = {"third_order": LensThirdOrderCriterion, "exact": LensExactCriterion}
"""The gradient route's criterion per wavefront model (``tradeoff --optimise --wavefront``)."""
