"""Bad inputs, second round (issue 20), class 1: the flags added since the first round (camera, focus, wavefront,
limits, windows, dask, as-built, studies): one line, status 2, before any work; a property test over the shared
checks.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenssim_cli.main import build_parser

E = ["--design", "end_to_end_paper"]


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
    (["simulate", "ok.png", *E, "--as-built", "1", "--full-frame", "--rl", "2", "--out", "o"],
     "--full-frame restores with one method"),  # --full-frame --as-built itself works since issue 28
    (["simulate", "ok.png", *E, "--as-built", "1", "--off", "warp", "--out", "o"], "--off 'warp' is not allowed"),
    (["simulate", "ok.png", *E, "--as-built", "1", "--tolerances", "tol_typo.toml", "--out", "o"],
     "unknown key(s) radius_pct"),
    (["simulate", "ok.png", *E, "--restore", "wiener:local=tile", "--out", "o"], "local='tile' is not allowed"),
    (["psnr-table", "ok.png", "ok.png", "--out", "o"], "is given twice"),
    (["tolerance", *E, "--lenses", "10000000000", "--out", "o"], "use fewer --lenses"),
    (["tolerance", *E, "--angles", "-1", "--out", "o"], "field angle=-1.0 is not allowed"),
    (["tolerance", *E, "--angles", "80", "--out", "o"], "at the field angle 80 deg: its third-order blur is"),
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
def test_new_flags_are_refused_on_one_line_before_any_work(argv, match, files, refused):
    refused(argv, match, files)


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
    ok = (memory is None or (math.isfinite(memory) and memory > 0)) and (fft is None or fft >= 16) \
        and (workers is None or workers >= 1)
    try:
        check_arguments(args)
    except ValueError as exc:
        assert "\n" not in str(exc) and "is not allowed" in str(exc)
        # more workers than 4 per core, or an FFT limit whose one OTF would not fit this machine's memory (issue 43)
        assert not ok or (workers is not None and workers > 4) or (fft is not None and "would need" in str(exc))
    else:
        assert ok
    e = build_parser().parse_args(["evaluate", *E])
    e.glass, e.wavelengths_per_channel = glass, wpc
    try:
        check_arguments(e)
    except ValueError as exc:
        assert "\n" not in str(exc)
        assert (glass is not None and not glass.strip()) or wpc is not None
