"""A 24 MP ``simulate --full-frame`` of any lens against the paper's singlet (issue 29's speed target: a Cooke
triplet within 1.5x the singlet's time), side by side on the same photo.

    python benchmarks/bench_lens_frame.py PHOTO [--lens cooke_triplet] [--skip-polychromatic]

Frames, one after the other in child processes (each its own peak resident memory, from ``getrusage``):

1. the paper's singlet: ``lenssim simulate PHOTO --design end_to_end_paper --full-frame`` (monochromatic, 0.5 um);
2. the lens at its primary wavelength only (a copy of its prescription with one wavelength): the sequential PSFs'
   own cost, the same light as the singlet's;
3. the lens in its own wavelengths (``simulate --lens LENS --full-frame``, the command's default).

Each lens spans the photo with its own field (its largest field angle at the frame's corners). Prints the wall times,
peaks, the ratios to the singlet's and the frames' PSNRs. A 24 MP photo is wanted (e.g. a 6000 x 4000 JPEG); nothing
is downloaded. No timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time


def frame(photo: str, extra: list[str]) -> tuple[float, float, dict]:
    """Wall time (s), peak resident memory (GiB) and the full-frame report of one ``lenssim simulate --full-frame``
    in a child process."""
    with tempfile.TemporaryDirectory() as tmp:
        code = ("import resource, sys, time; from lenssim_cli.main import main; t = time.perf_counter(); "
                "rc = main(sys.argv[1:]); "
                "print('BENCH', time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "
                "file=sys.stderr); sys.exit(rc)")
        cmd = [sys.executable, "-c", code, "simulate", photo, "--full-frame", "--out",
               os.path.join(tmp, "out"), *extra]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise SystemExit(f"simulate failed ({p.returncode}): {p.stderr.strip().splitlines()[-1:]}")
        line = [ln for ln in p.stderr.splitlines() if ln.startswith("BENCH")][-1].split()
        with open(os.path.join(tmp, "out", "metrics.json")) as f:
            report = json.load(f)["full_frame"]
        return float(line[1]), float(line[2]) / 2**20, report


def monochromatic_copy(lens: str, folder: str) -> str:
    """A TOML copy of ``lens`` with its primary wavelength only."""
    from dataclasses import replace

    from lenssim.io.prescription_file import read_lens, write_prescription_toml

    p = read_lens(lens)
    lam = p.primary_wavelength_um
    path = os.path.join(folder, "monochromatic.toml")
    write_prescription_toml(replace(p, wavelengths_um=(lam,), name=f"{p.name} at {lam:g} um"), path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo")
    ap.add_argument("--lens", default="cooke_triplet")
    ap.add_argument("--skip-polychromatic", action="store_true", help="leave out frame 3")
    args = ap.parse_args()
    rows = []
    t_s, m_s, r_s = frame(args.photo, ["--design", "end_to_end_paper"])
    rows.append(("paper's singlet (0.5 um)", t_s, m_s, r_s))
    with tempfile.TemporaryDirectory() as tmp:
        mono = monochromatic_copy(args.lens, tmp)
        rows.append((f"{args.lens}, primary wavelength", *frame(args.photo, ["--lens", mono])))
    if not args.skip_polychromatic:
        rows.append((f"{args.lens}, its wavelengths", *frame(args.photo, ["--lens", args.lens])))
    print("| frame | wall (s) | ratio | peak (GiB) | PSNR sensor -> restored (dB) | stages (s) |")
    print("|---|---|---|---|---|---|")
    for name, t, m, r in rows:
        print(f"| {name} | {t:.0f} | {t / t_s:.2f}x | {m:.2f} | {r['psnr_sensor_db']:.2f} -> "
              f"{r['psnr_restored_db']:.2f} | {r['seconds']} |", flush=True)


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    from pipeline.io import exit_without_teardown

    exit_without_teardown()
