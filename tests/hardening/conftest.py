"""Shared by the second round of bad-input tests (issue 20): a folder of good and hostile inputs, and the check
that a command refuses on one line, with status 2, before any work, leaving nothing behind."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lenssim_cli.main import main
from pipeline import write_image


@pytest.fixture
def files(tmp_path, monkeypatch):
    """A folder with a good photo, hostile files and configs; the tests run inside it."""
    monkeypatch.chdir(tmp_path)
    a = np.random.default_rng(0).random((3, 200, 240)).astype(np.float32)
    write_image(tmp_path / "ok.png", torch.from_numpy(a))
    import struct
    import zlib

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0)  # a header that claims 100,000 x 100,000 px
    (tmp_path / "huge.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    (tmp_path / "trunc.jpg").write_bytes(b"\xff\xd8\xff\xe0" + b"\x00" * 64)
    b = a.copy()
    b[:, 5:9, 5:9] = np.nan
    write_image(tmp_path / "nan.exr", torch.from_numpy(b), bits="float")
    (tmp_path / "adir").mkdir()
    (tmp_path / "grid.toml").write_text("[grid]\ns = [-1.0, 0.0, 1.0]\nQ = [-4.0, 0.0, 4.0]\nsnr_db = [27.6]\n"
                                        "[lens]\nfield_angles_deg = [0, 10]\n[numerics]\nmin_size = 128\n")
    (tmp_path / "typo.toml").write_text("[grid]\ns = [-1.0, 0.0, 1.0]\nQ = [-4.0, 0.0, 4.0]\nsnr_bd = [27.6]\n")
    (tmp_path / "focus_typo.toml").write_text("[grid]\ns = [-1.0, 0.0, 1.0]\nQ = [-4.0, 0.0, 4.0]\n"
                                              "[focus]\ncriteron = \"mse_r\"\n")
    (tmp_path / "fixed_typo.toml").write_text("[grid]\ns = [-1.0, 0.0, 1.0]\nQ = [-4.0, 0.0, 4.0]\n"
                                              "[fixed]\nQ_frnt = 1.0\n")
    (tmp_path / "channels_typo.toml").write_text("[grid]\ns = [-1.0, 0.0, 1.0]\nQ = [-4.0, 0.0, 4.0]\n"
                                                 "[channels]\nspectrm = \"Nikon 5100 (NPL)\"\n")
    (tmp_path / "tol_typo.toml").write_text("[tolerances]\nradius_pct = 0.5\n")
    return tmp_path


@pytest.fixture
def refused(capsys):
    """``refused(argv, match, root)``: see :func:`_refused`."""
    return lambda argv, match, root: _refused(argv, capsys, match, root)


def _refused(argv, capsys, match, root):
    """``main(argv)`` stops with one line naming the problem, status 2, and leaves nothing new in ``root``."""
    before = {p.name for p in root.iterdir()}
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert err and err[-1].startswith(f"lenssim {argv[0]}: error: ") and match in err[-1], err
    assert not any("Traceback" in line for line in err)
    assert {p.name for p in root.iterdir()} == before, "a refused run left files behind"
