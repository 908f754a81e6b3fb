"""Bad inputs, third round (issue 28): every operating-system error a user can provoke (a symbolic link loop, a
dangling link, a folder given as a file, a device or a named pipe as input, a name too long, an output on a read-only
or special file system, under a file, or a link loop) stops the command with exactly one line on stderr, exit status 2,
naming the user's path as given and never an internal name (the lock file, the staging folder), and leaves nothing.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
from pathlib import Path

import pytest

from lenssim.io.files import (InputFileError, OutputPathError, check_input_file, check_output_dir, check_output_file,
                              describe_os_error)
from lenssim_cli.main import main

E = ["--design", "end_to_end_paper"]
LONG = "n" * 300  # one path component over the 255 bytes of most file systems
INTERNAL = (".lock", "staging", "Traceback", "lenssim-probe")


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    """A folder (the tests run inside it) with a symbolic link loop, a dangling link, a folder, a named pipe, a
    regular file and a small sweep config."""
    monkeypatch.chdir(tmp_path)
    os.symlink("loop", tmp_path / "loop")
    os.symlink("nowhere", tmp_path / "dangling")
    (tmp_path / "adir").mkdir()
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "file").write_text("x")
    (tmp_path / "grid.toml").write_text("[grid]\ns = [-1.0, 0.0, 1.0]\nQ = [-4.0, 0.0, 4.0]\nsnr_db = [27.6]\n"
                                        "[lens]\nfield_angles_deg = [0]\n[numerics]\nmin_size = 64\n")
    return tmp_path


@contextlib.contextmanager
def deadline(seconds: float = 20):
    """Fail instead of hanging (a named pipe or /dev/zero read by mistake would block or never end)."""
    def expired(*_):
        raise TimeoutError(f"still running after {seconds} s: the input was read instead of refused")

    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _check_line(err: list[str], command: str, given: str, match: str) -> None:
    assert len(err) == 1, err
    line = err[0]
    assert line.startswith(f"lenssim {command}: error: "), line
    assert repr(given) in line, (given, line)
    assert match in line, (match, line)
    assert not any(k in line for k in INTERNAL), line


def refused_os(argv, capsys, root, given, match):
    """``main(argv)``: exit 2, one line naming ``given`` as given, the reason ``match``, no internal name; nothing
    new in ``root``."""
    before = sorted(p.name for p in root.iterdir())
    with deadline():
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    _check_line(err, argv[0], given, match)
    assert sorted(p.name for p in root.iterdir()) == before, "a refused run left files behind"


INPUTS = [("loop", "a symbolic link loop"),
          ("dangling", "a dangling symbolic link (its target 'nowhere' does not exist)"),
          ("adir", "is not a file: it is a folder"),
          ("fifo", "is not a regular file (a named pipe)"),
          ("/dev/zero", "is not a regular file (a character device)"),
          (f"{LONG}.toml", "the name is too long"),
          ("file/x.toml", "'file' is a file, not a folder"),
          ("missing.toml", "does not exist")]


@pytest.mark.parametrize("path, match", INPUTS)
def test_check_input_file_refuses_on_one_line_naming_the_path_as_given(hostile, path, match):
    with deadline(), pytest.raises(InputFileError) as info:
        check_input_file(path, "photo")
    msg = str(info.value)
    assert msg.startswith(f"photo {path!r} ") and match in msg and "\n" not in msg, msg
    assert isinstance(info.value, ValueError)


def test_check_input_file_accepts_a_file_and_a_link_to_one(hostile):
    os.symlink("file", hostile / "link")
    assert check_input_file("link", "photo") == Path("link")
    assert check_input_file(hostile / "file", "photo") == hostile / "file"


COMMANDS = {  # the inputs wired to check_input_file: argv for a hostile PATH
    "designs file": lambda p: ["designs", "--designs", p],
    "tolerances file": lambda p: ["tolerance", *E, "--tolerances", p, "--out", "o"],
    "sweep config": lambda p: ["sweep", p, "--out", "a.nc"],
    "sweep file": lambda p: ["optimum", p, "--criterion", "mse_r"],
    "photo": lambda p: ["simulate", p, *E, "--crop", "64", "--out", "o"],
}


@pytest.mark.parametrize("path, match", INPUTS)
@pytest.mark.parametrize("what", COMMANDS)
def test_hostile_inputs_are_refused_by_the_command_line(hostile, capsys, what, path, match):
    if what == "sweep file" and path == "adir":  # `lenssim optimum` reads a folder: a trade-off's output folder
        match = "holds no tradeoff.nc"
    refused_os(COMMANDS[what](path), capsys, hostile, path, match)


OUTPUTS = [("/proc/self/lenssim-out", "/proc is a special file system (proc)"),
           ("/sys/lenssim-out", "/sys is a special file system (sysfs)"),
           ("file/sub", "'file' is a file, not a folder"),
           ("loop", "a symbolic link loop"),
           ("loop/sub", "a symbolic link loop"),
           ("dangling", "a dangling symbolic link"),
           (LONG, "the name is too long"),
           (f"sub/{LONG}/x", "the name is too long")]

OUTPUT_COMMANDS = {
    "simulate": lambda p: ["simulate", "skimage:camera", *E, "--angles", "0", "--crop", "64", "--out", p],
    "tolerance": lambda p: ["tolerance", *E, "--out", p],
    "sweep": lambda p: ["sweep", "grid.toml", "--out", p],
}


@pytest.mark.parametrize("path, match", OUTPUTS)
@pytest.mark.parametrize("command", OUTPUT_COMMANDS)
def test_unwritable_outputs_are_refused_by_the_command_line(hostile, capsys, command, path, match):
    refused_os(OUTPUT_COMMANDS[command](path), capsys, hostile, path, match)


@pytest.mark.parametrize("path, match", OUTPUTS)
def test_check_output_dir_and_file_say_why(hostile, path, match):
    for check in (check_output_dir, check_output_file):
        with pytest.raises(OutputPathError) as info:
            check(path)
        msg = str(info.value)
        assert repr(path) in msg and match in msg and "\n" not in msg, msg
    assert sorted(p.name for p in hostile.iterdir()) == ["adir", "dangling", "fifo", "file", "grid.toml", "loop"]


def test_special_files_as_outputs_are_refused(hostile, capsys):
    refused_os(["sweep", "grid.toml", "--out", "fifo"], capsys, hostile, "fifo", "is not a regular file (a named pipe)")
    refused_os(["sweep", "grid.toml", "--out", "adir"], capsys, hostile, "adir", "is an existing folder")
    refused_os(["tolerance", *E, "--out", "/dev/null"], capsys, hostile, "/dev/null",
               "is not a folder (a character device)")


READ_ONLY_CHILD = """
import contextlib, ctypes, io, json, os, sys

folder, argvs = sys.argv[1], json.loads(sys.argv[2])
libc = ctypes.CDLL(None, use_errno=True)
CLONE_NEWNS, MS_RDONLY, MS_REC, MS_PRIVATE = 0x00020000, 1, 16384, 1 << 18
if (libc.unshare(CLONE_NEWNS) != 0 or libc.mount(None, b"/", None, MS_REC | MS_PRIVATE, None) != 0
        or libc.mount(b"none", os.fsencode(folder), b"tmpfs", MS_RDONLY, None) != 0):
    print(json.dumps({"skip": "no private read-only mount here: " + os.strerror(ctypes.get_errno())}))
    sys.exit(0)
from lenssim_cli.main import main

runs = []
for argv in argvs:
    buf = io.StringIO()
    with contextlib.redirect_stderr(buf):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
        except BaseException as exc:
            rc, buf = None, io.StringIO("Traceback: " + type(exc).__name__ + ": " + str(exc))
    runs.append([rc, buf.getvalue()])
print(json.dumps({"skip": None, "runs": runs}))
"""
"""A fresh process (one thread: it may enter a mount namespace of its own) mounts a read-only tmpfs on a folder and
runs the commands in it; root does not bypass a read-only file system as it bypasses permission bits."""


def test_an_output_on_a_read_only_file_system_is_refused(hostile):
    import subprocess
    import sys

    ro = hostile / "ro"
    ro.mkdir()
    argvs = [OUTPUT_COMMANDS[c](p) for c in OUTPUT_COMMANDS
             for p in (("ro/out", "ro") if c != "sweep" else ("ro/out.nc", "ro/sub/a.nc"))]
    done = subprocess.run([sys.executable, "-c", READ_ONLY_CHILD, str(ro), json.dumps(argvs)], cwd=hostile,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    if out["skip"]:
        pytest.skip(out["skip"])
    for argv, (rc, err) in zip(argvs, out["runs"]):
        lines = err.strip().splitlines()
        assert rc == 2, (argv, lines)
        _check_line(lines, argv[0], argv[-1], "read-only file system")
    assert sorted(p.name for p in ro.iterdir()) == []
    assert sorted(p.name for p in hostile.iterdir()) == ["adir", "dangling", "fifo", "file", "grid.toml", "loop", "ro"]


def test_describe_os_error_names_the_users_path_and_the_reason_in_words():
    internal = "/tmp/x/.out.lock"
    cases = [(errno.ELOOP, "a symbolic link loop"), (errno.ENAMETOOLONG, "the name is too long"),
             (errno.EACCES, "permission denied"), (errno.EPERM, "permission denied"),
             (errno.EROFS, "read-only file system"), (errno.ENOSPC, "no space left on the device"),
             (errno.EDQUOT, "disk quota exceeded"), (errno.EISDIR, "it is a folder"),
             (errno.EIO, "an input/output error"), (errno.EOVERFLOW, os.strerror(errno.EOVERFLOW)[1:])]
    for code, words in cases:
        msg = describe_os_error(OSError(code, os.strerror(code), internal), "out", "output folder", action="written")
        assert msg.startswith("output folder 'out' cannot be written: ") and words in msg, msg
        assert ".lock" not in msg and "Errno" not in msg
    assert describe_os_error(FileNotFoundError(errno.ENOENT, "x", internal), "x/y.png", "photo") == \
        "photo 'x/y.png' does not exist"


def test_an_os_error_reaching_main_is_one_line_without_internal_names(hostile, capsys, monkeypatch):
    """The last net: an OSError naming a staging folder, a lock file or a resolved path, and pathlib's
    RuntimeError for a link loop, become one line naming the path the user gave."""
    import lenssim_cli.optics as optics
    from lenssim.io.files import staged_output_dir

    stage = str(hostile / ".o.staging-abc123" / "sim.png")
    with pytest.raises(OutputPathError) as info:  # a full disk under a file the run writes into its staging folder
        with staged_output_dir("o") as staging:
            raise OSError(errno.ENOSPC, "No space left on device", str(staging / "sim.png"))
    assert str(info.value) == "output folder 'o' cannot be written: no space left on the device"
    assert sorted(p.name for p in hostile.iterdir()) == ["adir", "dangling", "fifo", "file", "grid.toml", "loop"]

    def failing(exc):
        def designs(*a, **k):
            raise exc
        return designs

    for exc, match in ((OSError(errno.EROFS, "Read-only file system", stage), "read-only file system"),
                       (OSError(errno.EACCES, "Permission denied", str(hostile / ".o.lock")), "permission denied"),
                       (RuntimeError(f"Symlink loop from {str(hostile / 'o')!r}"), "a symbolic link loop")):
        monkeypatch.setattr(optics, "designs", failing(exc))
        refused_os(["designs", "--designs", "o"], capsys, hostile, "o", match)
