"""Bounded reading of a decompression bomb (issue 28): a PNG of about 1 MB that decodes to N x N px (default 30000:
900 MP), simulated with one 128 px crop, against the same command on a 6000 x 4000 PNG of the same pattern, side by
side. Prints each run's wall time and peak memory (RSS of the `lenssim` process) and their ratios.

    python benchmarks/bench_bounded_read.py [--size 30000] [--dir DIR]

The PNGs are written row by row (bounded memory) into DIR (default: a temporary folder, removed afterwards).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def write_checkerboard_png(path: Path, height: int, width: int) -> None:
    """A grey 64 px checkerboard (values 64 and 192), written one scanline at a time."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(width, height, 1, "uint8")
    spec.attribute("png:compressionLevel", 9)
    if not out.open(str(path), spec):
        raise SystemExit(f"cannot write {path}: {out.geterror()}")
    x = np.arange(width)
    for y in range(height):
        out.write_scanline(y, 0, ((((x // 64) + (y // 64)) % 2) * 128 + 64).astype(np.uint8)[:, None])
    out.close()


def run(photo: Path, out: Path) -> tuple[float, float, str]:
    """Wall time (s), peak RSS (GiB) and the printed table of one `lenssim simulate` run in a fresh process."""
    code = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
            "r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
            "print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20); "
            "print(r.stdout + r.stderr[-400:], end=''); sys.exit(r.returncode)")
    argv = [sys.executable, "-c", code, "lenssim", "simulate", str(photo), "--design", "end_to_end_paper", "--crop",
            "128", "--angles", "0", "--out", str(out)]
    r = subprocess.run(argv, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{photo.name}: failed ({r.returncode}): {r.stdout[-600:]} {r.stderr[-600:]}")
    first, _, rest = r.stdout.partition("\n")
    seconds, gib = (float(v) for v in first.split())
    return seconds, gib, rest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=30000, help="side of the large PNG (px)")
    ap.add_argument("--dir", help="folder for the PNGs and outputs (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(args.dir or tmp)
        d.mkdir(parents=True, exist_ok=True)
        big, small = d / f"bomb_{args.size}.png", d / "baseline_6000x4000.png"
        for path, (h, w) in ((big, (args.size, args.size)), (small, (4000, 6000))):
            if not path.exists():
                t = time.perf_counter()
                write_checkerboard_png(path, h, w)
                print(f"wrote {path.name}: {w} x {h} px, {path.stat().st_size / 1e6:.2f} MB "
                      f"({time.perf_counter() - t:.0f} s)", file=sys.stderr)
        rows = []
        for name, path in (("baseline 24 MP", small), (f"{args.size ** 2 / 1e6:.0f} MP", big)):
            seconds, gib, table = run(path, d / f"out_{path.stem}")
            rows.append((name, seconds, gib))
            print(f"{name}: {seconds:.1f} s, peak {gib:.2f} GiB\n{table}")
        (b_name, b_s, b_g), (n, s, g) = rows
        print(f"ratio {n} / {b_name}: time {s / b_s:.2f}x, peak memory {g / b_g:.2f}x "
              f"(pixels {args.size ** 2 / 24e6:.1f}x)")


if __name__ == "__main__":
    main()
