"""Helpers shared by the command modules: design arguments, named designs, tables, devices."""

from __future__ import annotations

import argparse
import dataclasses

from lenssim import PARAMETERS, Design
from lenssim.torch_utils import DEVICE_CHOICES
from lenssim.validate import listed, quoted

__all__ = ["add_design_arguments", "design_from_args", "designs", "table", "add_device_argument",
           "add_camera_arguments", "resolve_wavefront", "camera_from_args", "add_tolerance_arguments", "tolerances_from_args",
           "check_arguments"]


DEFAULT_ILLUMINANT = "D65"
"""The CIE illuminant of a colour ``--spectrum`` when none is named."""

DEFAULT_GRADE = "commercial"
"""The tolerance grade when none is named."""

WORKERS_PER_CPU = 4
"""``--workers`` may ask for at most this many local processes per CPU core (more only thrash)."""

MAX_WORKER_THREADS = 1024
"""``--worker-threads`` at most: torch threads per task beyond the cores of any one machine (the largest have a few
hundred) only thrash, and the count may be for a cluster's machines, not this one's."""


def check_arguments(args) -> None:
    """Values of the common flags, checked before any work (each command has its own further checks): empty names,
    flags that need another one, limits that must be positive. Raises ``ValueError`` with one line."""
    import math
    import os

    from lenssim.validate import (MAX_SEED, check_distinct, check_max_fft_size, check_pixel_pitch_um,
                                  check_snr_db)

    for flag, name in (("--glass", "glass"), ("--spectrum", "spectrum"), ("--illuminant", "illuminant")):
        v = getattr(args, name, None)
        if v is not None and not str(v).strip():
            raise ValueError(f"{flag} '' is not allowed: give a name (see {flag} in --help)")
    colour = (getattr(args, "spectrum", None) or "paper") != "paper"
    for flag, name in (("--illuminant", "illuminant"), ("--wavelengths-per-channel", "wavelengths_per_channel")):
        if getattr(args, name, None) is not None and not colour and getattr(args, "command", "") != "study":
            raise ValueError(f"{flag} applies to a colour --spectrum (e.g. \"Nikon 5100 (NPL)\"); --spectrum paper "
                             "has one wavelength")
    resolve_wavefront(args)
    seed = getattr(args, "seed", None)
    if isinstance(seed, int) and not 0 <= seed <= MAX_SEED:
        raise ValueError(f"--seed {seed} is not allowed: a whole number from 0 to {MAX_SEED} (2**62)")
    n = getattr(args, "max_fft_size", None)
    if n is not None:
        check_max_fft_size(n, "--max-fft-size")
    pitch = getattr(args, "pixel_pitch", None)
    if pitch is not None:
        check_pixel_pitch_um(pitch, "--pixel-pitch")
    m = getattr(args, "memory_limit", None)
    if m is not None and not (math.isfinite(m) and m > 0):
        raise ValueError(f"--memory-limit {m:g} is not allowed: a positive number of GiB")
    for flag, name, what in (("--workers", "workers", "local worker processes"),
                             ("--worker-threads", "worker_threads", "threads")):
        v = getattr(args, name, None)
        if v is not None and v < 1:
            raise ValueError(f"{flag} {v} is not allowed: a number of {what} >= 1")
    t = getattr(args, "worker_threads", None)
    if t is not None and t > MAX_WORKER_THREADS:
        raise ValueError(f"--worker-threads {t} is not allowed: at most {MAX_WORKER_THREADS} threads per task")
    for flag, name in (("--snr", "snr"), ("--reference-snr", "reference_snr")):  # the criteria's rule (evaluate's)
        values = getattr(args, name, None)
        if values is not None:  # refused here; outside the validated range, warned where a run computes
            check_snr_db(values, flag, warn=False)
    for flag, name in (("--isos", "isos"), ("--snr", "snr"), ("--angles", "angles")):
        values = getattr(args, name, None)
        if isinstance(values, (list, tuple)):
            check_distinct(flag, values, as_written=True)  # as written in tables and file names
    w = getattr(args, "workers", None)
    most = WORKERS_PER_CPU * (os.cpu_count() or 1)
    if w is not None and w > most:
        raise ValueError(f"--workers {w} is not allowed: at most {most} local processes ({WORKERS_PER_CPU} per CPU "
                         "core); use --scheduler ADDRESS for a cluster")
    focus = getattr(args, "best_focus", None)
    if focus is not None:
        from lenssim.criteria import quality_criteria

        if focus not in quality_criteria():
            raise ValueError(f"--best-focus {focus!r} is not allowed: an image-quality criterion of one lens, one of "
                             f"{', '.join(quality_criteria())}")
        if getattr(args, "param_focus_shift_um", None) is not None:
            raise ValueError("--best-focus finds focus_shift_um; give it or --focus_shift_um, not both")
    if hasattr(args, "as_built") and args.as_built is None:
        given = [f for f, k in (("--grade", "grade"), ("--tolerances", "tolerances"), ("--off", "off"),
                                ("--no-focus-compensation", "no_focus_compensation")) if getattr(args, k, None)]
        if given:
            raise ValueError(f"{', '.join(given)} describe(s) the manufactured lens of --as-built SEED; give "
                             "--as-built, or leave them out")


def add_design_arguments(p: argparse.ArgumentParser, *, named: bool = True) -> None:
    """``--design NAME`` / ``--designs FILE`` and one ``--NAME VALUE`` per design parameter (and alias)."""
    if named:
        p.add_argument("--design", help="a named design (see `lenssim designs`)")
        p.add_argument("--designs", metavar="FILE", help="TOML file of named designs (added to the built-in ones)")
    for prm in PARAMETERS.values():
        flags = [f"--{prm.name}"] + [f"--{a}" for a in prm.aliases]
        p.add_argument(*flags, dest=f"param_{prm.name}", type=float, metavar="VALUE",
                       help=f"{prm.description} [{prm.unit}] (default {prm.default:g}"
                            + (f"; alias {', '.join('--' + a for a in prm.aliases)}" if prm.aliases else "") + ")")


def designs(path: str | None = None) -> dict[str, Design]:
    from lenssim_studies.paper import paper_designs

    return paper_designs(path)


def design_from_args(args, *, name: str = "custom") -> Design:
    """The design of ``--design NAME`` (parameters given beside it override the named values) or of
    the parameter flags (parameters not given take their defaults)."""
    given = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}
    if getattr(args, "design", None) is not None:
        table_ = designs(getattr(args, "designs", None))
        if args.design not in table_:
            raise ValueError(f"design {quoted(args.design)} is not known; choose from "
                             f"{listed(sorted(table_), near=[args.design])}")
        d = table_[args.design]
        return d.replace(**given) if given else d
    if not given:
        flags = ", ".join(f"--{n}" for n in PARAMETERS)
        raise ValueError(f"give a named design (--design NAME) or design parameters ({flags})")
    return Design(given, name=name)


def table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    line = lambda r: "  ".join(str(x).rjust(w) for x, w in zip(r, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths])] + [line(r) for r in rows])


def numerics_from_args(args, base=None):
    """``base`` (default :data:`lenssim.DEFAULT_NUMERICS`) with ``--max-fft-size`` where given."""
    from lenssim import DEFAULT_NUMERICS

    base = DEFAULT_NUMERICS if base is None else base
    return base.replace(max_fft_size=args.max_fft_size) if getattr(args, "max_fft_size", None) else base


def add_device_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="auto", help=DEVICE_CHOICES)


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """``--glass NAME``, ``--spectrum NAME``, ``--illuminant NAME``, ``--wavelengths-per-channel N``."""
    p.add_argument("--glass", help="a glass of the catalogue (configs/glasses.toml: paper, PMMA, and SCHOTT, OHARA, "
                                   "HOYA, CDGM, HIKARI glasses such as N-BK7, N-SF5, S-BSL7; any case, optionally "
                                   "CATALOGUE:NAME); default: the paper's non-dispersive n = 1.5")
    p.add_argument("--spectrum", default="paper",
                   help="paper (one wavelength, 0.5 um, every colour) or a camera's RGB sensitivities from "
                        "colour-science, e.g. \"Nikon 5100 (NPL)\" (one spectrum per colour channel)")
    p.add_argument("--illuminant", help="CIE illuminant of a colour --spectrum (default D65)")
    p.add_argument("--wavelengths-per-channel", type=int, metavar="N",
                   help="wavelengths sampled per colour channel, each channel its own (default: the 5 nm table "
                        "integrated with a few wavelengths shared by the channels, Numerics.spectral_tol)")
    p.add_argument("--wavefront", choices=("third_order", "exact"), default=None,
                   help="the paper's singlet: its third-order (Seidel) wavefront (default), or the exact one (the OPD "
                        "of a ray trace; one-wavelength spectrum only); --lens LENS: always exact (real rays)")
    p.set_defaults(wavefront_of_camera=True)  # resolve_wavefront applies to this flag, not tradeoff's own


def resolve_wavefront(args) -> None:
    """``args.wavefront`` made explicit before any work: with ``--lens`` the real rays' wavefront (``exact``), which
    is what a lens file is evaluated with (``--wavefront third_order`` is refused: it would be ignored); without it
    the paper's third order unless ``--wavefront exact`` was given."""
    if not getattr(args, "wavefront_of_camera", False):
        return
    if getattr(args, "lens", None) is not None:
        if args.wavefront == "third_order":
            raise ValueError("--wavefront third_order with --lens: a lens file is evaluated with its real rays' "
                             "wavefront (exact) here; the third-order route of a lens is `lenssim tradeoff --lens LENS "
                             "--wavefront third_order`")
        args.wavefront = "exact"
    elif args.wavefront is None:
        args.wavefront = "third_order"


def camera_from_args(args):
    """The paper's camera, with the glass and spectrum the arguments name."""
    from lenssim import Camera, Lens
    from lenssim_studies.paper import PAPER_CAMERA
    from lenssim.model.spectrum import channel_spectra

    lens = PAPER_CAMERA.lens if not getattr(args, "glass", None) else Lens.from_dict({**PAPER_CAMERA.lens.to_dict(),
                                                                                       "glass": args.glass,
                                                                                       "refractive_index": None})
    spec = getattr(args, "spectrum", "paper") or "paper"
    if spec == "paper":
        return Camera(lens, PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum)
    return Camera(lens, PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum,
                  channels=channel_spectra(spec, args.illuminant or DEFAULT_ILLUMINANT, args.wavelengths_per_channel))


def add_tolerance_arguments(p: argparse.ArgumentParser, *, switches: bool = True) -> None:
    """``--grade``, ``--tolerances FILE`` and (``switches``) ``--off TERM``, ``--no-focus-compensation``."""
    from lenssim.model.tolerances import GRADES

    p.add_argument("--grade", choices=tuple(GRADES),
                   help="tolerance grade (docs/as-built.md gives the values and sources; default commercial)")
    p.add_argument("--tolerances", metavar="FILE", help="TOML file with a [tolerances] table (grade = ..., and any "
                   "term's limit; see docs/as-built.md)")
    if switches:
        p.add_argument("--off", action="append", metavar="TERM", help="switch a tolerance term off (repeatable)")
        p.add_argument("--no-focus-compensation", action="store_true",
                       help="leave the image plane at the nominal distance (default: focused at assembly)")


def graded_tolerances(args, kind):
    """The tolerances of ``--grade`` (``kind.grade(name)``), or of ``--tolerances FILE``'s one ``[tolerances]`` table
    on top of that grade (``kind.from_dict``): the singlet's (``kind`` :class:`lenssim.Tolerances`) and any lens's
    (:class:`lenssim.model.tolerances.SurfaceTolerances`) alike."""
    from lenssim.io.files import read_toml

    name = args.grade or DEFAULT_GRADE
    if not args.tolerances:
        return kind.grade(name)
    table = read_toml(args.tolerances, "tolerances file")
    unknown = sorted(set(table) - {"tolerances"})
    if unknown or "tolerances" not in table:
        raise ValueError(f"tolerances file {args.tolerances!r}: expected one [tolerances] table"
                         + (f"; unknown table(s) {listed(unknown)}" if unknown else ""))
    return kind.from_dict({"grade": name, **table["tolerances"]})


def tolerances_from_args(args):
    """The :class:`lenssim.Tolerances` of ``--grade``, ``--tolerances FILE``, ``--off TERM`` and
    ``--no-focus-compensation``."""
    from lenssim.model.tolerances import Tolerances

    t = graded_tolerances(args, Tolerances)
    for term in getattr(args, "off", None) or ():
        if term == "figure":
            t = dataclasses.replace(t, figure_floor=0.0, figure_per_cost=0.0)
        elif term in {f.name for f in dataclasses.fields(t)} - {"figure_exponent", "focus_compensated"}:
            t = dataclasses.replace(t, **{term: 0.0})
        else:
            names = [n for n in Tolerances().to_dict() if not n.startswith(("figure", "focus"))]
            raise ValueError(f"--off {term!r} is not allowed: one of {', '.join(names)}, figure")
    if getattr(args, "no_focus_compensation", False):
        t = dataclasses.replace(t, focus_compensated=False)
    return t
