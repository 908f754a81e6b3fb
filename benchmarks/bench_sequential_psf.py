"""PSF throughput of any lens (real-ray wavefront table + Fourier optics) against the thin singlet, side by side.

    python benchmarks/bench_sequential_psf.py [--n 64] [--positions 64] [--repeat 3] [--lenses cooke_triplet double_gauss]

Both sides compute PSFs at the same pixel positions on the same ``n x n`` grid, as the windowed blur asks for them: the
paper's singlet (``LensPSF``: third-order pupil, the paper's camera, 6000 x 4000 px at 1.5625 um, its 14 deg at the
frame's corner) and each lens of a prescription (``SequentialPSF``: its wavelengths, the same frame spanning its own
largest field at the corners, as ``simulate --lens`` maps a 24 MP photo). For the prescriptions the wavefront table is
traced once (reported apart: it is made once per lens and image plane and shared by every PSF of a run) and the PSFs
are then timed from it. Prints PSFs per second and the ratio to the singlet's. No timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import math
import time

import torch


def _positions(width: int, height: int, count: int, generator: torch.Generator):
    """``count`` pixel positions spread over the frame (seeded), and the optical centre."""
    rows = torch.rand(count, generator=generator, dtype=torch.float64) * (height - 1)
    cols = torch.rand(count, generator=generator, dtype=torch.float64) * (width - 1)
    return rows, cols, ((height - 1) / 2, (width - 1) / 2)


def _time(fn, repeat: int) -> float:
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    from dataclasses import replace

    from lenssim import Design, LensPSF
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.spectrum import Spectrum
    from lenssim.optics.sequential import SequentialLens
    from lenssim.optics.psf_bank import image_scale_mm
    from lenssim.optics.psf_provider import SequentialPSF
    from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=64, help="PSF grid (px)")
    ap.add_argument("--positions", type=int, default=64, help="pixel positions per call")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--lenses", nargs="+", default=["cooke_triplet", "double_gauss"])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    sensor = PAPER_CAMERA.sensor
    W, H = sensor.width_px, sensor.height_px
    g = torch.Generator().manual_seed(args.seed)
    rows, cols, centre = _positions(W, H, args.positions, g)
    print(f"{args.positions} PSFs of {args.n} x {args.n} px per call over a {W} x {H} frame; best of {args.repeat}; "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    singlet = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"] if "end_to_end_paper" in PAPER_DESIGNS
                      else Design(s=-0.775, Q_back=-2.4))
    t_ref = _time(lambda: singlet.psf_at_pixels(rows, cols, centre, args.n), args.repeat)
    ref_rate = args.positions / t_ref
    print(f"{'lens':<34} {'surfaces':>8} {'wavelengths':>11} {'table (s)':>9} {'PSFs/s':>9} {'vs singlet':>10}")
    print(f"{'paper singlet (third order)':<34} {2:>8} {len(PAPER_CAMERA.spectrum):>11} {'-':>9} {ref_rate:>9.1f} "
          f"{1.0:>9.2f}x")
    for name in args.lenses:
        p = read_lens(name)
        seq = SequentialLens(p)
        corner_px = math.hypot(H - 1, W - 1) / 2
        pitch = image_scale_mm(seq) * math.tan(math.radians(max(p.fields))) / corner_px * 1e3
        prov = SequentialPSF(seq, replace(sensor, pixel_pitch_um=pitch), Spectrum(p.wavelengths_um,
                             (1.0,) * len(p.wavelengths_um)), max_field_deg=max(p.fields))
        t0 = time.perf_counter()
        table = prov.table()
        t_table = time.perf_counter() - t0
        t = _time(lambda: prov.psf_at_pixels(rows, cols, centre, args.n), args.repeat)
        rate = args.positions / t
        print(f"{(p.name or name)[:34]:<34} {len(p.surfaces):>8} {len(p.wavelengths_um):>11} {t_table:>9.1f} "
              f"{rate:>9.1f} {rate / ref_rate:>9.2f}x   ({len(table.angles_deg)} field nodes, pitch {pitch:.3g} um)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
