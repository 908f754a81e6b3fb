"""Issue 45: restoration methods side by side on the same noisy crops, per crop, in one process.

    python benchmarks/bench_restoration_methods.py PHOTO [PHOTO ...] [--designs end_to_end_paper rms_w_paper]
        [--isos 400 100] [--angles 0 5 10] [--crop 256] [--methods wiener richardson_lucy ...] [--threads 2]

Each photo's 256 px crops at the given field angles (where the photo reaches them) go through
:func:`pipeline.simulate_crops` with the methods of ``--methods`` (specs ``NAME[:key=value,...]``; the first is the
baseline the others' times are divided by, default the adaptive Wiener), the paper's sensor at each ISO. Every
``restore()`` call simulate_crops makes is timed (wall clock, s), so all methods run on the same noisy crops in the
same process; the table gives, per crop and ISO, the sensor image's and each method's PSNR (dB, sRGB) and each
method's time as a multiple of the baseline's, then the means (PSNR, time in s, ratio of mean times) and how many crops
each method restored below the sensor image. Nothing is asserted: a benchmark, not a test (the issue's targets: the
best method >= 0.5 dB over the Wiener at <= 10x its time; Richardson-Lucy <= 5x). The first call of a design also
computes PSFs the later ones find cached: it is timed like the others.
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
    ap.add_argument("--methods", nargs="+", default=["wiener", "richardson_lucy"])
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    methods = [parse_restoration(m) for m in args.methods]
    names = [m.name for m in methods]
    if len(set(names)) != len(names):
        ap.error(f"--methods names a method twice ({', '.join(names)}): one spec per method")
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
    rows = []  # (sensor dB, {name: dB}, {name: s})
    short = [n[:10] for n in names]
    print(f"{'photo':<24} {'design':<17} {'deg':>5} {'ISO':>4} {'sensor':>7} "
          + " ".join(f"{s:>10}" for s in short) + "  " + " ".join(f"{'x' + s:>11}" for s in short[1:]))
    for path in args.photos:
        photo = open_photo(path, PAPER_CAMERA)
        for design in args.designs:
            psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS[design])
            for angle in args.angles:
                try:
                    box = crop_at_field_angle(photo.shape, angle, args.crop, PAPER_CAMERA.geometry)
                except ValueError:  # the photo does not reach this angle
                    continue
                times.clear()
                res = simulate.simulate_crops(photo, psf, wells, [box], methods=methods, sensor=sensor)
                per: dict[str, list[float]] = {}
                for name, t in times:
                    per.setdefault(name, []).append(t)
                for j, (iso, r) in enumerate(zip(args.isos, res)):
                    s = {k: v["psnr_db"] for k, v in r[0].scores.items()}
                    t = {n: per[n][j] for n in names}
                    rows.append((s["sensor"], {n: s[n] for n in names}, t))
                    print(f"{Path(path).stem[:24]:<24} {design:<17} {r[0].field_deg:5.1f} {iso:>4} {s['sensor']:7.2f} "
                          + " ".join(f"{s[n]:10.2f}" for n in names) + "  "
                          + " ".join(f"{t[n] / t[names[0]]:11.2f}" for n in names[1:]), flush=True)
    if rows:
        n = len(rows)
        print(f"mean of {n} crop-ISOs: sensor {sum(r[0] for r in rows) / n:.2f} dB")
        base_t = sum(r[2][names[0]] for r in rows) / n
        for name in names:
            db = sum(r[1][name] for r in rows) / n
            t = sum(r[2][name] for r in rows) / n
            below = sum(r[1][name] < r[0] for r in rows)
            print(f"  {name:<18} {db:7.2f} dB ({db - sum(r[1][names[0]] for r in rows) / n:+.2f} vs {names[0]}), "
                  f"{t:6.2f} s per crop ({t / base_t:.2f}x), below the sensor image on {below} of {n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
