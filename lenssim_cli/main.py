"""The ``lenssim`` console command: assembles the subcommands of the command modules and turns
expected failures into one line on stderr (exit status 2) and Ctrl-C into status 130."""

from __future__ import annotations

import argparse
import re
import sys
import warnings

from lenssim import LensError, __version__
from lenssim_studies.cluster import ClusterError
from lenssim.validate import ResourceLimitError

from . import camera, optics, tolerance
from .common import check_arguments

COMMAND_MODULES = (optics, tolerance, camera)
"""Each module's ``register(subparsers)`` adds its subcommands."""

EXPECTED_ERRORS = (LensError, ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError,
                   PermissionError, OSError, ClusterError)

OVERRIDE_FLAGS = {"max_fft_size": "--max-fft-size N", "memory_limit_gib": "--memory-limit GIB"}
"""The command-line flag that raises each library limit (ResourceLimitError.setting)."""

NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-inf$|^-nan$", re.IGNORECASE)
"""Negative numbers, exponents included (``--Q -1e6``), are values, not options."""

DESCRIPTION = """Weigh a lens's manufacturing cost against the quality of the restored image.

optics:  evaluate, sweep, optimum, reproduce, study, designs, demo, tolerance
camera:  simulate, psnr-table, fig8        (lenssim COMMAND --help for each)"""


class OneLineParser(argparse.ArgumentParser):
    """argparse, with its errors on one line (``lenssim CMD: error: ...``, exit status 2) instead of the usage block
    and the message: the rule every other refusal of the command line follows (``--help`` still shows the usage)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {' '.join(str(message).split())} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="lenssim", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"lenssim {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    for module in COMMAND_MODULES:
        module.register(sub)
    for parser in [p, *sub.choices.values()]:
        parser._negative_number_matcher = NEGATIVE_NUMBER  # argparse's own matcher misses exponents
    return p


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    prefix = f"lenssim {args.command}"

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{prefix}: warning: {_one_line(message)}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        warnings.simplefilter("once")
        try:
            check_arguments(args)
            return args.func(args)
        except ResourceLimitError as exc:
            flag = OVERRIDE_FLAGS.get(exc.setting)
            print(f"{prefix}: error: {_one_line(exc)}" + (f"; raise it with {flag}" if flag else ""), file=sys.stderr)
            return 2
        except (MemoryError, RuntimeError) as exc:
            if isinstance(exc, RuntimeError) and "out of memory" not in str(exc).lower():
                raise
            print(f"{prefix}: error: out of memory ({_one_line(exc)[:200]}); use a smaller input, grid or window",
                  file=sys.stderr)
            return 2
        except EXPECTED_ERRORS as exc:
            print(f"{prefix}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f"{prefix}: interrupted; run the same command again to resume", file=sys.stderr)
            return 130


def entry() -> None:
    """The ``lenssim`` console script: :func:`main`, then exit without interpreter teardown.

    colour-science imports OpenImageIO, and with torch also loaded the interpreter's teardown runs
    in an order where OpenImageIO's nanobind bindings report their module-level objects as
    "leaked" (a page of messages after every pipeline command, exit status still 0). Every output
    is complete and closed when ``main`` returns (atomic writes), so the script flushes its streams
    and leaves directly. ``main`` itself (tests, Python callers) is unaffected.
    """
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())


if __name__ == "__main__":
    entry()
