"""The explorer's responsiveness (issue 32): the time from a control's change to its new picture, driving the update
functions of :mod:`lenssim_studies.explore` as the page does (no browser; the page's own round trip, ~80 ms with
Panel, is measured in docs/explore.md).

    python benchmarks/bench_explore.py [PHOTO] [--lens LENS --vary NAME=LO:HI[:STEP] ...]

For the paper's lens and a 256 px crop: the first picture (cold caches), then each control changed in turn (a new
design: criteria, PSF/MTF figure and the photo; the ISO; the seed; a click moving the crop; the CFA; a return to an
earlier state, served from the caches), 5 times each with fresh values; prints the median and the largest time per
control. With ``--lens``: any lens (``lenssim explore --lens``'s explorer), its first free parameter moved by one step
as the "new design". No timing is asserted anywhere.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import replace


def main() -> None:
    import argparse

    from lenssim_studies.explore import Explorer, PhotoControls
    from lenssim_studies.paper import PAPER_CAMERA
    from pipeline.photo import open_photo

    ap = argparse.ArgumentParser()
    ap.add_argument("photo", nargs="?", default="skimage:astronaut")
    ap.add_argument("--lens")
    ap.add_argument("--vary", action="append", default=[])
    a = ap.parse_args()
    spec = a.photo
    photo = open_photo(spec, PAPER_CAMERA)
    H, W = photo.shape[-2:]
    if a.lens:
        from lenssim.io.prescription_file import read_lens
        from lenssim_cli.explore import parse_slider

        ex = Explorer(photo=photo.load(), photo_source=photo.source, prescription=read_lens(a.lens), lens=a.lens,
                      free=tuple(parse_slider(v) for v in a.vary))
    else:
        ex = Explorer(photo=photo, photo_source=photo.source)
    d = ex.start
    first = next(f for f in ex.free if f.name == ex.map_axes[0])  # the singlet's Q_back, a lens's first

    def new_design(k):
        v = d.as_dict()
        v[first.name] = min(max(v[first.name] - first.step * (k + 1), first.start), first.end)
        return ex.controls_from(v, d.glass)
    label = f"{first.name} slider (new design)"
    pc = PhotoControls(center=(H // 3, W // 3))
    t0 = time.perf_counter()
    ex.criteria(d), ex.optics_figure(d), ex.photo_panel(d, pc)
    print(f"{spec} ({W} x {H}){', ' + a.lens if a.lens else ''}: first picture (cold) "
          f"{time.perf_counter() - t0:.2f} s")

    def timed(label, changes):
        ts = {"criteria": [], "optics": [], "photo": []}
        for dd, pp in changes:
            t = time.perf_counter()
            ex.criteria(dd)
            ts["criteria"].append(time.perf_counter() - t)
            t = time.perf_counter()
            ex.optics_figure(dd)
            ts["optics"].append(time.perf_counter() - t)
            t = time.perf_counter()
            ex.photo_panel(dd, pp)
            ts["photo"].append(time.perf_counter() - t)
        print(f"  {label:28s} " + ", ".join(f"{k} {statistics.median(v):.2f} s (max {max(v):.2f})"
                                             for k, v in ts.items()))

    timed(label, [(new_design(k), pc) for k in range(5)])
    timed("ISO", [(d, replace(pc, iso=400, seed=100 + k)) for k in range(5)])
    timed("seed", [(d, replace(pc, seed=k + 1)) for k in range(5)])
    timed("click (crop moved)", [(d, replace(pc, center=(H // 3 + 40 * (k + 1), W // 3 + 30 * (k + 1))))
                                 for k in range(5)])
    timed("CFA RGGB + Malvar", [(d, replace(pc, cfa="RGGB", seed=200 + k)) for k in range(5)])
    timed("back to an earlier state", [(d, pc)] * 5)


if __name__ == "__main__":
    main()
