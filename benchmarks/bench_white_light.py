"""Cost of white light, side by side in one process: PSF banks per field point and the windowed blur.

    python benchmarks/bench_white_light.py [--repeat 3]

Monochromatic (the paper: one wavelength, one PSF for every colour) against polychromatic (N-BK7,
Nikon 5100 RGB under D65): the default colour model (the 5 nm table integrated with the wavelengths shared by
every channel, issue 21) and the former one (16 wavelengths per channel, each channel its own, 48 in all): the OTF
bank of the metrics for the 15 field angles of one design and for a sweep chunk of 32 designs, and the blur of a
256 px crop at 8 degrees. Prints each time (best of --repeat) and the ratio to the monochromatic one.
"""

from __future__ import annotations

import argparse
import time
import warnings

import torch

from lenssim import Camera, Design, LensPSF, Numerics, evaluate

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from lenssim.model.spectrum import channel_spectra
from lenssim.validate import ModelValidityWarning
from pipeline import resolution_scene
from pipeline.blur import blur_windowed
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SPECTRUM


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--glass", default="N-BK7")
    ap.add_argument("--focus-um", type=float, default=-342.4,
                    help="image plane of the 32-design chunk (um; default: the study's common plane in N-BK7)")
    args = ap.parse_args()
    warnings.simplefilter("ignore", ModelValidityWarning)
    design = PAPER_DESIGNS["end_to_end_paper"]
    mono = PAPER_CAMERA
    lens = dataclasses.replace(PAPER_LENS, glass=args.glass)
    colour = {"shared": Camera(lens, PAPER_CAMERA.sensor, PAPER_SPECTRUM, channels=channel_spectra()),
              "former 3x16": Camera(lens, PAPER_CAMERA.sensor, PAPER_SPECTRUM, channels=channel_spectra(per_channel=16))}
    k = len(colour["shared"].with_quadrature(Numerics().spectral_tol).channels[0])
    print(f"{args.glass}, torch threads {torch.get_num_threads()}; shared: {k} wavelengths for 3 channels, former: 48")
    num = Numerics(oversample=1)
    t_m = best(lambda: evaluate(mono, design, [27.6], numerics=num, rho0=PAPER_RHO0), args.repeat)
    for name, cam in colour.items():
        t_p = best(lambda: evaluate(cam, design, [27.6], numerics=num, rho0=PAPER_RHO0), args.repeat)
        print(f"  one design, 15 field angles, fast numerics: monochromatic {t_m:.2f} s, {name} {t_p:.2f} s: "
              f"ratio {t_p / t_m:.1f}x")
    # a sweep's chunk: 32 designs at once, per field point (default and fast numerics)
    grid = Design(s=torch.linspace(-0.85, -0.7, 8).repeat_interleave(4), Q_back=torch.linspace(-3, -1.5, 4).repeat(8),
                  focus_shift_um=torch.full((32,), args.focus_um))
    for nm in (Numerics(), num):
        b_m = best(lambda: evaluate(mono, grid, [27.6], numerics=nm, rho0=PAPER_RHO0), args.repeat) / (32 * 15)
        for name, cam in colour.items():
            b_p = best(lambda: evaluate(cam, grid, [27.6], numerics=nm, rho0=PAPER_RHO0), args.repeat) / (32 * 15)
            print(f"  32 designs, oversample {nm.oversample}: monochromatic {1e3 * b_m:.2f} ms, {name} {1e3 * b_p:.2f} ms "
                  f"per field point: ratio {b_p / b_m:.1f}x")
    scene = resolution_scene(1200, 1600, geometry=PAPER_CAMERA.geometry)
    oc = (600 - 1200, 800 - 1800)  # the crop sits about 8 degrees from the axis
    reg = (472, 728, 672, 928)
    b_m = best(lambda: blur_windowed(scene, LensPSF(mono, design), optical_center=oc, region=reg), args.repeat)
    print("blur of a 256 px crop at ~8 deg (paper windows 512/32/64):")
    for name, cam in colour.items():
        b_p = best(lambda: blur_windowed(scene, LensPSF(cam, design), optical_center=oc, region=reg), args.repeat)
        print(f"  monochromatic {b_m:.2f} s, {name} {b_p:.2f} s: ratio {b_p / b_m:.1f}x")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown()  # no nanobind "leaked" noise at exit
