"""``lenssim rank-designs``: the paper's conclusion under each restoration (issue 45, item 4).

    lenssim rank-designs PHOTO ... [--designs end_to_end_paper rms_w_paper] [--cost-levels 2.5e-4 1e-3]
                         [--optimise mse_r rms_w] [--restore wiener richardson_lucy tikhonov] [--isos 400 100]
                         [--angles 0 5 10] [--crop 256] [--seed 0] --out DIR

ranks the named designs and the iso-cost optima by the mean PSNR each restoration reaches on crops of the photos,
beside the closed-form MSE_R of the paper (:mod:`lenssim_studies.restoration_ranking`); writes ``ranking.md``,
``ranking.csv``, ``ranking_crops.csv``, ``agreement.csv`` and ``pairs.csv``; resumes after an interruption.
"""

from __future__ import annotations

import math
import sys
import time

from lenssim_studies.paper import ISO_FOR_SNR, PAPER_CAMERA, PAPER_GRID, PAPER_RHO0

from .camera import _check_common, _crop_size, _header, _inputs, _iso_well, _load, _window_bar
from .common import add_device_argument, designs

RANK_DEFAULT_DESIGNS = ("end_to_end_paper", "rms_w_paper")
"""The designs ranked unless --designs names others: the paper's two (Fig. 8)."""

RANK_DEFAULT_OPTIMISE = ("mse_r", "rms_w")
"""The criteria whose iso-cost optima --cost-levels adds: the end-to-end (MSE_R) and the conventional (RMS_W) design;
the first one's optimum is compared head to head with each other's at every level."""

RANK_ANGLES_DEG = (0.0, 5.0, 10.0)
"""Crop field angles (deg) unless --angles: the axis, mid-field and the edge of a 3:2 photo's reach at 256 px."""

RANK_S_STEP = PAPER_GRID["s"][2]
"""Step in s along each iso-cost curve (the paper grid's, 0.025); the best sample is refined by a parabola."""

RANK_S_RANGE = (-1.5, 0.25)
"""The shape factors searched along each iso-cost curve: the band of the white-light study's grid, which holds every
optimum of the paper's trade-off (s from -0.8 to -0.2, docs/reproduction.md) with room on either side."""

MAX_COST_LEVELS = 8
"""Most --cost-levels (each adds one design per --optimise criterion)."""


def _snr_for_iso(iso: int) -> float:
    """The paper's SNR (dB) of an ISO: the noise level at which its closed-form criterion is read."""
    for snr, i in ISO_FOR_SNR.items():
        if i == iso:
            return snr
    raise ValueError(f"ISO {iso} is not allowed: one of {', '.join(map(str, ISO_FOR_SNR.values()))} (the paper's ISOs, "
                     "each with its SNR for the closed-form criterion)")


def cmd_rank_designs(args) -> int:
    from lenssim.criteria import CRITERIA
    from lenssim.io.files import check_output_dir
    from lenssim.model.numerics import DEFAULT_NUMERICS, FAST_NUMERICS
    from lenssim import select_device
    from lenssim.validate import listed, quoted
    from lenssim_studies.restoration_ranking import (MAX_RANKING_DESIGNS, MAX_RANKING_METHODS, MAX_RANKING_PHOTOS,
                                                     RankingStudy, ranking_angles, iso_cost_optima, optimum_name,
                                                     rank_designs)
    from pipeline.blur import PAPER_SCHEME
    from pipeline.photo import PHOTO_KEEP_BYTES
    from pipeline.restoration import parse_restoration
    from pipeline.simulate import check_methods

    photos = args.photos or [None]
    if len(photos) > MAX_RANKING_PHOTOS:
        raise ValueError(f"{len(photos)} photos are too many: at most {MAX_RANKING_PHOTOS}")
    for photo in photos:
        _header(photo)
    _check_common(args)
    named = designs(args.designs_file)
    chosen = list(RANK_DEFAULT_DESIGNS if args.designs is None else args.designs)
    for d in chosen:
        if d not in named:
            raise ValueError(f"design {quoted(d)} is not known; choose from {listed(sorted(named), near=[d])}")
    if len(set(chosen)) != len(chosen):
        raise ValueError(f"--designs {' '.join(chosen)}: give each design once")
    levels = [] if args.cost_levels is None else list(args.cost_levels)
    if len(levels) > MAX_COST_LEVELS or len(set(levels)) != len(levels):
        raise ValueError(f"--cost-levels {' '.join(f'{v:g}' for v in levels)}: at most {MAX_COST_LEVELS} distinct levels")
    for v in levels:
        if not (math.isfinite(v) and 0 < v <= 1):
            raise ValueError(f"--cost-levels {v:g} is not allowed: an asphere cost C_a in (0, 1] (the paper's range: "
                             "0 to 2e-3)")
    optimise = list(RANK_DEFAULT_OPTIMISE if args.optimise is None else args.optimise)
    for c in optimise:
        if c not in CRITERIA or CRITERIA[c].role != "quality":
            raise ValueError(f"--optimise {quoted(c)} is not allowed: one of "
                             f"{listed(sorted(k for k, v in CRITERIA.items() if v.role == 'quality'), near=[c])}")
    if len(set(optimise)) != len(optimise):
        raise ValueError(f"--optimise {' '.join(optimise)}: give each criterion once")
    count = len(chosen) + len(levels) * len(optimise)
    if not 2 <= count <= MAX_RANKING_DESIGNS:
        raise ValueError(f"{count} design(s) to rank (--designs and --cost-levels x --optimise): give 2 to "
                         f"{MAX_RANKING_DESIGNS}")
    if not 1 <= len(args.restore) <= MAX_RANKING_METHODS:
        raise ValueError(f"--restore: {len(args.restore)} methods; give 1 to {MAX_RANKING_METHODS}")
    isos = list(args.isos or sorted(ISO_FOR_SNR.values(), reverse=True))
    if len(set(isos)) != len(isos):
        raise ValueError(f"--isos {' '.join(map(str, isos))}: give each ISO once")
    snrs = [_snr_for_iso(i) for i in isos]
    wells = [_iso_well(PAPER_CAMERA.sensor, i, args) for i in isos]
    specs = tuple(check_methods([parse_restoration(m) for m in args.restore], scheme=PAPER_SCHEME))
    angles = tuple(RANK_ANGLES_DEG if args.angles is None else args.angles)
    if len(set(angles)) != len(angles):
        raise ValueError(f"--angles {' '.join(f'{a:g}' for a in angles)}: give each angle once")
    out = check_output_dir(args.out, _inputs(photos))
    opened, kept = [], 0
    for photo in photos:  # every photo's pixels checked before the first computation; kept in memory while they fit
        ideal, source = _load(photo, select_device(args.device), max(PHOTO_KEEP_BYTES - kept, 0))
        kept += ideal.nbytes() if ideal.in_memory else 0
        opened.append((source, ideal))
    size = min(_crop_size(args, ideal, source) for source, ideal in opened)
    ranking_angles([(source, ideal.shape) for source, ideal in opened], size, PAPER_CAMERA.geometry, angles)  # bounds
    t0 = time.perf_counter()
    found = iso_cost_optima(PAPER_CAMERA, levels, optimise, snrs[len(snrs) // 2], PAPER_RHO0,
                            s_range=RANK_S_RANGE, s_step=RANK_S_STEP, Q_range=PAPER_GRID["Q_back"][:2],
                            numerics=FAST_NUMERICS) if levels else {}  # the fast preset, as the paper-grid sweep's
    for k, d in found.items():
        print(f"{k}: {d.label()}", file=sys.stderr)
    all_designs = {**{d: named[d] for d in chosen}, **found}
    pairs = []
    if "end_to_end_paper" in all_designs and "rms_w_paper" in all_designs:
        pairs.append(("the paper's designs", "end_to_end_paper", "rms_w_paper"))
    for v in levels:
        for c in optimise[1:]:
            pairs.append((f"C_a = {v:g}", optimum_name(optimise[0], v), optimum_name(c, v)))
    study = RankingStudy(PAPER_CAMERA, all_designs, specs, tuple(isos), tuple(wells), tuple(snrs), angles, size,
                         args.seed, PAPER_RHO0, DEFAULT_NUMERICS, tuple(pairs))
    with _window_bar("rank-designs") as bar:
        rank_designs(study, opened, out, log=lambda m: print(m, file=sys.stderr), progress=bar.update)
    md = (out / "ranking.md").read_text()
    print(md)
    print(f"wrote {out}/ranking.md (+ ranking.csv, ranking_crops.csv, agreement.csv, pairs.csv) in "
          f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


def register(sub) -> None:
    from pipeline import RESTORATION_METHODS

    r = sub.add_parser("rank-designs", help="designs ranked by the PSNR each restoration reaches on photos, beside the "
                       "closed-form MSE_R (the paper's conclusion under each restoration)")
    r.add_argument("photos", nargs="*", help="image files or skimage:NAME; default: the generated scene")
    r.add_argument("--designs", nargs="+", default=None,
                   help=f"named designs (see `lenssim designs`; default: {' '.join(RANK_DEFAULT_DESIGNS)})")
    r.add_argument("--designs-file", metavar="FILE", help="TOML file of named designs (added to the built-in ones)")
    r.add_argument("--cost-levels", type=float, nargs="+", metavar="C_A",
                   help="asphere costs C_a at which the iso-cost optima of --optimise are added (e.g. 2.5e-4 1e-3; the "
                        "paper's range is 0 to 2e-3)")
    r.add_argument("--optimise", nargs="+", metavar="CRITERION",
                   help=f"criteria whose iso-cost optima --cost-levels adds, at the middle ISO's SNR (default: "
                        f"{' '.join(RANK_DEFAULT_OPTIMISE)}; the first is compared with each other at every level)")
    r.add_argument("--restore", nargs="+", default=["wiener"], metavar="NAME[:KEY=VALUE,...]",
                   help=f"restoration methods and their options ({', '.join(RESTORATION_METHODS)}; default: wiener)")
    r.add_argument("--isos", type=int, nargs="+", default=None,
                   help=f"ISOs (default: {' '.join(map(str, sorted(ISO_FOR_SNR.values(), reverse=True)))}); the "
                        "closed form is read at each one's SNR")
    r.add_argument("--angles", type=float, nargs="+", default=None,
                   help=f"crop field angles (deg; default {' '.join(f'{a:g}' for a in RANK_ANGLES_DEG)}, those that fit "
                        "each photo)")
    r.add_argument("--crop", type=int, default=256, help="crop size (px; default 256)")
    r.add_argument("--seed", type=int, default=0, help="noise seed (the same draws for every design)")
    add_device_argument(r)
    r.add_argument("--out", required=True, help="output folder (a rerun with the same settings resumes)")
    r.set_defaults(func=cmd_rank_designs)
