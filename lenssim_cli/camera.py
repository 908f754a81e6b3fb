"""Camera-pipeline commands: simulate a photo through a design, PSNR tables, the Fig. 8 mosaic.

    lenssim simulate [PHOTO|skimage:NAME] (--design NAME | --s S --Q_back Q) [--iso 100 | --full-well E]
                     [--angles 0 4 8 12] [--crop 256] [--seed 0] [--scheme 512 32 64] [--blur-windows zoned|fitted|full]
                     [--full-frame] --out DIR

writes, for crops centred at the given field angles (along the frame diagonal), the ideal, sensor
and restored images (8-bit sRGB PNG), a mosaic, and ``metrics.json`` (PSNR/SSIM in sRGB per
restoration method); with ``--full-frame`` also the whole sensor and restored frames and
whole-frame metrics (resumable). With ``--as-built SEED`` the image is blurred by one manufactured lens and
restored with the nominal lens's PSFs and with the lens's own (crops, or the whole frame with ``--full-frame``).
Without PHOTO the built-in generated 6000 x 4000 scene is used.
"""

from __future__ import annotations

import math
import sys
import time


from lenssim import AsBuiltPSF, LensPSF, select_device

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from lenssim.io.files import atomic_write_text, json_text
from lenssim_studies.paper import PAPER_FIG8_ANGLES_DEG
from pipeline import RESTORATION_METHODS, write_image
from pipeline.blur import PAPER_SCHEME, WINDOW_ANCHORS
from pipeline.restoration.richardson_lucy import MAX_RL_ITERATIONS
from pipeline.figures import mosaic_figure
from pipeline.denoise import DENOISE_STRENGTH_RANGE
from pipeline.photo import PHOTO_KEEP_BYTES, Photo
from pipeline.simulate import MAP_TILE_PX

from .optics import add_fft_limit_argument
from .lens import (add_lens_arguments, check_lens_arguments, each_lens, lens_label, lens_psf_from_args,
                   note_lens_field)
from .common import (add_camera_arguments, add_design_arguments, add_device_argument, add_tolerance_arguments,
                     camera_from_args, design_from_args, designs, tolerances_from_args)

DEFAULT_ANGLES_DEG = (0.0, 4.0, 8.0, 12.0)
TABLE_ANGLES_DEG = (1.0, 5.0, 9.0)
MIN_CROP_PX = 16
PROGRESS_DELAY_S = 5.0
"""Work that runs longer than this (s) shows a progress bar with its rate and time left on stderr."""
MIN_IMAGE_PX = 32
DEFAULT_ISO = 100
"""The ISO of ``simulate`` when neither ``--iso`` nor ``--full-well`` is given (the paper's lowest)."""


def _check_common(args) -> None:
    """Arguments every camera command checks before any work."""
    if getattr(args, "crop", None) is not None and args.crop < MIN_CROP_PX:
        raise ValueError(f"--crop {args.crop} is not allowed: at least {MIN_CROP_PX} px")
    if getattr(args, "seed", 0) < 0:
        raise ValueError(f"--seed {args.seed} is not allowed: a whole number >= 0")
    for a in getattr(args, "angles", None) or []:
        if not (math.isfinite(a) and a >= 0):
            raise ValueError(f"--angles {a:g} is not allowed: field angles are finite and >= 0 degrees")
    if getattr(args, "at", None) is not None:
        if args.angles is not None:
            raise ValueError("--at and --angles both place the crops; give one")
        args.at_pixels = [_parse_at(v) for v in args.at]
    _, table = chain_from_args(args)
    isos = getattr(args, "isos", None)
    for iso in isos or []:
        _iso_well(table, iso, args)
    if getattr(args, "iso", None) is not None and getattr(args, "full_well", None) is not None:
        raise ValueError(f"--iso {args.iso} and --full-well {args.full_well:g} both set the full well; give one")
    if getattr(args, "iso", None) is not None:
        _iso_well(table, args.iso, args)
    select_device(args.device)


_CHAIN_OPTIONS = ("sensor", "cfa", "demosaic", "exposure_ms", "restore_on", "white_balance", "raw_out")


def add_chain_arguments(p, raw_out: bool = False) -> None:
    """The camera chain's options (issue 31): a sensor preset or file, its CFA, demosaicing, exposure, where to
    restore."""
    from lenssim.io.sensor_file import DEFAULT_SENSOR, sensor_names
    from pipeline.camera_chain import DEFAULT_EXPOSURE_MS, RESTORE_PLACES, WHITE_BALANCE_METHODS
    from pipeline.cfa import CFA_PATTERNS, DEMOSAIC_METHODS

    g = p.add_argument_group("camera chain", "a real sensor and its ISP in place of the paper's photon-noise model "
                             "(any of these options turns it on)")
    g.add_argument("--sensor", metavar="PRESET|FILE.toml",
                   help=f"sensor preset ({', '.join(sensor_names())}; default {DEFAULT_SENSOR}) or a TOML file with a "
                        "[sensor] table: full well per ISO, read noise, dark current, ADC, black/white level, PRNU, "
                        "DSNU, QE, CFA (the optics stay sampled at the lens camera's pixel pitch)")
    g.add_argument("--cfa", choices=("none",) + CFA_PATTERNS, help="Bayer colour filter array (default: the sensor's)")
    g.add_argument("--demosaic", choices=list(DEMOSAIC_METHODS), help="demosaicing method (default Malvar2004)")
    g.add_argument("--exposure-ms", type=float, metavar="MS",
                   help=f"exposure time (ms; sets the dark electrons; default {DEFAULT_EXPOSURE_MS:g})")
    g.add_argument("--restore-on", choices=RESTORE_PLACES,
                   help="restore the demosaicked RGB image (default) or each CFA plane of the mosaic")
    g.add_argument("--white-balance", choices=WHITE_BALANCE_METHODS, help="white-balance gains (default illuminant)")
    if raw_out:
        g.add_argument("--raw-out", action="store_true",
                       help="also write the simulated mosaic as 16-bit DNGs (crop_*_raw.dng; sensor_raw.dng with "
                            "--full-frame): needs a CFA and an ADC (a sensor with bit_depth)")


def chain_from_args(args, optics_sensor=None):
    """The camera chain the options ask for (None: none given, the paper's model) and the sensor whose ISO table sets
    the full wells. Checked before any work: a mosaic restoration or a demosaicing method needs a CFA; ``--raw-out``
    a CFA and an ADC."""
    from dataclasses import replace

    from lenssim.io.sensor_file import DEFAULT_SENSOR, load_sensor
    from pipeline.camera_chain import DEFAULT_EXPOSURE_MS, CameraChain

    if not any(getattr(args, k, None) not in (None, False) for k in _CHAIN_OPTIONS):
        return None, PAPER_CAMERA.sensor if optics_sensor is None else optics_sensor
    sensor = load_sensor(args.sensor or DEFAULT_SENSOR) if args.sensor or optics_sensor is None else optics_sensor
    if args.cfa is not None:
        sensor = replace(sensor, cfa=args.cfa)
    if sensor.cfa == "none" and (args.demosaic or args.restore_on == "mosaic"):
        raise ValueError(f"--{'demosaic' if args.demosaic else 'restore-on mosaic'} needs a colour filter array: give "
                         "--cfa RGGB (or BGGR, GRBG, GBRG) or a --sensor with one")
    if args.exposure_ms is not None and not (math.isfinite(args.exposure_ms) and args.exposure_ms > 0):
        raise ValueError(f"--exposure-ms {args.exposure_ms:g} is not allowed: a finite time > 0 ms")
    if getattr(args, "raw_out", False) and (sensor.cfa == "none" or sensor.bit_depth is None):
        raise ValueError("--raw-out writes a Bayer mosaic in DN: it needs a CFA (--cfa) and an ADC (a --sensor with "
                         "bit_depth, e.g. sony_imx477)")
    chain = CameraChain(sensor, demosaic=args.demosaic or "Malvar2004", restore_on=args.restore_on or "rgb",
                        exposure_ms=DEFAULT_EXPOSURE_MS if args.exposure_ms is None else args.exposure_ms,
                        white_balance=args.white_balance or "illuminant")
    return chain, sensor


def _check_chain_photo(chain, shape, source) -> None:
    if chain is not None and chain.cfa is not None and shape[1] != 3:
        raise ValueError(f"the {chain.cfa} colour filter array samples an RGB photo; {source!r} has {shape[1]} "
                         "channel(s): give an RGB photo or --cfa none")


def _iso_well(sensor, iso, args) -> float:
    """The full well (e-) of ``sensor`` at ``iso``; refused in one line naming the sensor's ISOs."""
    try:
        return sensor.full_well_for_iso(iso)
    except ValueError:
        from lenssim.validate import listed

        where = f" of --sensor {args.sensor}" if getattr(args, "sensor", None) else ""
        raise ValueError(f"ISO {iso} is not allowed: one of {listed(sensor.isos)} (the ISO table{where}; "
                         "or give --full-well)") from None


def _inputs(photos) -> list[str]:
    """The photos that are files (not ``skimage:`` names); a photo given twice is refused (its rows would be
    counted twice in a table's means)."""
    from pathlib import Path

    seen = {}
    for p in photos or ():
        key = p if not p or p.startswith("skimage:") else str(Path(p).resolve())
        if key in seen:
            raise ValueError(f"photo {p!r} is given twice (as {seen[key]!r} too); give each photo once")
        seen[key] = p
    return [p for p in photos if p and not p.startswith("skimage:")]


def _header(spec):
    """A photo file's header, checked before anything else (size, channels; no pixel decoded); None for
    ``skimage:`` names and the generated scene."""
    from pipeline.photo import photo_info

    if not spec or spec.startswith("skimage:"):
        return None
    info = photo_info(spec, "photo")
    _check_size(spec, info.shape)
    return info


def _check_size(source, shape) -> None:
    H, W = shape[-2:]
    if min(H, W) < MIN_IMAGE_PX:
        raise ValueError(f"photo {source!r} is {W} x {H} px: at least {MIN_IMAGE_PX} x {MIN_IMAGE_PX} px")


def _load(spec, device, keep_bytes=None):
    """The photo as a :class:`pipeline.photo.Photo` (every pixel checked, kept in memory if it fits, else read
    region by region), on ``device``, and its description."""
    from lenssim_studies.progress import progress_bar
    from pipeline.photo import PHOTO_KEEP_BYTES, open_photo

    info = _header(spec)
    with progress_bar(total=None if info is None else info.height, unit="row", desc=f"checking {spec}",
                      delay=PROGRESS_DELAY_S, leave=False) as bar:  # shown only for a long check
        photo = open_photo(spec, PAPER_CAMERA, keep_bytes=PHOTO_KEEP_BYTES if keep_bytes is None else keep_bytes,
                           progress=bar.update)
    _check_size(photo.source, photo.shape)
    return photo.to(device), photo.source


def _parse_at(text: str) -> tuple[int, int]:
    """``--at ROW,COL`` -> ``(row, col)`` (whole numbers >= 0; checked against the photo later)."""
    parts = text.split(",")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"--at {text!r} is not allowed: ROW,COL, the crop's centre pixel (whole numbers >= 0, from "
                         "the top-left corner)")
    return int(parts[0]), int(parts[1])


def _check_at(args, shape, source) -> None:
    """Every ``--at`` pixel inside the photo."""
    H, W = shape[-2:]
    for (r, c), text in zip(getattr(args, "at_pixels", None) or [], args.at or []):
        if not (r < H and c < W):
            raise ValueError(f"--at {text} is not allowed: {source!r} is {W} x {H} px (rows 0 to {H - 1}, columns 0 "
                             f"to {W - 1})")


def _angles(args, ideal, size, geometry, preferred, source) -> tuple[float, ...]:
    """``--angles`` as given, or (none given) angles that fit this image: the preferred ones whose crop lies inside
    the frame, else evenly from the axis to the largest that fits; said on stderr."""
    from pipeline.simulate import fitting_angles

    if args.angles is not None:
        return tuple(args.angles)
    chosen = fitting_angles(ideal.shape, size, geometry, preferred)
    if chosen != tuple(preferred):
        H, W = ideal.shape[-2:]
        print(f"crop angles {', '.join(f'{a:g}' for a in chosen)} deg: those that fit {source!r} ({W} x {H} px, "
              f"{size} px crops; give --angles to choose)", file=sys.stderr)
    return chosen


def _window_bar(desc: str):
    """A progress bar of windows computed, shown once the work has run :data:`PROGRESS_DELAY_S`; its total is set by
    ``simulate_crops(..., progress_total=bar.reset)`` before the work starts."""
    from lenssim_studies.progress import progress_bar

    return progress_bar(total=None, unit="window", desc=desc, delay=PROGRESS_DELAY_S, leave=False)


def _check_photo_shape(args, shape, source, psf, method, scheme) -> None:
    """What a photo's size and channels must meet for this run (from its header, before its pixels are read); the
    whole frame's memory planned for the restoration ``method`` in the windows of ``scheme``."""
    if psf.channels not in (1, shape[1]):
        raise ValueError(f"--spectrum {args.spectrum!r} has {psf.channels} colour channels but {source!r} has "
                         f"{shape[1]}: use an RGB image, or --spectrum paper")
    H, W = shape[-2:]
    if args.full_frame:
        if min(H, W) < MAP_TILE_PX:
            raise ValueError(f"--full-frame needs an image of at least {MAP_TILE_PX} x {MAP_TILE_PX} px (one tile of "
                             f"the PSNR map); {source!r} is {W} x {H}: simulate crops instead")
        from lenssim.validate import check_memory
        from pipeline.simulate import frame_memory_bytes

        restored = 1 if args.as_built is None else 2  # --as-built: nominal and calibrated restored frames
        how = f" restored with {method.name}" if method.memory_bytes(shape, scheme) else ""  # what needs more
        check_memory(frame_memory_bytes(shape, restored, method, scheme), f"--full-frame on the {W} x {H} photo "
                     f"{source!r}{how}", _memory_limit(args))
    elif args.denoise:
        from lenssim.validate import check_memory
        from pipeline.denoise import DENOISE_WORKING_COPIES

        check_memory(DENOISE_WORKING_COPIES * 4 * math.prod(shape), f"--denoise on the {W} x {H} photo {source!r}",
                     _memory_limit(args))


def _photo_name(source: str) -> str:
    """A photo as a table names it: its file name (the full path stays in the CSV); other sources as they are."""
    from pathlib import Path

    return source if source.startswith("skimage:") or source.startswith("generated") else Path(source).name


def _crop_size(args, ideal, source) -> int:
    """``--crop``, or the image's smaller side when the image is smaller (said on stderr, not done silently)."""
    size = min(args.crop, *ideal.shape[-2:])
    if size < args.crop:
        print(f"lenssim {args.command}: note: --crop {args.crop} is larger than {source!r} "
              f"({ideal.shape[-1]} x {ideal.shape[-2]} px); crops of {size} px", file=sys.stderr)
    return size


def _memory_limit(args):
    return None if getattr(args, "memory_limit", None) is None else args.memory_limit * 2**30


def _methods(args, scheme):
    """The restorations ``simulate`` runs: ``--restore NAME[:key=value,...] ...`` (default: the adaptive Wiener
    filter; for the whole frame in its bank evaluation, :data:`pipeline.simulate.FRAME_METHOD`), plus ``--rl N``
    (shorthand, kept from 0.1: Richardson-Lucy with N iterations besides them)."""
    from pipeline.restoration import parse_restoration
    from pipeline.simulate import FRAME_METHOD, check_methods

    specs = [parse_restoration(m) for m in (args.restore or [FRAME_METHOD if args.full_frame else "wiener"])]
    if args.rl is not None:
        specs = [r for r in specs if r.name != "richardson_lucy"] + [parse_restoration(f"richardson_lucy:iterations={args.rl}")]
    return check_methods(specs, scheme=scheme)


def cmd_simulate(args) -> int:
    from lenssim.io.files import check_output_dir, staged_output_dir
    from pipeline import crop_at_field_angle, simulate_crops
    from pipeline.blur import WindowScheme
    from pipeline.checks import check_full_well
    from pipeline.colour_space import linear_to_srgb

    # the photo's header, every argument and the output folder are checked before any work, then the photo's pixels
    header = _header(args.photo)
    _check_common(args)
    lens_file = check_lens_arguments(args)
    if lens_file is None:
        design = design_from_args(args)
        camera = camera_from_args(args)
        psf = LensPSF(camera, design, wavefront=args.wavefront)
    else:  # any lens: its PSFs depend on the frame's size (the photo spans the lens's field), known from the header
        design = camera = None
        psf = None if header is None else lens_psf_from_args(args, header.shape)
    built = None
    if args.as_built is not None:
        if args.as_built < 0:
            raise ValueError(f"--as-built {args.as_built} is not allowed: a seed >= 0")
        if args.wavefront != "third_order":
            raise ValueError("--as-built takes the third-order wavefront (the as-built model's), not --wavefront exact")
        tol = tolerances_from_args(args)
        built = AsBuiltPSF(camera, design, tol.sample(1, seed=args.as_built))
    chain, table = chain_from_args(args, None if camera is None else camera.sensor)
    if args.full_well is not None:
        fwc = check_full_well(args.full_well, "--full-well")
    else:
        args.iso = (DEFAULT_ISO if DEFAULT_ISO in table.isos or not table.isos else table.isos[0]) \
            if args.iso is None else args.iso
        fwc = _iso_well(table, args.iso, args)
    scheme = WindowScheme(*args.scheme, anchor=args.window_grid, fit=args.blur_windows in ("zoned", "fitted"))
    if args.rl is not None and not 1 <= args.rl <= MAX_RL_ITERATIONS:  # as richardson_lucy:iterations=N is checked
        raise ValueError(f"--rl {args.rl} is not allowed: a number of Richardson-Lucy iterations from 1 to "
                         f"{MAX_RL_ITERATIONS} (leave --rl out for none)")
    lo, hi = DENOISE_STRENGTH_RANGE
    if args.denoise and not lo <= args.denoise <= hi:
        raise ValueError(f"--denoise {args.denoise:g} is not allowed: a strength from {lo:g} to {hi:g}, or 0 for none")
    specs = _methods(args, scheme)
    methods = tuple(r.name for r in specs)
    if args.full_frame and len(specs) > 1:
        raise ValueError(f"--full-frame restores with one method; {len(specs)} were given ({', '.join(methods)}): "
                         "give one with --restore, or compare methods on crops")
    whole = bool(args.full_frame or args.denoise)  # the whole frame in memory (else crops read what they need)
    inputs = _inputs([args.photo])
    out = check_output_dir(args.out, inputs)
    if header is not None:
        _check_photo_shape(args, header.shape, header.path, psf, specs[0], scheme)
        _check_chain_photo(chain, header.shape, header.path)
        _check_at(args, header.shape, header.path)
    t0 = time.perf_counter()
    # the whole frame (checked against the memory limit above) is decoded once; crops of a photo too large to keep
    # read only the rows or tiles they reach
    ideal, source = _load(args.photo, select_device(args.device), math.inf if whole else None)
    meta = ideal.metadata or {}  # a RAW photo's pattern, levels and white balance, for metrics.json
    if psf is None:
        psf = lens_psf_from_args(args, ideal.shape)
    _check_photo_shape(args, ideal.shape, source, psf, specs[0], scheme)
    _check_chain_photo(chain, ideal.shape, source)
    _check_at(args, ideal.shape, source)
    args.chain = chain
    size = _crop_size(args, ideal, source)
    geometry = psf.geometry
    # the blur's windows: coarser where the blurring lens's PSF varies slowly (--blur-windows zoned)
    args.zones = None
    if args.blur_windows == "zoned":
        from pipeline.blur import choose_stride_zones

        args.zones = choose_stride_zones(psf if built is None else built, ideal.shape, scheme)
        args.zones = None if args.zones.uniform else args.zones
    if getattr(args, "at_pixels", None):  # crops centred at the given pixels (moved inside at the edges)
        from pipeline.simulate import crop_at_pixel

        boxes = [crop_at_pixel(ideal.shape, r, c, size) for r, c in args.at_pixels]
        angles = [round(geometry.box_field_angle(ideal.shape, b), 3) for b in boxes]
    else:
        angles = _angles(args, ideal, size, geometry, DEFAULT_ANGLES_DEG if lens_file is None else
                         _lens_angles(psf), source)
        boxes = [crop_at_field_angle(ideal.shape, a, size, geometry) for a in angles]
    if args.denoise:
        from pipeline import gentle_denoise

        source += f" (gently denoised, strength {args.denoise:g})"
        ideal = Photo.of(gentle_denoise(ideal.load(), args.denoise), source)
    if args.full_frame:
        ideal = ideal.load()
    report = {"source": source, **meta, "iso": args.iso, "full_well_electrons": fwc, "seed": args.seed,
              "scheme_window_stride_core": list(args.scheme), "window_grid": args.window_grid,
              "blur_windows": args.blur_windows, **_zones_report(args),
              "methods": list(methods), "restorations": [r.to_dict() for r in specs], "restored_method": methods[0],
              **_chain_report(chain, _sensor(psf))}
    if lens_file is None:
        params = design.complete().floats()
        report.update({"design": design.name or "custom", "parameters": params, **params,
                       "glass": camera.lens.glass.name, "wavefront": args.wavefront,
                       "spectrum": [c.name for c in camera.channels] if camera.channels else camera.spectrum.name})
        # what the figures' titles say of the optics: the design, and the glass and colour channels where not the
        # paper's
        report["optics"] = ", ".join([design.label()] + ([camera.lens.glass.name] if camera.lens.glass !=
                                                         PAPER_CAMERA.lens.glass or camera.channels else [])
                                     + ([f"{args.spectrum} RGB"] if camera.channels else []))
    else:
        note_lens_field(args, psf)
        report.update(_lens_report(args, psf))
        report["optics"] = ", ".join([report["lens"]["name"]] + ([f"{args.spectrum} RGB"] if psf.colour_channels
                                                                  else []) + [_lens_sampling_words(psf)])
    with staged_output_dir(out) as stage:
        if args.full_frame:
            results = _full_frame(ideal, psf, fwc, args, out, stage, inputs, boxes, report, scheme, specs[0], built)
            if built is not None:  # the crops cut from the frame carry both restorations, as --as-built crops do
                methods = tuple(f"{m}@{tag}" for m in methods for tag in ("nominal", "calibrated"))
        elif built is not None:
            results = _as_built_crops(ideal, psf, built, fwc, boxes, args, specs, scheme, camera, report)
            methods = tuple(f"{m}@{tag}" for m in methods for tag in ("nominal", "calibrated"))
        else:
            with _window_bar("blur + restore crops") as bar:
                results = simulate_crops(ideal, psf, fwc, boxes, seed=args.seed, methods=specs, scheme=scheme,
                                         blur_zones=args.zones,
                                         sensor=chain or _sensor(psf), progress=bar.update, progress_total=bar.reset)
        report["crops"] = []
        for i, (a, r) in enumerate(zip(angles, results)):
            asked = {"requested_deg": a} if not getattr(args, "at_pixels", None) else \
                {"requested_at_row_col": list(args.at_pixels[i])}
            tag = _crop_tag({**asked, "field_deg": round(r.field_deg, 3)})
            for kind in ("ideal", "sensor") + methods:
                if kind in r.images:
                    write_image(stage / f"{tag}_{_file_kind(kind)}.png", linear_to_srgb(r.images[kind].clamp(0, 1)))
            if getattr(args, "raw_out", False):
                _write_raw(stage / f"{tag}_raw.dng", r.images["raw"], chain, r.box[0], r.box[2])
            report["crops"].append({**asked, "field_deg": round(r.field_deg, 3),
                                    "box_r0_r1_c0_c1": list(r.box), "scores": r.scores,
                                    "psnr_sensor_db": r.scores["sensor"]["psnr_db"],
                                    "psnr_restored_db": r.scores[methods[0]]["psnr_db"],
                                    **({"psnr_restored_calibrated_db": r.scores[methods[1]]["psnr_db"]}
                                       if built is not None else {})})
        title = f"{source}: {report['optics']}, " + (f"ISO {args.iso}, " if args.iso else "") + f"{fwc:g} e- full well" \
            + ("" if chain is None else f"; {chain.label()}")
        shown = [m for m in methods if m in results[0].images]
        mosaic_figure(results, shown, stage / "mosaic.png", title=title)
        atomic_write_text(stage / "metrics.json", json_text(report))
        _index_page(stage, title, report, results, shown)
    print(f"{source}, {report['optics']}, " + (f"ISO {args.iso} " if args.iso else "") + f"({fwc:g} e- full well):")
    print("  field [deg]   PSNR [dB] / SSIM: sensor -> " + ", ".join(_kind_label(m) for m in methods))
    for c in report["crops"]:
        sc = c["scores"]
        restored = ", ".join(f"{sc[m]['psnr_db']:.2f} / {sc[m]['ssim']:.3f}" for m in methods if m in sc)
        print(f"  {c['field_deg']:10.2f}   {sc['sensor']['psnr_db']:.2f} / {sc['sensor']['ssim']:.3f} -> {restored}")
    print(f"wrote {out}/ (index.html, crop PNGs, mosaic.png, metrics.json) in {time.perf_counter() - t0:.0f} s",
          file=sys.stderr)
    return 0


def _zones_report(args) -> dict:
    """The blur's stride zones for metrics.json (absent at the scheme's stride everywhere)."""
    from pipeline.blur import BLUR_ZONE_TOL_DB

    z = getattr(args, "zones", None)
    return {} if z is None else {"blur_zones": {**z.to_dict(), "tolerance_db": BLUR_ZONE_TOL_DB}}


def _crop_tag(entry: dict) -> str:
    """A crop's file-name stem from its metrics entry: by the angle asked (``--angles``) or the pixel (``--at``); a crop
    moved inside the frame by more than :data:`pipeline.simulate.CROP_SHIFT_WARN_DEG` names where it went too."""
    from pipeline.simulate import CROP_SHIFT_WARN_DEG

    if "requested_at_row_col" in entry:
        r, c = entry["requested_at_row_col"]
        return f"crop_r{r}_c{c}"
    asked, field = entry["requested_deg"], entry["field_deg"]
    return f"crop_{asked:g}deg" + (f"_moved_to_{field:.2f}deg" if abs(field - asked) > CROP_SHIFT_WARN_DEG else "")


def _index_page(stage, title, report, results, methods) -> None:
    """``index.html``: the mosaic, the scores of every crop, the whole-frame results; self-contained."""
    from lenssim_studies import html

    header = ["field [deg]", "box (r0, r1, c0, c1)", "sensor PSNR [dB] / SSIM"] + \
        [f"{_kind_label(m)} PSNR [dB] / SSIM" for m in methods]
    fmt = lambda sc: "identical" if sc is None else f"{sc['psnr_db']:.2f} / {sc['ssim']:.3f}"  # noqa: E731
    rows = [[f"{r.field_deg:.2f}", str(r.box), fmt(r.scores["sensor"])] + [fmt(r.scores.get(m)) for m in methods]
            for r in results]
    body = [html.image(stage / "mosaic.png", "Crops across the field: ideal, sensor image and restorations "
                       "(PSNR / SSIM in sRGB against the ideal image)"),
            "<h2>Scores</h2>", html.table(header, rows)]
    for r, c in zip(results, report["crops"]):
        tag = _crop_tag(c)
        body.append(f"<h2>Crop at {r.field_deg:.2f} deg</h2>")
        label = lambda k: "ideal (the reference)" if k == "ideal" else (  # noqa: E731
            f"{_kind_label(k)}: {fmt(r.scores.get(k))}")
        body.append(html.row([html.image(stage / f"{tag}_{_file_kind(k)}.png", label(k))
                              for k in ("ideal", "sensor", *methods) if (stage / f"{tag}_{_file_kind(k)}.png").exists()]))
    if "full_frame" in report:
        f = report["full_frame"]
        body += ["<h2>Whole frame</h2>",
                 html.table(["image", "PSNR [dB]", "SSIM"], _frame_rows(f))]
        if (stage / "field_psnr.png").exists():
            body.append(html.image(stage / "field_psnr.png", "PSNR per 256-px tile and against field angle"))
    html.write_page(stage / "index.html", title, body, note="lenssim simulate; numbers also in metrics.json")


def _kind_label(kind: str) -> str:
    """A restoration's label; ``METHOD@nominal`` / ``METHOD@calibrated`` (``--as-built``) say whose PSFs it used."""
    base, _, tag = kind.partition("@")
    label = RESTORATION_METHODS[base].label if base in RESTORATION_METHODS else base
    return {"nominal": f"{label} (nominal PSFs)", "calibrated": f"{label} (the lens's own PSFs)"}.get(tag, label)


def _as_built_crops(ideal, nominal, built, fwc, boxes, args, specs, scheme, camera, report):
    """``simulate --as-built``: the crops blurred by the as-built lens (the same noise for both), restored with the
    nominal lens's PSFs (``METHOD@nominal``) and with the lens's own (``METHOD@calibrated``)."""
    from pipeline import simulate_crops

    runs = {tag: simulate_crops(ideal, built, fwc, boxes, seed=args.seed, methods=specs, scheme=scheme,
                                blur_zones=args.zones,
                                sensor=args.chain or camera.sensor, restoration_psf=prov)
            for tag, prov in (("nominal", nominal), ("calibrated", built))}
    results = runs["nominal"]
    for r, c in zip(results, runs["calibrated"]):
        for m in [s.name for s in specs]:
            r.images[f"{m}@nominal"], r.scores[f"{m}@nominal"] = r.images.pop(m), r.scores.pop(m)
            r.images[f"{m}@calibrated"], r.scores[f"{m}@calibrated"] = c.images[m], c.scores[m]
    report["as_built"] = _as_built_report(built, args.as_built)
    return results


def _file_kind(kind: str) -> str:
    """File-name part of an image kind: ideal, sensor, restored (Wiener), restored_rl, restored_METHOD
    (``_nominal`` / ``_calibrated`` after it for ``--as-built``)."""
    base, _, tag = kind.partition("@")
    if tag:
        return f"{_file_kind(base)}_{tag}"
    return {"wiener": "restored", "richardson_lucy": "restored_rl"}.get(kind, kind if kind in ("ideal", "sensor")
                                                                        else f"restored_{kind}")


def _chain_columns(chain) -> dict:
    """A table row's description of the camera chain (pattern and method by name, where restored); none without."""
    if chain is None:
        return {}
    return {"sensor": chain.sensor.name or "custom", "cfa": chain.cfa or "none",
            "demosaic": chain.demosaic if chain.cfa else "", "restore_on": chain.restore_on}


def _chain_report(chain, optics_sensor) -> dict:
    """``metrics.json``'s ``camera_chain``: the chain by its names (pattern, demosaicing, where restored, stages), or
    nothing for the paper's model."""
    if chain is None:
        return {}
    d = chain.to_dict()
    d["label"] = chain.label()
    d["optics_pixel_pitch_um"] = optics_sensor.pixel_pitch_um
    if abs(chain.sensor.pixel_pitch_um - optics_sensor.pixel_pitch_um) > 0.05 * optics_sensor.pixel_pitch_um:
        print(f"note: the sensor's pixel pitch ({chain.sensor.pixel_pitch_um:g} um) is not the optics' sampling "
              f"({optics_sensor.pixel_pitch_um:g} um): its noise and ADC apply per simulated pixel", file=sys.stderr)
    return {"camera_chain": d}


def _write_raw(path, raw, chain, row, col) -> None:
    """The raw mosaic (DN) whose top-left pixel is the frame's ``(row, col)`` as a DNG with the chain's pattern there,
    levels and white balance."""
    from pipeline.camera_chain import pattern_at
    from pipeline.dng import write_dng

    s = chain.sensor
    qe = s.qe(3)
    write_dng(path, raw.to("cpu"), pattern_at(chain.cfa, row, col), black_level=s.black_level_dn,
              white_level=s.white_level, as_shot_neutral=tuple(q / max(qe) for q in qe),
              color_matrix=chain.xyz_to_camera())


def _sensor(psf):
    """The sensor a provider's PSFs are sampled on (the paper's camera's, or any lens's own)."""
    return psf.sensor if hasattr(psf, "sensor") else psf.camera.sensor


def _lens_angles(psf) -> tuple[float, ...]:
    """``simulate --lens``'s crop angles: the axis and three more up to 90% of the frame corner's field angle."""
    top = 0.9 * psf.max_field_deg
    return tuple(round(top * k / 3, 2) for k in range(4))


def _lens_report(args, psf) -> dict:
    """``metrics.json``'s description of ``--lens``: the lens, its focus, the sensor it is sampled on, the light, and
    the wavefront table's nodes and interpolation error."""
    seq = psf.lens
    p = seq.prescription
    par = seq.paraxial()
    table = psf.table(progress=None)
    lams, weights = psf.spectrum()
    return {"lens": {"name": p.name or str(args.lens), "file": str(args.lens), "source": p.source,
                     "efl_mm": par.efl_mm, "f_number": par.f_number, "working_f_number": par.working_f_number,
                     "refocus": args.refocus or "file", "image_shift_mm": seq.image_shift_mm,
                     "image_scale_mm": psf.image_scale_mm, "pixel_pitch_um": psf.sensor.pixel_pitch_um,
                     "pixel_pitch_from": "--pixel-pitch" if args.pixel_pitch is not None else
                     "the photo spanning the lens's largest field (its corners and the blur's margin beyond them)",
                     "corner_field_deg": psf.geometry.max_field_angle_deg((psf.sensor.height_px, psf.sensor.width_px)),
                     "psf_field_deg": psf.max_field_deg, "lens_field_deg": max(p.fields), "psf_sampling": psf.sampling,
                     "samples_per_pixel": psf.oversample(),
                     "wavefront_table_angles_deg": [round(float(a), 6) for a in table.angles_deg],
                     "wavefront_table_error_waves": table.interpolation_error_waves},
            "wavefront": "real rays (sequential ray trace)",
            "spectrum": [c.name for c in psf.colour_channels] if psf.colour_channels else psf.light.name,
            "wavelengths_um": list(lams), "wavelength_weights": list(weights)}


def _lens_sampling_words(psf) -> str:
    """What a figure's title says of the sensor a lens's photo is taken on: the pixel pitch and the corners' field."""
    corner = psf.geometry.max_field_angle_deg((psf.sensor.height_px, psf.sensor.width_px))
    return f"{psf.sensor.pixel_pitch_um:.3g} um pixels, corners at {corner:.3g} deg"


def _full_frame(ideal, psf, fwc, args, out, stage, inputs, boxes, report, scheme, method, built=None):
    """``simulate --full-frame``: the whole frame (resumable from ``out/.checkpoint``), whole-frame metrics,
    crops cut from it; files go to ``stage``. With ``built`` (``--as-built``): blurred once by that lens, the same
    noisy frame restored with the nominal lens's PSFs (``restored_nominal``) and with the lens's own
    (``restored_calibrated``); the checkpoint's stamp holds the lens, so no other lens's sensor image is resumed."""
    import shutil

    from lenssim_studies.progress import progress_bar
    from pipeline.blur import window_count
    from pipeline.field_map import plot_field_psnr
    from pipeline.simulate import crops_from_frame, score_frame, simulate_frame

    blur, restorers = (psf, None) if built is None else (built, {"nominal": psf, "calibrated": built})
    n = window_count(ideal.shape, scheme)
    checkpoint = out / ".checkpoint"
    passes = 1 if restorers is None else len(restorers)
    total = passes * n + window_count(ideal.shape, scheme, zones=args.zones)
    with progress_bar(total=total, unit="window", desc="blur + restore") as bar:
        frame = simulate_frame(ideal, blur, fwc, seed=args.seed, scheme=scheme, progress=bar.update, blur_zones=args.zones,
                               checkpoint=checkpoint, sensor=args.chain or _sensor(psf), method=method,
                               restoration_psf=restorers)
    if getattr(args, "raw_out", False):
        _write_raw(stage / "sensor_raw.dng", frame.raw, args.chain, 0, 0)
    if frame.resumed:
        print(f"resumed from the sensor image in {checkpoint}/", file=sys.stderr)
    def write(kind, enc, img):  # each image is sRGB-encoded once, for its PNG and for all its scores
        write_image(stage / f"{kind}.png", enc.cpu(), bits=args.bits)
        if args.exr:
            write_image(stage / f"{kind}_linear.exr", img, bits="float")

    scores = score_frame(ideal, frame, psf.geometry, tile=MAP_TILE_PX, on_encoded=write)
    frame.seconds.update(scores.pop("seconds"))
    t0 = time.perf_counter()
    maps = scores.pop("maps")
    report["full_frame"] = {
        "shape_c_h_w": list(ideal.shape[1:]), "windows_per_pass": n, "electrons_per_unit": frame.electrons_per_unit,
        "method": frame.method, **scores, "resumed": frame.resumed}
    labels = {}
    if built is not None:
        report["full_frame"]["restorations"] = {"restored_nominal": "the nominal design's PSFs",
                                                "restored_calibrated": "the as-built lens's own PSFs"}
        report["as_built"] = _as_built_report(built, args.as_built)
        labels = {"restored_nominal": "restored, nominal PSFs", "restored_calibrated": "restored, the lens's own PSFs"}
    plot_field_psnr(maps, stage / "field_psnr.png", labels=labels,
                    title=f"{report['source']}: {report['optics']}, {fwc:g} e- full well"
                          + (f", as built (seed {args.as_built})" if built is not None else ""))
    report["full_frame"]["field_psnr_256px_tiles"] = {  # JSON has no inf: identical tiles are null
        k: [[round(x, 3) if math.isfinite(x) else None for x in row] for row in v.tolist()] for k, v in maps.items()}
    frame.seconds["metrics"] += time.perf_counter() - t0
    report["full_frame"]["seconds"] = {k: round(v, 2) for k, v in frame.seconds.items()}
    shutil.rmtree(checkpoint, ignore_errors=True)  # done: the checkpoint is no longer needed
    f = report["full_frame"]
    if built is None:
        print(f"whole frame: PSNR sensor {f['psnr_sensor_db']:.2f} dB -> restored {f['psnr_restored_db']:.2f} dB, "
              f"SSIM {f['ssim_sensor']:.3f} -> {f['ssim_restored']:.3f}")
    else:
        kinds = [k for k in frame.restored_images()]
        print(f"whole frame: PSNR sensor {f['psnr_sensor_db']:.2f} dB -> "
              + ", ".join(f"{_frame_label(f, k)} {f[f'psnr_{k}_db']:.2f} dB" for k in kinds)
              + f"; SSIM {f['ssim_sensor']:.3f} -> " + ", ".join(f"{f[f'ssim_{k}']:.3f}" for k in kinds))
    return crops_from_frame(ideal, frame, boxes, psf.geometry)


def _frame_label(f: dict, kind: str) -> str:
    """The label of a whole-frame image kind (``sensor``, ``restored``, ``restored_TAG``) of ``report["full_frame"]``
    ``f``."""
    if kind in ("sensor", "restored"):
        return kind
    return "restored, " + _kind_label(f"{f['method']}@{kind.removeprefix('restored_')}")


def _frame_rows(f: dict) -> list[list[str]]:
    """The index page's whole-frame table: image, PSNR, SSIM for the sensor image and every restored frame."""
    kinds = [k[len("psnr_"):-len("_db")] for k in f if k.startswith("psnr_") and k.endswith("_db")]
    return [[_frame_label(f, k), f"{f[f'psnr_{k}_db']:.2f}", f"{f[f'ssim_{k}']:.3f}"] for k in kinds]


def _as_built_report(built, seed) -> dict:
    """``metrics.json``'s ``as_built`` block: the seed, the tolerances and the sampled lens's errors (with units)."""
    lens = built.lens
    return {"seed": seed, "tolerances": lens.tolerances.to_dict(),
            "errors": {k: round(float(v[0]), 6) for k, (v, _) in lens.variables().items()},
            "units": {k: u for k, (_, u) in lens.variables().items()}}


def _method_columns(names, mean, chain, angles) -> dict:
    """A psnr-table row's method, chain and score columns: the first method's ``psnr_restored_db`` and
    ``ssim_restored`` (the table's columns with one method), and with several methods ``psnr_NAME_db`` and
    ``ssim_NAME`` of each."""
    out = {"method": " ".join(names), **_chain_columns(chain), "angles_deg": " ".join(f"{a:g}" for a in angles),
           "psnr_sensor_db": mean("sensor", "psnr_db"), "psnr_restored_db": mean(names[0], "psnr_db"),
           "ssim_restored": mean(names[0], "ssim")}
    if len(names) > 1:
        for m in names:
            out[f"psnr_{m}_db"], out[f"ssim_{m}"] = mean(m, "psnr_db"), mean(m, "ssim")
    return out


def cmd_psnr_table(args) -> int:
    from lenssim.io.files import check_output_dir, staged_output_dir
    from pipeline import crop_at_field_angle, simulate_crops

    photos = args.photos or [None]
    chain, table = chain_from_args(args)
    if args.isos is None:  # the sensor's ISOs, highest first
        args.isos = sorted(table.isos, reverse=True)
    for photo in photos:  # every photo's header first, then the designs and options, the output, every photo's pixels
        info = _header(photo)
        if info is not None:
            _check_chain_photo(chain, info.shape, photo)
    _check_common(args)
    lenses = each_lens(args)
    if args.designs is None:  # the paper's designs, unless only lenses are asked for
        args.designs = [] if lenses else list(PAPER_DESIGNS)
    from lenssim.validate import listed, quoted

    named = designs(args.designs_file)
    for d in args.designs:
        if d not in named:
            raise ValueError(f"design {quoted(d)} is not known; choose from {listed(sorted(named), near=[d])}")
    camera = PAPER_CAMERA
    wells = [_iso_well(table, i, args) for i in args.isos]
    from pipeline.restoration import parse_restoration
    from pipeline.simulate import check_methods

    specs = check_methods([parse_restoration(m) for m in ([args.method] if args.method else args.restore)],
                          scheme=PAPER_SCHEME)  # the windows psnr-table restores in
    if args.method is not None:  # after the check: an error stays one line
        print("note: --method is the former name of --restore", file=sys.stderr)
    spec, names = specs[0], [r.name for r in specs]
    method = spec.name
    lens = None
    if args.as_built is not None:
        if args.as_built < 0:
            raise ValueError(f"--as-built {args.as_built} is not allowed: a seed >= 0")
        if len(specs) > 1:
            raise ValueError(f"--as-built compares the nominal and the lens's own PSFs with one restoration; "
                             f"{len(specs)} were given ({', '.join(names)}): give one with --restore")
        lens = tolerances_from_args(args).sample(1, seed=args.as_built)
    out = check_output_dir(args.out, _inputs(photos))
    rows = []
    t0 = time.perf_counter()
    opened, kept = [], 0
    for photo in photos:  # all checked before the first computation; kept in memory while they fit together
        ideal, source = _load(photo, select_device(args.device), max(PHOTO_KEEP_BYTES - kept, 0))
        _check_chain_photo(chain, ideal.shape, source)
        kept += ideal.nbytes() if ideal.in_memory else 0
        opened.append((ideal, source))
    plans = []
    for ideal, source in opened:  # every crop of every photo and lens placed (or refused) before the first simulation
        size = _crop_size(args, ideal, source)
        angles = boxes = None
        if args.designs:  # the paper's camera's crops
            angles = _angles(args, ideal, size, camera.geometry, TABLE_ANGLES_DEG, source)
            boxes = [crop_at_field_angle(ideal.shape, a, size, camera.geometry) for a in angles]
        lens_jobs = []
        for ns in lenses:  # any lens: the photo spans its field (or --pixel-pitch), its own crop angles
            ns.scheme = (PAPER_SCHEME.window, PAPER_SCHEME.stride, PAPER_SCHEME.core)  # the windows psnr-table uses
            psf = lens_psf_from_args(ns, ideal.shape)
            lens_angles = _angles(args, ideal, size, psf.geometry, _lens_angles(psf), source)
            lens_jobs.append((ns, psf, lens_angles,
                              [crop_at_field_angle(ideal.shape, a, size, psf.geometry) for a in lens_angles]))
        plans.append((ideal, source, angles, boxes, lens_jobs))
    for _, _, _, _, lens_jobs in plans:  # every crop placed: the sensors the lenses' photos are taken on
        for ns, psf, _, _ in lens_jobs:
            note_lens_field(ns, psf)
    for ideal, source, angles, boxes, lens_jobs in plans:
        for name in args.designs:
            d = named[name]
            nominal = LensPSF(camera, d)
            blur = nominal if lens is None else AsBuiltPSF(camera, d, lens)
            with _window_bar(f"{source} | {name}") as bar:
                per_iso = simulate_crops(ideal, blur, wells, boxes, seed=args.seed, methods=specs,
                                         sensor=chain or camera.sensor, restoration_psf=nominal, progress=bar.update,
                                         progress_total=bar.reset, blur_zones="auto")
            calibrated = None if lens is None else simulate_crops(ideal, blur, wells, boxes, seed=args.seed,
                                                                  methods=(spec,), sensor=chain or camera.sensor,
                                                                  blur_zones="auto")
            for j, (iso, res) in enumerate(zip(args.isos, per_iso)):
                mean = lambda kind, key, res=res: sum(r.scores[kind][key] for r in res) / len(res)  # noqa: E731
                rows.append({"photo": source, "design": name, **d.complete().floats(), "iso": iso,
                             **_method_columns(names, mean, chain, angles)})
                if calibrated is not None:  # the lens restored with its own PSFs; the columns above: nominal PSFs
                    cal = calibrated[j]
                    rows[-1].update({"as_built_seed": args.as_built,
                                     "psnr_restored_calibrated_db": sum(r.scores[method]["psnr_db"] for r in cal) / len(cal),
                                     "ssim_restored_calibrated": sum(r.scores[method]["ssim"] for r in cal) / len(cal)})
                print(f"{source} | {name} | ISO {iso}: restored {rows[-1]['psnr_restored_db']:.2f} dB", file=sys.stderr)
        for ns, psf, angles, boxes in lens_jobs:
            name = lens_label(ns)
            with _window_bar(f"{source} | {name}") as bar:
                per_iso = simulate_crops(ideal, psf, wells, boxes, seed=args.seed, methods=specs,
                                         sensor=chain or psf.sensor, progress=bar.update, progress_total=bar.reset,
                                         blur_zones="auto")
            for iso, res in zip(args.isos, per_iso):
                mean = lambda kind, key, res=res: sum(r.scores[kind][key] for r in res) / len(res)  # noqa: E731
                rows.append({"photo": source, "design": name, "lens_file": ns.lens,
                             "pixel_pitch_um": round(psf.sensor.pixel_pitch_um, 6), "iso": iso,
                             **_method_columns(names, mean, chain, angles)})
                print(f"{source} | {name} | ISO {iso}: restored {rows[-1]['psnr_restored_db']:.2f} dB", file=sys.stderr)
    for r in rows:
        for k in ("psnr_sensor_db", "psnr_restored_db", "ssim_restored", "psnr_restored_calibrated_db",
                  "ssim_restored_calibrated", *(f"{q}_{m}{u}" for m in names for q, u in (("psnr", "_db"), ("ssim", "")))):
            if k in r and not math.isfinite(r[k]):
                raise ValueError(f"{k} of {r['photo']} / {r['design']} / ISO {r['iso']} is not finite (identical "
                                 "images?): not written")
    keys = list(dict.fromkeys(k for r in rows for k in r))
    import csv as csv_module
    import io

    buf = io.StringIO()  # quoted where a field holds a comma (a sensor's name, a photo's path)
    csv_module.writer(buf, lineterminator="\n").writerows([keys] + [[r.get(k, "") for k in keys] for r in rows])
    where = (f"at {', '.join(f'{a:g}' for a in args.angles)} deg" if args.angles is not None
             else "at the angles that fit each photo (column angles_deg of the CSV)")
    label = lambda r: r.method.label + (f" ({', '.join(f'{k}={v}' for k, v in r.options.items())})"  # noqa: E731
                                        if r.options else "")
    if len(specs) == 1:
        head = "| PSNR restored [dB] | SSIM restored |"
        cells = lambda r: f" {r['psnr_restored_db']:.2f} | {r['ssim_restored']:.3f} |"  # noqa: E731
    else:  # a column per method
        head = "".join(f"| PSNR {m} [dB] " for m in names) + "".join(f"| SSIM {m} " for m in names) + "|"
        cells = lambda r: ("".join(f" {r[f'psnr_{m}_db']:.2f} |" for m in names)  # noqa: E731
                           + "".join(f" {r[f'ssim_{m}']:.3f} |" for m in names))
    worse = [(r, m) for r in rows for m in names
             if r[f"psnr_{m}_db" if len(specs) > 1 else "psnr_restored_db"] < r["psnr_sensor_db"]]
    md = (f"Mean over crops {where} ({args.crop} px), sRGB PSNR/SSIM vs the "
          f"ideal image; restoration: {'; '.join(label(r) for r in specs)}.\n\n"
          + (f"One manufactured lens per design (--as-built {args.as_built}): restored with the nominal PSFs and with "
             "the lens's own (calibrated).\n\n" if lens is not None else "")
          + (f"Camera chain: {chain.label()}.\n\n" if chain is not None else "")
          + ("| photo | design | ISO | PSNR sensor [dB] " + head
             + (" PSNR calibrated [dB] | SSIM calibrated |" if lens is not None else "")
             + "\n|---|---|---|---|" + "---|" * (2 * len(specs)) + ("---|---|" if lens is not None else "") + "\n")
          + "".join(f"| {_photo_name(r['photo'])} | {r['design']} | {r['iso']} | {r['psnr_sensor_db']:.2f} |" + cells(r)
                    + (f" {r['psnr_restored_calibrated_db']:.2f} | {r['ssim_restored_calibrated']:.3f} |" if lens is not None
                       else "") + "\n" for r in rows)
          + ("".join(f"\nNote: {m} restored {_photo_name(r['photo'])} / {r['design']} / ISO {r['iso']} below its sensor "
                     f"image ({r[f'psnr_{m}_db' if len(specs) > 1 else 'psnr_restored_db']:.2f} dB against "
                     f"{r['psnr_sensor_db']:.2f} dB)." for r, m in worse) + "\n" if worse else ""))
    with staged_output_dir(out) as stage:
        for name, text in (("psnr_table.csv", buf.getvalue()), ("psnr_table.md", md)):
            atomic_write_text(stage / name, text)
    print(md)
    print(f"wrote {out}/psnr_table.csv and psnr_table.md in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def cmd_fig8(args) -> int:
    from lenssim.io.files import check_output_dir, staged_output_dir
    from lenssim_studies.figure8 import figure8, lens_mosaic

    from pipeline.restoration import parse_restoration

    _header(args.photo)
    _check_common(args)
    lens_file = check_lens_arguments(args)
    spec = parse_restoration(args.restore)
    spec.check(PAPER_SCHEME)  # the windows fig8 restores in
    chain, _ = chain_from_args(args)
    info = _header(args.photo)
    if info is not None:
        _check_chain_photo(chain, info.shape, args.photo)
    out = check_output_dir(args.out, _inputs([args.photo]))
    ideal, source = _load(args.photo, select_device(args.device))
    _check_chain_photo(chain, ideal.shape, source)
    size = _crop_size(args, ideal, source)
    psf = None
    if lens_file is None:
        geometry, preferred = PAPER_CAMERA.geometry, PAPER_FIG8_ANGLES_DEG
    else:  # any lens: the photo spans its field (or --pixel-pitch), its own crop angles
        args.scheme = (PAPER_SCHEME.window, PAPER_SCHEME.stride, PAPER_SCHEME.core)
        psf = lens_psf_from_args(args, ideal.shape)
        geometry, preferred = psf.geometry, _lens_angles(psf)
    angles = _angles(args, ideal, size, geometry, preferred, source)
    for a in angles:  # every crop fits the image, before any work
        from pipeline import crop_at_field_angle

        crop_at_field_angle(ideal.shape, a, size, geometry)
    if psf is not None:
        note_lens_field(args, psf)
    t0 = time.perf_counter()
    with staged_output_dir(out) as stage:
        if psf is None:
            png, tiles = figure8(ideal, stage, angles=angles, crop=size, seed=args.seed, method=spec, chain=chain)
        else:
            png, tiles = lens_mosaic(ideal, stage, psf, lens_file.name or lens_label(args), about=_lens_sampling_words(psf),
                                     angles=angles, crop=size,
                                     seed=args.seed, method=spec, sensor=chain)
        atomic_write_text(stage / "fig8_psnr.json", json_text({"source": source, "tiles": tiles,
                                                               **_chain_report(chain, PAPER_CAMERA.sensor)}))
    print(f"wrote {out / png.name} (+ .svg, fig8_psnr.json) from {source} in {time.perf_counter() - t0:.0f} s")
    return 0


def register(sub) -> None:
    isos = camera_isos = PAPER_CAMERA.sensor.isos
    methods = ", ".join(RESTORATION_METHODS)
    p = sub.add_parser("simulate", help="photo -> sensor image -> restored image, at crops across the field")
    p.add_argument("photo", nargs="?", help="image file (JPEG/PNG/TIFF/EXR) or skimage:NAME; default: generated scene")
    add_design_arguments(p)
    add_camera_arguments(p)
    add_lens_arguments(p)
    add_fft_limit_argument(p)  # --lens: a lens whose PSF needs more is refused before any work
    p.add_argument("--iso", type=int, help="one of " + ", ".join(
        f"{i} ({PAPER_CAMERA.sensor.full_well_for_iso(i):g} e- full well)" for i in camera_isos)
        + f" (default {DEFAULT_ISO})")
    p.add_argument("--full-well", type=float, metavar="E", help="any full-well capacity (electrons) instead of --iso")
    p.add_argument("--scheme", type=int, nargs=3, default=[512, 32, 64], metavar=("WINDOW", "STRIDE", "CORE"),
                   help="local-convolution windows (px): window, stride, blended core (paper: 512 32 64); a window "
                        "grows where its PSF and core do not fit")
    p.add_argument("--window-grid", choices=WINDOW_ANCHORS, default=PAPER_SCHEME.anchor,
                   help="where the windows lie: 'axis' (symmetric about the optical axis, one PSF per mirror group "
                        "of up to 8 windows; default) or 'origin' (from pixel 0, the first version's grid)")
    p.add_argument("--blur-windows", choices=("zoned", "fitted", "full"), default="zoned",
                   help="'zoned' (default): fitted, and twice the stride and core where the PSF varies slowly enough "
                        "(an estimated interpolation error of at most -55 dB for the paper's image model; the blurred "
                        "frame 75+ dB from the stride's everywhere, docs/performance.md); 'fitted': each window's "
                        "transform sized to the local PSF's support plus the core (the same result to 1e-4 of the "
                        "signal at a fraction of the cost) at the scheme's stride everywhere; 'full': every window "
                        "WINDOW px (the paper's transforms). The Wiener restoration's windows are fitted likewise "
                        "(except with 'full'); its stride is always the scheme's")
    p.add_argument("--angles", type=float, nargs="+", default=None,
                   help=f"crop field angles (deg); default {' '.join(f'{a:g}' for a in DEFAULT_ANGLES_DEG)}, those of them "
                        "that fit the photo (else evenly from the axis to the largest that fits)")
    p.add_argument("--at", nargs="+", metavar="ROW,COL",
                   help="instead of --angles: crops centred at these pixels (from the photo's top-left corner; a crop "
                        "that would cross an edge is moved inside)")
    p.add_argument("--crop", type=int, default=256, help="crop size (px)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--denoise", type=float, default=0.0, metavar="STRENGTH",
                   help="gently denoise the photo first (wavelet, strength in (0, 2]; off by default, as a paper option)")
    p.add_argument("--restore", nargs="+", metavar="NAME[:KEY=VALUE,...]",
                   help=f"restoration methods to run, each with its options ({methods}; default: wiener; for "
                        "--full-frame wiener:bank=3, the same filter evaluated in less work and nearer its fine "
                        "limit, docs/performance.md), e.g. --restore wiener tikhonov:weight=0.003 "
                        "richardson_lucy:iterations=30; --full-frame takes one")
    p.add_argument("--rl", type=int, default=None, metavar="N",
                   help="shorthand: also restore with N (1 to %d) iterations of windowed Richardson-Lucy (slow)"
                        % MAX_RL_ITERATIONS)
    p.add_argument("--full-frame", action="store_true",
                   help="simulate the whole frame (sensor.png, restored.png, whole-frame PSNR/SSIM; ~1.5 min at 24 MP on "
                        "2 CPU cores; resumes after an interruption) instead of crops only")
    p.add_argument("--as-built", type=int, metavar="SEED",
                   help="render through one manufactured lens (drawn from --grade/--tolerances with SEED) and restore "
                        "with the nominal lens's PSFs and with the lens's own (calibrated), from the same noisy image; "
                        "crops, or with --full-frame the whole frame (restored_nominal.png, restored_calibrated.png)")
    add_tolerance_arguments(p)
    add_chain_arguments(p, raw_out=True)
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="--full-frame PNG bit depth (sRGB)")
    p.add_argument("--exr", action="store_true", help="--full-frame: also write linear float EXRs")
    p.add_argument("--memory-limit", type=float, metavar="GIB",
                   help="memory a --full-frame run may plan to use (default: 80%% of the available memory)")
    add_device_argument(p)
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=cmd_simulate)

    f = sub.add_parser("fig8", help="Fig. 8-style mosaic: two designs x three ISOs at crops across the field (with "
                       "--lens: any lens's sensor image and restorations, lens_mosaic.png)")
    f.add_argument("photo", nargs="?", help="image file or skimage:NAME; default: the generated scene")
    f.add_argument("--angles", type=float, nargs="+", default=None,
                   help="crop field angles (deg); default the paper's Fig. 8 angles that fit the photo")
    f.add_argument("--crop", type=int, default=128)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--restore", default="wiener", metavar="NAME[:KEY=VALUE,...]",
                   help=f"restoration method and its options ({methods}; default: wiener)")
    add_lens_arguments(f)
    add_fft_limit_argument(f)  # --lens: a lens whose PSF needs more is refused before any work
    add_chain_arguments(f)
    add_device_argument(f)
    f.add_argument("--out", required=True)
    f.set_defaults(func=cmd_fig8)

    t = sub.add_parser("psnr-table", help="PSNR of restored images: photos x designs x ISOs (CSV + Markdown)")
    t.add_argument("photos", nargs="*", help="image files or skimage:NAME; default: the generated scene")
    t.add_argument("--designs", nargs="+", default=None, help="named designs (see `lenssim designs`; default: the "
                   "paper's, or none when --lens is given)")
    add_lens_arguments(t, many=True)
    add_fft_limit_argument(t)
    t.add_argument("--designs-file", metavar="FILE", help="TOML file of named designs (added to the built-in ones)")
    t.add_argument("--isos", type=int, nargs="+", default=None,
                   help=f"ISOs (default: the sensor's, highest first; the paper's {' '.join(map(str, sorted(isos, reverse=True)))})")
    t.add_argument("--restore", nargs="+", default=["wiener"], metavar="NAME[:KEY=VALUE,...]",
                   help=f"restoration methods and their options ({methods}; default: wiener); several: a column "
                        "each")
    t.add_argument("--method", default=None, help="former name of --restore")
    t.add_argument("--angles", type=float, nargs="+", default=None,
                   help=f"crop field angles (deg); default {' '.join(f'{a:g}' for a in TABLE_ANGLES_DEG)}, those that fit "
                        "each photo")
    t.add_argument("--crop", type=int, default=192)
    t.add_argument("--seed", type=int, default=0)
    add_device_argument(t)
    t.add_argument("--out", required=True)
    t.add_argument("--as-built", type=int, metavar="SEED",
                   help="blur with one manufactured lens per design (drawn with SEED from --grade/--tolerances) and "
                        "add the columns of its restoration with its own PSFs (calibrated) beside the nominal PSFs'")
    add_tolerance_arguments(t, switches=False)
    add_chain_arguments(t)
    t.set_defaults(func=cmd_psnr_table)
