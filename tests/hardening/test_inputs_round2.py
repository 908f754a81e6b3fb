"""Bad inputs, second round (issue 20, section 3): the flags, config sections and commands added since the first
round, hostile files, an edited sweep file, two runs on one output, a full disk, a scheduler that is not one.

Each class holds the first round's rules: one line on stderr with exit status 2 before any work, no wrong number,
nothing left behind.
"""

from __future__ import annotations

import errno
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lenssim_cli.main import build_parser, main
from pipeline import write_image

E = ["--design", "end_to_end_paper"]


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


# class 1: the flags added since the first round (camera, focus, wavefront, limits, windows, as-built)
FLAGS = [
    (["evaluate", *E, "--glass", ""], "--glass '' is not allowed"),
    (["evaluate", *E, "--glass", "N-BK8"], "glass 'N-BK8' is not in the catalogue"),
    (["evaluate", *E, "--spectrum", ""], "--spectrum '' is not allowed"),
    (["evaluate", *E, "--spectrum", "Nikon 9999"], "'Nikon 9999' are not known"),
    (["evaluate", *E, "--illuminant", "D65"], "--illuminant applies to a colour --spectrum"),
    (["evaluate", *E, "--wavelengths-per-channel", "4"], "--wavelengths-per-channel applies to a colour"),
    (["evaluate", *E, "--spectrum", "Nikon 5100 (NPL)", "--wavelengths-per-channel", "0"], "per_channel=0"),
    (["evaluate", *E, "--spectrum", "Nikon 5100 (NPL)", "--wavelengths-per-channel", "2.5"], "invalid int value"),
    (["evaluate", *E, "--spectrum", "Nikon 5100 (NPL)", "--illuminant", "D99"], "illuminant 'D99' is not known"),
    (["evaluate", *E, "--best-focus", "cost"], "--best-focus 'cost' is not allowed"),
    (["evaluate", *E, "--best-focus", "mse_r_nominal"], "--best-focus 'mse_r_nominal' is not allowed"),
    (["evaluate", *E, "--best-focus", "mse_r", "--focus_shift_um", "10"], "not both"),
    (["evaluate", *E, "--Q_front", "nan"], "Q_front=nan is not allowed"),
    (["evaluate", *E, "--focus_shift_um", "inf"], "focus_shift_um=inf is not allowed"),
    (["evaluate", *E, "--focus_shift_um", "abc"], "invalid float value"),
    (["evaluate", *E, "--wavefront", "sixth"], "invalid choice"),
    (["evaluate", *E, "--wavefront", "exact", "--spectrum", "Nikon 5100 (NPL)"], "one-wavelength spectrum"),
    (["evaluate", *E, "--max-fft-size", "0"], "--max-fft-size 0 is not allowed"),
    (["evaluate", *E, "--max-fft-size", "64"], "a PSF needs an FFT of"),
    (["sweep", "grid.toml", "--out", "a.nc", "--memory-limit", "0"], "--memory-limit 0 is not allowed"),
    (["sweep", "grid.toml", "--out", "a.nc", "--memory-limit", "nan"], "--memory-limit nan is not allowed"),
    (["sweep", "grid.toml", "--out", "a.nc", "--workers", "100000"], "--workers 100000 is not allowed"),
    (["sweep", "grid.toml", "--out", "a.nc", "--worker-threads", "0"], "--worker-threads 0 is not allowed"),
    (["sweep", "grid.toml", "--out", "a.nc", "--workers", "2", "--scheduler", "tcp://h:1"], "not allowed with"),
    (["sweep", "grid.toml", "--out", "a.nc", "--scheduler", "not-an-address"], "--scheduler 'not-an-address'"),
    (["sweep", "grid.toml", "--out", "a.nc", "--scheduler", "tcp://host-without-port"], "protocol, host and port"),
    (["sweep", "grid.toml", "--out", "a.nc", "--max-fft-size", "7"], "--max-fft-size 7 is not allowed"),
    (["simulate", "ok.png", *E, "--blur-windows", "half", "--out", "o"], "invalid choice: 'half'"),
    (["simulate", "ok.png", *E, "--window-grid", "centre", "--out", "o"], "invalid choice: 'centre'"),
    (["simulate", "ok.png", *E, "--scheme", "100000", "32", "64", "--out", "o"], "window=100000 is not allowed"),
    (["simulate", "ok.png", *E, "--memory-limit", "-5", "--out", "o"], "--memory-limit -5 is not allowed"),
    (["simulate", "ok.png", *E, "--grade", "precision", "--out", "o"], "give --as-built"),
    (["simulate", "ok.png", *E, "--as-built", "-1", "--out", "o"], "--as-built -1 is not allowed"),
    (["simulate", "ok.png", *E, "--as-built", "1", "--full-frame", "--out", "o"], "--full-frame is not available"),
    (["simulate", "ok.png", *E, "--as-built", "1", "--off", "warp", "--out", "o"], "--off 'warp' is not allowed"),
    (["simulate", "ok.png", *E, "--as-built", "1", "--tolerances", "tol_typo.toml", "--out", "o"],
     "unknown key(s) ['radius_pct']"),
    (["simulate", "ok.png", *E, "--restore", "wiener:local=tile", "--out", "o"], "local='tile' is not allowed"),
    (["psnr-table", "ok.png", "ok.png", "--out", "o"], "is given twice"),
    (["tolerance", *E, "--lenses", "10000000000", "--out", "o"], "use fewer --lenses"),
    (["tolerance", *E, "--angles", "-1", "--out", "o"], "field angle=-1.0 is not allowed"),
    (["tolerance", *E, "--angles", "80", "--out", "o"], "a PSF needs an FFT of"),
    (["tolerance", *E, "--snr", "inf", "--out", "o"], "SNR [inf] dB is not allowed"),
    (["tolerance", *E, "--yield", "mse_r<0.04", "--out", "o"], "CRITERION<=VALUE"),
    (["tolerance", *E, "--wavefront", "exact", "--out", "o"], "the as-built model is third order"),
    (["tolerance", *E, "--scheduler", "nope", "--out", "o"], "--scheduler 'nope' is not allowed"),
    (["study", "white-light", "--glass", "N-BK8", "--out", "o"], "glass 'N-BK8' is not in the catalogue"),
    (["study", "white-light", "--wavelengths-per-channel", "0", "--out", "o"], "per_channel=0"),
    (["study", "white-light", "--grid-step", "1e-9", "1e-9", "--out", "o"], "at most 100000 per parameter"),
    (["study", "white-light", "--illuminant", "D99", "--out", "o"], "illuminant 'D99' is not known"),
    (["study", "exact-wavefront", "--glass", "N-BK7", "--out", "o"], "--glass belongs to `lenssim study white-light`"),
    (["study", "exact-wavefront", "--lenses", "5", "--out", "o"], "--lenses belongs to `lenssim study as-built`"),
    (["study", "as-built", "--seed", "-3", "--out", "o"], "--seed -3 is not allowed"),
    (["study", "as-built", "--grade", "x", "--out", "o"], "invalid choice: 'x'"),
]


@pytest.mark.parametrize("argv, match", FLAGS, ids=lambda v: " ".join(v)[:70] if isinstance(v, list) else "")
def test_new_flags_are_refused_on_one_line_before_any_work(argv, match, files, capsys):
    _refused(argv, capsys, match, files)


# class 2: config sections added since the first round: a typo is reported, never ignored
@pytest.mark.parametrize("name, match", [("typo.toml", "snr_bd"), ("focus_typo.toml", "criteron"),
                                         ("fixed_typo.toml", "Q_frnt"), ("channels_typo.toml", "spectrm")])
def test_unknown_keys_in_config_sections_are_reported(name, match, files, capsys):
    _refused(["sweep", name, "--out", "a.nc"], capsys, match, files)


# class 3: hostile files
@pytest.mark.parametrize("photo, match", [("huge.png", "cannot read image"), ("trunc.jpg", "cannot read image"),
                                          ("nan.exr", "NaN or infinite"), ("adir", "is not a file")])
def test_hostile_photos_are_refused(photo, match, files, capsys):
    _refused(["simulate", photo, *E, "--out", "o"], capsys, match, files)


def test_a_sweep_file_edited_by_hand_is_refused_by_optimum(files, capsys):
    """The sweep writes a SHA-256 of its data; optimum (and a rerun that would reuse the file) checks it, so a
    number changed by hand never becomes an optimum."""
    import xarray as xr

    assert main(["sweep", "grid.toml", "--out", "a.nc", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["optimum", "a.nc", "--criterion", "mse_r"]) == 0
    good = capsys.readouterr().out
    ds = xr.load_dataset(files / "a.nc", engine="scipy")
    for name, edit in (("lower.nc", lambda d: d["mse_r"].values.__imul__(0.5)),
                       ("nan.nc", lambda d: d["mse_r"].values.__setitem__((0, 0, 0), math.nan))):
        e = ds.copy(deep=True)
        edit(e)
        e.to_netcdf(files / name, engine="scipy")
        _refused(["optimum", name, "--criterion", "mse_r"], capsys, "was modified after the sweep wrote it", files)
    assert "best mse_r" in good
    del ds.attrs["data_sha256"]
    ds.to_netcdf(files / "bare.nc", engine="scipy")
    _refused(["optimum", "bare.nc", "--criterion", "mse_r"], capsys, "carries no data checksum", files)
    _refused(["sweep", "grid.toml", "--out", "lower.nc"], capsys, "was modified after the sweep wrote it", files)


# class 4: two runs writing one output
def test_a_second_run_on_a_locked_output_stops_with_a_clear_error(files, capsys):
    from lenssim.io.files import output_lock

    with output_lock(files / "a.nc"):
        _refused(["sweep", "grid.toml", "--out", "a.nc"], capsys, "another lenssim run is writing", files)
    with output_lock(files / "o"):
        _refused(["simulate", "ok.png", *E, "--angles", "0", "--crop", "64", "--out", "o"], capsys,
                 "another lenssim run is writing", files)
    assert main(["sweep", "grid.toml", "--out", "a.nc", "--quiet"]) == 0  # released: the run goes through
    assert not list(files.glob(".*.lock"))


# class 5: a full disk
def test_a_full_disk_stops_the_run_with_one_line_and_no_partial_output(files, capsys, monkeypatch):
    import lenssim_cli.camera as cam

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(cam, "write_image", full)
    _refused(["simulate", "ok.png", *E, "--angles", "0", "--crop", "64", "--out", "o"], capsys,
             "No space left on device", files)
    assert not list(files.glob(".o.staging-*"))


# class 6: a refused or failed sweep leaves no chunk folder it created
def test_a_sweep_that_fails_before_any_chunk_leaves_no_partial_folder(files, capsys):
    _refused(["sweep", "grid.toml", "--out", "a.nc", "--max-fft-size", "31", "--quiet"], capsys, "a PSF needs an FFT",
             files)


# class 7: properties over the new flags: any value passes the checks or is refused with one ValueError line
@settings(max_examples=60, deadline=None)
@given(memory=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)),
       workers=st.one_of(st.none(), st.integers(-5, 10**6)), fft=st.one_of(st.none(), st.integers(-5, 10**5)),
       glass=st.one_of(st.none(), st.text(max_size=5)), wpc=st.one_of(st.none(), st.integers(-3, 200)))
def test_check_arguments_accepts_or_refuses_in_one_line(memory, workers, fft, glass, wpc):
    from lenssim_cli.common import check_arguments

    argv = ["sweep", "grid.toml", "--out", "a.nc"]
    args = build_parser().parse_args(argv)
    args.memory_limit, args.workers, args.max_fft_size = memory, workers, fft
    ok = (memory is None or (math.isfinite(memory) and memory > 0)) and (fft is None or fft >= 16)
    try:
        check_arguments(args)
    except ValueError as exc:
        assert "\n" not in str(exc) and "is not allowed" in str(exc)
        assert not ok or (workers is not None and workers > 4)
    else:
        assert ok
    e = build_parser().parse_args(["evaluate", *E])
    e.glass, e.wavelengths_per_channel = glass, wpc
    try:
        check_arguments(e)
    except ValueError as exc:
        assert "\n" not in str(exc)
        assert (glass is not None and not glass.strip()) or wpc is not None
