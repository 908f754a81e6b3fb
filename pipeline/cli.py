"""The ``lenssim`` console command: the optics commands of :mod:`lenssim.cli` plus the camera pipeline.

This module sits on top of both packages (``lenssim`` never imports ``pipeline``)::

    lenssim simulate [PHOTO|skimage:NAME] (--design NAME | --s S --Q Q) [--iso 100 | --full-well E]
                     [--angles 0 4 8 12] [--crop 256] [--seed 0] [--scheme 512 32 64] [--full-frame] --out DIR

writes, for crops centred at the given field angles (along the frame diagonal), the ideal, sensor
and restored images (8-bit sRGB PNG), a mosaic, and ``metrics.json`` (PSNR/SSIM in sRGB); with
``--full-frame`` also the whole sensor and restored frames and whole-frame metrics (resumable).
Without PHOTO the built-in generated 6000 x 4000 scene is used. ::

    lenssim psnr-table [PHOTO ...] [--designs A B] [--isos 400 100 25] --out DIR

writes ``psnr_table.csv`` and ``psnr_table.md`` (mean over the crops).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import torch

from lenssim.cli import _designs, main as _lenssim_main
from lenssim.files import atomic_write_text
from lenssim.sweep import select_device

from .io import ImageFileError, read_image, write_image


def load_photo(spec: str | None) -> tuple[torch.Tensor, str]:
    """Linear ``(1, C, H, W)`` float32 image from a file, ``skimage:NAME`` or (None) the generated scene."""
    from .colour_space import srgb_to_linear

    if spec is None:
        from .scene import resolution_scene

        return resolution_scene(), "generated resolution scene 6000x4000"
    if spec.startswith("skimage:"):
        import numpy as np
        import skimage.data

        name = spec.split(":", 1)[1]
        fn = getattr(skimage.data, name, None)
        if fn is None or not callable(fn):
            raise ValueError(f"{spec!r}: scikit-image ships no image called {name!r}")
        arr = np.asarray(fn())
        if arr.dtype != np.uint8:
            raise ValueError(f"{spec!r}: only 8-bit scikit-image images are supported")
        t = torch.from_numpy(arr.astype(np.float32) / 255)
        t = t[None, None] if t.ndim == 2 else t.permute(2, 0, 1)[None, :3]
        return srgb_to_linear(t), spec
    img, info = read_image(spec)
    return (img if info.linear else srgb_to_linear(img)), spec


def _mosaic(results) -> torch.Tensor:
    rows = [torch.cat([r.ideal, r.sensor, r.restored], dim=-1) for r in results]
    c = max(x.shape[1] for x in rows)
    rows = [x.expand(-1, c, -1, -1) for x in rows]
    return torch.cat(rows, dim=-2)


def cmd_simulate(args) -> int:
    from .colour_space import linear_to_srgb
    from .noise import full_well_for_iso
    from .simulate import crop_at_field_angle, simulate_crops

    if args.design is not None:
        designs = _designs(None)
        if args.design not in designs:
            raise ValueError(f"--design {args.design!r} is not known; choose from {sorted(designs)}")
        s, Q = designs[args.design].s, designs[args.design].Q
    elif args.s is not None and args.Q is not None:
        s, Q = args.s, args.Q
    else:
        raise ValueError("give --design NAME, or both --s and --Q")
    from .blur import WindowScheme

    if args.full_well is not None:
        if not args.full_well > 0:
            raise ValueError(f"--full-well {args.full_well!r} is not allowed: must be > 0 electrons")
        fwc, args.iso = float(args.full_well), None
    else:
        fwc = full_well_for_iso(args.iso)
    scheme = WindowScheme(*args.scheme)
    t0 = time.perf_counter()
    ideal, source = load_photo(args.photo)
    ideal = ideal.to(select_device(args.device))
    if args.denoise:
        from .denoise import gentle_denoise

        ideal = gentle_denoise(ideal, args.denoise)
        source += f" (gently denoised, strength {args.denoise:g})"
    out = Path(args.out)
    inputs = [args.photo] if args.photo and not args.photo.startswith("skimage:") else []
    size = min(args.crop, ideal.shape[-2], ideal.shape[-1])
    boxes = [crop_at_field_angle(ideal.shape, a, size) for a in args.angles]
    report = {"source": source, "s": s, "Q": Q, "iso": args.iso, "full_well_electrons": fwc, "seed": args.seed,
              "scheme_window_stride_core": list(args.scheme)}
    if args.full_frame:
        results = _full_frame(ideal, s, Q, fwc, args, out, inputs, boxes, report, scheme)
    else:
        results = simulate_crops(ideal, s, Q, fwc, boxes, seed=args.seed, rl_iterations=args.rl, scheme=scheme)
    report["crops"] = []
    for a, r in zip(args.angles, results):
        tag = f"crop_{a:g}deg"
        for kind in ("ideal", "sensor", "restored") + (("restored_rl",) if args.rl else ()):
            write_image(out / f"{tag}_{kind}.png", linear_to_srgb(getattr(r, kind).clamp(0, 1)), inputs=inputs)
        report["crops"].append({"requested_deg": a, "field_deg": round(r.field_deg, 3), "box_r0_r1_c0_c1": list(r.box),
                                "psnr_sensor_db": r.psnr_sensor_db, "psnr_restored_db": r.psnr_restored_db,
                                "ssim_sensor": r.ssim_sensor, "ssim_restored": r.ssim_restored,
                                "psnr_richardson_lucy_db": r.psnr_rl_db, "ssim_richardson_lucy": r.ssim_rl})
    write_image(out / "mosaic.png", linear_to_srgb(_mosaic(results).clamp(0, 1)), inputs=inputs)
    atomic_write_text(out / "metrics.json", json.dumps(report, indent=2))
    print(f"{source}, s = {s:g}, Q = {Q:g}, " + (f"ISO {args.iso} " if args.iso else "") + f"({fwc:g} e- full well):")
    print("  field [deg]   PSNR sensor -> restored [dB]   SSIM sensor -> restored")
    for c in report["crops"]:
        rl = (f"   (Richardson-Lucy: {c['psnr_richardson_lucy_db']:.2f} dB, SSIM {c['ssim_richardson_lucy']:.3f})"
              if c["psnr_richardson_lucy_db"] is not None else "")
        print(f"  {c['field_deg']:10.2f}   {c['psnr_sensor_db']:11.2f} -> {c['psnr_restored_db']:.2f}"
              f"              {c['ssim_sensor']:.3f} -> {c['ssim_restored']:.3f}{rl}")
    print(f"wrote {out}/ (crop PNGs, mosaic.png, metrics.json) in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def _full_frame(ideal, s, Q, fwc, args, out, inputs, boxes, report, scheme):
    """``simulate --full-frame``: the whole frame (resumable), whole-frame metrics, crops cut from it."""
    import shutil

    from tqdm import tqdm

    from .blur import window_count
    from .field_map import plot_field_psnr, tile_field_angles
    from .quality import encode_srgb, scores_encoded
    from .simulate import crops_from_frame, simulate_frame

    if args.rl:
        raise ValueError("--rl is not available with --full-frame (Richardson-Lucy on 24 MP is hours on a CPU); "
                         "use it on crops")
    n = window_count(ideal.shape, scheme)
    checkpoint = out / ".checkpoint"
    with tqdm(total=2 * n, unit="window", desc="blur + restore", file=sys.stderr, mininterval=2.0) as bar:
        frame = simulate_frame(ideal, s, Q, fwc, seed=args.seed, scheme=scheme, progress=bar.update,
                               checkpoint=checkpoint)
    if frame.resumed:
        print(f"resumed from the sensor image in {checkpoint}/", file=sys.stderr)
    # each image is sRGB-encoded once, for its PNG and for all its scores
    frame.seconds["write"], frame.seconds["metrics"] = 0.0, 0.0
    ref = encode_srgb(ideal)
    scores = {}
    for kind in ("sensor", "restored"):
        t0 = time.perf_counter()
        img = getattr(frame, kind)
        enc = encode_srgb(img)
        write_image(out / f"{kind}.png", torch.from_numpy(enc).permute(2, 0, 1), bits=args.bits, inputs=inputs)
        if args.exr:
            write_image(out / f"{kind}_linear.exr", img, bits="float", inputs=inputs)
        t1 = time.perf_counter()
        scores[kind] = scores_encoded(ref, enc, tile=256)
        frame.seconds["write"] += t1 - t0
        frame.seconds["metrics"] += time.perf_counter() - t1
    t0 = time.perf_counter()
    report["full_frame"] = {
        "shape_c_h_w": list(ideal.shape[1:]), "windows_per_pass": n, "electrons_per_unit": frame.electrons_per_unit,
        "psnr_sensor_db": scores["sensor"]["psnr_db"], "psnr_restored_db": scores["restored"]["psnr_db"],
        "ssim_sensor": scores["sensor"]["ssim"], "ssim_restored": scores["restored"]["ssim"],
        "resumed": frame.resumed}
    maps = {"sensor_db": scores["sensor"]["psnr_map_db"], "restored_db": scores["restored"]["psnr_map_db"],
            "field_deg": tile_field_angles(ideal.shape, 256)}
    plot_field_psnr(maps, out / "field_psnr.png", title=f"{report['source']}: s = {s:g}, Q = {Q:g}, {fwc:g} e- full well")
    report["full_frame"]["field_psnr_256px_tiles"] = {  # JSON has no inf: identical tiles are null
        k: [[round(x, 3) if math.isfinite(x) else None for x in row] for row in v.tolist()] for k, v in maps.items()}
    frame.seconds["metrics"] += time.perf_counter() - t0
    report["full_frame"]["seconds"] = {k: round(v, 2) for k, v in frame.seconds.items()}
    shutil.rmtree(checkpoint, ignore_errors=True)  # done: the checkpoint is no longer needed
    f = report["full_frame"]
    print(f"whole frame: PSNR sensor {f['psnr_sensor_db']:.2f} dB -> restored {f['psnr_restored_db']:.2f} dB, "
          f"SSIM {f['ssim_sensor']:.3f} -> {f['ssim_restored']:.3f}")
    return crops_from_frame(ideal, frame, boxes)


def cmd_psnr_table(args) -> int:
    from .noise import full_well_for_iso
    from .simulate import crop_at_field_angle, simulate_crops

    designs = _designs(None)
    for d in args.designs:
        if d not in designs:
            raise ValueError(f"--designs {d!r} is not known; choose from {sorted(designs)}")
    photos = args.photos or [None]
    rows = []
    t0 = time.perf_counter()
    for photo in photos:
        ideal, source = load_photo(photo)
        ideal = ideal.to(select_device(args.device))
        size = min(args.crop, ideal.shape[-2], ideal.shape[-1])
        boxes = [crop_at_field_angle(ideal.shape, a, size) for a in args.angles]
        for name in args.designs:
            d = designs[name]
            per_iso = simulate_crops(ideal, d.s, d.Q, [full_well_for_iso(i) for i in args.isos], boxes, seed=args.seed)
            for iso, res in zip(args.isos, per_iso):
                rows.append({"photo": source, "design": name, "s": d.s, "Q": d.Q, "iso": iso,
                             "psnr_sensor_db": sum(r.psnr_sensor_db for r in res) / len(res),
                             "psnr_restored_db": sum(r.psnr_restored_db for r in res) / len(res),
                             "ssim_restored": sum(r.ssim_restored for r in res) / len(res)})
                print(f"{source} | {name} | ISO {iso}: restored {rows[-1]['psnr_restored_db']:.2f} dB", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = list(rows[0])
    csv = "".join(",".join(str(r[k]) for k in keys) + "\n" for r in rows)
    md = (f"Mean over crops at {', '.join(f'{a:g}' for a in args.angles)} deg ({args.crop} px), sRGB PSNR/SSIM vs the ideal image.\n\n"
          "| photo | design | ISO | PSNR sensor [dB] | PSNR restored [dB] | SSIM restored |\n|---|---|---|---|---|---|\n"
          + "".join(f"| {r['photo']} | {r['design']} | {r['iso']} | {r['psnr_sensor_db']:.2f} | {r['psnr_restored_db']:.2f} | "
                    f"{r['ssim_restored']:.3f} |\n" for r in rows))
    for name, text in (("psnr_table.csv", ",".join(keys) + "\n" + csv), ("psnr_table.md", md)):
        atomic_write_text(out / name, text)
    print(md)
    print(f"wrote {out}/psnr_table.csv and psnr_table.md in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def cmd_fig8(args) -> int:
    from .figure8 import figure8

    ideal, source = load_photo(args.photo)
    ideal = ideal.to(select_device(args.device))
    t0 = time.perf_counter()
    png, table = figure8(ideal, args.out, angles=tuple(args.angles), crop=args.crop, seed=args.seed)
    atomic_write_text(Path(args.out) / "fig8_psnr.json", json.dumps({"source": source, "tiles": table}, indent=2))
    print(f"wrote {png} (+ .svg, fig8_psnr.json) from {source} in {time.perf_counter() - t0:.0f} s")
    return 0


def _extend(sub) -> None:
    p = sub.add_parser("simulate", help="photo -> sensor image -> restored image, at crops across the field")
    p.add_argument("photo", nargs="?", help="image file (JPEG/PNG/TIFF/EXR) or skimage:NAME; default: generated scene")
    p.add_argument("--design", help="a named design (see `lenssim designs`)")
    p.add_argument("--s", type=float)
    p.add_argument("--Q", type=float)
    p.add_argument("--iso", type=int, default=100, help="25, 100 or 400 (full well 12800, 3200, 800 e-)")
    p.add_argument("--full-well", type=float, metavar="E", help="any full-well capacity (electrons) instead of --iso")
    p.add_argument("--scheme", type=int, nargs=3, default=[512, 32, 64], metavar=("WINDOW", "STRIDE", "CORE"),
                   help="local-convolution windows (px): window, stride, blended core (paper: 512 32 64)")
    p.add_argument("--angles", type=float, nargs="+", default=[0.0, 4.0, 8.0, 12.0], help="crop field angles (deg)")
    p.add_argument("--crop", type=int, default=256, help="crop size (px)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--denoise", type=float, default=0.0, metavar="STRENGTH",
                   help="gently denoise the photo first (wavelet, strength in (0, 2]; off by default, as a paper option)")
    p.add_argument("--rl", type=int, default=0, metavar="N",
                   help="also restore with N iterations of windowed Richardson-Lucy (non-linear comparison; slow)")
    p.add_argument("--full-frame", action="store_true",
                   help="simulate the whole frame (sensor.png, restored.png, whole-frame PSNR/SSIM; ~5 min at 24 MP on "
                        "2 CPU cores; resumes after an interruption) instead of crops only")
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="--full-frame PNG bit depth (sRGB)")
    p.add_argument("--exr", action="store_true", help="--full-frame: also write linear float EXRs")
    p.add_argument("--device", default="auto", help="auto (GPU if present), cpu, cuda")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=cmd_simulate)

    f = sub.add_parser("fig8", help="Fig. 8-style mosaic: two designs x three ISOs at crops across the field")
    f.add_argument("photo", nargs="?", help="image file or skimage:NAME; default: the generated scene")
    f.add_argument("--angles", type=float, nargs="+", default=[1.3, 2.1, 7.1, 3.4, 4.8, 8.8])
    f.add_argument("--crop", type=int, default=128)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--device", default="auto", help="auto (GPU if present), cpu, cuda")
    f.add_argument("--out", required=True)
    f.set_defaults(func=cmd_fig8)

    t = sub.add_parser("psnr-table", help="PSNR of restored images: photos x designs x ISOs (CSV + Markdown)")
    t.add_argument("photos", nargs="*", help="image files or skimage:NAME; default: the generated scene")
    t.add_argument("--designs", nargs="+", default=["rms_w_paper", "end_to_end_paper"])
    t.add_argument("--isos", type=int, nargs="+", default=[400, 100, 25])
    t.add_argument("--angles", type=float, nargs="+", default=[1.0, 5.0, 9.0])
    t.add_argument("--crop", type=int, default=192)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--device", default="auto", help="auto (GPU if present), cpu, cuda")
    t.add_argument("--out", required=True)
    t.set_defaults(func=cmd_psnr_table)


def main(argv: list[str] | None = None) -> int:
    try:
        return _lenssim_main(argv, extend=_extend)
    except ImageFileError as exc:
        print(f"lenssim: error: {exc}", file=sys.stderr)
        return 2


def entry() -> None:
    """The ``lenssim`` console script: :func:`main`, then exit without interpreter teardown.

    colour-science imports OpenImageIO, and with torch also loaded the interpreter's teardown runs
    in an order where OpenImageIO's nanobind bindings report their module-level objects as
    "leaked" (a page of messages after every pipeline command, exit status still 0). Every output
    is complete and closed when ``main`` returns (atomic writes), so the script flushes its streams
    and leaves directly. ``main`` itself (tests, Python callers) is unaffected.
    """
    rc = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)


if __name__ == "__main__":
    entry()
