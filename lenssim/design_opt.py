"""Gradient-based trade-off without a grid (paper Section 5): optimise quality along an iso-cost curve.

The whole chain ``(s, Q) -> W -> pupil -> PSF -> OTF -> MSE`` is differentiable torch code, and so
is the cost ``C_a`` (a Newton step at the converged best-fit sphere carries its gradient). At each step the
quality gradient is projected on the subspace orthogonal to the cost gradient, a backtracking
step is taken along it, and the point is pulled back onto ``C_a = level`` by Newton steps along
the cost gradient. FFT sizes are fixed per field angle at the start (piecewise-constant in the
design, so they carry no gradient). The optimisation vector ``x`` holds the design parameters
named in ``names`` (default the paper's ``s``, ``Q_back``); coordinates are scaled by each
parameter's typical step (:data:`lenssim.model.design.PARAMETERS`: the paper's grid steps, 0.025 in s,
0.1 in Q) so all parameters move comparably.


Any lens (issue 30, item 4: more free parameters than a grid can hold): :class:`LensThirdOrderCriterion` is the same
criterion of a prescription as a function of the values of its free parameters (:mod:`lenssim.model.lens_parameters`),
with the solves the designer holds (:mod:`lenssim.optics.lens_solves`). Its chain has two parts:

* ``x -> wavefront coefficients`` (the solves, the paraxial rays, the Seidel sums:
  :func:`lenssim.optics.seidel_wavefront.third_order_coefficients`): closed-form arithmetic on the prescription's
  numbers, milliseconds a design. Its Jacobian is taken by central differences (steps of
  :data:`FD_STEP` of each parameter's typical step; the sums are smooth rational functions of the parameters, so the
  truncation error is about ``FD_STEP^2`` relative and the rounding error about ``1e-16 / FD_STEP``);
* ``coefficients -> pupil -> PSF -> OTF -> criterion``: the FFTs, where the work is; differentiated by autograd, the
  singlet's code (:class:`DifferentiableCriterion`, of which it is a subclass).

The cost ``C_a`` (:func:`lenssim.optics.cost.prescription_costs`, summed over the aspheric surfaces) is
differentiated by central differences likewise, and :func:`optimise_on_iso_cost` runs on it unchanged. The PSF's
scale (the working F-number) must not move with ``x``: a design that changes it is refused (hold the focal length:
``hold=("efl",)``). :class:`LensExactCriterion` is the same chain on the real rays' wavefront (``tradeoff --optimise
--wavefront exact``): the first part is a real-ray trace and a degree-8 fit per field angle and wavelength (tenths of
a second a design) on the design's numbers as tensors, differentiated by autograd through the solves, the aiming, the
trace and the fit; its cost too, where the file gives the apertures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .model.camera import Camera
from .model.prescription import Prescription
from .optics.cost import lens_cost, prescription_costs, slope_departure_cost
from .criteria import OTFContext, quarter_weights, validate_criterion
from .model.design import PARAMETERS, Design, parameter_name
from .optics.image_model import image_psd_quarter, noise_variance
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .optics.exact_wavefront import EXACT_TERMS, lens_exact_coefficients
from .optics.lens_solves import solve_design, solve_numbers
from .optics.psf_bank import fft_size, otf_quarter_spectrum, spectral_coefficients
from .optics.seidel_wavefront import SEIDEL_TERMS, check_third_order_parameters, third_order_coefficients
from .optics.sequential import SequentialLens
from .metrics import third_order_camera
from .torch_utils import HOST, abs_square, tensor_of

__all__ = ["DifferentiableCriterion", "IsoCostResult", "optimise_on_iso_cost", "LensThirdOrderCriterion",
           "LensExactCriterion", "GRADIENT_CRITERIA", "FD_STEP", "F_NUMBER_TOLERANCE"]

LENS_PARAMETERS = ("s", "Q_back")
"""The thin lens's two design parameters: the default optimisation vector."""


class DifferentiableCriterion:
    """An OTF criterion of :mod:`lenssim.criteria` (field average at one SNR) as a differentiable
    function of ``x``, the values of the design parameters ``names``."""

    def __init__(self, camera: Camera, snr_db: float, criterion: str, *, rho0: float, psd_model: str = "discrete",
                 names=LENS_PARAMETERS, numerics: Numerics = DEFAULT_NUMERICS.replace(oversample=1), dtype=torch.float64):
        crit = validate_criterion(criterion)
        if crit.from_otf is None:
            raise ValueError(f"criterion={criterion!r} is not allowed: an OTF criterion "
                             "(the design criteria have their own closed forms)")
        self.camera, self.criterion, self.numerics, self.dtype = camera, crit, numerics, dtype
        self.rho0, self.psd_model = rho0, psd_model  # the image model, as in evaluate() and sweeps
        self.names = tuple(parameter_name(n) for n in names)
        self.sigma2 = noise_variance([snr_db]).to(dtype)
        self.sizes: list[int] | None = None
        self.evaluations = 0

    @property
    def lens(self):
        return self.camera.lens

    def design(self, x: torch.Tensor) -> Design:
        return Design(dict(zip(self.names, x.unbind(0))))

    terms = None
    """The coefficients' monomial table (None: :data:`lenssim.optics.aberrations.TERMS`)."""

    def coefficients(self, x: torch.Tensor) -> torch.Tensor:
        """The wavefront coefficients ``(A, K, T)`` (waves) of design ``x`` at the camera's field angles and
        wavelengths, differentiable in ``x``."""
        return spectral_coefficients(self.camera, self.design(x))

    def fix_sizes(self, x: torch.Tensor) -> None:
        """Choose the FFT size per field angle at design ``x`` (with a 25% margin for the way ahead)."""
        c = self.coefficients(x.detach()).to(torch.float64)
        self.sizes = [int(v) for v in fft_size(self.camera, c * 1.25, self.numerics, terms=self.terms)]

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if self.sizes is None:
            self.fix_sizes(x)
        self.evaluations += 1
        coeffs = self.coefficients(x).to(self.dtype)  # (A, K, T)
        over = self.numerics.oversample
        total = 0
        for a, n in enumerate(self.sizes):
            m = n * over
            H = otf_quarter_spectrum(self.camera, coeffs[a:a + 1], n, oversample=over, numerics=self.numerics,
                                     terms=self.terms)
            psd = image_psd_quarter(m, self.rho0, model=self.psd_model, dtype=self.dtype, device=H.device)
            w = quarter_weights(m, psd.dtype, psd.device)
            ctx = OTFContext(H, abs_square(H), psd, w, psd * w, self.sigma2.to(H.device), n, self.camera,
                             self.numerics)
            v = self.criterion.from_otf(ctx)
            total = total + (v[0, 0] if self.criterion.per_snr else v[0])
        return total / len(self.sizes)

    def objective(self, x: torch.Tensor) -> torch.Tensor:
        """The value to minimise: the criterion, negated for a criterion to maximise (its ``sense``)."""
        return self.criterion.sign * self(x)



@dataclass
class IsoCostResult:
    design: dict
    value: float
    cost: float
    level: float
    iterations: int
    evaluations: int
    history: list = field(default_factory=list)
    stopped: str = ""
    """Why the descent stopped: ``gradient`` (the tangential gradient per typical step below ``tol`` relative to the
    value: converged), ``step`` (no step of at least 1e-3 typical steps lowers the value: converged to that
    resolution, or held by a bound), ``steps`` (the step budget ran out: not converged)."""
    gradient: float = float("nan")
    """The last tangential gradient per typical step, relative to the value."""


SCALED_PROJECTION_ITERATIONS = 30
"""Newton steps of the projection onto a cost level in scaled coordinates (any lens)."""
MAX_PROJECTION_STEP = 2.0
"""Longest Newton step of that projection, in typical steps (a trust region)."""


def _cost(quality, x, points):
    """``C_a`` at ``x``, differentiable: the quality's own ``cost(x, points)`` where it has one (any lens,
    :class:`LensThirdOrderCriterion`), else the singlet's :func:`lenssim.optics.cost.slope_departure_cost`."""
    if hasattr(quality, "cost"):
        return quality.cost(x, points)
    return slope_departure_cost(quality.lens, quality.design(x), points)


def _scale_of(quality) -> torch.Tensor:
    """Each coordinate's typical step: the quality's own ``scale`` where it has one, else the singlet's grid steps."""
    if hasattr(quality, "scale"):
        return quality.scale
    return torch.tensor([PARAMETERS[n].step for n in quality.names], dtype=torch.float64, device=HOST)


def _project_to_level(quality, x, level, points, iters=6):
    """Newton steps along the cost gradient back onto ``C_a = level``: the least step in the coordinates scaled by each
    parameter's typical step where the quality has its own ``scale`` (any lens: parameters of different units), in
    the singlet's raw ``(s, Q)`` otherwise (the steps its pinned results were found with)."""
    S = quality.scale if hasattr(quality, "scale") else None
    for _ in range(iters if S is None else SCALED_PROJECTION_ITERATIONS):
        xx = x.detach().requires_grad_(True)
        c = _cost(quality, xx, points)
        (g,) = torch.autograd.grad(c, xx)
        err = c.item() - level
        if abs(err) <= 1e-10 * max(level, 1e-12):
            break
        if S is None:
            x = x.detach() - err * g / g.dot(g)
            continue
        gu = g * S
        if not (bool(torch.isfinite(gu).all()) and float(gu.dot(gu)) > 0):
            raise ValueError(f"the cost has no gradient at {quality.design(x)} (C_a = {c.item():.3g}): the level "
                             f"{level:.3g} cannot be reached from there")
        step = -err * gu / gu.dot(gu)
        n = float(step.norm())
        if n > MAX_PROJECTION_STEP:  # a trust region: the cost is far from linear over many typical steps
            step = step * (MAX_PROJECTION_STEP / n)
        x = x.detach() + step * S
    if S is not None and abs(_cost(quality, x.detach(), points).item() - level) > 1e-6 * max(level, 1e-12):
        raise ValueError(f"the level C_a = {level:.3g} was not reached from {quality.design(x)}")
    return x.detach()


def optimise_on_iso_cost(quality: DifferentiableCriterion, x0, level: float | None, *, steps: int = 30,
                         step0: float = 2.0, tol: float = 1e-7, cost_points: int = DEFAULT_NUMERICS.cost_points,
                         bounds=None) -> IsoCostResult:
    """Optimise ``quality`` (minimised, or maximised if its criterion's sense is ``"max"``) along
    ``C_a = level`` from ``x0`` (values of ``quality.names``) by projected gradient descent.

    ``step0`` is the first trial step in grid steps; steps are halved until the quality decreases.
    Stops when the tangential gradient (per grid step) is below ``tol`` relative to the value, or
    after ``steps`` accepted steps. Designs are kept inside ``bounds`` ``{name: (lo, hi)}`` (a parameter
    left out is unbounded; the paper's scenario passes its grid, ``lenssim_studies.paper.PAPER_GRID``).
    ``level`` None: plain descent without the cost constraint (the unconstrained optimum).
    """
    bounds = dict(bounds or {})
    x = tensor_of(x0, torch.float64).clone()
    SCALE = _scale_of(quality).to(x.device)
    free = level is None
    if not free:
        x = _project_to_level(quality, x, level, cost_points)
    quality.fix_sizes(x)
    lo, hi = (torch.tensor([bounds.get(n, (-float("inf"), float("inf")))[i] for n in quality.names], dtype=torch.float64,
                           device=x.device) for i in (0, 1))
    step = step0
    history = []
    it = 0
    stopped, rel = "steps", float("nan")
    for it in range(1, steps + 1):
        xx = x.clone().requires_grad_(True)
        q = quality.objective(xx)
        (gq,) = torch.autograd.grad(q, xx)
        gq_u = gq * SCALE  # the gradient per grid step
        if free:
            tangent = gq_u
        else:
            xc = x.clone().requires_grad_(True)
            (gc,) = torch.autograd.grad(_cost(quality, xc, cost_points), xc)
            gc_u = gc * SCALE
            nrm = gc_u / gc_u.norm()
            tangent = gq_u - gq_u.dot(nrm) * nrm
        qv = q.item()
        history.append(tuple(float(v) for v in x) + (quality.criterion.sign * qv,))
        rel = float(tangent.norm()) / abs(qv) if qv else float(tangent.norm())
        if tangent.norm() <= tol * abs(qv):
            stopped = "gradient"
            break
        direction = -tangent / tangent.norm() * SCALE  # in the parameters' units, one typical step long
        accepted = False
        while step >= 1e-3:
            trial = torch.maximum(torch.minimum(x + step * direction, hi), lo)
            try:  # a trial design that cannot be made (any lens: crossing surfaces, a solve that fails) is not taken
                if not free:
                    trial = _project_to_level(quality, trial, level, cost_points)
                    trial = torch.maximum(torch.minimum(trial, hi), lo)
                with torch.no_grad():
                    qt = quality.objective(trial).item()
            except ValueError:
                qt = float("inf")
            if qt < qv:
                x, accepted = trial, True
                step *= 1.5
                break
            step *= 0.5
        if not accepted:
            stopped = "step"
            break
    with torch.no_grad():
        v = float(quality(x))
    return IsoCostResult(dict(zip(quality.names, (float(t) for t in x))), v, _cost(quality, x, cost_points).item(),
                         level, it, quality.evaluations, history, stopped, rel)


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
    the PSF about the primary wavelength's chief ray), differentiated by autograd end to end: the design's numbers as
    tensors (:func:`lenssim.optics.lens_solves.solve_numbers`, the ``efl`` solve included), the real aiming (its last
    Newton step carries the implicit derivative), the trace, the OPD and its fit, then pupil -> PSF -> OTF ->
    criterion as the third-order route. The cost ``C_a`` likewise (:func:`lenssim.optics.cost.lens_cost`) where every
    surface it counts has a semi-diameter in the file, else by central differences (the aperture then follows the
    design's paraxial beam). Each design is first made by the float route (:meth:`lens_at`), which refuses what cannot
    be made. Any free parameter of the lens may move (no third-order restriction); the working F-number must not."""

    terms = EXACT_TERMS

    def _check_parameters(self, parameters) -> None:
        pass

    def _numbers(self, x: torch.Tensor):
        """The batched lens at ``x`` (one design, numbers ``(1, 1)`` tensors carrying ``x``'s graph), after the float
        route has checked the design."""
        self._checked_lens(x.detach())
        return solve_numbers(self.prescription, self.parameters, x.to(torch.float64).reshape(1, -1), hold=self.hold,
                             image=self.image)

    def coefficients(self, x: torch.Tensor) -> torch.Tensor:
        seq = self._numbers(x)
        return lens_exact_coefficients(seq, self.angles, self.camera.spectrum.wavelengths_um)[0]

    def cost(self, x: torch.Tensor, points: int) -> torch.Tensor:
        """``C_a`` at ``x`` (:meth:`LensThirdOrderCriterion.cost`), by autograd where the file gives every counted
        surface's semi-diameter."""
        q = self.prescription
        if any(s.semi_diameter_mm is None for s in q.surfaces if s.is_aspheric) or any(
                q.surfaces[p.index].semi_diameter_mm is None for p in self.parameters
                if p.kind == "conic" or p.kind.startswith("A")):
            return super().cost(x, points)
        return lens_cost(self._numbers(x), int(points))[0]


GRADIENT_CRITERIA = {"third_order": LensThirdOrderCriterion, "exact": LensExactCriterion}
"""The gradient route's criterion per wavefront model (``tradeoff --optimise --wavefront``)."""
