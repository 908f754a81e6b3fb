"""``lenssim tradeoff --lens LENS --vary NAME=LO:HI[:STEP] ...``: the paper's cost-performance trade-off on any lens
(:mod:`lenssim_studies.tradeoff`)."""

from __future__ import annotations

import math
import sys
import time

from lenssim.validate import check_distinct, check_pixel_pitch_um

from .common import add_device_argument, numerics_from_args

__all__ = ["register", "cmd_tradeoff", "parse_vary"]

DEFAULT_GRID_VALUES = 9
"""Values of a ``--vary NAME=LO:HI`` range without a step (LO and HI included)."""
MAX_VARY_VALUES = 100_000
"""Values of one ``--vary`` range at most (a grid holds at most ``MAX_GRID_DESIGNS`` designs in all: this bounds the
list itself, before the grid is counted)."""
TRADEOFF_LEVELS = 30
"""Cost levels of the front by default (the paper's 30)."""
GRADIENT_LEVELS = 5
"""Cost levels of the gradient route (--optimise) by default (each level a descent from every start)."""


def parse_vary(text: str) -> tuple[str, tuple[float, ...]]:
    """``NAME=LO:HI[:STEP]`` (LO and HI included; without STEP, :data:`DEFAULT_GRID_VALUES` values) or
    ``NAME=V1,V2,...`` -> ``(NAME, values)``; a one-line ``ValueError`` otherwise."""
    if "=" not in text:
        raise ValueError(f"--vary {text!r} is not allowed: NAME=LO:HI[:STEP] or NAME=V1,V2,... (e.g. S7.conic=-2:0:0.25)")
    name, spec = (t.strip() for t in text.split("=", 1))

    def numbers(parts):
        try:
            return [float(v) for v in parts]
        except ValueError:
            raise ValueError(f"--vary {text!r} is not allowed: NAME=LO:HI[:STEP] or NAME=V1,V2,... with numbers") \
                from None

    if "," in spec:
        values = tuple(numbers(spec.split(",")))
    else:
        parts = numbers(spec.split(":"))
        if len(parts) not in (2, 3):
            raise ValueError(f"--vary {text!r} is not allowed: NAME=LO:HI[:STEP] or NAME=V1,V2,... with numbers")
        lo, hi = parts[:2]
        if not (math.isfinite(lo) and math.isfinite(hi) and hi >= lo):
            raise ValueError(f"--vary {text!r} is not allowed: finite LO <= HI")
        if len(parts) == 2:
            values = tuple(lo + (hi - lo) * k / (DEFAULT_GRID_VALUES - 1) for k in range(DEFAULT_GRID_VALUES))
        else:
            step = parts[2]
            if not (math.isfinite(step) and step > 0):
                raise ValueError(f"--vary {text!r} is not allowed: LO <= HI and a STEP > 0")
            count = (hi - lo) / step
            if not count < MAX_VARY_VALUES:  # also a count that overflowed to inf
                raise ValueError(f"--vary {text!r} is not allowed: more than {MAX_VARY_VALUES} values")
            n = round(count)
            if abs(count - n) > 1e-9 * max(1.0, count):
                raise ValueError(f"--vary {text!r} is not allowed: HI - LO is not a whole number of STEPs")
            if n + 1 > MAX_VARY_VALUES:
                raise ValueError(f"--vary {text!r} is not allowed: {n + 1} values (at most {MAX_VARY_VALUES})")
            values = tuple(lo + step * k for k in range(n + 1))
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"--vary {text!r} is not allowed: finite numbers")
    check_distinct(f"--vary {text!r}", values)  # a value twice: two designs on one coordinate
    return name, values


def parse_surfaces(flag: str, items, count: int) -> tuple[int, ...]:
    """Surface names ``S5`` (or ``5``) of ``flag`` as 1-based numbers, each once and from 1 to ``count``; a one-line
    ``ValueError`` otherwise."""
    out = []
    for item in items:
        text = str(item).strip()
        digits = text[1:] if text[:1] in ("S", "s") else text
        if not (digits.isascii() and digits.isdigit()) or not 1 <= int(digits) <= count:
            raise ValueError(f"{flag} {text!r} is not allowed: surfaces S1 to S{count}")
        if int(digits) in out:
            raise ValueError(f"{flag} names S{int(digits)} more than once; give each surface once")
        out.append(int(digits))
    return tuple(out)


def cmd_tradeoff(args) -> int:
    from lenssim.io.files import atomic_write_text, check_output_dir, json_text, output_lock
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.numerics import DEFAULT_NUMERICS, FAST_NUMERICS
    from lenssim.optics.lens_solves import HOLDS
    from lenssim.optics.sequential import SequentialLens
    from lenssim.torch_utils import select_device
    from lenssim_studies.html import image, markdown, table
    from lenssim_studies.chunks import finished_result
    from lenssim_studies.figures import tradeoff_figure
    from lenssim_studies.tradeoff import LensTradeoffRun, run_lens_tradeoff, tradeoff_json, tradeoff_mismatch
    from lenssim_studies.paper import PAPER_RHO0

    vary = [parse_vary(v) for v in args.vary]
    hold = tuple(h.strip() for h in (args.hold or "").split(",") if h.strip())
    for h in hold:
        if h not in HOLDS:
            raise ValueError(f"--hold {h!r} is not allowed: a comma-separated list of {', '.join(HOLDS)}")
        if hold.count(h) > 1:
            raise ValueError(f"--hold holds {h} more than once; give each once")
    levels = (GRADIENT_LEVELS if args.optimise else TRADEOFF_LEVELS) if args.levels is None else args.levels
    if not (1 if args.optimise else 2) <= levels <= (100 if args.optimise else 1000):
        raise ValueError(f"--levels {levels} is not allowed: " + ("1 to 100 cost levels with --optimise"
                                                                   if args.optimise else "2 to 1000 cost levels"))
    snr = tuple(args.snr)
    p = read_lens(args.lens)
    SequentialLens(p).check_aperture()
    aspherize = parse_surfaces("--aspherize", args.aspherize or (), len(p.surfaces))
    par = SequentialLens(p).paraxial()
    pitch = check_pixel_pitch_um(p.primary_wavelength_um * par.working_f_number / 2 if args.pixel_pitch is None
                                 else args.pixel_pitch, "--pixel-pitch")
    # the third-order route is the paper's image model: the PSF sampled at points of the pixel grid
    sampling = "point" if args.pixel_pitch is None or args.wavefront == "third_order" else "area"
    numerics = numerics_from_args(args, DEFAULT_NUMERICS if args.accurate else FAST_NUMERICS)
    tol = None
    if args.robust is not None:
        from lenssim_studies.lens_robustness import MAX_ROBUST_COPIES

        from .tolerance import surface_tolerances_from_args

        if args.optimise:
            raise ValueError("--robust takes a grid trade-off: leave out --optimise (the gradient route's optima are "
                             "lens files: run `lenssim tolerance --lens designs/NAME.toml` on them)")
        if not 1 <= args.robust <= MAX_ROBUST_COPIES:
            raise ValueError(f"--robust {args.robust} is not allowed: 1 to {MAX_ROBUST_COPIES} copies per design")
        tol = surface_tolerances_from_args(args)
    elif args.grade is not None or args.tolerances is not None:
        raise ValueError("--grade and --tolerances set the Monte Carlo of --robust COPIES: give --robust too")
    if args.optimise:
        return _gradient_tradeoff(args, p, vary, hold, snr, aspherize, pitch, numerics, levels)
    run = LensTradeoffRun(p, str(args.lens), tuple(vary), snr, PAPER_RHO0, pitch, sampling,
                          numerics, hold=hold, image=args.image, aspherize=aspherize, coarse=not args.accurate,
                          levels=levels, wavefront=args.wavefront)
    run.check_sampling()  # pixels on which no design could be scored: refused before the grid
    out = check_output_dir(args.out)
    finished_result(out / "tradeoff.nc", run.digest(), "trade-off", tradeoff_mismatch)  # a damaged one: refused now
    select_device(args.device)
    t0 = time.perf_counter()
    with output_lock(out):  # one run at a time writes this folder; a second run resumes the sweep
        out.mkdir(parents=True, exist_ok=True)
        print(f"{run.size} designs of {p.name or args.lens} ({' x '.join(str(n) for n in run.shape)}: "
              f"{', '.join(run.names)})", file=sys.stderr)
        ds = run_lens_tradeoff(run, out / "tradeoff.nc", show_progress=not args.quiet)
        res = tradeoff_json(ds, run.levels)
        _record(run, res, args, p, sampling, run.evaluation_angles, out)
        title = f"Trade-off of {p.name or args.lens}: {', '.join(run.names)}"
        extra = []
        if tol is not None:  # the as-built Monte Carlo at each optimum of mse_r along the front (resumable)
            from lenssim_studies.lens_robustness import robust_front, robustness_figure

            res["robustness"] = robust = robust_front(run, res, tol, copies=args.robust, seed=args.seed,
                                                      out_dir=out / "robust", show_progress=not args.quiet)
            rfig = robustness_figure(robust, out, f"As built along the front: {p.name or args.lens}")
            rrows = [[f"{d['cost']:.4g}", _design_text(d["design"]),
                      f"{d['nominal']:.5g}", f"{d['mean']:.5g}", f"{d['p90']:.5g}",
                      f"{d['nominal_restoration_mean']:.4g}"] for d in robust["designs"]]
            n, r = robust["designs"][robust["nominal_optimum"]], robust["designs"][robust["robust_optimum"]]
            rtext = (f"As built ({args.robust} copies per optimum of mse_r, the same seed {args.seed} for each; "
                     f"real-ray Monte Carlo at {robust['snr_db']:g} dB): nominal optimum C_a {n['cost']:.3g}, "
                     f"p90 mse_r {n['p90']:.4g}; robust optimum (best p90) C_a {r['cost']:.3g}, p90 {r['p90']:.4g}.")
            extra = [markdown(rtext), image(rfig, "mse_r of each optimum along the front, nominal and as built"),
                     table(["cost", "design", "nominal mse_r", "as built: mean", "p90", "design's filter: mean"],
                           rrows, "as built along the front")]
        atomic_write_text(out / "tradeoff.json", json_text(res))
        fig = tradeoff_figure(ds, res, out, title)
        rows = [[name, f"{u['value']:.5g}", f"{u['cost']:.4g}", _design_text(u["design"])]
                for name, u in res["unconstrained"].items() if u is not None]
        text = (f"{res['designs']} designs, {res['invalid']} invalid (reasons in tradeoff.json); SNR "
                f"{', '.join(f'{s:g}' for s in snr)} dB; pixels {pitch:.4g} um ({sampling} samples); holds: "
                f"{', '.join(hold) or 'none'}; wavefront {args.wavefront} at {len(run.evaluation_angles)} field "
                "angles.")
        gain = res["end_to_end_vs_rms_w"].get("mse_r")
        if gain is not None:
            text += (f" Designed for the restored image instead of the wavefront (the RMS_W optimum, cost "
                     f"{gain['rms_w_optimum']['cost']:.3g}) at {snr[0]:g} dB: mse_r x{gain['mse_r_ratio']:.3f} at "
                     f"no more cost; its mse_r for {100 * gain['cost_saving']:.0f}% less asphere cost "
                     "(end_to_end_vs_rms_w in tradeoff.json).")
        capped = int(ds["mtf50_capped"].values.sum())
        if capped:
            text += (f" MTF50 of {capped} design(s) is a lower bound (their MTF stays above 0.5 up to the sensor's "
                     "Nyquist frequency at some field angle; mtf50_capped in tradeoff.nc).")
        _publish(out, title, text, [image(fig, "each criterion against the asphere cost: grid designs, the best at "
                                             "each cost level"),
                                    table(["criterion", "best value", "cost", "design"], rows, "unconstrained optima")]
                 + extra, rows, rtext if extra else None)
    print(f"wrote {args.out}/ (tradeoff.nc, tradeoff.json, tradeoff.png/.svg, index.html, designs/*.toml: each "
          "optimum as a lens file for --lens) in "
          f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def register(sub) -> None:
    from lenssim_studies.paper import PAPER_SNR_DB

    t = sub.add_parser("tradeoff", help="any lens: every criterion against the asphere cost over a grid of its free "
                                        "parameters, and the optima per cost level",
                       description="The paper's cost-performance trade-off on any lens (docs/design-any-lens.md). "
                                   "Free parameters by name: S5.curvature|radius|conic|thickness, S5.A4..A16 (even "
                                   "aspheres; --aspherize S5 makes a surface one), E1.bending, focus_um (surfaces "
                                   "numbered as in the file). A design that cannot be made is kept, marked invalid "
                                   "with its reason. Resumes a killed run.")
    t.add_argument("--lens", required=True, help="a .zmx or .toml prescription, or a shipped lens's name")
    t.add_argument("--vary", action="append", required=True, metavar="NAME=LO:HI[:STEP]",
                   help=f"a free parameter and its grid (inclusive; without STEP {DEFAULT_GRID_VALUES} values; or "
                        "NAME=V1,V2,...); repeat for up to 3")
    t.add_argument("--hold", help="what each design holds: a comma-separated list of efl (by the last curved "
                                  "surface's curvature) and fnum (by the entrance pupil)")
    t.add_argument("--image", choices=("file", "paraxial", "best"), default="file",
                   help="each design's image plane: the file's distance (default), its paraxial focus, or its best "
                        "focus (least RMS wavefront over the file's fields; slower)")
    t.add_argument("--aspherize", nargs="+", metavar="S5", help="surfaces made even aspheres (their A4..A16 free)")
    t.add_argument("--snr", type=float, nargs="+", default=list(PAPER_SNR_DB),
                   help=f"SNRs in dB (default: {' '.join(f'{v:g}' for v in PAPER_SNR_DB)}); mse_r is at the first")
    t.add_argument("--levels", type=int, help=f"cost levels (default {TRADEOFF_LEVELS}; {GRADIENT_LEVELS} with "
                                              "--optimise)")
    t.add_argument("--optimise", metavar="CRITERION",
                   help="instead of a grid: iso-cost projected gradient descent of CRITERION (mse_r, mse_s, strehl, "
                        "mtf50; at the first --snr) at each cost level and unconstrained, from several starts, for "
                        "any number of --vary LO:HI ranges (the bounds); on the --wavefront given (exact: real rays, slower)")
    t.add_argument("--starts", type=int, default=4, help="--optimise: starts per level, the file's design and random "
                                                         "ones in the bounds (default 4)")
    t.add_argument("--seed", type=int, default=0, help="--optimise: the random starts' seed; --robust: the Monte "
                                                       "Carlo's (default 0)")
    t.add_argument("--robust", type=int, metavar="COPIES",
                   help="the as-built Monte Carlo (real rays, per-surface tolerances as `tolerance --lens`) of "
                        "COPIES copies at each optimum of mse_r along the front: the nominal restoration penalty and "
                        "the robust optimum (best p90 mse_r); resumable, in OUT/robust/")
    from lenssim.model.tolerances import GRADES

    t.add_argument("--grade", choices=sorted(GRADES), help="--robust: the tolerance grade (default commercial)")
    t.add_argument("--tolerances", metavar="FILE", help="--robust: a [tolerances] table over the grade")
    t.add_argument("--steps", type=int, default=30, help="--optimise: most descent steps per start (default 30)")
    t.add_argument("--wavefront", choices=("exact", "third_order"), default="exact",
                   help="exact (default): real-ray wavefronts at 5 field angles; third_order: the Seidel wavefront of "
                        "the surfaces (the paper's route: fast, no ray traced) at the file's field angles, point "
                        "samples")
    t.add_argument("--pixel-pitch", type=float, metavar="UM",
                   help="the sensor's pixel pitch (um; area samples, point samples with third_order) instead of the "
                        "nominal lens's Nyquist pitch")
    t.add_argument("--accurate", action="store_true", help="the default numerics and full wavefront tables "
                                                           "(slower) instead of the fast ones")
    from .optics import add_fft_limit_argument

    add_fft_limit_argument(t)  # a design needing more is kept invalid, with the reason
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.add_argument("--out", required=True, help="output folder (a second run resumes the sweep)")
    add_device_argument(t)
    t.set_defaults(func=cmd_tradeoff)


def _gradient_tradeoff(args, p, vary, hold, snr, aspherize, pitch, numerics, levels) -> int:
    """``tradeoff --optimise``: the front by iso-cost projected gradient descent (:mod:`lenssim_studies.tradeoff`)."""
    from lenssim.io.files import atomic_write_text, check_output_dir, json_text, output_lock
    from lenssim.torch_utils import select_device
    from lenssim_studies.html import image, table
    from lenssim_studies.figures import gradient_figure
    from lenssim_studies.tradeoff import LensGradientRun, gradient_json, run_lens_gradient, score_optima
    from lenssim_studies.paper import PAPER_RHO0

    bounds = []
    for name, values in vary:
        if len(values) < 2 or not max(values) > min(values):
            raise ValueError(f"--vary {name}: --optimise needs a range LO:HI (its bounds), LO < HI")
        bounds.append((name, min(values), max(values)))
    run = LensGradientRun(p, str(args.lens), tuple(bounds), args.optimise, snr, PAPER_RHO0, pitch, numerics,
                          hold=hold, image=args.image, aspherize=aspherize, levels=levels, starts=args.starts,
                          seed=args.seed, steps=args.steps, wavefront=args.wavefront)
    out = check_output_dir(args.out)
    select_device(args.device)
    t0 = time.perf_counter()
    with output_lock(out):  # one run at a time writes this folder; a second run resumes the descents
        out.mkdir(parents=True, exist_ok=True)
        print(f"{levels + 1} descents x {run.starts} starts of {p.name or args.lens} ({', '.join(run.names)}; "
              f"{args.optimise} at {snr[0]:g} dB, {args.wavefront.replace('_', ' ')} wavefront)", file=sys.stderr)
        ds = run_lens_gradient(run, out / "gradient.nc", show_progress=not args.quiet)
        res = gradient_json(run, ds)
        res["scores"] = score_optima(run, res)  # every criterion at each optimum
        _record(run, res, args, p, "point", p.fields, out)
        atomic_write_text(out / "tradeoff.json", json_text(res))
        title = f"Gradient trade-off of {p.name or args.lens}: {args.optimise} over {', '.join(run.names)}"
        fig = gradient_figure(run, res, out, title)
        conv = [[("unconstrained" if c["level"] is None else f"{c['level']:.4g}"), str(c["start"]), c["stopped"],
                 str(c["iterations"]), str(c["evaluations"]),
                 f"{c['value']:.5g}" if "value" in c else "-", f"{c['cost']:.4g}" if "cost" in c else "-"]
                for c in res["convergence"]]
        n_conv = sum(c["stopped"] in ("gradient", "step") for c in res["convergence"])
        text = (f"{len(res['convergence'])} descents ({levels} cost levels and unconstrained, {run.starts} starts "
                f"each), {n_conv} converged (tangential gradient below tolerance, or no step of 1e-3 typical steps "
                f"lowers the value), the others stopped by --steps {run.steps} or an invalid start. SNR "
                f"{snr[0]:g} dB; pixels {pitch:.4g} um (point samples); holds: {', '.join(hold) or 'none'}; "
                f"{'real-ray' if args.wavefront == 'exact' else 'third-order'} wavefront at {len(p.fields)} field angles.")
        u = res["unconstrained"][args.optimise]
        rows = [[("unconstrained" if lv is None else f"{lv:.4g}"), f"{o['value']:.5g}", f"{o['cost']:.4g}",
                 _design_text(o["design"])]
                for lv, o in list(zip(res["levels"], res["optima"][args.optimise])) + [(None, u)] if o is not None]
        _publish(out, title, text, [
            image(fig, f"{args.optimise} against the asphere cost: each start's end point, the best per cost level"),
            table(["level C_a", args.optimise, "cost", "design"], rows, "optima"),
            table(["level", "start", "stopped", "steps", "evaluations", args.optimise, "cost"], conv, "convergence")],
            rows)
    print(f"wrote {args.out}/ (gradient.nc, tradeoff.json, tradeoff.png/.svg, index.html, designs/*.toml) in "
          f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def _design_text(design: dict) -> str:
    return ", ".join(f"{k} = {v:.6g}" for k, v in design.items())


def _record(run, res: dict, args, p, sampling: str, angles, out) -> None:
    """The run's settings into ``res`` (``tradeoff.json``), and each optimum as a lens file (``designs/``: ``--lens``
    on inspect, tolerance, ...)."""
    from lenssim_studies.tradeoff import write_design_files

    res |= {"lens": p.name or str(args.lens), "snr_db": list(args.snr), "hold": list(run.hold),
            "pixel_pitch_um": run.pitch_um, "sampling": sampling, "wavefront": args.wavefront,
            "angles_deg": list(angles)}
    res["design_files"] = write_design_files(run, res, out / "designs")


def _publish(out, title: str, text: str, parts: list, rows: list, more: str | None = None) -> None:
    """``index.html`` (``text``, then ``parts``), and on stdout ``text``, ``more`` and each optimum of ``rows``."""
    from lenssim_studies.html import markdown, write_page

    write_page(out / "index.html", title, [markdown(text)] + parts)
    print(text)
    if more:
        print(more)
    for r in rows:
        print(f"  {r[0]}: {r[1]} at cost {r[2]} ({r[3]})")
