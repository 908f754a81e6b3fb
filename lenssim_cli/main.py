"""The ``lenssim`` console command: assembles the subcommands of the command modules and turns
expected failures into one line on stderr (exit status 2) and Ctrl-C into status 130."""

from __future__ import annotations

import argparse
import os
import sys

from lenssim import LensError, __version__

from . import camera, optics

COMMAND_MODULES = (optics, camera)
"""Each module's ``register(subparsers)`` adds its subcommands."""

EXPECTED_ERRORS = (LensError, ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError,
                   PermissionError)

DESCRIPTION = """Weigh a lens's manufacturing cost against the quality of the restored image.

optics:  evaluate, sweep, optimum, reproduce, designs, demo
camera:  simulate, psnr-table, fig8        (lenssim COMMAND --help for each)"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lenssim", description=DESCRIPTION,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"lenssim {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for module in COMMAND_MODULES:
        module.register(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except EXPECTED_ERRORS as exc:
        print(f"lenssim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"lenssim {args.command}: interrupted; run the same command again to resume", file=sys.stderr)
        return 130


def entry() -> None:
    """The ``lenssim`` console script: :func:`main`, then exit without interpreter teardown.

    colour-science imports OpenImageIO, and with torch also loaded the interpreter's teardown runs
    in an order where OpenImageIO's nanobind bindings report their module-level objects as
    "leaked" (a page of messages after every pipeline command, exit status still 0). Every output
    is complete and closed when ``main`` returns (atomic writes), so the script flushes its streams
    and leaves directly. ``main`` itself (tests, Python callers) is unaffected.
    """
    rc = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)


if __name__ == "__main__":
    entry()
