"""Camera-pipeline commands: simulate a photo through a design, PSNR tables, the Fig. 8 mosaic.

    lenssim simulate [PHOTO|skimage:NAME] (--design NAME | --s S --Q_back Q) [--iso 100 | --full-well E]
                     [--angles 0 4 8 12] [--crop 256] [--seed 0] [--scheme 512 32 64] [--full-frame] --out DIR

writes, for crops centred at the given field angles (along the frame diagonal), the ideal, sensor
and restored images (8-bit sRGB PNG), a mosaic, and ``metrics.json`` (PSNR/SSIM in sRGB per
restoration method); with ``--full-frame`` also the whole sensor and restored frames and
whole-frame metrics (resumable). Without PHOTO the built-in generated 6000 x 4000 scene is used.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import torch

from lenssim import PAPER_CAMERA, PAPER_DESIGNS, LensPSF, select_device
from lenssim.files import atomic_write_text
from lenssim.paper import PAPER_FIG8_ANGLES_DEG
from pipeline import RESTORATION_METHODS, load_photo, write_image
from pipeline.restoration import validate_method

from .common import add_design_arguments, add_device_argument, design_from_args, designs

DEFAULT_ANGLES_DEG = (0.0, 4.0, 8.0, 12.0)
TABLE_ANGLES_DEG = (1.0, 5.0, 9.0)


def _methods(args) -> tuple[tuple[str, ...], dict]:
    methods = ["wiener"]
    options = {}
    if args.rl:
        methods.append("richardson_lucy")
        options["richardson_lucy"] = {"iterations": args.rl}
    for m in args.restore or []:
        validate_method(m)
        if m not in methods:
            methods.append(m)
    return tuple(methods), options


def _mosaic(results, methods) -> torch.Tensor:
    rows = [torch.cat([r.ideal, r.sensor] + [r.images[m] for m in methods], dim=-1) for r in results]
    c = max(x.shape[1] for x in rows)
    rows = [x.expand(-1, c, -1, -1) for x in rows]
    return torch.cat(rows, dim=-2)


def cmd_simulate(args) -> int:
    from pipeline import crop_at_field_angle, simulate_crops
    from pipeline.colour_space import linear_to_srgb
    from pipeline.blur import WindowScheme

    design = design_from_args(args)
    camera = PAPER_CAMERA
    psf = LensPSF(camera, design)
    if args.full_well is not None:
        if not args.full_well > 0:
            raise ValueError(f"--full-well {args.full_well!r} is not allowed: must be > 0 electrons")
        fwc, args.iso = float(args.full_well), None
    else:
        fwc = camera.sensor.full_well_for_iso(args.iso)
    scheme = WindowScheme(*args.scheme)
    methods, options = _methods(args)
    t0 = time.perf_counter()
    ideal, source = load_photo(args.photo)
    ideal = ideal.to(select_device(args.device))
    if args.denoise:
        from pipeline import gentle_denoise

        ideal = gentle_denoise(ideal, args.denoise)
        source += f" (gently denoised, strength {args.denoise:g})"
    out = Path(args.out)
    inputs = [args.photo] if args.photo and not args.photo.startswith("skimage:") else []
    size = min(args.crop, ideal.shape[-2], ideal.shape[-1])
    boxes = [crop_at_field_angle(ideal.shape, a, size, camera.geometry) for a in args.angles]
    params = design.complete().floats()
    report = {"source": source, "design": design.name or "custom", "parameters": params, **params,
              "iso": args.iso, "full_well_electrons": fwc, "seed": args.seed,
              "scheme_window_stride_core": list(args.scheme), "methods": list(methods)}
    if args.full_frame:
        results = _full_frame(ideal, psf, fwc, args, out, inputs, boxes, report, scheme, methods)
    else:
        results = simulate_crops(ideal, psf, fwc, boxes, seed=args.seed, methods=methods, method_options=options,
                                 scheme=scheme, sensor=camera.sensor)
    report["crops"] = []
    for a, r in zip(args.angles, results):
        tag = f"crop_{a:g}deg"
        for kind in ("ideal", "sensor") + methods:
            name = "restored" if kind == "wiener" else ("restored_rl" if kind == "richardson_lucy" else f"restored_{kind}")
            if kind in r.images:
                write_image(out / f"{tag}_{name if kind not in ('ideal', 'sensor') else kind}.png",
                            linear_to_srgb(r.images[kind].clamp(0, 1)), inputs=inputs)
        report["crops"].append({"requested_deg": a, "field_deg": round(r.field_deg, 3), "box_r0_r1_c0_c1": list(r.box),
                                "scores": r.scores,
                                "psnr_sensor_db": r.scores["sensor"]["psnr_db"],
                                "psnr_restored_db": r.scores["wiener"]["psnr_db"] if "wiener" in r.scores else None})
    write_image(out / "mosaic.png", linear_to_srgb(_mosaic(results, [m for m in methods if m in results[0].images])
                                                   .clamp(0, 1)), inputs=inputs)
    atomic_write_text(out / "metrics.json", json.dumps(report, indent=2))
    print(f"{source}, {design.label()}, " + (f"ISO {args.iso} " if args.iso else "") + f"({fwc:g} e- full well):")
    print("  field [deg]   PSNR [dB] / SSIM: sensor -> " + ", ".join(RESTORATION_METHODS[m].label for m in methods))
    for c in report["crops"]:
        sc = c["scores"]
        restored = ", ".join(f"{sc[m]['psnr_db']:.2f} / {sc[m]['ssim']:.3f}" for m in methods if m in sc)
        print(f"  {c['field_deg']:10.2f}   {sc['sensor']['psnr_db']:.2f} / {sc['sensor']['ssim']:.3f} -> {restored}")
    print(f"wrote {out}/ (crop PNGs, mosaic.png, metrics.json) in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def _full_frame(ideal, psf, fwc, args, out, inputs, boxes, report, scheme, methods):
    """``simulate --full-frame``: the whole frame (resumable), whole-frame metrics, crops cut from it."""
    import shutil

    from tqdm import tqdm

    from pipeline.blur import window_count
    from pipeline.field_map import plot_field_psnr, tile_field_angles
    from pipeline.quality import encode_srgb, scores_encoded
    from pipeline.simulate import crops_from_frame, simulate_frame

    if len(methods) > 1:
        raise ValueError("--full-frame restores with the adaptive Wiener filter only (Richardson-Lucy on 24 MP is "
                         "hours on a CPU); use other methods on crops")
    n = window_count(ideal.shape, scheme)
    checkpoint = out / ".checkpoint"
    with tqdm(total=2 * n, unit="window", desc="blur + restore", file=sys.stderr, mininterval=2.0) as bar:
        frame = simulate_frame(ideal, psf, fwc, seed=args.seed, scheme=scheme, progress=bar.update,
                               checkpoint=checkpoint, sensor=PAPER_CAMERA.sensor)
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
        "method": frame.method,
        "psnr_sensor_db": scores["sensor"]["psnr_db"], "psnr_restored_db": scores["restored"]["psnr_db"],
        "ssim_sensor": scores["sensor"]["ssim"], "ssim_restored": scores["restored"]["ssim"],
        "resumed": frame.resumed}
    maps = {"sensor_db": scores["sensor"]["psnr_map_db"], "restored_db": scores["restored"]["psnr_map_db"],
            "field_deg": tile_field_angles(ideal.shape, 256, psf.geometry)}
    plot_field_psnr(maps, out / "field_psnr.png",
                    title=f"{report['source']}: {psf.design.label()}, {fwc:g} e- full well")
    report["full_frame"]["field_psnr_256px_tiles"] = {  # JSON has no inf: identical tiles are null
        k: [[round(x, 3) if math.isfinite(x) else None for x in row] for row in v.tolist()] for k, v in maps.items()}
    frame.seconds["metrics"] += time.perf_counter() - t0
    report["full_frame"]["seconds"] = {k: round(v, 2) for k, v in frame.seconds.items()}
    shutil.rmtree(checkpoint, ignore_errors=True)  # done: the checkpoint is no longer needed
    f = report["full_frame"]
    print(f"whole frame: PSNR sensor {f['psnr_sensor_db']:.2f} dB -> restored {f['psnr_restored_db']:.2f} dB, "
          f"SSIM {f['ssim_sensor']:.3f} -> {f['ssim_restored']:.3f}")
    return crops_from_frame(ideal, frame, boxes, psf.geometry)


def cmd_psnr_table(args) -> int:
    from pipeline import crop_at_field_angle, simulate_crops

    named = designs(args.designs_file)
    for d in args.designs:
        if d not in named:
            raise ValueError(f"design {d!r} is not known; choose from {', '.join(sorted(named))}")
    camera = PAPER_CAMERA
    wells = [camera.sensor.full_well_for_iso(i) for i in args.isos]
    method = args.method
    validate_method(method)
    photos = args.photos or [None]
    rows = []
    t0 = time.perf_counter()
    for photo in photos:
        ideal, source = load_photo(photo)
        ideal = ideal.to(select_device(args.device))
        size = min(args.crop, ideal.shape[-2], ideal.shape[-1])
        boxes = [crop_at_field_angle(ideal.shape, a, size, camera.geometry) for a in args.angles]
        for name in args.designs:
            d = named[name]
            per_iso = simulate_crops(ideal, LensPSF(camera, d), wells, boxes, seed=args.seed, methods=(method,),
                                     sensor=camera.sensor)
            for iso, res in zip(args.isos, per_iso):
                mean = lambda kind, key: sum(r.scores[kind][key] for r in res) / len(res)  # noqa: E731
                rows.append({"photo": source, "design": name, **d.floats(), "iso": iso, "method": method,
                             "psnr_sensor_db": mean("sensor", "psnr_db"), "psnr_restored_db": mean(method, "psnr_db"),
                             "ssim_restored": mean(method, "ssim")})
                print(f"{source} | {name} | ISO {iso}: restored {rows[-1]['psnr_restored_db']:.2f} dB", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    csv = "".join(",".join(str(r.get(k, "")) for k in keys) + "\n" for r in rows)
    md = (f"Mean over crops at {', '.join(f'{a:g}' for a in args.angles)} deg ({args.crop} px), sRGB PSNR/SSIM vs the "
          f"ideal image; restoration: {RESTORATION_METHODS[method].label}.\n\n"
          "| photo | design | ISO | PSNR sensor [dB] | PSNR restored [dB] | SSIM restored |\n|---|---|---|---|---|---|\n"
          + "".join(f"| {r['photo']} | {r['design']} | {r['iso']} | {r['psnr_sensor_db']:.2f} | {r['psnr_restored_db']:.2f} | "
                    f"{r['ssim_restored']:.3f} |\n" for r in rows))
    for name, text in (("psnr_table.csv", ",".join(keys) + "\n" + csv), ("psnr_table.md", md)):
        atomic_write_text(out / name, text)
    print(md)
    print(f"wrote {out}/psnr_table.csv and psnr_table.md in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def cmd_fig8(args) -> int:
    from pipeline.figure8 import figure8

    ideal, source = load_photo(args.photo)
    ideal = ideal.to(select_device(args.device))
    t0 = time.perf_counter()
    png, tiles = figure8(ideal, args.out, angles=tuple(args.angles), crop=args.crop, seed=args.seed)
    atomic_write_text(Path(args.out) / "fig8_psnr.json", json.dumps({"source": source, "tiles": tiles}, indent=2))
    print(f"wrote {png} (+ .svg, fig8_psnr.json) from {source} in {time.perf_counter() - t0:.0f} s")
    return 0


def register(sub) -> None:
    isos = camera_isos = PAPER_CAMERA.sensor.isos
    methods = ", ".join(RESTORATION_METHODS)
    p = sub.add_parser("simulate", help="photo -> sensor image -> restored image, at crops across the field")
    p.add_argument("photo", nargs="?", help="image file (JPEG/PNG/TIFF/EXR) or skimage:NAME; default: generated scene")
    add_design_arguments(p)
    p.add_argument("--iso", type=int, default=100, help="one of " + ", ".join(
        f"{i} ({PAPER_CAMERA.sensor.full_well_for_iso(i):g} e- full well)" for i in camera_isos))
    p.add_argument("--full-well", type=float, metavar="E", help="any full-well capacity (electrons) instead of --iso")
    p.add_argument("--scheme", type=int, nargs=3, default=[512, 32, 64], metavar=("WINDOW", "STRIDE", "CORE"),
                   help="local-convolution windows (px): window, stride, blended core (paper: 512 32 64)")
    p.add_argument("--angles", type=float, nargs="+", default=list(DEFAULT_ANGLES_DEG), help="crop field angles (deg)")
    p.add_argument("--crop", type=int, default=256, help="crop size (px)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--denoise", type=float, default=0.0, metavar="STRENGTH",
                   help="gently denoise the photo first (wavelet, strength in (0, 2]; off by default, as a paper option)")
    p.add_argument("--restore", nargs="+", metavar="METHOD",
                   help=f"restoration methods besides the adaptive Wiener filter ({methods})")
    p.add_argument("--rl", type=int, default=0, metavar="N",
                   help="also restore with N iterations of windowed Richardson-Lucy (non-linear comparison; slow)")
    p.add_argument("--full-frame", action="store_true",
                   help="simulate the whole frame (sensor.png, restored.png, whole-frame PSNR/SSIM; ~5 min at 24 MP on "
                        "2 CPU cores; resumes after an interruption) instead of crops only")
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="--full-frame PNG bit depth (sRGB)")
    p.add_argument("--exr", action="store_true", help="--full-frame: also write linear float EXRs")
    add_device_argument(p)
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=cmd_simulate)

    f = sub.add_parser("fig8", help="Fig. 8-style mosaic: two designs x three ISOs at crops across the field")
    f.add_argument("photo", nargs="?", help="image file or skimage:NAME; default: the generated scene")
    f.add_argument("--angles", type=float, nargs="+", default=list(PAPER_FIG8_ANGLES_DEG))
    f.add_argument("--crop", type=int, default=128)
    f.add_argument("--seed", type=int, default=0)
    add_device_argument(f)
    f.add_argument("--out", required=True)
    f.set_defaults(func=cmd_fig8)

    t = sub.add_parser("psnr-table", help="PSNR of restored images: photos x designs x ISOs (CSV + Markdown)")
    t.add_argument("photos", nargs="*", help="image files or skimage:NAME; default: the generated scene")
    t.add_argument("--designs", nargs="+", default=list(PAPER_DESIGNS), help="named designs (see `lenssim designs`)")
    t.add_argument("--designs-file", metavar="FILE", help="TOML file of named designs (added to the built-in ones)")
    t.add_argument("--isos", type=int, nargs="+", default=sorted(isos, reverse=True))
    t.add_argument("--method", default="wiener", help=f"restoration method ({methods})")
    t.add_argument("--angles", type=float, nargs="+", default=list(TABLE_ANGLES_DEG))
    t.add_argument("--crop", type=int, default=192)
    t.add_argument("--seed", type=int, default=0)
    add_device_argument(t)
    t.add_argument("--out", required=True)
    t.set_defaults(func=cmd_psnr_table)
