"""As-built lenses per second (issue 19, item 6), side by side with the nominal evaluation in one process.

    python benchmarks/bench_as_built.py [--lenses 40] [--repeat 2]

For the paper's end-to-end design, fast numerics, its 15 field angles and the tolerance run's 5, at 27.6 dB:

* baseline: ``evaluate`` of the nominal design (one lens, the mirror-symmetric bank), as lenses per second;
* rotationally symmetric tolerances (radius, conic, index, despace): rows of the mirror-symmetric bank, one
  azimuth per angle (chosen automatically);
* the full commercial grade (decentre, tilt, figure error): the non-symmetric path, four azimuths per angle.

Prints lenses per second and the ratio to the baseline; no timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from lenssim import FAST_NUMERICS, Camera, evaluate
from lenssim.model.tolerances import GRADES
from lenssim.tolerancing import as_built_criteria
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_RHO0
from lenssim_studies.tolerance import TOLERANCE_FIELD_ANGLES
from pipeline.io import exit_without_teardown

DESIGN = PAPER_DESIGNS["end_to_end_paper"]
SNR = [27.6]


def rate(fn, lenses: int, repeat: int) -> float:
    fn()  # warm-up: caches of pupil bases and FFT plans
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return lenses / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lenses", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    full = GRADES["commercial"]
    sym = dataclasses.replace(full, asphere_decentre_um=0.0, asphere_tilt_arcmin=0.0, lens_tilt_arcmin=0.0,
                              figure_floor=0.0, figure_per_cost=0.0)
    print(f"end-to-end design, fast numerics, {SNR[0]} dB, {a.lenses} lenses, best of {a.repeat}")
    print(f"{'field':>22s} {'case':>34s} {'lenses/s':>9s} {'x baseline':>10s}")
    for label, angles in (("15 angles (paper)", PAPER_CAMERA.lens.field_angles_deg),
                          ("5 angles (tolerance)", TOLERANCE_FIELD_ANGLES)):
        cam = Camera(dataclasses.replace(PAPER_CAMERA.lens, field_angles_deg=tuple(angles)), PAPER_CAMERA.sensor,
                     PAPER_CAMERA.spectrum)
        base = rate(lambda: evaluate(cam, DESIGN, SNR, rho0=PAPER_RHO0, numerics=FAST_NUMERICS), 1, a.repeat)
        print(f"{label:>22s} {'nominal evaluate (baseline)':>34s} {base:9.2f} {1.0:10.2f}")
        for case, tol in (("symmetric errors (fast path)", sym), ("commercial grade (non-symmetric)", full)):
            p = tol.sample(a.lenses, seed=0)
            r = rate(lambda: as_built_criteria(cam, DESIGN, p, SNR, rho0=PAPER_RHO0, numerics=FAST_NUMERICS),
                     a.lenses, a.repeat)
            print(f"{label:>22s} {case:>34s} {r:9.2f} {r / base:10.2f}")


if __name__ == "__main__":
    main()
    exit_without_teardown(0)
