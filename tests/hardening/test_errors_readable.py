"""Class 5 (issue 9): every expected failure is one line on stderr with exit status 2 (no traceback);
Ctrl-C says how to resume, with status 130; negative numbers work as values."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from lenssim_cli import main as cli_main
from lenssim_cli.main import build_parser, main

CASES = [
    ["evaluate"],
    ["evaluate", "--design", "nope"],
    ["evaluate", "--s", "nan"],
    ["evaluate", "--s", "-0.775", "--Q", "-2.4", "--snr", "1e6"],
    ["evaluate", "--s", "-0.775", "--Q", "-2.4", "--snr", "nan"],
    ["evaluate", "--s", "40", "--Q", "0"],
    ["evaluate", "--design", "end_to_end_paper", "--device", "tpu"],
    ["evaluate", "--design", "end_to_end_paper", "--designs", "/nonexistent.toml"],
    ["sweep", "/nonexistent.toml", "--out", "x.nc"],
    ["sweep", "no_such_builtin", "--out", "x.nc"],
    ["optimum", "/nonexistent.nc", "--criterion", "mse_r"],
    ["optimum", "afile", "--criterion", "mse_r"],
    ["reproduce", "--out", "afile/x"],
    ["designs", "--designs", "/nonexistent.toml"],
    ["simulate", "/nonexistent.jpg", "--design", "end_to_end_paper", "--out", "o"],
    ["simulate", "skimage:nothing", "--design", "end_to_end_paper", "--out", "o"],
    ["simulate", "afile", "--design", "end_to_end_paper", "--out", "o"],
    ["psnr-table", "--designs", "nope", "--out", "o"],
    ["psnr-table", "--isos", "123", "--out", "o"],
    ["psnr-table", "--method", "nonesuch", "--out", "o"],
    ["fig8", "skimage:camera", "--angles", "99", "--out", "o"],
    ["fig8", "skimage:camera", "--crop", "4", "--out", "o"],
]


@pytest.mark.parametrize("argv", CASES, ids=lambda a: " ".join(a)[:60])
def test_expected_failures_are_one_line_with_status_2(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not an image, not a sweep, not a folder\n")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"lenssim {argv[0]}: error: "), err
    assert "Traceback" not in err


def test_ctrl_c_says_how_to_resume(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt
    parser = build_parser()
    monkeypatch.setattr(cli_main, "build_parser", lambda: _with(parser, interrupted))
    assert main(["designs"]) == 130
    assert capsys.readouterr().err == "lenssim designs: interrupted; run the same command again to resume\n"


def _with(parser, func):
    for action in parser._subparsers._group_actions:
        for sub in action.choices.values():
            sub.set_defaults(func=func)
    return parser


@pytest.mark.parametrize("value", ["-1e6", "-1E+3", "-.5", "-2", "-0.775"])
def test_negative_numbers_are_values(value):
    args = build_parser().parse_args(["evaluate", "--s", value, "--Q", value])
    assert args.param_s == float(value) and args.param_Q_back == float(value)


def test_the_console_script_prints_one_line_and_no_teardown_noise(tmp_path):
    r = subprocess.run([sys.executable, "-m", "lenssim_cli.main", "evaluate", "--s", "-0.775", "--Q", "-300"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "max-fft-size" in r.stderr
    ok = subprocess.run([sys.executable, "-m", "lenssim_cli.main", "evaluate", "--design", "end_to_end_paper", "--snr",
                         "27.6", "--json"], capture_output=True, text=True, cwd=tmp_path)
    assert ok.returncode == 0 and json.loads(ok.stdout)["mse_r"][0] > 0 and "leaked" not in ok.stderr


def test_the_exact_wavefront_flags(capsys, tmp_path):
    assert main(["evaluate", "--design", "end_to_end_paper", "--snr", "27.6", "--wavefront", "exact", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["mse_r"][0] == pytest.approx(0.03891, rel=2e-3) and r["wavefront"].startswith("exact")
    assert main(["evaluate", "--design", "end_to_end_paper", "--wavefront", "exact", "--spectrum",
                 "Nikon 5100 (NPL)"]) == 2
    assert "one-wavelength spectrum" in capsys.readouterr().err
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--wavefront", "exact", "--spectrum",
                 "Nikon 5100 (NPL)", "--out", str(tmp_path / "o")]) == 2
    assert "one-wavelength camera" in capsys.readouterr().err
