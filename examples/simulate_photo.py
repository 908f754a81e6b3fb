"""Simulate the camera on a photo (or the built-in scene) with the pipeline's Python API.

    python examples/simulate_photo.py [PHOTO] [--iso 100] [--out sim_example]

With no PHOTO it uses ../shared/photos/outdoor_misty_forest_6016x4016.jpg when present, else the
generated 6000 x 4000 resolution scene. Crops at 1, 5 and 9 degrees (or, on a smaller photo, angles that fit it); the end-to-end and the
RMS_W designs side by side (ideal | sensor | restored per row) in one PNG.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from lenssim import LensPSF

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import linear_to_srgb, load_photo, write_image
from pipeline.simulate import crop_at_field_angle, fitting_angles, simulate_crops
from lenssim_studies.paper import PAPER_SENSOR

DESIGNS = {"end-to-end": PAPER_DESIGNS["end_to_end_paper"], "RMS_W": PAPER_DESIGNS["rms_w_paper"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--iso", type=int, default=100)
    ap.add_argument("--out", default="sim_example")
    args = ap.parse_args()
    shared = Path(__file__).resolve().parents[1].parent / "shared" / "photos" / "outdoor_misty_forest_6016x4016.jpg"
    photo = args.photo or (str(shared) if shared.exists() else None)
    ideal, source = load_photo(photo, PAPER_CAMERA)
    size = min(192, *ideal.shape[-2:])
    angles = fitting_angles(ideal.shape, size, PAPER_CAMERA.geometry, (1.0, 5.0, 9.0))  # those that fit the photo
    boxes = [crop_at_field_angle(ideal.shape, a, size, PAPER_CAMERA.geometry) for a in angles]
    rows = []
    for name, design in DESIGNS.items():
        psf = LensPSF(PAPER_CAMERA, design)
        for r in simulate_crops(ideal, psf, PAPER_CAMERA.sensor.full_well_for_iso(args.iso), boxes, sensor=PAPER_SENSOR):
            print(f"{source} | {name} ({design.label()}) | {r.field_deg:4.1f} deg: sensor "
                  f"{r.scores['sensor']['psnr_db']:.2f} dB -> restored {r.scores['wiener']['psnr_db']:.2f} dB")
            rows.append(torch.cat([r.ideal, r.sensor, r.images["wiener"]], dim=-1))
    path = write_image(Path(args.out) / "comparison.png", linear_to_srgb(torch.cat(rows, dim=-2).clamp(0, 1)))
    print(f"wrote {path}  (rows: end-to-end at 1/5/9 deg, then RMS_W at 1/5/9 deg)")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown()  # no nanobind "leaked" noise at exit
