import os
import stat

import pytest

from lenssim.io.files import atomic_write, atomic_write_text


def test_atomic_write_replaces_whole_files_with_normal_permissions(tmp_path):
    p = atomic_write_text(tmp_path / "sub" / "a.json", "{}")
    assert p.read_text() == "{}"
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask  # not mkstemp's 0o600
    atomic_write_text(p, "[1]")
    assert p.read_text() == "[1]" and os.listdir(p.parent) == ["a.json"]


def test_a_failing_writer_leaves_the_old_file_and_no_temporary(tmp_path):
    p = atomic_write_text(tmp_path / "keep.txt", "old")

    def broken(tmp):
        with open(tmp, "w") as f:
            f.write("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(p, broken)
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["keep.txt"]
