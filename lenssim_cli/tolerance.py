"""``lenssim tolerance``: a Monte Carlo of manufactured lenses of one design (lenssim_studies.tolerance)."""

from __future__ import annotations

import sys
import time

MAX_SENSITIVITY_LENSES = 100_000
"""Most lenses per tolerance term of the sensitivity table: 9 terms x 100,000 lenses is already past a long Monte
Carlo on a workstation; 2**31 asked for 16 GiB before it was bounded."""

from .common import (add_camera_arguments, add_design_arguments, add_device_argument, add_tolerance_arguments,
                     camera_from_args, design_from_args, tolerances_from_args)

__all__ = ["register", "cmd_tolerance"]


def cmd_tolerance(args) -> int:
    from lenssim.io.files import atomic_write_text, check_output_dir, json_text, output_lock
    from lenssim.model.numerics import DEFAULT_NUMERICS, FAST_NUMERICS
    from lenssim.torch_utils import select_device
    from lenssim_studies.paper import PAPER_RHO0
    from lenssim_studies.tolerance import (ToleranceRun, nominal_values, parse_yield, run_tolerance, sensitivity,
                                           summarise, tolerance_figures, tolerance_report)

    design = design_from_args(args)
    camera = camera_from_args(args)
    if args.wavefront != "third_order":
        raise ValueError("--wavefront exact is not allowed here: the as-built model is third order")
    tol = tolerances_from_args(args)
    yields = [parse_yield(s) for s in args.yield_ or ()]
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers {args.workers} is not allowed: a number of local worker processes >= 1")
    if not 0 <= args.sensitivity_lenses <= MAX_SENSITIVITY_LENSES:
        raise ValueError(f"--sensitivity-lenses {args.sensitivity_lenses} is not allowed: from 0 to "
                         f"{MAX_SENSITIVITY_LENSES} (0: no sensitivity table)")
    snr = list(args.snr)
    ref_snr = snr[len(snr) // 2] if args.reference_snr is None else args.reference_snr
    if ref_snr not in snr:
        raise ValueError(f"--reference-snr {ref_snr:g} is not allowed: one of the --snr values {snr}")
    run = ToleranceRun(camera, design, tol, tuple(snr), PAPER_RHO0, n_lenses=args.lenses, seed=args.seed,
                       numerics=DEFAULT_NUMERICS if args.accurate else FAST_NUMERICS,
                       field_angles_deg=tuple(args.angles) if args.angles else ToleranceRun.__dataclass_fields__[
                           "field_angles_deg"].default)
    run.check_fft_sizes()
    if args.scheduler is not None:
        from lenssim_studies.cluster import check_scheduler

        check_scheduler(args.scheduler)
    out = check_output_dir(args.out)
    with output_lock(out):  # one run at a time writes this folder
        select_device(args.device)
        t0 = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        ds = run_tolerance(run, out / "tolerance.nc", device=args.device, show_progress=not args.quiet,
                           scheduler=args.scheduler, workers=args.workers, worker_threads=args.worker_threads)
        summary = summarise(ds, nominal_values(run, ref_snr), ref_snr, yields, seed=run.seed)
        sens = None
        if args.sensitivity_lenses:
            print(f"sensitivity: each tolerance alone, {args.sensitivity_lenses} lenses", file=sys.stderr)
            sens = sensitivity(run, ref_snr, args.sensitivity_lenses, log=lambda m: print(m, file=sys.stderr))
        text = tolerance_report(run, summary, sens, ref_snr)
        tolerance_figures(ds, summary, out, ref_snr, run.design.name or "custom design")
        atomic_write_text(out / "summary.json", json_text({"run": run.to_dict(), "summary": summary, "sensitivity": sens}))
        atomic_write_text(out / "report.md", text)
        print(text)
        print(f"wrote {args.out}/ (tolerance.nc, report.md, summary.json, histogram and cdf .png/.svg) in "
              f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
        return 0


def register(sub) -> None:
    from lenssim_studies.paper import PAPER_SNR_DB
    from lenssim_studies.tolerance import DEFAULT_LENSES, TOLERANCE_FIELD_ANGLES

    t = sub.add_parser("tolerance", help="Monte Carlo of manufactured lenses of one design: as-built criteria, "
                                         "restored with their own and with the nominal PSFs")
    add_design_arguments(t)
    add_camera_arguments(t)
    add_tolerance_arguments(t)
    t.add_argument("-n", "--lenses", type=int, default=DEFAULT_LENSES,
                   help=f"Monte Carlo lenses (default {DEFAULT_LENSES})")
    t.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    t.add_argument("--snr", type=float, nargs="+", default=list(PAPER_SNR_DB),
                   help=f"SNRs in dB (default: {' '.join(f'{v:g}' for v in PAPER_SNR_DB)})")
    t.add_argument("--reference-snr", type=float, help="SNR (dB) of the summary, yields and figures (default: the "
                                                        "middle --snr)")
    t.add_argument("--angles", type=float, nargs="+", metavar="DEG",
                   help=f"field angles (each at 4 azimuths; default {' '.join(f'{a:g}' for a in TOLERANCE_FIELD_ANGLES)})")
    t.add_argument("--yield", dest="yield_", action="append", metavar="CRITERION<=VALUE",
                   help="report the fraction of lenses meeting a threshold, e.g. 'mse_r_nominal<=0.05' (repeatable)")
    t.add_argument("--sensitivity-lenses", type=int, default=200, metavar="N",
                   help="lenses per tolerance term for the sensitivity table (default 200; 0: none)")
    t.add_argument("--accurate", action="store_true", help="the default numerics (2x oversampled OTFs) instead of "
                                                           "the fast ones")
    t.add_argument("--out", required=True, help="output folder (a second run resumes the Monte Carlo)")
    add_device_argument(t)
    where = t.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="run the chunks on the dask scheduler at ADDRESS")
    where.add_argument("--workers", type=int, metavar="N", help="run the chunks on a local dask cluster of N processes")
    t.add_argument("--worker-threads", type=int, metavar="K", help="torch threads per dask task (default: this "
                   "process's count: the file is then byte-identical to a run in one process)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_tolerance)
