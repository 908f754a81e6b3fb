"""Atomic file output shared by every command: a crash or Ctrl-C never leaves a half-written file.

The writer fills a temporary file in the destination folder (same extension, so format-sniffing
writers such as matplotlib and OpenImageIO still work), which is then given the usual permissions
(``0o666`` less the umask, as ``open()`` would) and renamed over the destination.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_text", "json_text", "check_output_dir", "staged_output_dir", "read_toml"]


def _default_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path, writer) -> Path:
    """Call ``writer(tmp_path: str)`` and move the result to ``path`` (folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        writer(tmp)
        os.chmod(tmp, _default_mode())
        os.replace(tmp, path)
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


def _existing_ancestor(p: Path) -> Path:
    q = p.resolve()
    while not q.exists():
        q = q.parent
    return q


def check_output_dir(path, inputs=()) -> Path:
    """Before any work: ``path`` is, or can be created as, a writable folder that holds none of ``inputs``."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise NotADirectoryError(f"output folder {str(p)!r} is an existing file; choose a folder")
    anc = _existing_ancestor(p)
    if not anc.is_dir() or not os.access(anc, os.W_OK | os.X_OK):
        raise PermissionError(f"output folder {str(p)!r} cannot be written (no write permission in {str(anc)!r})")
    target = p.resolve()
    for q in inputs:
        qp = Path(q).resolve()
        if target == qp or target in qp.parents:
            raise ValueError(f"output folder {str(p)!r} holds the input {str(q)!r}; choose another folder")
    return p


@contextlib.contextmanager
def staged_output_dir(path):
    """Write a run's files into a hidden staging folder; on success move them into ``path`` (created then),
    on failure or interruption remove them, so a failed run leaves no partial outputs. The run holds
    :func:`output_lock` on ``path`` throughout: a second run writing the same output stops with one clear error."""
    p = Path(path)
    anc = _existing_ancestor(p)
    with output_lock(p):
        for old in anc.glob(f".{p.name}.staging-*"):  # left by a run that was killed (we hold the lock)
            shutil.rmtree(old, ignore_errors=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{p.name}.staging-", dir=anc))
        try:
            yield stage
            p.mkdir(parents=True, exist_ok=True)
            for f in sorted(stage.rglob("*")):
                if f.is_file():
                    dest = p / f.relative_to(stage)
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(f, dest)
        finally:
            shutil.rmtree(stage, ignore_errors=True)


class OutputLockedError(OSError):
    """Another run holds the lock of the output a run would write."""


@contextlib.contextmanager
def output_lock(path):
    """An exclusive, non-blocking lock on the output ``path`` (a file ``.NAME.lock`` beside it, locked with
    ``flock``; the operating system releases it when the process ends, however it ends). Held: another lenssim run
    is writing ``path``, and :class:`OutputLockedError` says so before any work."""
    import fcntl

    p = Path(path).resolve()
    lock = _existing_ancestor(p.parent) / f".{p.name}.lock"
    while True:
        fh = open(lock, "a+")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            raise OutputLockedError(f"another lenssim run is writing {str(p)!r} (it holds {str(lock)!r}); wait for "
                                    "it to finish or choose another output") from None
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
        except FileNotFoundError:
            pass
        fh.close()


def read_toml(path, what: str) -> dict:
    """The TOML file ``path`` as a dict; ``what`` names it in the errors (missing file, invalid TOML)."""
    import tomllib

    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {str(path)!r} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{what} {str(path)!r} is not valid TOML: {exc}") from None
