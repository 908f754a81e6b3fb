"""Speed of the gradient route of the trade-off on any lens (issue 30): gradient evaluations and descent steps per
second for the Cooke triplet with 6 free parameters (third-order wavefront, its 3 field angles and 3 wavelengths),
against the paper singlet's end-to-end autograd gradient (lenssim.design_opt.DifferentiableCriterion at its 15 field
angles) run side by side in the same process.

    python benchmarks/bench_lens_gradient.py [--starts 4] [--steps 10] [--repeats 3] [--exact-steps 8] [--dense 3]

Then the real-ray route (``tradeoff --optimise --wavefront exact``, :class:`lenssim.design_opt.LensExactCriterion`)
on the same lens: one gradient timed beside the third-order one, and an unconstrained descent over 4 free parameters
(E1 and E2 bendings, S7's conic, the focus) from the file's design, then the iso-cost descent at half its optimum's
cost from that optimum, each end point checked against a dense grid about it (``--dense`` points per parameter over +-1 typical step,
every combination; for the iso-cost one, the points within the cost): no grid point may be lower.

Prints one line per measurement and a JSON summary on the last line.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from lenssim.design_opt import DifferentiableCriterion, optimise_on_iso_cost
from lenssim.io.prescription_file import read_lens
from lenssim.design_opt import LensExactCriterion, LensThirdOrderCriterion
from lenssim.model.lens_parameters import parameter_values, parse_parameter
from lenssim.model.numerics import FAST_NUMERICS
from lenssim.optics.sequential import SequentialLens
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0

COOKE_PARAMETERS = ("E1.bending", "E2.bending", "S1.conic", "S6.conic", "S7.conic", "S7.A4")
COOKE_BOUNDS = ((0.3, 1.3), (-0.6, 0.4), (-1.0, 1.0), (-1.0, 1.0), (-2.0, 0.5), (-3e-6, 3e-6))
"""About the file's design (E1 bending 0.80, E2 bending -0.08, spherical); S7's conic and A4 over the region
docs/design-any-lens.md's grid explored, widened."""
LEVEL = 3.5e-4
"""The cost level (C_a) descended on: the grid's rms_w optimum's cost (docs/design-any-lens.md)."""


def _time(fn, repeats: int) -> float:
    fn()  # warm-up (FFT plans, the FFT sizes fixed)
    t = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - t) / repeats


def _gradient(f, x):
    def run():
        xx = x.clone().requires_grad_(True)
        torch.autograd.grad(f.objective(xx), xx)
    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=4)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--exact-steps", type=int, default=8, help="steps of the real-ray descent (0: skip it)")
    ap.add_argument("--dense", type=int, default=3, help="grid points per parameter about the real-ray optimum")
    args = ap.parse_args()
    torch.set_num_threads(torch.get_num_threads())
    p = read_lens("cooke_triplet")
    pars = [parse_parameter(p, n, aspherize=(7,)) for n in COOKE_PARAMETERS]
    seq = SequentialLens(p)
    pitch = p.primary_wavelength_um * seq.paraxial().working_f_number / 2
    scale = [(hi - lo) / 20 for lo, hi in COOKE_BOUNDS]
    f = LensThirdOrderCriterion(p, pars, 27.6, "mse_r", rho0=PAPER_RHO0, pitch_um=pitch, angles_deg=p.fields,
                                scale=scale, hold=("efl",), numerics=FAST_NUMERICS)
    x0 = torch.tensor(list(parameter_values(p, pars).values()), dtype=torch.float64)
    base = DifferentiableCriterion(PAPER_CAMERA, 27.6, "mse_r", rho0=PAPER_RHO0, numerics=FAST_NUMERICS)
    xb = torch.tensor([-0.775, -2.4], dtype=torch.float64)
    t_base = _time(_gradient(base, xb), args.repeats)
    t_grad = _time(_gradient(f, x0), args.repeats)
    print(f"baseline: paper singlet, 2 parameters, 15 angles, 1 wavelength: one gradient {t_base:.3f} s")
    print(f"Cooke triplet, 6 parameters, {len(p.fields)} angles, {len(p.wavelengths_um)} wavelengths: one gradient "
          f"{t_grad:.3f} s ({t_grad / t_base:.2f}x the baseline); FFT sizes {f.sizes}")
    level = LEVEL
    g = torch.Generator().manual_seed(0)
    lo = torch.tensor([b[0] for b in COOKE_BOUNDS], dtype=torch.float64)
    hi = torch.tensor([b[1] for b in COOKE_BOUNDS], dtype=torch.float64)
    x0 = torch.where(x0 == 0, (hi - lo) / 20, x0)  # as LensGradientRun.start_points: off the cost's apex
    starts = [torch.maximum(torch.minimum(x0, hi), lo)] + [lo + (hi - lo) * torch.rand(6, generator=g, dtype=torch.float64)
                                                          for _ in range(args.starts - 1)]
    bounds = {n: b for n, b in zip(f.names, COOKE_BOUNDS)}
    steps = evals = 0
    t = time.perf_counter()
    results = []
    for x in starts:
        fs = LensThirdOrderCriterion(p, pars, 27.6, "mse_r", rho0=PAPER_RHO0, pitch_um=pitch, angles_deg=p.fields,
                                     scale=scale, hold=("efl",), numerics=FAST_NUMERICS)
        try:
            r = optimise_on_iso_cost(fs, x, level, steps=args.steps, cost_points=FAST_NUMERICS.cost_points,
                                     bounds=bounds)
        except ValueError as exc:
            results.append({"stopped": "invalid", "reason": str(exc)[:120]})
            continue
        steps += r.iterations
        evals += r.evaluations
        results.append({"stopped": r.stopped, "iterations": r.iterations, "value": r.value, "cost": r.cost})
    wall = time.perf_counter() - t
    print(f"{len(starts)} starts on C_a = {level:.3g}: {steps} descent steps, {evals} criterion evaluations in "
          f"{wall:.1f} s: {steps / wall:.3f} steps/s")
    for r in results:
        print("  ", r)
    exact = _exact_route(p, pitch, args) if args.exact_steps > 0 else {}
    print(json.dumps({"baseline_gradient_s": t_base, "cooke_gradient_s": t_grad, "ratio": t_grad / t_base,
                      "steps": steps, "evaluations": evals, "wall_s": wall, "steps_per_s": steps / wall,
                      "threads": torch.get_num_threads(), "results": results, "exact": exact}))


EXACT_PARAMETERS = ("E1.bending", "E2.bending", "S7.conic", "focus_um")
EXACT_SCALE = (0.05, 0.05, 0.125, 10.0)
"""The real-ray descent's free parameters and their typical steps (bendings, conic, um of focus)."""


def _exact_route(p, pitch: float, args) -> dict:
    """One gradient of each route on the same parameters, side by side; an unconstrained real-ray descent and the
    dense grid about its end point."""

    pars = [parse_parameter(p, n, aspherize=(7,)) for n in EXACT_PARAMETERS]
    kw = dict(rho0=PAPER_RHO0, pitch_um=pitch, angles_deg=p.fields, scale=list(EXACT_SCALE), hold=("efl",),
              numerics=FAST_NUMERICS)
    x0 = torch.tensor([v if v == v else 0.0 for v in parameter_values(p, pars).values()], dtype=torch.float64)
    third, exact = LensThirdOrderCriterion(p, pars, 27.6, "mse_r", **kw), LensExactCriterion(p, pars, 27.6, "mse_r", **kw)
    t3 = _time(_gradient(third, x0), args.repeats)
    te = _time(_gradient(exact, x0), args.repeats)
    print(f"4 parameters ({', '.join(EXACT_PARAMETERS)}), {len(p.fields)} angles, {len(p.wavelengths_um)} "
          f"wavelengths: one gradient third order {t3:.3f} s (FFT sizes {third.sizes}), real rays {te:.3f} s "
          f"(FFT sizes {exact.sizes}): {te / t3:.2f}x")
    r, t_desc = _descend(exact, x0, None, args.exact_steps, "unconstrained, from the file's design")
    grid_free = _dense_check(exact, r, None, args.dense)
    level = r.cost / 2  # the iso-cost descent where the cost binds: half the unconstrained optimum's asphere
    # from the unconstrained optimum: off the sphere's kink, where the cost has no gradient to project along
    start = torch.tensor([r.design[n] for n in exact.names], dtype=torch.float64)
    ri, t_iso = _descend(exact, start, level, args.exact_steps, f"on C_a = {level:.4g}, from the unconstrained optimum")
    grid_iso = _dense_check(exact, ri, level, args.dense)
    return {"third_order_gradient_s": t3, "exact_gradient_s": te, "ratio": te / t3, "descent_steps": r.iterations,
            "descent_s": t_desc, "start_value": float(exact(x0)), "value": r.value, "design": r.design,
            "stopped": r.stopped, "grid": grid_free, "iso_level": level, "iso_steps": ri.iterations, "iso_s": t_iso,
            "iso_value": ri.value, "iso_cost": ri.cost, "iso_design": ri.design, "iso_stopped": ri.stopped,
            "iso_grid": grid_iso}


def _descend(exact, x0, level, steps: int, what: str):
    """One real-ray descent (``level`` None: unconstrained) and its wall time, printed."""
    t = time.perf_counter()
    r = optimise_on_iso_cost(exact, x0, level, steps=steps, cost_points=FAST_NUMERICS.cost_points)
    wall = time.perf_counter() - t
    print(f"real-ray descent, {what}: {r.iterations} steps, {r.evaluations} evaluations in {wall:.1f} s, stopped: "
          f"{r.stopped}; mse_r {float(exact(x0)):.6g} -> {r.value:.6g} at cost {r.cost:.4g}, "
          + ", ".join(f"{k} = {v:.5g}" for k, v in r.design.items()))
    return r, wall


def _dense_check(exact, r, level, dense: int) -> dict:
    """The dense grid about a descent's end point (``dense`` points per parameter over +-1 typical step, every
    combination): with a ``level``, only the points whose cost is at most it compete (the best design within the
    cost); none may be lower than the descent's value."""
    import itertools

    best = torch.tensor([r.design[n] for n in exact.names], dtype=torch.float64)
    offsets = torch.linspace(-1, 1, dense, dtype=torch.float64)
    scale = torch.tensor(EXACT_SCALE, dtype=torch.float64)
    t = time.perf_counter()
    values = []
    with torch.no_grad():
        for o in itertools.product(offsets.tolist(), repeat=len(EXACT_PARAMETERS)):
            if any(o):
                x = best + torch.tensor(o, dtype=torch.float64) * scale
                try:
                    if level is not None and float(exact.cost(x, FAST_NUMERICS.cost_points)) > level * (1 + 1e-9):
                        continue
                    values.append(float(exact(x)))
                except ValueError:
                    pass
    lowest = min(values) if values else float("nan")
    where = "" if level is None else f" within C_a <= {level:.4g}"
    print(f"dense grid about it{where} ({dense}^{len(EXACT_PARAMETERS)} - 1 points, {len(values)} valid and "
          f"competing, +-1 typical step, {time.perf_counter() - t:.0f} s): lowest {lowest:.6g}, the descent's "
          f"{r.value:.6g}: " + ("no grid point is lower" if not lowest < r.value else
                                f"a grid point is lower by {r.value - lowest:.3g}"))
    return {"points": len(values), "lowest": lowest, "lower": bool(lowest < r.value)}


if __name__ == "__main__":
    main()
