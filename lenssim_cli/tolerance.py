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


def _snrs(args) -> tuple[list[float], float]:
    """``--snr`` and ``--reference-snr`` (default the middle ``--snr``; one of them)."""
    snr = list(args.snr)
    ref_snr = snr[len(snr) // 2] if args.reference_snr is None else args.reference_snr
    if ref_snr not in snr:
        raise ValueError(f"--reference-snr {ref_snr:g} is not allowed: one of the --snr values {snr}")
    return snr, ref_snr


def cmd_tolerance(args) -> int:
    if getattr(args, "lens", None) is not None:
        return cmd_tolerance_lens(args)
    from .lens import check_lens_arguments

    check_lens_arguments(args)  # --refocus and --pixel-pitch without --lens
    if args.lenses is None:
        from lenssim_studies.tolerance import DEFAULT_LENSES

        args.lenses = DEFAULT_LENSES
    if args.sensitivity_lenses is None:
        args.sensitivity_lenses = DEFAULT_SENSITIVITY_LENSES
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
    snr, ref_snr = _snrs(args)
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


DEFAULT_SENSITIVITY_LENSES = 200
"""Lenses per tolerance term of the singlet's sensitivity table by default."""
MAX_LENS_COPIES = 100_000
"""Most copies of a Monte Carlo of any lens (each traces its own wavefront table: far past a day's run)."""
LENS_REFUSED = (("--yield", "yield_"), ("--sensitivity-lenses", "sensitivity_lenses"))
"""Flags of the singlet's Monte Carlo that a Monte Carlo of any lens does not take."""


def surface_tolerances_from_args(args):
    """The :class:`lenssim.model.tolerances.SurfaceTolerances` of ``--grade``, ``--tolerances FILE``,
    ``--off TERM`` and ``--no-focus-compensation`` (for ``--lens``)."""
    import dataclasses

    from lenssim.model.tolerances import SurfaceTolerances

    from .common import graded_tolerances

    t = graded_tolerances(args, SurfaceTolerances)
    terms = [f.name for f in dataclasses.fields(t) if f.name != "focus_compensated"]
    for term in getattr(args, "off", None) or ():
        if term not in terms:
            raise ValueError(f"--off {term!r} is not allowed with --lens: one of {', '.join(terms)}")
        t = dataclasses.replace(t, **{term: 0.0})
    if getattr(args, "no_focus_compensation", False):
        t = dataclasses.replace(t, focus_compensated=False)
    return t


def cmd_tolerance_lens(args) -> int:
    """``lenssim tolerance --lens LENS``: a Monte Carlo of manufactured copies of any lens
    (:func:`lenssim_studies.tolerance.run_tolerance` of a :class:`LensToleranceRun`): every argument checked before
    any work."""
    import math

    from lenssim.io.files import atomic_write_text, check_output_dir, json_text, output_lock
    from lenssim.model.numerics import DEFAULT_NUMERICS, FAST_NUMERICS
    from lenssim.tolerancing import DEFAULT_LENS_COPIES
    from lenssim_studies.tolerance import LensToleranceRun, lens_tolerance_report, run_tolerance, summarise_lens_tolerance
    from lenssim_studies.tradeoff import check_psf_sampling
    from lenssim.torch_utils import select_device
    from lenssim_studies.paper import PAPER_RHO0

    from .lens import check_lens_arguments, lens_provider, refocused_lens

    given = [f for f, k in LENS_REFUSED if getattr(args, k, None) is not None]
    if given:
        raise ValueError(f"{', '.join(given)} belong(s) to the paper's singlet's Monte Carlo; leave them out with "
                         f"--lens {args.lens}")
    n = DEFAULT_LENS_COPIES if args.lenses is None else args.lenses
    if not 1 <= n <= MAX_LENS_COPIES:
        raise ValueError(f"-n/--lenses {n} is not allowed: from 1 to {MAX_LENS_COPIES} copies")
    tol = surface_tolerances_from_args(args)
    snr, ref_snr = _snrs(args)
    p = check_lens_arguments(args)  # the paper's singlet's flags refused, the lens read and its aperture checked
    amax = max(p.fields)
    for a in args.angles or ():
        if not (math.isfinite(a) and 0 <= a <= amax):
            raise ValueError(f"--angles {a:g} is not allowed: field angles from 0 to the lens's largest, {amax:g} deg")
    if args.scheduler is not None:
        from lenssim_studies.cluster import check_scheduler

        check_scheduler(args.scheduler)
    out = check_output_dir(args.out)
    select_device(args.device)
    seq, shift = refocused_lens(p, args.refocus or "file")
    pitch = (seq.primary_wavelength_um * seq.paraxial().working_f_number / 2 if args.pixel_pitch is None
             else float(args.pixel_pitch))
    sampling = "point" if args.pixel_pitch is None else "area"  # as evaluate --lens: Nyquist pixels, point samples
    psf = lens_provider(args, p, seq, pitch_um=pitch, width_px=1, height_px=1, max_field_deg=amax, sampling=sampling)
    numerics = DEFAULT_NUMERICS if args.accurate else FAST_NUMERICS
    check_psf_sampling(psf, numerics)  # pixels no copy could be scored on: refused before the nominal lens is
    run = LensToleranceRun(psf, tol, n, args.seed, tuple(snr), PAPER_RHO0, numerics,
                           angles_deg=tuple(args.angles) if args.angles else None, coarse=not args.accurate)
    t0 = time.perf_counter()
    with output_lock(out):  # one run at a time writes this folder; a second run resumes the Monte Carlo
        out.mkdir(parents=True, exist_ok=True)
        ds = run_tolerance(run, out / "tolerance.nc", show_progress=not args.quiet, scheduler=args.scheduler,
                           workers=args.workers, worker_threads=args.worker_threads,
                           attrs={"refocus": args.refocus or "file", "file": str(args.lens)})
        summary = summarise_lens_tolerance(ds, ref_snr)
        text = lens_tolerance_report(ds, summary)
        info = {"lens": p.name or str(args.lens), "file": str(args.lens), "refocus": args.refocus or "file",
                "image_shift_mm": shift, "pixel_pitch_um": pitch, "sampling": sampling, "lenses": n, "seed": args.seed,
                "snr_db": snr, "angles_deg": list(ds.attrs["angles_deg"]), "tolerances": tol.to_dict(),
                "numerics": numerics.to_dict(), "copies_numerics": ds.attrs["numerics"],
                "not_modelled": ds.attrs["not_modelled"], "config_digest": run.digest()}
        atomic_write_text(out / "summary.json", json_text({"run": info, "summary": summary}))
        atomic_write_text(out / "report.md", text)
    print(text)
    print(f"wrote {args.out}/ (tolerance.nc, report.md, summary.json) in {time.perf_counter() - t0:.0f} s",
          file=sys.stderr)
    return 0


def register(sub) -> None:
    from lenssim_studies.paper import PAPER_SNR_DB
    from lenssim.tolerancing import DEFAULT_LENS_COPIES
    from lenssim_studies.tolerance import DEFAULT_LENSES, TOLERANCE_FIELD_ANGLES

    from .lens import add_lens_arguments

    t = sub.add_parser("tolerance", help="Monte Carlo of manufactured lenses of one design: as-built criteria, "
                                         "restored with their own and with the nominal PSFs",
                       description="The paper's singlet (--design and its parameters), or any lens with --lens LENS: "
                                   "copies with radius, thickness, conic and index errors, decentres and tilts per "
                                   "surface and per element, and a despace (--grade, --tolerances FILE, --off TERM), "
                                   "each focused at assembly unless --no-focus-compensation, evaluated at --angles "
                                   "(default 4 from the axis to the largest; a decentred or tilted copy at 4 "
                                   "azimuths).")
    add_design_arguments(t)
    add_camera_arguments(t)
    add_tolerance_arguments(t)
    add_lens_arguments(t, pitch_help="--lens: the sensor's pixel pitch (um; area samples) instead of the Nyquist "
                                     "pitch lambda N_w / 2 with point samples")
    t.add_argument("-n", "--lenses", type=int, default=None,
                   help=f"Monte Carlo lenses (default {DEFAULT_LENSES}; with --lens {DEFAULT_LENS_COPIES}, each "
                        "copy tracing its own wavefronts)")
    t.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    t.add_argument("--snr", type=float, nargs="+", default=list(PAPER_SNR_DB),
                   help=f"SNRs in dB (default: {' '.join(f'{v:g}' for v in PAPER_SNR_DB)})")
    t.add_argument("--reference-snr", type=float, help="SNR (dB) of the summary, yields and figures (default: the "
                                                        "middle --snr)")
    t.add_argument("--angles", type=float, nargs="+", metavar="DEG",
                   help=f"field angles (each at 4 azimuths; default {' '.join(f'{a:g}' for a in TOLERANCE_FIELD_ANGLES)}; "
                        "with --lens: one azimuth, default 4 angles from the axis to the lens's largest)")
    t.add_argument("--yield", dest="yield_", action="append", metavar="CRITERION<=VALUE",
                   help="report the fraction of lenses meeting a threshold, e.g. 'mse_r_nominal<=0.05' (repeatable)")
    t.add_argument("--sensitivity-lenses", type=int, default=None, metavar="N",
                   help=f"lenses per tolerance term for the sensitivity table (default {DEFAULT_SENSITIVITY_LENSES}; "
                        "0: none)")
    t.add_argument("--accurate", action="store_true", help="the default numerics (2x oversampled OTFs; with --lens "
                                                           "also each copy's full wavefront table) instead of "
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
