"""Helpers shared by the command modules: design arguments, named designs, tables, devices."""

from __future__ import annotations

import argparse
import dataclasses

from lenssim import PARAMETERS, Design
from lenssim.torch_utils import DEVICE_CHOICES

__all__ = ["add_design_arguments", "design_from_args", "designs", "table", "add_device_argument",
           "add_camera_arguments", "camera_from_args", "add_tolerance_arguments", "tolerances_from_args"]


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
            raise ValueError(f"design {args.design!r} is not known; choose from {', '.join(sorted(table_))}")
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


def add_device_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="auto", help=DEVICE_CHOICES)


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """``--glass NAME``, ``--spectrum NAME``, ``--illuminant NAME``, ``--wavelengths-per-channel N``."""
    from lenssim.model.spectrum import DEFAULT_WAVELENGTHS_PER_CHANNEL

    p.add_argument("--glass", help="a glass of the catalogue (configs/glasses.toml: paper, N-BK7, N-SF5, PMMA); "
                                   "default: the paper's non-dispersive n = 1.5")
    p.add_argument("--spectrum", default="paper",
                   help="paper (one wavelength, 0.5 um, every colour) or a camera's RGB sensitivities from "
                        "colour-science, e.g. \"Nikon 5100 (NPL)\" (one spectrum per colour channel)")
    p.add_argument("--illuminant", default="D65", help="CIE illuminant of a colour --spectrum (default D65)")
    p.add_argument("--wavelengths-per-channel", type=int, default=DEFAULT_WAVELENGTHS_PER_CHANNEL, metavar="N",
                   help=f"wavelengths sampled per colour channel (default {DEFAULT_WAVELENGTHS_PER_CHANNEL})")
    p.add_argument("--wavefront", choices=("third_order", "exact"), default="third_order",
                   help="the paper's third-order (Seidel) wavefront, or the exact one (the OPD of a ray trace) "
                        "(one-wavelength spectrum only)")


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
                  channels=channel_spectra(spec, args.illuminant, args.wavelengths_per_channel))


def add_tolerance_arguments(p: argparse.ArgumentParser, *, switches: bool = True) -> None:
    """``--grade``, ``--tolerances FILE`` and (``switches``) ``--off TERM``, ``--no-focus-compensation``."""
    from lenssim.model.tolerances import GRADES

    p.add_argument("--grade", default="commercial", choices=tuple(GRADES),
                   help="tolerance grade (docs/as-built.md gives the values and sources; default commercial)")
    p.add_argument("--tolerances", metavar="FILE", help="TOML file with a [tolerances] table (grade = ..., and any "
                   "term's limit; see docs/as-built.md)")
    if switches:
        p.add_argument("--off", action="append", metavar="TERM", help="switch a tolerance term off (repeatable)")
        p.add_argument("--no-focus-compensation", action="store_true",
                       help="leave the image plane at the nominal distance (default: focused at assembly)")


def tolerances_from_args(args):
    """The :class:`lenssim.Tolerances` of ``--grade``, ``--tolerances FILE``, ``--off TERM`` and
    ``--no-focus-compensation``."""
    from lenssim.io.files import read_toml
    from lenssim.model.tolerances import Tolerances, grade

    t = grade(args.grade)
    if args.tolerances:
        table = read_toml(args.tolerances, "tolerances file")
        unknown = sorted(set(table) - {"tolerances"})
        if unknown or "tolerances" not in table:
            raise ValueError(f"tolerances file {args.tolerances!r}: expected one [tolerances] table"
                             + (f"; unknown table(s) {unknown}" if unknown else ""))
        t = Tolerances.from_dict({"grade": args.grade, **table["tolerances"]})
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
