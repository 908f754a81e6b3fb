"""Files shared by every command: atomic output (a crash or Ctrl-C never leaves a half-written file), the checks
of the files a user names (inputs that can be read, outputs that can be written) and their errors in words.

The writer fills a temporary file in the destination folder (same extension, so format-sniffing
writers such as matplotlib and OpenImageIO still work), which is then given the usual permissions
(``0o666`` less the umask, as ``open()`` would) and renamed over the destination.

An operating-system error a user can provoke (a symbolic link loop, a name too long, a read-only or special file
system, a folder given as a file, a named pipe, ...) becomes one line that names the user's path as given
(:func:`describe_os_error`); internal names (the lock file, the staging folder, temporaries) never reach a message.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_text", "json_text", "check_input_file", "check_output_dir",
           "check_output_file", "describe_os_error", "InputFileError", "OutputPathError", "OutputLockedError",
           "output_lock", "staged_output_dir", "read_toml"]


def _default_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _naming(exc: OSError, path) -> OSError:
    """``exc`` naming ``path`` (the destination) instead of an internal temporary."""
    return OSError(exc.errno, exc.strerror, str(path))


def atomic_write(path, writer) -> Path:
    """Call ``writer(tmp_path: str)`` and move the result to ``path`` (folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    except OSError as exc:
        raise _naming(exc, path) from None
    os.close(fd)
    try:
        writer(tmp)
        os.chmod(tmp, _default_mode())
        os.replace(tmp, path)
    except OSError as exc:
        if exc.errno is None or tmp not in (exc.filename, exc.filename2):
            raise
        raise _naming(exc, path) from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def json_text(obj, *, indent: int = 2) -> str:
    """JSON of ``obj`` with every number finite: ``inf`` (e.g. the PSNR of identical images) becomes ``null``,
    NaN raises :class:`lenssim.validate.NumericalError` naming where it is (bare NaN is not JSON)."""
    import math

    from ..validate import NumericalError

    def clean(v, where):
        if isinstance(v, float):
            if math.isnan(v):
                raise NumericalError(f"{where or 'a result'} is NaN: not written")
            return v if math.isfinite(v) else None
        if isinstance(v, dict):
            return {k: clean(x, f"{where}.{k}" if where else str(k)) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x, f"{where}[{i}]") for i, x in enumerate(v)]
        return v

    import json

    return json.dumps(clean(obj, ""), indent=indent, allow_nan=False)


class InputFileError(ValueError):
    """A file the user named cannot be read (missing, a folder, a device or named pipe, a symbolic link loop, ...);
    the message is one line naming the path as the user gave it."""


class OutputPathError(OSError):
    """An output the user named cannot be written (read-only or special file system, a file where a folder is needed,
    a symbolic link loop, a name too long, ...); the message is one line naming the path as the user gave it."""


class OutputLockedError(OSError):
    """Another run holds the lock of the output a run would write."""


_REASONS = {
    errno.ELOOP: "a symbolic link loop",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied (operation not permitted)",
    errno.EROFS: "read-only file system",
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EISDIR: "it is a folder, not a file",
    errno.EIO: "an input/output error (a failing disk or a lost network file system?)",
    errno.ENXIO: "no such device (a device that is not there, or a socket)",
    errno.ENODEV: "no such device",
    errno.EBUSY: "the device is busy",
    errno.ETXTBSY: "the file is busy (a program being run)",
    errno.EMFILE: "too many open files",
    errno.ENFILE: "too many open files in the system",
    errno.EFBIG: "the file is too large",
    errno.ESTALE: "a stale network file handle",
    errno.EEXIST: "it exists already",
    errno.EXDEV: "it is on another file system",
    errno.EINVAL: "the file system refuses this name or operation",
}
"""errno -> the reason in words (others: ``os.strerror``)."""

_SPECIAL_FILE_SYSTEMS = frozenset({
    "proc", "sysfs", "devtmpfs", "devpts", "cgroup", "cgroup2", "debugfs", "tracefs", "securityfs", "configfs",
    "pstore", "bpf", "fusectl", "efivarfs", "mqueue", "hugetlbfs", "binfmt_misc", "autofs", "selinuxfs", "nsfs",
    "rpc_pipefs"})
"""Kernel file systems (``/proc``, ``/sys``, ``/dev``, ...): not a place for a run's outputs."""

_FILE_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a named pipe"),
               (stat.S_ISSOCK, "a socket"))


def _shown(path) -> str:
    return repr(os.fsdecode(path) if isinstance(path, bytes) else str(path))


def _non_folder_on(path) -> str | None:
    """The first part of ``path`` (as given) that exists and is not a folder, if any."""
    parts = Path(path).parts
    for i in range(1, len(parts)):
        q = Path(*parts[:i])
        try:
            if not stat.S_ISDIR(os.stat(q).st_mode):
                return str(q)
        except (OSError, ValueError):
            return None
    return None


def _reason(exc: OSError, path) -> str:
    """Why ``exc`` happened to ``path``, in words (never naming another path than the user's)."""
    code = exc.errno
    if code == errno.ENOENT:
        try:
            if os.path.islink(path):
                return f"a dangling symbolic link (its target {os.readlink(path)!r} does not exist)"
        except (OSError, ValueError):
            pass
        return "it does not exist"
    if code == errno.ENOTDIR:
        bad = _non_folder_on(path)
        return f"{bad!r} is a file, not a folder" if bad else "a part of the path is not a folder"
    if code in _REASONS:
        return _REASONS[code]
    if code is not None:
        return os.strerror(code)[:1].lower() + os.strerror(code)[1:]
    return " ".join(str(exc.strerror or type(exc).__name__).split())


def describe_os_error(exc: OSError, path, what: str, *, action: str = "read") -> str:
    """One line for ``exc`` raised on ``path`` (shown as the user gave it, never resolved), e.g.
    ``photo 'x/y.png' cannot be read: a symbolic link loop`` or ``output folder 'o' cannot be written: read-only
    file system``. ``what`` names the file ("photo", "designs file"; empty: the path alone; ``path`` None: ``what``
    alone), ``action`` what was to be done with it ("read", "written", "used"). The reason comes from ``exc.errno``
    (``os.strerror`` for the rarer ones); ``exc.filename`` is never shown (it may be an internal or resolved name)."""
    subject = what if path is None else f"{what} {_shown(path)}" if what else _shown(path)
    reason = _reason(exc, "" if path is None else path)
    if reason == "it does not exist" and action == "read":
        return f"{subject} does not exist"
    return f"{subject} cannot be {action}: {reason}"


def _loop_error(path) -> OSError:
    return OSError(errno.ELOOP, os.strerror(errno.ELOOP), str(path))


def _resolve(path) -> Path:
    """``Path(path).resolve()``, a symbolic link loop raising ``OSError(ELOOP)`` on the path given (Python 3.11's
    pathlib raises ``RuntimeError`` naming the resolved path)."""
    try:
        return Path(path).resolve()
    except RuntimeError:
        raise _loop_error(path) from None


def check_input_file(path, what: str) -> Path:
    """Before any work: ``path`` names a regular file (or a symbolic link to one) that can be opened for reading.

    A folder, a device (``/dev/zero`` would never end), a named pipe (it would block) or a socket, a missing file,
    a dangling link, a symbolic link loop, a name too long, or a file that cannot be opened raise
    :class:`InputFileError`, one line naming ``what`` and the path as given. Returns ``Path(path)``."""
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
        if stat.S_ISDIR(mode):
            raise InputFileError(f"{what} {_shown(path)} is not a file: it is a folder")
        if not stat.S_ISREG(mode):
            raise InputFileError(f"{what} {_shown(path)} is not a regular file ({_kind(mode)})")
        _resolve(p)
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)  # non-blocking: a file swapped for a pipe meanwhile cannot hang
        os.close(fd)
    except OSError as exc:
        raise InputFileError(describe_os_error(exc, path, what)) from None
    except ValueError as exc:
        if isinstance(exc, InputFileError):
            raise
        raise InputFileError(f"{what} {_shown(path)} is not a valid file name ({exc})") from None
    return p


def _mount_type(path: Path) -> tuple[str, str] | None:
    """(mount point, file-system type) of the existing ``path``, from ``/proc/self/mountinfo``; None if unknown."""
    try:
        real = os.path.realpath(path)
        with open("/proc/self/mountinfo", encoding="utf-8", errors="surrogateescape") as fh:
            lines = fh.read().splitlines()
    except (OSError, ValueError):
        return None

    def unescape(s):  # mount points escape spaces, tabs, newlines and backslashes in octal (\040)
        import re

        return re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), s)

    best = None
    for line in lines:
        fields = line.split()
        try:
            point, fstype = unescape(fields[4]), fields[fields.index("-", 6) + 1]
        except (IndexError, ValueError):
            continue
        inside = real == point or real.startswith(point.rstrip("/") + "/")
        if inside and (best is None or len(point) >= len(best[0])):  # the last (top) of equal mounts wins
            best = (point, fstype)
    return best


def _writable_ancestor(path, what: str) -> Path:
    """The nearest existing folder of ``path`` (spelt as given; ``path`` itself if it is a folder, its folder if it is
    a file), proved writable by creating and removing a file in it; else :class:`OutputPathError`,
    ``"{what} 'PATH' cannot be written: REASON"``."""
    def fail(reason):
        return OutputPathError(f"{what} {_shown(path)} cannot be written: {reason}")

    q = Path(path)
    try:
        while True:
            try:
                mode = os.stat(q).st_mode
            except FileNotFoundError:
                if os.path.islink(q) or q.parent == q:  # a dangling link: creating the output would follow it
                    raise
                q = q.parent
                continue
            if stat.S_ISDIR(mode):
                break
            if q != Path(path):
                raise fail(f"{str(q)!r} is a file, not a folder")
            q = q.parent  # an existing output file: its folder
        _resolve(q)
    except OSError as exc:
        if isinstance(exc, OutputPathError):
            raise
        raise fail(_reason(exc, q if exc.errno == errno.ENOENT else path)) from None
    except ValueError as exc:
        raise fail(f"not a valid file name ({exc})") from None
    try:  # the folders still to be created: no name may exceed the file system's limit (checked now, not at the end)
        name_max, path_max = os.pathconf(q, "PC_NAME_MAX"), os.pathconf(q, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    if (any(len(os.fsencode(c)) > name_max for c in Path(path).parts[len(q.parts):])
            or len(os.fsencode(os.path.abspath(path))) >= path_max):
        raise fail(_REASONS[errno.ENAMETOOLONG])
    mount = _mount_type(q)
    if mount is not None and mount[1] in _SPECIAL_FILE_SYSTEMS:
        raise fail(f"{mount[0]} is a special file system ({mount[1]}), not a place for files")
    try:
        fd, probe = tempfile.mkstemp(prefix=".lenssim-probe-", dir=q)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise fail(_reason(exc, path)) from None
    return q


def _stat_output(path, what: str) -> os.stat_result | None:
    """The ``stat`` of the output ``path`` if it exists, None if not; a symbolic link loop, a name too long, a file
    in the way or an invalid name raise :class:`OutputPathError`."""
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise OutputPathError(describe_os_error(exc, path, what, action="written")) from None
    except ValueError as exc:
        raise OutputPathError(f"{what} {_shown(path)} is not a valid file name ({exc})") from None


def _kind(mode: int) -> str:
    return next((k for test, k in _FILE_KINDS if test(mode)), "a special file")


def check_output_dir(path, inputs=()) -> Path:
    """Before any work: ``path`` is, or can be created as, a writable folder that holds none of ``inputs``.

    Writability is proved (a file is created and removed in the nearest existing folder: permission bits do not stop
    root, a read-only file system does); a file in the way, a symbolic link loop, a name too long and the special
    file systems (``/proc``, ``/sys``, ...) are refused. Errors: :class:`OutputPathError`, one line naming the path
    as given and the reason in words."""
    p = Path(path)
    st = _stat_output(p, "output folder")
    if st is not None and stat.S_ISREG(st.st_mode):
        raise OutputPathError(f"output folder {_shown(path)} is an existing file; choose a folder")
    if st is not None and not stat.S_ISDIR(st.st_mode):
        raise OutputPathError(f"output folder {_shown(path)} is not a folder ({_kind(st.st_mode)}); choose a folder")
    _writable_ancestor(p, "output folder")
    target = _resolve_quietly(p)
    for q in inputs:
        qp = _resolve_quietly(q)
        if target is not None and qp is not None and (target == qp or target in qp.parents):
            raise ValueError(f"output folder {_shown(path)} holds the input {str(q)!r}; choose another folder")
    return p


def check_output_file(path, what: str = "output file") -> Path:
    """Before any work: ``path`` is, or can be written as, a file (an existing one is a regular file, to be reused or
    replaced by the caller's rules), in a writable folder; errors as :func:`check_output_dir`'s."""
    st = _stat_output(path, what)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise OutputPathError(f"{what} {_shown(path)} is an existing folder; choose a file")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputPathError(f"{what} {_shown(path)} is not a regular file ({_kind(st.st_mode)})")
    _writable_ancestor(path, what)
    return Path(path)


def _resolve_quietly(path) -> Path | None:
    try:
        return _resolve(path)
    except (OSError, ValueError):
        return None


def _existing_ancestor(p: Path) -> Path:
    """The nearest existing folder of the resolved (absolute) ``p``."""
    while not p.is_dir() and p.parent != p:
        p = p.parent
    return p


def _lock_place(path, what: str) -> Path:
    """The lock file of the output ``path``: ``.NAME.lock`` in the nearest existing folder of its resolved parent, so
    that every spelling of one output shares it; :class:`OutputPathError` if that place cannot be written."""
    _stat_output(path, what)
    _writable_ancestor(path, what)
    try:
        p = _resolve(path)
    except OSError as exc:
        raise OutputPathError(describe_os_error(exc, path, what, action="written")) from None
    return _existing_ancestor(p.parent) / f".{p.name}.lock"


@contextlib.contextmanager
def staged_output_dir(path):
    """Write a run's files into a hidden staging folder; on success move them into ``path`` (created then),
    on failure or interruption remove them, so a failed run leaves no partial outputs. The run holds
    :func:`output_lock` on ``path`` throughout: a second run writing the same output stops with one clear error.
    Errors of the folder itself (and of files written into the staging folder) are :class:`OutputPathError`,
    ``output folder 'PATH' cannot be written: REASON``: the staging folder is never named."""
    what = "output folder"
    p = Path(path)

    def fail(exc):
        return OutputPathError(f"{what} {_shown(path)} cannot be written: {_reason(exc, path)}")

    with output_lock(p, what=what):
        anc = _writable_ancestor(p, what)
        try:
            for old in anc.glob(f".{p.name}.staging-*"):  # left by a run that was killed (we hold the lock)
                shutil.rmtree(old, ignore_errors=True)
            stage = Path(tempfile.mkdtemp(prefix=f".{p.name}.staging-", dir=anc))
        except OSError as exc:
            raise fail(exc) from None
        try:
            try:
                yield stage
            except OSError as exc:  # a file of the run in the staging folder: the user's folder is named instead
                inside = Path(os.path.abspath(stage))
                names = [Path(os.path.abspath(os.fsdecode(f))) for f in (exc.filename, exc.filename2)
                         if isinstance(f, (str, bytes))]
                if exc.errno is None or not any(f == inside or inside in f.parents for f in names):
                    raise
                raise fail(exc) from None
            try:
                p.mkdir(parents=True, exist_ok=True)
                for f in sorted(stage.rglob("*")):
                    if f.is_file():
                        dest = p / f.relative_to(stage)
                        dest.parent.mkdir(parents=True, exist_ok=True)
                        os.replace(f, dest)
            except OSError as exc:
                raise fail(exc) from None
        finally:
            shutil.rmtree(stage, ignore_errors=True)


@contextlib.contextmanager
def output_lock(path, *, what: str = "output"):
    """An exclusive, non-blocking lock on the output ``path`` (a file ``.NAME.lock`` beside it, locked with
    ``flock``; the operating system releases it when the process ends, however it ends). Held: another lenssim run
    is writing ``path``, and :class:`OutputLockedError` says so before any work. A folder that cannot be written
    raises :class:`OutputPathError` (``{what} 'PATH' cannot be written: REASON``); the lock file is never named."""
    import fcntl

    lock = _lock_place(path, what)

    def fail(exc):
        return OutputPathError(f"{what} {_shown(path)} cannot be written: {_reason(exc, Path(path).parent)}")

    while True:
        try:
            fh = open(lock, "a+")
        except OSError as exc:
            raise fail(exc) from None
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            raise OutputLockedError(f"another lenssim run is writing the {what} {_shown(path)}; wait for it to finish "
                                    "or choose another output") from None
        except OSError as exc:
            fh.close()
            raise fail(exc) from None
        try:
            same = os.stat(lock).st_ino == os.fstat(fh.fileno()).st_ino
        except FileNotFoundError:
            same = False
        if same:  # not a lock file its previous holder removed meanwhile
            break
        fh.close()
    try:
        yield
    finally:
        try:
            os.unlink(lock)  # nothing left behind; a run that opened it meanwhile re-checks the inode
        except OSError:
            pass
        fh.close()


MAX_TOML_BYTES = 2**20
"""The largest TOML file read, in bytes (1 MiB): the project's own (lens prescriptions, sensors, sweep configs,
tolerances, designs, the glass catalogue) are at most a few kilobytes; a larger file is refused before it is
parsed."""

MAX_TOML_DEPTH = 16
"""The deepest nesting of tables and arrays a TOML file may have (the top level: 0; ``a = [[1]]``: 2; ``[a.b.c]``:
3). The project's files nest at most 3 levels (a lens's ``[[surfaces]]`` > surface > an array of coefficients);
Python's TOML reader recurses once or twice per level (a file nested 5000 deep exhausts the interpreter's stack),
and the code that reads the tables back walks them recursively too."""

_TOML_STOPS = re.compile(r"[\[\]{}\"'#]")
"""What the nesting scan of a TOML text stops at: brackets, braces, the start of a string or a comment."""
_TOML_BASIC = re.compile(r'(?:[^"\\\n]+|\\[^\n])*')
"""The body of a one-line basic string (``"..."``, backslash escapes); it always matches (linear time)."""
_TOML_ML_BASIC = re.compile(r'(?:[^"\\]+|\\.|"(?!""))*', re.DOTALL)
"""The body of a multi-line basic string (``\"\"\"...\"\"\"``): up to the first unescaped three quotes."""


def _toml_too_deep(text: str, limit: int) -> bool:
    """Whether the brackets and braces of the TOML ``text`` (outside its strings and comments) nest deeper than
    ``limit``: a linear scan, as TOML's own grammar reads strings (the four kinds, escapes, up to two quotes
    that end a multi-line string) and comments. A string that does not end stops the scan: the TOML reader stops
    with an error there too."""
    depth, i, n = 0, 0, len(text)
    while i < n:
        m = _TOML_STOPS.search(text, i)
        if m is None:
            return False
        i, c = m.start(), m.group()
        if c in "[{":
            depth += 1
            if depth > limit:
                return True
            i += 1
        elif c in "]}":
            depth = max(depth - 1, 0)
            i += 1
        elif c == "#":
            i = text.find("\n", i)
            if i < 0:
                return False
        elif text.startswith(c * 3, i):  # a multi-line string: it ends at three quotes (and up to two more)
            j = _TOML_ML_BASIC.match(text, i + 3).end() if c == '"' else text.find(c * 3, i + 3)
            if j < 0 or not text.startswith(c * 3, j):
                return False
            i = j + 3
            for _ in range(2):
                i += text.startswith(c, i)
        elif c == '"':
            j = _TOML_BASIC.match(text, i + 1).end()
            if not text.startswith('"', j):
                return False
            i = j + 1
        else:  # a literal string: no escapes, one line
            j = text.find("'", i + 1)
            if j < 0 or "\n" in text[i + 1:j]:
                return False
            i = j + 1
    return False


def _toml_depth_exceeds(table: dict, limit: int) -> bool:
    """Whether the tables and arrays of ``table`` (a parsed TOML file) nest deeper than ``limit``, dotted keys and
    headers (``[a.b.c]``) counted: an iterative walk."""
    stack = [(table, 0)]
    while stack:
        x, d = stack.pop()
        if d > limit:
            return True
        stack.extend((c, d + 1) for c in (x.values() if isinstance(x, dict) else x) if isinstance(c, (dict, list)))
    return False


def read_toml(path, what: str) -> dict:
    """The TOML file ``path`` as a dict; ``what`` names it in the errors: :class:`InputFileError` for a file that
    cannot be read (:func:`check_input_file`), ``ValueError`` for one larger than :data:`MAX_TOML_BYTES`, nested
    deeper than :data:`MAX_TOML_DEPTH` (both checked before it is parsed) or not valid TOML: one line naming the
    file as the user gave it and what is allowed. The one reader of TOML files of the project."""
    import tomllib

    check_input_file(path, what)
    name = f"{what} {_shown(path)}"
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_TOML_BYTES + 1)
    except OSError as exc:
        raise InputFileError(describe_os_error(exc, path, what)) from None
    if len(raw) > MAX_TOML_BYTES:
        most = f"{MAX_TOML_BYTES // 2**20} MiB" if MAX_TOML_BYTES % 2**20 == 0 else f"{MAX_TOML_BYTES} bytes"
        raise ValueError(f"{name} is larger than {most}: not allowed for a TOML file (the project's lens, sensor, "
                         "config and tolerance files are a few kilobytes)")
    too_deep = ValueError(f"{name} nests tables or arrays more than {MAX_TOML_DEPTH} levels deep: not allowed (the "
                          "project's files nest at most 3)")
    try:
        text = raw.decode("utf-8")
        if _toml_too_deep(text, MAX_TOML_DEPTH):
            raise too_deep
        table = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{name} is not valid TOML: {' '.join(str(exc).split())}") from None
    except RecursionError:  # the scan above should have caught it: the same refusal
        raise too_deep from None
    if _toml_depth_exceeds(table, MAX_TOML_DEPTH):
        raise too_deep
    return table
