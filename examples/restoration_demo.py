"""Train-free restoration demo: adaptive local Wiener vs windowed Richardson-Lucy.

    python examples/restoration_demo.py [PHOTO] [--iso 100] [--rl 20] [--out restoration_demo]

Crops at 2 and 8 degrees of the photo (default: the generated scene), end-to-end design; prints
PSNR/SSIM (sRGB) of the sensor image, the Wiener and the Richardson-Lucy restorations, and writes
ideal | sensor | Wiener | Richardson-Lucy side by side.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from lenssim import LensPSF

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import RESTORATION_METHODS, linear_to_srgb, load_photo, write_image
from pipeline.simulate import crop_at_field_angle, fitting_angles, simulate_crops
from lenssim_studies.paper import PAPER_SENSOR


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--iso", type=int, default=100)
    ap.add_argument("--rl", type=int, default=20, help="Richardson-Lucy iterations")
    ap.add_argument("--out", default="restoration_demo")
    args = ap.parse_args()
    ideal, source = load_photo(args.photo, PAPER_CAMERA)
    size = min(160, *ideal.shape[-2:])
    angles = fitting_angles(ideal.shape, size, PAPER_CAMERA.geometry, (2.0, 8.0))  # those that fit the photo
    boxes = [crop_at_field_angle(ideal.shape, a, size, PAPER_CAMERA.geometry) for a in angles]
    methods = ("wiener", "richardson_lucy")
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    res = simulate_crops(ideal, psf, PAPER_CAMERA.sensor.full_well_for_iso(args.iso), boxes, methods=methods,
                         method_options={"richardson_lucy": {"iterations": args.rl}}, sensor=PAPER_SENSOR)
    rows = []
    for r in res:
        scores = "; ".join(f"{RESTORATION_METHODS[m].label if m != 'sensor' else 'sensor'} "
                           f"{r.scores[m]['psnr_db']:.2f} dB / SSIM {r.scores[m]['ssim']:.3f}" for m in ("sensor",) + methods)
        print(f"{source}, {r.field_deg:.1f} deg, ISO {args.iso} (Richardson-Lucy: {args.rl} it.): {scores}")
        rows.append(torch.cat([r.ideal, r.sensor] + [r.images[m] for m in methods], dim=-1))
    path = write_image(Path(args.out) / "wiener_vs_rl.png", linear_to_srgb(torch.cat(rows, dim=-2).clamp(0, 1)))
    print(f"wrote {path}")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown()  # no nanobind "leaked" noise at exit
