"""Accuracy of the shared spectral quadrature against the dense 5 nm table (issue 21, target 1's error bound).

    python benchmarks/bench_spectral_quadrature.py [--study DIR] [--tol 0.2] [--former]

For N-BK7, N-SF5 and PMMA (Nikon 5100 channels under D65, the paper's lens, its 15 field angles, fast numerics,
27.6 dB): every channel's MSE_R with the wavelengths :func:`lenssim.model.spectrum.shared_quadrature` picks under
``--tol`` (default ``Numerics.spectral_tol``) against the same with every table wavelength (79, the colour model
itself). Designs: the paper grid's four corners (s -1.5 / 0.25, Q_back -10 / 1.2), the paper's two designs at the
d-line focus and at the study's common plane z0, and the white-light optima (RMS_W, MSE_S, MSE_R, focus free) of a
``lenssim study white-light`` output folder (``--study``; without it, the corners and paper designs at the focus
planes below). ``--former`` adds the former default (16 wavelengths per channel, each channel its own) for
comparison. Prints the worst relative error per glass and the wavelength counts.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import warnings
from pathlib import Path

import torch

from lenssim import FAST_NUMERICS, Camera, Design, evaluate
from lenssim.model.spectrum import channel_spectra, channel_table
from lenssim.validate import ModelValidityWarning
from lenssim_studies.paper import PAPER_DESIGNS, PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM
from pipeline.io import exit_without_teardown

GLASSES = ("N-BK7", "N-SF5", "PMMA")
FALLBACK_Z0_UM = {"N-BK7": -342.4, "N-SF5": -640.0, "PMMA": -400.0}
"""Common planes (um) used without --study: about the study's best MSE_R plane of the paper's end-to-end design."""
SNR = [27.6]


def designs_for(glass: str, study: Path | None) -> list[tuple[str, dict]]:
    z0, optima = FALLBACK_Z0_UM[glass], {}
    if study is not None:
        summary = json.loads((study / "summary.json").read_text())
        for r in summary["results"]:
            if r["glass"] == glass:
                z0 = r["focus_z0_um"]
                optima = {k: v["design"] for k, v in r["optima_focus_free"].items()}
    out = [(f"corner s {s:g} Q {q:g} @z0", dict(s=s, Q_back=q, focus_shift_um=z0))
           for s in (-1.5, 0.25) for q in (-10.0, 1.2)]
    for name, d in PAPER_DESIGNS.items():
        out += [(f"{name} @d-line", {**d.floats(), "focus_shift_um": 0.0}), (f"{name} @z0", {**d.floats(), "focus_shift_um": z0})]
    out += [(f"{k} optimum", d) for k, d in optima.items()]
    return out


def mse_r(camera: Camera, rows: list[dict], numerics) -> torch.Tensor:
    d = Design({k: torch.tensor([r[k] for r in rows], dtype=torch.float64) for k in ("s", "Q_back", "focus_shift_um")})
    return evaluate(camera, d, SNR, rho0=PAPER_RHO0, numerics=numerics)["mse_r_per_channel"][..., 0].T  # (D, C)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--study", type=Path, help="a `lenssim study white-light` output folder (its z0 and optima)")
    ap.add_argument("--tol", type=float, default=FAST_NUMERICS.spectral_tol)
    ap.add_argument("--former", action="store_true", help="also the former 16 wavelengths per channel")
    args = ap.parse_args()
    warnings.simplefilter("ignore", ModelValidityWarning)
    num = FAST_NUMERICS.replace(spectral_tol=args.tol)
    dense = FAST_NUMERICS.replace(spectral_tol=1e-9)
    print(f"MSE_R at {SNR[0]:g} dB per channel (R, G, B), relative to the 79-wavelength table; tol {args.tol:g} px")
    for glass in GLASSES:
        lens = dataclasses.replace(PAPER_LENS, glass=glass)
        cam = Camera(lens, PAPER_SENSOR, PAPER_SPECTRUM, channels=channel_table())
        k = len(cam.with_quadrature(args.tol).channels[0])
        items = designs_for(glass, args.study)
        rows = [d for _, d in items]
        t0 = time.perf_counter()
        ref = mse_r(cam, rows, dense)
        t_ref = time.perf_counter() - t0
        t0 = time.perf_counter()
        got = mse_r(cam, rows, num)
        t_got = time.perf_counter() - t0
        former = None
        if args.former:
            former = mse_r(Camera(lens, PAPER_SENSOR, PAPER_SPECTRUM, channels=channel_spectra(per_channel=16)), rows, num)
        err = 100 * (got / ref - 1)
        print(f"\n{glass}: {k} shared wavelengths ({t_got:.0f} s) against 79 ({t_ref:.0f} s)")
        for i, (name, _) in enumerate(items):
            line = f"  {name:34s} ref {' '.join(f'{v:.5f}' for v in ref[i].tolist())}  error % " + \
                " ".join(f"{v:+.2f}" for v in err[i].tolist())
            if former is not None:
                line += "  former 3x16: " + " ".join(f"{v:+.2f}" for v in (100 * (former[i] / ref[i] - 1)).tolist())
            print(line)
        worst = float(err.abs().max())
        print(f"  worst |error| {worst:.2f}% ({'within' if worst <= 0.5 else 'OUTSIDE'} 0.5%)"
              + (f"; former 3x16 worst {float((100 * (former / ref - 1)).abs().max()):.2f}%" if former is not None else ""))


if __name__ == "__main__":
    main()
    exit_without_teardown()
