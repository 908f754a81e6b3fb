"""The colour 24 MP frame (issue 21, target 3): time, peak memory and accuracy, against the monochromatic frame.

    python benchmarks/bench_colour_frame.py PHOTO [--glass N-BK7] [--spectrum "Nikon 5100 (NPL)"] [--skip-frames | --skip-accuracy]

1. Accuracy: the windowed colour blur of PHOTO (the simulate default: the paper's scheme, fitted windows, grown
   where the PSF outgrows 512 px) against one PSF per pixel (``blur_exact``, the same provider, on the PSF grid the
   windows use there and on 1024 px, which also holds the far diffraction tail a 512 px grid lumps into its pedestal)
   on 6 x 6 pixels at about 1, 6, 12 and 12.5 degrees of field (the frame's corner is at 12.6); prints the SNR (dB)
   of the difference over the three channels and the windows' sizes there.
2. Frames: ``lenssim simulate PHOTO --design end_to_end_paper --full-frame --angles 1 5 9`` monochromatic (the
   paper's camera, at its focus), then with ``--glass``, ``--spectrum`` and ``--focus_shift_um`` (``--focus-um``), one after the other in child processes (each its own
   peak resident memory, read from ``getrusage``); prints wall times, peaks and the ratio.

A 24 MP photo is wanted (e.g. a 6000 x 4000 JPEG); nothing is downloaded. No timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import warnings

import torch

DESIGN = "end_to_end_paper"
REFERENCE_PX = 1024
"""The per-pixel reference's PSF grid (px): twice the paper's window, beyond the corners' colour PSFs (~500 px)."""


def accuracy(photo: str, glass: str, spectrum: str, focus_um: float) -> list[tuple[float, float]]:
    from lenssim import Camera, LensPSF
    from lenssim.model.spectrum import channel_spectra
    from lenssim.validate import ModelValidityWarning
    from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
    from lenssim.model.geometry import frame_center
    from pipeline.blur import PAPER_SCHEME, blur_exact, blur_windowed, window_sizes
    from pipeline.photo import load_photo
    import dataclasses

    warnings.simplefilter("ignore", ModelValidityWarning)
    cam = Camera(dataclasses.replace(PAPER_CAMERA.lens, glass=glass), PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum,
                 channels=channel_spectra(spectrum))
    provider = LensPSF(cam, PAPER_DESIGNS[DESIGN].replace(focus_shift_um=focus_um))
    img, _ = load_photo(photo)
    H, W = img.shape[-2:]
    center = frame_center(img.shape)
    out = []
    hyp = math.hypot(H, W)
    for deg in (1.0, 6.0, 12.0, 12.5):  # towards the corner (12.6 deg on the paper's 24 MP sensor)
        r_px = float(cam.geometry.image_height_mm(deg)) / (cam.pixel_pitch_um * 1e-3)
        r0 = min(max(int(center[0] + r_px * H / hyp) - 3, 0), H - 6)
        c0 = min(max(int(center[1] + r_px * W / hyp) - 3, 0), W - 6)
        rows, cols = torch.meshgrid(torch.arange(r0, r0 + 6), torch.arange(c0, c0 + 6), indexing="ij")
        win = blur_windowed(img, provider, region=(r0, r0 + 6, c0, c0 + 6))
        ext = int(provider.extents_px(torch.tensor([r0 + 3.0]), torch.tensor([c0 + 3.0]), center)[0])
        size = int(window_sizes(torch.tensor([ext]), PAPER_SCHEME, True)[0])
        got = win[:, :, r0:r0 + 6, c0:c0 + 6].flatten(2).double()
        x, y = cam.geometry.offsets_mm(torch.tensor([r0 + 3]), torch.tensor([c0 + 3]), center)
        alpha = float(cam.geometry.field_angle_deg(x, y))
        snrs = []
        # the reference on the PSF grid the windows use (the scheme's 512 px, or the grown window), and on 1024 px
        for n in sorted({max(size, PAPER_SCHEME.window), REFERENCE_PX}):
            ref = blur_exact(img, provider, rows.flatten(), cols.flatten(), n=n).double()
            snrs.append((n, 10 * math.log10(float((ref ** 2).sum() / ((ref - got) ** 2).sum()))))
        out.append((alpha, min(s for _, s in snrs)))
        print(f"  {alpha:5.1f} deg (rows {r0}.., cols {c0}..): PSF support {ext} px, blur window {size} px; windowed vs "
              "per-pixel " + ", ".join(f"{v:.1f} dB ({n} px PSFs)" for n, v in snrs), flush=True)
    return out


def frame(photo: str, extra: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak resident memory (GiB) of one ``lenssim simulate --full-frame`` in a child process."""
    with tempfile.TemporaryDirectory() as tmp:
        code = ("import resource, sys, time; from lenssim_cli.main import main; t = time.perf_counter(); "
                "rc = main(sys.argv[1:]); "
                "print('BENCH', time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "
                "file=sys.stderr); sys.exit(rc)")
        cmd = [sys.executable, "-c", code, "simulate", photo, "--design", DESIGN, "--full-frame", "--angles", "1", "5",
               "9", "--out", os.path.join(tmp, "out"), *extra]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise SystemExit(f"simulate failed ({p.returncode}): {p.stderr.strip().splitlines()[-1:]}")
        line = [ln for ln in p.stderr.splitlines() if ln.startswith("BENCH")][-1].split()
        with open(os.path.join(tmp, "out", "metrics.json")) as f:
            report = json.load(f)["full_frame"]
        print(f"  stages (s): {report['seconds']}; PSNR sensor {report['psnr_sensor_db']:.2f} dB -> restored "
              f"{report['psnr_restored_db']:.2f} dB", flush=True)
        return float(line[1]), float(line[2]) / 2**20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo")
    ap.add_argument("--glass", default="N-BK7")
    ap.add_argument("--spectrum", default="Nikon 5100 (NPL)")
    ap.add_argument("--focus-um", type=float, default=-342.4,
                    help="the colour camera's image plane (um; default -342.4: the white-light study's best plane for "
                         "this design in N-BK7)")
    ap.add_argument("--skip-frames", action="store_true", help="the accuracy check only")
    ap.add_argument("--skip-accuracy", action="store_true", help="the frames only")
    args = ap.parse_args()
    if not args.skip_accuracy:
        print(f"accuracy of the colour blur ({args.glass}, {args.spectrum}):")
        accuracy(args.photo, args.glass, args.spectrum, args.focus_um)
    if args.skip_frames:
        return
    t_m, m_m = frame(args.photo, [])
    print(f"monochromatic frame: {t_m:.0f} s, peak {m_m:.2f} GiB", flush=True)
    t_c, m_c = frame(args.photo, ["--glass", args.glass, "--spectrum", args.spectrum, "--focus_shift_um",
                                  str(args.focus_um)])
    print(f"colour frame: {t_c:.0f} s, peak {m_c:.2f} GiB; ratio {t_c / t_m:.2f}x")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    from pipeline.io import exit_without_teardown

    exit_without_teardown()
