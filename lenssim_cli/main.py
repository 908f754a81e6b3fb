"""The ``lenssim`` console command: assembles the subcommands of the command modules and turns
expected failures into one line on stderr (exit status 2) and Ctrl-C into status 130."""

from __future__ import annotations

import argparse
import os
import re
import sys
import warnings

from lenssim import LensError, __version__
from lenssim_studies.cluster import ClusterError
from lenssim.validate import ResourceLimitError

from . import camera, design, explore, lens, optics, rank, tolerance
from .common import check_arguments

COMMAND_MODULES = (optics, tolerance, camera, rank, lens, design, explore)
"""Each module's ``register(subparsers)`` adds its subcommands."""

EXPECTED_ERRORS = (LensError, ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError,
                   PermissionError, OSError, ClusterError)

OUT_OF_MEMORY_WORDS = ("out of memory", "can't allocate memory", "cannot allocate memory")
"""How torch's allocators (CPU, CUDA) word a failed allocation in their RuntimeErrors."""

OVERRIDE_FLAGS = {"max_fft_size": "--max-fft-size N", "memory_limit_gib": "--memory-limit GIB"}
"""The command-line flag that raises each library limit (ResourceLimitError.setting)."""

NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-inf$|^-nan$", re.IGNORECASE)
"""Negative numbers, exponents included (``--Q -1e6``), are values, not options."""

DESCRIPTION = """Weigh a lens's manufacturing cost against the quality of the restored image.

optics:  evaluate, sweep, optimum, reproduce, study, designs, demo, tolerance
camera:  simulate, psnr-table, fig8, rank-designs
lens:    inspect, tradeoff                 (lenssim COMMAND --help for each)"""


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


MAX_MESSAGE_CHARS = 1000
"""The longest error or warning line printed (characters): the net under every message, whose own wording keeps to
a few names and short quotes (:func:`lenssim.validate.listed`, :func:`lenssim.validate.quoted`); a longer one keeps
its start and its end (what is allowed) and says how much was left out."""


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    if len(text) <= MAX_MESSAGE_CHARS:
        return text
    head, tail = MAX_MESSAGE_CHARS * 2 // 3, MAX_MESSAGE_CHARS // 4
    return f"{text[:head]} [... {len(text) - head - tail} characters left out ...] {text[-tail:]}"


SYMLINK_LOOP = re.compile(r"^Symlink loop from (.*)$", re.DOTALL)
"""Python 3.11's ``pathlib.Path.resolve()`` reports a symbolic link loop as this RuntimeError (naming the resolved
path)."""


def _user_paths(args) -> list[str]:
    """The string values of the command line (the paths the user gave among them)."""
    out = []
    for v in vars(args).values():
        for x in v if isinstance(v, (list, tuple)) else (v,):
            if isinstance(x, (str, os.PathLike)) and str(x):
                out.append(str(x))
    return out


def _as_given(filename, args) -> str | None:
    """The path the user gave for ``filename`` (an error's file name, maybe resolved or internal: a lock file, a
    staging folder or a temporary beside an output), or None."""
    name = os.fsdecode(filename)
    if name in _user_paths(args):
        return name
    target = os.path.abspath(name)
    best = None
    for v in _user_paths(args):
        for a in {os.path.abspath(v), os.path.realpath(v)}:
            base, folder = os.path.basename(a.rstrip("/")), os.path.dirname(a.rstrip("/"))
            inside = target == a or target.startswith(a.rstrip("/") + "/")
            beside = bool(base) and any(target.startswith(os.path.join(folder, f".{b}.")) for b in
                                        {base, os.path.splitext(base)[0]})  # .NAME.lock, .NAME.staging-*, .STEM.*.EXT
            if (inside or beside) and (best is None or len(a) > best[0]):
                best = (len(a), v)
    return best[1] if best else None


def _internal(filename) -> bool:
    base = os.path.basename(os.fsdecode(filename).rstrip("/"))
    return base.startswith(".") and any(k in base for k in (".lock", ".staging-", ".lenssim-probe-"))


def _os_error_line(exc: OSError, args) -> str:
    from lenssim.io.files import describe_os_error

    given = _as_given(exc.filename, args)
    if given is None and _internal(exc.filename):
        return describe_os_error(exc, None, "an output", action="written")
    return describe_os_error(exc, given if given is not None else os.fsdecode(exc.filename), "", action="used")


def _loop_line(exc: RuntimeError, args) -> str:
    """A symbolic link loop (pathlib's RuntimeError) on one line, naming the path the user gave that loops."""
    import errno

    from lenssim.io.files import describe_os_error

    loop = OSError(errno.ELOOP, os.strerror(errno.ELOOP))
    for v in _user_paths(args):
        try:
            os.stat(v)
        except OSError as e:
            if e.errno == errno.ELOOP:
                return describe_os_error(loop, v, "", action="used")
        except ValueError:
            pass
    found = SYMLINK_LOOP.match(str(exc)).group(1).strip()
    given = _as_given(found.strip("'\""), args)
    return describe_os_error(loop, given, "", action="used") if given else f"a symbolic link loop at {found}"


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
            if isinstance(exc, RuntimeError) and SYMLINK_LOOP.match(str(exc)):
                print(f"{prefix}: error: {_loop_line(exc, args)}", file=sys.stderr)
                return 2
            if isinstance(exc, RuntimeError) and not any(w in str(exc).lower() for w in OUT_OF_MEMORY_WORDS):
                raise
            print(f"{prefix}: error: out of memory ({_one_line(exc)[:200]}); use a smaller input, grid or window",
                  file=sys.stderr)
            return 2
        except OSError as exc:  # the last net: one line naming the user's path, the reason in words
            if exc.filename is not None and exc.errno is not None:
                print(f"{prefix}: error: {_os_error_line(exc, args)}", file=sys.stderr)
            else:
                print(f"{prefix}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        except EXPECTED_ERRORS as exc:
            print(f"{prefix}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f"{prefix}: interrupted; run the same command again to resume", file=sys.stderr)
            return 130


GLIBC_MMAP_THRESHOLD_BYTES = 64 * 2**20
"""Allocations at least this large get their own pages from the kernel (glibc's ``M_MMAP_THRESHOLD``; its own default
adapts up to 32 MiB). The whole-frame passes allocate and free buffers of 9-40 MB over and over (bands of 128 rows of a
24 MP frame, window batches sized to the CPU's cache): each such buffer mapped afresh is a page fault per 4 KiB,
zeroed by the kernel, on every pass."""

GLIBC_TRIM_THRESHOLD_BYTES = 128 * 2**20
"""Free memory at the top of glibc's heap kept for the next allocation instead of handed back to the kernel
(``M_TRIM_THRESHOLD``; its own default adapts to twice the mmap threshold): at most this much is held beyond what
is in use. Scoring a 24 MP pair (``scores_encoded``, 2 cores) took 2.2-3.2 s with glibc's defaults, 1.7-1.9 s with
either threshold of 64, 128, 256 or 512 MiB (the mmap threshold is what counts); with 512 MiB the whole frame's
peak resident memory reached 3.13 GB in one run of two (docs/performance.md)."""

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
"""glibc's ``mallopt`` parameter numbers (malloc.h)."""


def tune_allocator() -> bool:
    """Set glibc's heap thresholds (:data:`GLIBC_MMAP_THRESHOLD_BYTES`, :data:`GLIBC_TRIM_THRESHOLD_BYTES`) for this
    process; True if they were set, False where the C library is not glibc (nothing changes there). For the console
    command only: a Python caller's process is the caller's to tune."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        libc.gnu_get_libc_version  # glibc only (musl, macOS and Windows have no mallopt of these meanings)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, GLIBC_MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, GLIBC_TRIM_THRESHOLD_BYTES))


def entry() -> None:
    """The ``lenssim`` console script: :func:`main` (glibc's heap thresholds set first, :func:`tune_allocator`), then
    exit without interpreter teardown.

    colour-science imports OpenImageIO, and with torch also loaded the interpreter's teardown runs
    in an order where OpenImageIO's nanobind bindings report their module-level objects as
    "leaked" (a page of messages after every pipeline command, exit status still 0). Every output
    is complete and closed when ``main`` returns (atomic writes), so the script flushes its streams
    and leaves directly. ``main`` itself (tests, Python callers) is unaffected.
    """
    from pipeline.io import exit_without_teardown

    tune_allocator()
    exit_without_teardown(main())


if __name__ == "__main__":
    entry()
