"""Speed of a batch of designs traced at once (issue 44, item 3): the real-ray wavefront coefficients of the Cooke
triplet (5 free parameters, focal length held, 2 field angles, 1 wavelength; rays aimed at the stop inside the lens)
for designs one at a time on the float route (the baseline) beside the batched route on the CPU and, where present,
on CUDA, in the same process; then one value and gradient of a design (autograd through the solve, the aiming, the
trace and the fit). Every batched result is compared with the float route's on the same designs.

    python benchmarks/bench_batched_rays.py [--designs 16] [--batches 16,64,256] [--repeats 2] [--cpu-max 64]

Prints one line per measurement and a JSON summary on the last line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import torch

from lenssim.io.prescription_file import read_lens
from lenssim.model.lens_parameters import parameter_values, parse_parameter
from lenssim.optics.exact_wavefront import lens_exact_coefficients
from lenssim.optics.lens_solves import solve_design, solve_numbers
from lenssim.optics.sequential import SequentialLens

NAMES = ("E1.bending", "E2.bending", "S6.conic", "S6.A4", "focus_um")
SPREAD = (0.05, 0.05, 0.2, 2e-6, 5.0)
"""The designs: the file's plus seeded normal draws of these standard deviations (bendings, conic, mm^-3, um)."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--designs", type=int, default=16, help="designs traced one at a time (the baseline)")
    ap.add_argument("--batches", default="16,64,256", help="batch sizes of the batched route")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--cpu-max", type=int, default=64, help="largest batch timed on the CPU")
    args = ap.parse_args()
    batches = [int(b) for b in args.batches.split(",")]
    p = read_lens("cooke_triplet")
    p = dataclasses.replace(p, wavelengths_um=(p.primary_wavelength_um,), fields=(0.0, 6.0))
    pars = [parse_parameter(p, n, aspherize=(6,)) for n in NAMES]
    x0 = torch.tensor([v if v == v else 0.0 for v in parameter_values(p, pars).values()], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    xs = x0 + torch.tensor(SPREAD, dtype=torch.float64) * torch.randn(max(batches + [args.designs]), len(NAMES),
                                                                       generator=g, dtype=torch.float64)

    def one(x):
        q, shift = solve_design(p, dict(zip(pars, x.tolist())), hold=("efl",))
        return lens_exact_coefficients(SequentialLens(q, image_shift_mm=shift), p.fields, p.wavelengths_um)

    t = time.perf_counter()
    ref = torch.stack([one(x) for x in xs[:args.designs]])
    t_one = (time.perf_counter() - t) / args.designs
    print(f"float route, one design at a time (CPU, {torch.get_num_threads()} threads): {t_one * 1e3:.1f} ms a design")
    rows = {"float_ms_per_design": t_one * 1e3, "threads": torch.get_num_threads()}
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for dev in devices:
        for b in batches:
            if dev == "cpu" and b > args.cpu_max:
                continue
            x = xs[:b].to(dev)

            def run():
                with torch.no_grad():
                    c = lens_exact_coefficients(solve_numbers(p, pars, x, hold=("efl",)), p.fields, p.wavelengths_um)
                if dev == "cuda":
                    torch.cuda.synchronize()
                return c

            c = run()
            t = time.perf_counter()
            for _ in range(args.repeats):
                run()
            per = (time.perf_counter() - t) / args.repeats / b
            n = min(b, args.designs)
            err = float((c[:n].cpu() - ref[:n]).abs().max() / ref[:n].abs().max())
            print(f"batched, {dev}, B = {b}: {per * 1e3:.2f} ms a design ({t_one / per:.1f}x the float route), "
                  f"largest difference from the float route {err:.1e} of the largest coefficient")
            rows[f"{dev}_B{b}_ms_per_design"] = per * 1e3
            rows[f"{dev}_B{b}_rel_diff"] = err
        x = xs[:1].to(dev).clone().requires_grad_(True)
        t = time.perf_counter()
        for _ in range(args.repeats):
            c = lens_exact_coefficients(solve_numbers(p, pars, x, hold=("efl",)), p.fields, p.wavelengths_um)
            torch.autograd.grad((c ** 2).sum(), x)
        tg = (time.perf_counter() - t) / args.repeats
        print(f"one design's value and gradient ({len(NAMES)} parameters), {dev}: {tg:.3f} s "
              f"({tg / t_one:.1f}x one float-route value)")
        rows[f"{dev}_gradient_s"] = tg
    if torch.cuda.is_available():
        rows["gpu"] = torch.cuda.get_device_name(0)
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
