"""Issue 45, item 2: Richardson-Lucy on the blur's operator against the adaptive Wiener, per crop, in one process.

    python benchmarks/bench_restoration_rl.py PHOTO [PHOTO ...] [--designs end_to_end_paper rms_w_paper]
        [--isos 400 100] [--angles 0 5 10] [--crop 256] [--rl richardson_lucy] [--threads 2]

Each photo's 256 px crops at the given field angles (where the photo reaches them) go through
:func:`pipeline.simulate_crops` with the methods ``[wiener, RL]`` (``--rl``: the Richardson-Lucy spec, e.g.
``richardson_lucy:iterations=10``), the paper's sensor at each ISO. Every ``restore()`` call simulate_crops makes is
timed (wall clock, s), so both methods run on the same noisy crops in the same process; the table gives, per crop and
ISO, the sensor image's, the Wiener's and Richardson-Lucy's PSNR (dB, sRGB) and the two times with their ratio, and the
means. Nothing is asserted: a benchmark, not a test (the target is RL <= 5x the Wiener's time per crop on 2 CPU cores).
The first call of a design also computes PSFs the later ones find cached: it is timed like the others.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

import pipeline.simulate as simulate
from lenssim import LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import crop_at_field_angle
from pipeline.photo import open_photo
from pipeline.restoration import parse_restoration


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photos", nargs="+")
    ap.add_argument("--designs", nargs="+", default=["end_to_end_paper", "rms_w_paper"])
    ap.add_argument("--isos", nargs="+", type=int, default=[400, 100])
    ap.add_argument("--angles", nargs="+", type=float, default=[0.0, 5.0, 10.0])
    ap.add_argument("--crop", type=int, default=256)
    ap.add_argument("--rl", default="richardson_lucy")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    methods = [parse_restoration("wiener"), parse_restoration(args.rl)]
    sensor = PAPER_CAMERA.sensor
    wells = [sensor.full_well_for_iso(i) for i in args.isos]
    times: list[tuple[str, float]] = []
    inner = simulate.restore

    def timed(spec, *a, **kw):  # every restore() simulate_crops makes, timed where it is made
        t0 = time.perf_counter()
        out = inner(spec, *a, **kw)
        times.append((spec.name, time.perf_counter() - t0))
        return out

    simulate.restore = timed
    rows = []
    print(f"{'photo':<24} {'design':<17} {'deg':>5} {'ISO':>4} {'sensor':>7} {'wiener':>7} {'RL':>7} "
          f"{'t_wiener':>8} {'t_RL':>7} {'ratio':>6}")
    for path in args.photos:
        photo = open_photo(path, PAPER_CAMERA)
        H, W = photo.shape[-2:]
        for design in args.designs:
            psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS[design])
            for angle in args.angles:
                try:
                    box = crop_at_field_angle(photo.shape, angle, args.crop, PAPER_CAMERA.geometry)
                except ValueError:  # the photo does not reach this angle
                    continue
                times.clear()
                res = simulate.simulate_crops(photo, psf, wells, [box], methods=methods, sensor=sensor)
                per = {}
                for name, t in times:
                    per.setdefault(name, []).append(t)
                for j, (iso, r) in enumerate(zip(args.isos, res)):
                    s = {k: v["psnr_db"] for k, v in r[0].scores.items()}
                    tw, tr = per["wiener"][j], per[methods[1].name][j]
                    rows.append((s["sensor"], s["wiener"], s[methods[1].name], tw, tr))
                    print(f"{Path(path).stem[:24]:<24} {design:<17} {r[0].field_deg:5.1f} {iso:>4} {s['sensor']:7.2f} "
                          f"{s['wiener']:7.2f} {s[methods[1].name]:7.2f} {tw:8.2f} {tr:7.2f} {tr / tw:6.2f}", flush=True)
    if rows:
        n = len(rows)
        mean = [sum(r[k] for r in rows) / n for k in range(5)]
        print(f"mean of {n}: sensor {mean[0]:.2f} dB, wiener {mean[1]:.2f} dB, {args.rl} {mean[2]:.2f} dB; "
              f"time wiener {mean[3]:.2f} s, RL {mean[4]:.2f} s, ratio of means {mean[4] / mean[3]:.2f}, "
              f"mean ratio {sum(r[4] / r[3] for r in rows) / n:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
