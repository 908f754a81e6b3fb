"""The explorer's responsiveness (issue 32): the time from a control's change to its new picture, driving the update
functions of :mod:`lenssim_studies.explore` as the page does (no browser; the page's own round trip, ~80 ms with
Panel, is measured in docs/explore.md).

    python benchmarks/bench_explore.py [PHOTO]

For the paper's lens and a 256 px crop: the first picture (cold caches), then each control changed in turn (a new
design: criteria, PSF/MTF figure and the photo; the ISO; the seed; a click moving the crop; the CFA; a return to an
earlier state, served from the caches), 5 times each with fresh values; prints the median and the largest time per
control. No timing is asserted anywhere.
"""

from __future__ import annotations

import statistics
import sys
import time
from dataclasses import replace


def main() -> None:
    from lenssim_studies.explore import DesignControls, Explorer, PhotoControls
    from pipeline.photo import open_photo
    from lenssim_studies.paper import PAPER_CAMERA

    spec = sys.argv[1] if len(sys.argv) > 1 else "skimage:astronaut"
    photo = open_photo(spec, PAPER_CAMERA)
    ex = Explorer(photo=photo, photo_source=photo.source)
    H, W = photo.shape[-2:]
    d, pc = DesignControls(), PhotoControls(center=(H // 3, W // 3))
    t0 = time.perf_counter()
    ex.criteria(d), ex.optics_figure(d), ex.photo_panel(d, pc)
    print(f"{spec} ({W} x {H}): first picture (cold) {time.perf_counter() - t0:.2f} s")

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

    timed("Q_back slider (new design)", [(replace(d, Q_back=d.Q_back - 0.1 * (k + 1)), pc) for k in range(5)])
    timed("ISO", [(d, replace(pc, iso=i)) for i in (400, 25, 400, 25, 400)][:5] if False else
          [(d, replace(pc, iso=400, seed=100 + k)) for k in range(5)])
    timed("seed", [(d, replace(pc, seed=k + 1)) for k in range(5)])
    timed("click (crop moved)", [(d, replace(pc, center=(H // 3 + 40 * (k + 1), W // 3 + 30 * (k + 1))))
                                 for k in range(5)])
    timed("CFA RGGB + Malvar", [(d, replace(pc, cfa="RGGB", seed=200 + k)) for k in range(5)])
    timed("back to an earlier state", [(d, pc)] * 5)


if __name__ == "__main__":
    main()
