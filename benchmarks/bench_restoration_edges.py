"""Issue 45, item 1: is a restoration ever worse than the sensor image? Crops at the centre, every edge midpoint and
every corner of each photo, each method's PSNR beside the sensor image's.

    python benchmarks/bench_restoration_edges.py PHOTO [PHOTO ...] [--designs end_to_end_paper rms_w_paper]
        [--iso 400 100] [--size 256] [--methods wiener:taper=0 wiener] [--seed 0]

For every photo (linear, its centre on the optical axis of the paper's camera), design and ISO: nine ``--size`` px
crops (centre; top, bottom, left and right edge midpoints; the four corners), blurred by the design's PSFs
(:func:`pipeline.simulate_crops`, the paper's window scheme and sensor: photon noise, the ISO's full well), then
restored by each of ``--methods`` (``NAME[:key=value,...]``; the default compares the adaptive Wiener without its
window taper, as before issue 45, with today's default). Prints one line per crop (PSNR in dB, sRGB; ``!`` marks a
method below the sensor image) and the mean PSNR per design, ISO and place (centre, edges, corners). The photos are
the user's (none ship with the project). Nothing is asserted.
"""

from __future__ import annotations

import argparse
import sys
import time

from lenssim import LensPSF
from lenssim_studies.paper import ISO_FULL_WELL, PAPER_CAMERA, PAPER_DESIGNS, PAPER_SENSOR
from pipeline.photo import open_photo
from pipeline.restoration import parse_restoration
from pipeline.simulate import simulate_crops

PLACES = ("centre", "top", "bottom", "left", "right", "top-left", "top-right", "bottom-left", "bottom-right")
"""The crops of every photo, in this order: ``centre``, the edge midpoints, the corners."""


def place_boxes(shape, size: int) -> dict[str, tuple[int, int, int, int]]:
    """The ``size`` px box ``(r0, r1, c0, c1)`` at each of :data:`PLACES` in a frame of ``shape`` ``(..., H, W)``."""
    H, W = shape[-2:]
    rows = {"top": 0, "mid": (H - size) // 2, "bottom": H - size}
    cols = {"left": 0, "mid": (W - size) // 2, "right": W - size}
    at = {"centre": ("mid", "mid"), "top": ("top", "mid"), "bottom": ("bottom", "mid"), "left": ("mid", "left"),
          "right": ("mid", "right")}
    at.update({f"{r}-{c}": (r, c) for r in ("top", "bottom") for c in ("left", "right")})
    return {p: (rows[at[p][0]], rows[at[p][0]] + size, cols[at[p][1]], cols[at[p][1]] + size) for p in PLACES}


def group(place: str) -> str:
    return "centre" if place == "centre" else "corners" if "-" in place else "edges"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photos", nargs="+")
    ap.add_argument("--designs", nargs="+", default=["end_to_end_paper", "rms_w_paper"], choices=list(PAPER_DESIGNS))
    ap.add_argument("--iso", nargs="+", type=int, default=[400, 100], choices=sorted(ISO_FULL_WELL))
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--methods", nargs="+", default=["wiener:taper=0", "wiener"])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    methods = [parse_restoration(m) for m in args.methods]
    names = [m.name for m in methods]
    if len(set(names)) != len(names):  # simulate_crops files results by name: one run per spec
        runs = [[m] for m in methods]
    else:
        runs = [methods]
    labels = list(args.methods)
    rows = []  # (photo, design, iso, place, sensor dB, [method dB ...])
    for path in args.photos:
        photo = open_photo(path)
        boxes = place_boxes(photo.shape, args.size)
        for design in args.designs:
            psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS[design])
            cache = {}
            t = time.perf_counter()
            per_run = [simulate_crops(photo, psf, [ISO_FULL_WELL[i] for i in args.iso], list(boxes.values()),
                                      seed=args.seed, methods=run, sensor=PAPER_SENSOR, blur_cache=cache)
                       for run in runs]
            for i, iso in enumerate(args.iso):
                for k, place in enumerate(PLACES):
                    sensor = per_run[0][i][k].scores["sensor"]["psnr_db"]
                    scores = [res[i][k].scores[m.name]["psnr_db"] for run, res in zip(runs, per_run) for m in run]
                    rows.append((path.rsplit("/", 1)[-1], design, iso, place, sensor, scores,
                                 per_run[0][i][k].field_deg))
                    marks = " ".join(f"{s:6.2f}{'!' if s < sensor else ' '}" for s in scores)
                    print(f"{rows[-1][0][:24]:24s} {design:17s} ISO {iso:4d} {place:12s} {rows[-1][6]:5.1f} deg  "
                          f"sensor {sensor:6.2f}  {marks}", flush=True)
            print(f"  ({time.perf_counter() - t:.0f} s)", file=sys.stderr, flush=True)
    print("\nmean PSNR (dB): design, ISO, place | sensor | " + " | ".join(labels))
    for design in args.designs:
        for iso in args.iso:
            for g in ("centre", "edges", "corners", "all"):
                sel = [r for r in rows if r[1] == design and r[2] == iso and (g == "all" or group(r[3]) == g)]
                if not sel:
                    continue
                mean = lambda v: sum(v) / len(v)  # noqa: E731
                cols = [mean([r[5][j] for r in sel]) for j in range(len(labels))]
                below = [sum(r[5][j] < r[4] for r in sel) for j in range(len(labels))]
                print(f"{design:17s} ISO {iso:4d} {g:8s} ({len(sel):2d}) | {mean([r[4] for r in sel]):6.2f} | "
                      + " | ".join(f"{c:6.2f} ({b} below)" for c, b in zip(cols, below)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
