"""Class 3 (issue 9): work that would not fit this machine is refused before it starts, naming the
limit and the flag that raises it."""

from __future__ import annotations

import pytest

from lenssim import Design, Numerics, evaluate

from lenssim_studies.paper import PAPER_CAMERA
from lenssim.validate import ResourceLimitError, check_memory
from lenssim_cli.main import main
from lenssim_studies.paper import PAPER_RHO0


@pytest.mark.parametrize("Q", ["-300", "-600"])  # a third-order blur of 11 and 21 mm (below f = 25 mm)
def test_a_huge_fft_is_refused_with_the_limit_and_its_flag(capsys, Q):
    assert main(["evaluate", "--s", "-0.775", "--Q", Q]) == 2
    err = capsys.readouterr().err
    assert "the limit is max_fft_size = 4096; raise it with --max-fft-size N" in err and err.count("\n") == 1


def test_the_fft_limit_is_a_setting():
    with pytest.raises(ResourceLimitError, match="max_fft_size = 512") as exc:
        evaluate(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), [27.6], numerics=Numerics(max_fft_size=512), rho0=PAPER_RHO0)
    assert exc.value.setting == "max_fft_size" and "at 14 deg" in str(exc.value)


def test_a_sweep_grid_too_fine_is_refused_before_allocating(tmp_path, capsys):
    cfg = tmp_path / "fine.toml"
    cfg.write_text("[grid]\ns = [-2.0, 1.0, 1e-7]\nQ = [-10.0, 1.0, 0.1]\n")
    assert main(["sweep", str(cfg), "--out", str(tmp_path / "x.nc")]) == 2
    assert "at most 100000 per parameter" in capsys.readouterr().err
    cfg.write_text("[grid]\ns = [-2.0, 1.0, 1e-4]\nQ = [-10.0, 1.0, 1e-3]\n")
    assert main(["sweep", str(cfg), "--out", str(tmp_path / "x.nc"), "--memory-limit", "1"]) == 2
    err = capsys.readouterr().err
    assert "needs about" in err and "raise it with --memory-limit GIB" in err
    assert not (tmp_path / "x.nc.partial").exists()


def test_a_full_frame_larger_than_the_memory_limit_is_refused(tmp_path, capsys):
    assert main(["simulate", "skimage:astronaut", "--design", "end_to_end_paper", "--full-frame", "--angles", "0", "--memory-limit", "0.001",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--full-frame on the 512 x 512 photo 'skimage:astronaut' needs about" in err and "--memory-limit GIB" in err


def test_check_memory_names_the_setting():
    with pytest.raises(ResourceLimitError, match=r"needs about 2 GiB of memory; the limit is 1 GiB \(x\)"):
        check_memory(2 * 2**30, "a thing", 2**30, setting="x")
    check_memory(2**20, "a small thing")
