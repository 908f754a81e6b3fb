"""Optics commands: evaluate designs, run sweeps, find optima, reproduce the paper, list designs."""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

from lenssim import DEFAULT_NUMERICS, PARAMETERS, Design, select_device
from lenssim.criteria import lens_criteria

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_SNR_DB
from lenssim.io.files import json_text
from lenssim.io.resources import builtin_configs, config_path

from .common import (add_camera_arguments, add_design_arguments, add_device_argument, camera_from_args,
                     design_from_args, designs, numerics_from_args, table)
from lenssim_studies.paper import PAPER_RHO0
from lenssim.optics.psf_bank import SAMPLINGS

from .lens import add_lens_arguments

DEMO_DESIGNS = tuple(PAPER_DESIGNS)
DEMO_CONFIG = "small_grid"
REPRODUCE_CONFIG = "paper_grid_fast"


def evaluate_design(design: Design, snr, device: str = "auto", numerics=DEFAULT_NUMERICS, camera=PAPER_CAMERA,
                    wavefront: str = "third_order") -> dict:
    """Every registered criterion of one design under the ``wavefront`` model, as JSON-ready values keyed by
    criterion name (with colour channels: their mean, and ``NAME_per_channel``)."""
    from lenssim.optics.wavefront_models import validate_wavefront_model

    model = validate_wavefront_model(wavefront)
    res = model.evaluate(camera, design, snr, rho0=PAPER_RHO0, numerics=numerics, device=select_device(device))
    params = design.complete().floats()
    out = {"parameters": params, **params}
    for name, c in lens_criteria().items():
        v = res[name]
        out[name] = [float(x) for x in v] if c.per_snr else float(v)
        if f"{name}_per_channel" in res:
            out[f"{name}_per_channel"] = res[f"{name}_per_channel"].tolist()
    out["units"] = {name: c.units for name, c in lens_criteria().items()}
    out["camera"] = {"glass": camera.lens.glass.name, "spectrum": camera.spectrum.name if not camera.channels
                     else [c.name for c in camera.channels]}
    out["rms_w_piston_removed_waves"] = float(res["rms_w_piston_removed"])
    out["snr_db"] = [float(v) for v in res["snr_db"]]
    out["fft_size_per_angle"] = [int(v) for v in res["fft_size"]]
    out["alpha_deg"] = [float(v) for v in res["alpha_deg"]]
    out["wavefront"] = f"{model.name}: {model.label}"
    return out


def design_table(results: list[tuple[str, dict]]) -> str:
    snrs = results[0][1]["snr_db"]
    names = list(results[0][1]["parameters"])
    header = ["design"] + names
    for name, c in lens_criteria().items():
        header += [f"{c.label}@{v:g}dB" for v in snrs] if c.per_snr else [f"{c.label} [{c.units.split()[0]}]"]
    rows = []
    for label, r in results:
        row = [label] + [f"{r['parameters'][n]:g}" for n in names]
        for name, c in lens_criteria().items():
            row += [f"{v:.5f}" for v in r[name]] if c.per_snr else [f"{r[name]:.4g}"]
        rows.append(row)
    return table(rows, header)


def cmd_evaluate(args) -> int:
    if args.lens is not None:
        from .lens import cmd_evaluate_lens

        return cmd_evaluate_lens(args)
    if args.sampling is not None:
        raise ValueError("--sampling applies to --lens LENS (any lens); the paper's singlet samples its PSFs at the "
                         "pixel centres")
    design = design_from_args(args)
    select_device(args.device)
    t0 = time.perf_counter()
    camera = camera_from_args(args)
    if args.best_focus:
        from lenssim.focus import best_focus

        crit = args.best_focus
        fr = best_focus(camera, design, crit, args.snr[len(args.snr) // 2], numerics=numerics_from_args(args), rho0=PAPER_RHO0)
        print(f"best focus for {crit} at {args.snr[len(args.snr) // 2]:g} dB: focus_shift_um = {fr.focus_shift_um:.1f} "
              f"({fr.evaluations} evaluations)", file=sys.stderr)
        design = design.replace(focus_shift_um=round(fr.focus_shift_um, 2))
    if args.wavefront == "exact" and (camera.channels or len(camera.spectrum) != 1):
        raise ValueError("--wavefront exact takes a one-wavelength spectrum (--spectrum paper)")
    r = evaluate_design(design, args.snr, args.device, numerics_from_args(args), camera, wavefront=args.wavefront)
    if args.json:
        print(json_text({"design": design.name or "custom", **r}))
    else:
        if camera.channels or getattr(camera.lens.glass, "dispersive", False):
            print(f"glass {camera.lens.glass.name}; " + (f"{len(camera.channels)} colour channels (the criteria are "
                  f"their mean): {'; '.join(c.name for c in camera.channels)}" if camera.channels else
                  f"spectrum {camera.spectrum.name}"))
        print(design_table([(design.name or "custom", r)]))
        print(f"\nFFT sizes per field angle {r['alpha_deg'][0]:g}..{r['alpha_deg'][-1]:g} deg: "
              f"{r['fft_size_per_angle']}  ({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_sweep(args) -> int:
    from lenssim_studies.sweep import load_config, run_sweep

    cfg = load_config(config_path(args.config))
    if args.max_fft_size:
        cfg = dataclasses.replace(cfg, numerics=cfg.numerics.replace(max_fft_size=args.max_fft_size))  # validated again
    select_device(args.device)
    t0 = time.perf_counter()
    if args.scheduler is not None:
        from lenssim_studies.cluster import check_scheduler

        check_scheduler(args.scheduler)
    from lenssim.io.files import check_output_file, output_lock

    check_output_file(args.out, "sweep output")
    with output_lock(args.out, what="sweep output"):  # one run at a time writes this sweep
        run_sweep(cfg, args.out, device=args.device, show_progress=not args.quiet, keep_chunks=args.keep_chunks,
                  memory_limit_bytes=args.memory_limit * 2**30 if args.memory_limit else None,
                  scheduler=args.scheduler, workers=args.workers, worker_threads=args.worker_threads)
    sizes = " x ".join(f"{len(cfg.values(d))} {d}" for d in cfg.dims)
    print(f"wrote {args.out} ({sizes} x {len(cfg.lens.field_angles_deg)} angles) in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr)
    return 0


def cmd_optimum(args) -> int:
    import xarray as xr

    from lenssim.io.files import check_input_file
    from lenssim_studies.tradeoff import TRADEOFF_FILE, check_max_cost, is_lens_tradeoff

    max_cost = check_max_cost(args.max_cost)
    if args.write_lens is not None:
        _check_lens_output(args.write_lens)
    path = Path(args.file)
    folder = None
    if path.is_dir():  # a trade-off's output folder
        folder = path
        path = path / TRADEOFF_FILE
        if not path.exists():
            raise ValueError(f"folder {str(args.file)!r} holds no {TRADEOFF_FILE}: give a sweep file, or a `lenssim "
                             "tradeoff` output folder or its tradeoff.nc")
    path = check_input_file(path, "sweep or trade-off file")
    try:
        ds = xr.load_dataset(path, engine="scipy")
    except Exception:  # noqa: BLE001 - whatever the reader says, the file is not a sweep
        from lenssim_studies.chunks import damaged_netcdf, is_netcdf

        if is_netcdf(path):
            raise ValueError(damaged_netcdf(path, "run `lenssim sweep` or `lenssim tradeoff` again")) from None
        raise ValueError(f"{str(path)!r} is not a sweep file or a trade-off (NetCDF written by `lenssim sweep` or "
                         "`lenssim tradeoff`)") from None
    if is_lens_tradeoff(ds):
        from lenssim_studies.tradeoff import verify_lens_tradeoff

        verify_lens_tradeoff(ds, path)  # its checksum and its sense, before any number of it is read
        return _tradeoff_optimum(args, ds, path, folder if folder is not None else path.parent, max_cost)
    if "config_digest" not in ds.attrs:
        raise ValueError(f"{str(path)!r} is a NetCDF file but not a lenssim sweep (no config digest)")
    if args.write_lens is not None:
        raise ValueError("--write-lens takes a trade-off of any lens (`lenssim tradeoff --lens`): a sweep's designs "
                         "are the paper's singlet, not a prescription")
    from lenssim_studies.tradeoff import find_optimum
    from lenssim_studies.sweep import verify_sweep

    verify_sweep(ds, path)
    r = find_optimum(ds, args.criterion, args.snr, max_cost) | {"max_cost": max_cost}
    if args.json:
        print(json_text(r))
    else:
        snr_txt = f" at {r['snr_db']:g} dB" if r["snr_db"] is not None else ""
        cost_txt = f" at cost <= {max_cost:g}" if max_cost is not None else ""
        where = ", ".join(f"{k} = {v:g}" for k, v in r["design"].items())
        print(f"best {r['criterion']}{snr_txt}{cost_txt}: {where}  (value {r['value']:.6g})"
              + ("  [on the grid boundary]" if r["on_grid_boundary"] else ""))
        for k, c in lens_criteria().items():  # every criterion the sweep holds, at that design
            if k in r and k != r["criterion"] or isinstance(r.get(k), dict):
                v = r[k]
                print(f"  {c.label}: " + (", ".join(f"{x:.5g} @ {snr} dB" for snr, x in v.items()) if isinstance(v, dict)
                                          else f"{v:.5g} [{c.units}]"))
    return 0


def _check_lens_output(path) -> None:
    """Before any work: ``--write-lens`` names a new ``.toml`` file in a writable folder."""
    from lenssim.io.files import check_output_file

    if Path(path).suffix.lower() != ".toml":
        raise ValueError(f"--write-lens {str(path)!r} is not allowed: a lens file named *.toml")
    check_output_file(path, "lens file")
    if Path(path).exists():
        raise FileExistsError(f"{str(path)!r} exists; choose another lens file or remove it")


def _tradeoff_optimum(args, ds, path: Path, folder: Path, max_cost) -> int:
    """``lenssim optimum`` of a trade-off of any lens (:mod:`lenssim_studies.tradeoff`)."""
    from lenssim_studies.tradeoff import OPTIMUM_CRITERIA, find_lens_optimum, write_optimum_lens

    r = find_lens_optimum(ds, args.criterion, args.snr, max_cost, folder=folder)
    written = None
    if args.write_lens is not None:
        _check_lens_output(args.write_lens)  # again: the file may have appeared meanwhile
        written = str(write_optimum_lens(ds, r["design"], args.write_lens, where=repr(str(path))))
    if args.json:
        print(json_text(r | {"lens_written": written}))
        return 0
    snr_txt = f" at {r['snr_db']:g} dB" if r["snr_db"] is not None else ""
    cost_txt = f" at cost <= {max_cost:g}" if max_cost is not None else ""
    where = ", ".join(f"{k} = {v:g}" for k, v in r["design"].items())
    print(f"best {r['criterion']}{snr_txt}{cost_txt}: {where}  (value {r['value']:#.3g}, cost {r['cost']:#.3g})"
          + ("  [on the grid boundary]" if r["on_grid_boundary"] else ""))
    crits = lens_criteria()
    for k in OPTIMUM_CRITERIA:  # every criterion at that design, each per-SNR one at every SNR
        c, v = crits[k], r[k]
        print(f"  {c.label}: " + (", ".join(f"{x:.5g} @ {snr} dB" for snr, x in v.items()) if isinstance(v, dict)
                                  else f"{v:.5g} [{c.units}]"))
    if r["on_grid_boundary"]:
        edge = r["boundary_parameters"]
        print(f"  at the edge of the grid of {', '.join(edge)}: widen "
              + ("its --vary range" if len(edge) == 1 else "their --vary ranges"))
    print(f"  {r['valid_designs']} of {r['designs']} designs valid"
          + (f"; lens file {r['lens_file']}" if r["lens_file"] else ""))
    if written is not None:
        print(f"wrote {written} (this design as a lens file for --lens)", file=sys.stderr)
    return 0


def cmd_demo(args) -> int:
    from lenssim_studies.sweep import load_config, run_sweep
    from lenssim_studies.tradeoff import find_optimum

    from lenssim.io.files import check_output_file

    named = designs()
    check_output_file(args.out, "demo sweep output")
    select_device(args.device)
    results = [(n, evaluate_design(named[n], PAPER_SNR_DB, args.device)) for n in DEMO_DESIGNS]
    lens = PAPER_CAMERA.lens
    print(f"The paper's two highlighted designs (f = {lens.focal_length_mm:g} mm, f/{lens.f_number:g}, "
          f"n = {lens.refractive_index:g}, {PAPER_CAMERA.spectrum.name}, field "
          f"{lens.field_angles_deg[0]:g}-{lens.field_angles_deg[-1]:g} deg):\n")
    print(design_table(results))
    cfg = load_config(config_path(DEMO_CONFIG))
    out = Path(args.out)
    sizes = " x ".join(f"{len(cfg.values(d))} {d}" for d in cfg.dims)
    print(f"\nSmall sweep {DEMO_CONFIG}: {sizes} x {len(cfg.lens.field_angles_deg)} angles -> {out}", file=sys.stderr)
    ds = run_sweep(cfg, out, device=args.device, show_progress=not args.quiet)
    ref = f"{PAPER_SNR_DB[1]:g}"
    rows = []
    for crit, c in lens_criteria().items():
        for snr in (ds["snr"].values if c.per_snr else [None]):
            r = find_optimum(ds, crit, snr)
            rows.append([crit + (f"@{snr:g}dB" if snr is not None else "")]
                        + [f"{r['design'][d]:g}" for d in cfg.dims]
                        + [f"{r['value']:.5g}", f"{r['rms_w']:.3f}", f"{r['cost']:.3e}",
                           f"{r['mse_r'][ref]:.5f}" if ref in r["mse_r"] else "-"])
    print("\nGrid optima of the small sweep (coarse grid; the paper's grid is the built-in config paper_grid):\n")
    print(table(rows, ["criterion", *cfg.dims, "value", "RMS_W", "C_a", f"MSE_R@{ref}dB"]))
    return 0


def cmd_reproduce(args) -> int:
    from lenssim_studies.report import reproduce
    from lenssim_studies.sweep import load_config

    from lenssim.io.files import check_output_dir

    cfg = load_config(config_path(args.config or REPRODUCE_CONFIG))
    if args.max_fft_size:
        cfg = dataclasses.replace(cfg, numerics=cfg.numerics.replace(max_fft_size=args.max_fft_size))  # validated again
    check_output_dir(args.out)
    select_device(args.device)
    t0 = time.perf_counter()
    report = reproduce(args.out, cfg, device=args.device, show_progress=not args.quiet)
    print(report.read_text())
    print(f"wrote {args.out}/ (report.md, fig3..6 .png/.svg, table1.csv/.md) in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr)
    return 0


def cmd_study(args) -> int:
    """``lenssim study white-light|exact-wavefront`` (lenssim.study)."""
    from lenssim.io.files import atomic_write_text, check_output_dir, json_text
    from lenssim_studies.study import STUDY_GRID, WhiteLightStudy, exact_along_tradeoff, exact_tradeoff_report, white_light_study

    _check_study_flags(args)
    if args.name == "as-built":
        from lenssim_studies.as_built import AsBuiltStudy, as_built_study
        from lenssim_studies.paper import REFERENCE_SNR_DB

        from .common import tolerances_from_args

        from lenssim_studies.as_built import STUDY_LENSES

        args.lenses = STUDY_LENSES if args.lenses is None else args.lenses
        args.seed = 0 if args.seed is None else args.seed
        from .tolerance import MAX_SENSITIVITY_LENSES

        if not 2 <= args.lenses <= MAX_SENSITIVITY_LENSES:  # the singlet's Monte Carlo lenses, as tolerance's
            raise ValueError(f"--lenses {args.lenses} is not allowed: from 2 to {MAX_SENSITIVITY_LENSES} lenses per "
                             "design")
        if args.seed < 0:
            raise ValueError(f"--seed {args.seed} is not allowed: a whole number >= 0")
        check_output_dir(args.out)
        t0 = time.perf_counter()
        study_ = AsBuiltStudy(PAPER_CAMERA, PAPER_RHO0, REFERENCE_SNR_DB, tolerances=tolerances_from_args(args),
                              n_lenses=args.lenses, seed=args.seed)
        as_built_study(study_, args.out, reference=PAPER_DESIGNS["end_to_end_paper"],
                       log=lambda m: print(m, file=sys.stderr), show_progress=not args.quiet)
        print((Path(args.out) / "report.md").read_text())
        print(f"wrote {args.out}/ (report.md, as_built.json, fig6_as_built.png/.svg) in {time.perf_counter() - t0:.0f} s",
              file=sys.stderr)
        return 0

    if args.name == "exact-wavefront":
        check_output_dir(args.out)
        t0 = time.perf_counter()
        rows = exact_along_tradeoff(log=lambda m: print(m, file=sys.stderr))
        text = exact_tradeoff_report(rows)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "exact_tradeoff.json", json_text(rows))
        atomic_write_text(out / "exact_tradeoff.md", text)
        print(text)
        print(f"wrote {args.out}/exact_tradeoff.md/.json in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        return 0

    grid = dict(STUDY_GRID)
    if args.grid_step:
        if not len(args.grid_step) == 2 or not all(v > 0 for v in args.grid_step):
            raise ValueError(f"--grid-step {args.grid_step!r} is not allowed: two positive steps (s, Q_back)")
        grid = {"s": (*STUDY_GRID["s"][:2], args.grid_step[0]), "Q_back": (*STUDY_GRID["Q_back"][:2], args.grid_step[1])}
        from lenssim_studies.config import grid_count

        for name, (lo, hi, step) in grid.items():  # the trade-off interpolates over each: at least 2 values
            if not all(math.isfinite(v) for v in (lo, hi, step)) or grid_count(lo, hi, step) < 2:
                raise ValueError(f"--grid-step {args.grid_step[0]:g} {args.grid_step[1]:g} is not allowed: steps "
                                 f"that give {name} over [{lo:g}, {hi:g}] at least 2 values")
    defaults = WhiteLightStudy.__dataclass_fields__
    study = WhiteLightStudy(glasses=tuple(args.glass or STUDY_GLASSES),
                            sensitivities=args.spectrum or defaults["sensitivities"].default,
                            illuminant=args.illuminant or defaults["illuminant"].default,
                            per_channel=defaults["per_channel"].default if args.wavelengths_per_channel is None
                            else args.wavelengths_per_channel, grid=grid,
                            max_evaluations=defaults["max_evaluations"].default if args.evaluations is None
                            else args.evaluations, q_front=not args.no_q_front)
    check_output_dir(args.out)
    t0 = time.perf_counter()
    report = white_light_study(args.out, study, log=lambda m: print(m, file=sys.stderr), show_progress=not args.quiet)
    print(report.read_text())
    print(f"wrote {args.out}/ (report.md, summary.json, per glass: sweep, trade-off, figures, Table 1) in "
          f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


STUDY_GLASSES = ("paper", "N-BK7", "N-SF5", "PMMA")
"""The white-light study's glasses unless --glass names others ('paper': the paper's model, as the baseline)."""

STUDY_FLAGS = {"white-light": ("glass", "spectrum", "illuminant", "wavelengths_per_channel", "grid_step",
                               "evaluations", "no_q_front"),
               "exact-wavefront": (),
               "as-built": ("lenses", "seed", "grade", "tolerances", "off", "no_focus_compensation")}
"""The options each study takes (the others are refused, not ignored)."""


def _check_study_flags(args) -> None:
    for name, keys in STUDY_FLAGS.items():
        if name == args.name:
            continue
        for k in keys:
            if k in STUDY_FLAGS[args.name]:
                continue
            v = getattr(args, k, None)
            if v not in (None, False):
                raise ValueError(f"--{k.replace('_', '-')} belongs to `lenssim study {name}`, not to "
                                 f"`lenssim study {args.name}`")


def cmd_designs(args) -> int:
    if args.parameters:
        for p in PARAMETERS.values():
            alias = f" (alias {', '.join(p.aliases)})" if p.aliases else ""
            print(f"{p.name:10s} {p.description} [{p.unit}], default {p.default:g}{alias}")
        return 0
    for name, d in designs(args.designs).items():
        print(f"{name:20s} {d.label():32s} {d.description}")
    return 0


def add_fft_limit_argument(p) -> None:
    p.add_argument("--max-fft-size", type=int, metavar="N",
                   help=f"largest FFT size per PSF (default {DEFAULT_NUMERICS.max_fft_size}; larger designs are refused "
                        "before any work)")


def register(sub) -> None:
    from lenssim_studies.paper import REFERENCE_SNR_DB

    configs = ", ".join(builtin_configs())
    e = sub.add_parser("evaluate", help="criteria of one design, or of any lens (--lens)")
    add_design_arguments(e)
    add_camera_arguments(e)
    add_lens_arguments(e, pitch_help="--lens: the sensor's pixel pitch (um); default the Nyquist pitch lambda N_w / 2 "
                                     "at the primary wavelength, as the paper's camera")
    e.add_argument("--sampling", choices=SAMPLINGS, help="--lens: PSFs integrated over each pixel's area or sampled at "
                   "the pixel centres (default: point at the default Nyquist pitch, as the paper; area with "
                   "--pixel-pitch)")
    e.add_argument("--best-focus", metavar="CRITERION", help="first move the image plane (focus_shift_um) to the "
                   "position that minimises CRITERION (e.g. mse_r) at the middle --snr")
    e.add_argument("--snr", type=float, nargs="+", default=list(PAPER_SNR_DB),
                   help=f"SNRs in dB (default: {' '.join(f'{v:g}' for v in PAPER_SNR_DB)})")
    add_device_argument(e)
    add_fft_limit_argument(e)
    e.add_argument("--json", action="store_true", help="JSON output for scripts")
    e.set_defaults(func=cmd_evaluate)

    s = sub.add_parser("sweep", help="run or resume a design sweep")
    s.add_argument("config", help=f"sweep config (TOML file, or a built-in one: {configs})")
    s.add_argument("--out", required=True, help="output NetCDF file")
    add_device_argument(s)
    s.add_argument("--keep-chunks", action="store_true", help="keep OUT.partial/ after finishing")
    add_fft_limit_argument(s)
    s.add_argument("--memory-limit", type=float, metavar="GIB",
                   help="memory the sweep's results may take (default: 80%% of the available memory)")
    where = s.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="run the chunks as tasks on the dask scheduler at ADDRESS "
                       "(e.g. tcp://10.0.0.5:8786; see docs/scale-out.md); same output file, byte for byte")
    where.add_argument("--workers", type=int, metavar="N", help="run the chunks on a local dask cluster of N processes")
    s.add_argument("--worker-threads", type=int, metavar="K", help="torch threads per dask task (default: this "
                   "process's count, which keeps the file byte-identical to a run in one process; the last bits of "
                   "torch's reductions depend on it)")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_sweep)

    o = sub.add_parser("optimum", help="best grid design of a sweep, or of a trade-off of any lens (lenssim "
                                       "tradeoff --lens)")
    o.add_argument("file", help="sweep NetCDF file, or a trade-off: its output folder or its tradeoff.nc")
    o.add_argument("--criterion", required=True, help=f"{', '.join(lens_criteria())} (a trade-off: rms_w, mse_s, "
                   "mse_r, strehl, mtf50, cost, or NAME@SNR as tradeoff.json names them)")
    o.add_argument("--snr", type=float, help=f"SNR in dB for SNR-dependent criteria (default {REFERENCE_SNR_DB:g} for "
                   "a sweep, the run's first --snr for a trade-off)")
    o.add_argument("--max-cost", type=float, metavar="C", help="the best design whose asphere cost C_a is at most C "
                   "(the iso-cost optimum to the grid's resolution); a sweep or a trade-off")
    o.add_argument("--write-lens", metavar="FILE.toml", help="a trade-off only: write the chosen design as a lens file "
                   "(its solves applied; --lens on every command); an existing file is refused")
    o.add_argument("--json", action="store_true")
    o.set_defaults(func=cmd_optimum)

    d = sub.add_parser("demo", help="the paper's designs and a small sweep")
    d.add_argument("--out", default="lenssim-demo-sweep.nc", help="where the small sweep is written (reused if present)")
    add_device_argument(d)
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=cmd_demo)

    r = sub.add_parser("reproduce", help="the paper's figures 3-6, Table 1 and a claims report")
    r.add_argument("--out", required=True, help="output folder (a second run reuses what is there)")
    r.add_argument("--config", help=f"sweep config (default: {REPRODUCE_CONFIG}, ~10 min on 2 cores; built-in: {configs})")
    add_fft_limit_argument(r)
    add_device_argument(r)
    r.add_argument("--quiet", action="store_true")
    r.set_defaults(func=cmd_reproduce)

    st = sub.add_parser("study", help="studies beyond the paper: white-light, exact-wavefront, as-built")
    st.add_argument("name", choices=("white-light", "exact-wavefront", "as-built"), help="white-light: the paper's "
                    "optima, Fig. 6 and Table 1 per glass under white light, focus optimised, and a second asphere at "
                    "equal cost; exact-wavefront: the end-to-end trade-off with third-order and ray-traced wavefronts; "
                    "as-built: the trade-off for manufactured lenses restored with the nominal PSFs, and a robust design")
    st.add_argument("--out", required=True, help="output folder (a second run resumes the sweeps)")
    st.add_argument("--glass", nargs="+",
                    help="glasses (configs/glasses.toml; 'paper' = the paper's one-wavelength model as baseline)")
    st.add_argument("--spectrum", help="camera RGB sensitivities (colour-science; default Nikon 5100 (NPL))")
    st.add_argument("--illuminant", help="CIE illuminant (default D65)")
    st.add_argument("--wavelengths-per-channel", type=int, metavar="N",
                    help="wavelengths per colour channel, each channel its own (default: the 5 nm table integrated "
                         "with a few wavelengths shared by the channels)")
    st.add_argument("--grid-step", type=float, nargs=2, metavar=("DS", "DQ"),
                    help="steps of the (s, Q_back) grid (default 0.125 0.8 over s -1.5..0.25, Q_back -10..1.2)")
    st.add_argument("--evaluations", type=int, help="Nelder-Mead budget per refined optimum (default 60)")
    st.add_argument("--no-q-front", action="store_true", help="skip the second-asphere search")
    from lenssim_studies.as_built import STUDY_LENSES

    from .common import add_tolerance_arguments
    st.add_argument("--lenses", type=int, help=f"as-built: lenses per design (default {STUDY_LENSES})")
    st.add_argument("--seed", type=int, help="as-built: seed of the lenses (default 0)")
    add_tolerance_arguments(st)
    st.add_argument("--quiet", action="store_true", help="no progress bars")
    st.set_defaults(func=cmd_study)

    g = sub.add_parser("designs", help="list named designs (or the design parameters)")
    g.add_argument("--designs", metavar="FILE", help="TOML file of named designs (added to the built-in ones)")
    g.add_argument("--parameters", action="store_true", help="list the design parameters instead")
    g.set_defaults(func=cmd_designs)
