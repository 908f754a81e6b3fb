"""Third round (issue 28): bounded work for every input, every input checked first.

Images are read within bounds (header first; a crop decodes only the rows or tiles it needs; a whole file is checked
in bands of bounded size), absurd design values are refused at once, and the same rule is written once for options
given in two ways (``--rl N`` and ``richardson_lucy:iterations=N``).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import torch

import pipeline
import pipeline.io as pio
from lenssim.optics.psf_bank import nice_fft_size
from lenssim_cli.main import main
from pipeline.io import MAX_LINEAR_VALUE, ImageFileError, image_info, read_image, scan_image
from pipeline.photo import Photo, open_photo


def _write(path, arr, fmt="uint8", tile=0):
    """Write ``arr`` ``(H, W, C)`` float in [0, 1] with OpenImageIO (tiled if ``tile``)."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(arr.shape[1], arr.shape[0], arr.shape[2], fmt)
    if tile:
        spec.tile_width = spec.tile_height = tile
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(arr, dtype=np.float32)), out.geterror()
    out.close()
    return str(path)


def _brute_nice(n, multiple=16):
    m = max(multiple, int(math.ceil(n / multiple)) * multiple)
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += multiple


def test_nice_fft_size_equals_counting_up_and_answers_any_size_at_once():
    for n in list(range(0, 5000)) + [12345.5, 99999, 2**20 + 1]:
        assert nice_fft_size(n) == _brute_nice(n), n
    for multiple in (1, 2, 8, 30):
        for n in range(0, 2000, 13):
            assert nice_fft_size(n, multiple) == _brute_nice(n, multiple)
    big = nice_fft_size(4.5e13)  # counting up took minutes for such a size (an absurd conic)
    assert big >= 4.5e13 and big % 16 == 0
    k = big // 16
    for p in (2, 3, 5):
        while k % p == 0:
            k //= p
    assert k == 1
    with pytest.raises(ValueError, match="no prime factor above 5"):
        nice_fft_size(100, 7)


@pytest.mark.parametrize("argv, match", [
    (["evaluate", "--design", "end_to_end_paper", "--Q_back", "-300"], "a PSF needs an FFT of"),
    (["evaluate", "--design", "end_to_end_paper", "--Q_back", "-1e12"], "its third-order blur is 3.58e+10 mm, not "
                                                                        "smaller than the focal length 25 mm"),
    (["evaluate", "--design", "end_to_end_paper", "--Q_front", "-1e308"], "its third-order blur is 7.29e+303 mm"),
    (["evaluate", "--design", "end_to_end_paper", "--focus_shift_um", "1e9"], "|focus_shift_um| < 25000 um"),
    (["evaluate", "--design", "end_to_end_paper", "--focus_shift_um", "-25000"], "focus_shift_um=-25000.0 is not"),
])
def test_absurd_design_values_are_refused_with_a_reason(capsys, argv, match):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err


@pytest.mark.parametrize("fmt, tile, suffix", [("uint8", 0, ".png"), ("uint16", 32, ".tif"), ("half", 32, ".exr"),
                                              ("uint8", 0, ".jpg")])
def test_a_region_read_equals_the_same_pixels_of_the_whole_read(tmp_path, monkeypatch, fmt, tile, suffix):
    arr = np.random.default_rng(1).random((150, 110, 3)).astype(np.float32)
    path = _write(tmp_path / f"img{suffix}", arr, fmt, tile)
    whole, info = read_image(path)
    assert info.shape == tuple(whole.shape) == image_info(path).shape
    assert info.tile_height == tile
    monkeypatch.setattr(pio, "READ_BAND_BYTES", 110 * 3 * 4 * 7)  # bands of 7 rows (of whole tiles when tiled)
    for region in ((0, 150, 0, 110), (3, 77, 5, 101), (31, 33, 63, 65), (149, 150, 109, 110)):
        r0, r1, c0, c1 = region
        part, _ = read_image(path, region)
        assert torch.equal(part, whole[..., r0:r1, c0:c1]), region
    info2, stats = scan_image(path)
    assert info2 == info and stats.minimum == float(whole.min()) and stats.maximum == float(whole.max())
    with pytest.raises(ImageFileError, match="is not inside"):
        read_image(path, (0, 151, 0, 10))


def test_a_photo_too_large_to_keep_gives_the_same_crops_as_one_in_memory(tmp_path):
    arr = np.random.default_rng(2).random((300, 340, 3)).astype(np.float32)
    path = _write(tmp_path / "p.png", arr)
    kept, streamed = open_photo(path), open_photo(path, keep_bytes=0)
    assert kept.in_memory and not streamed.in_memory
    assert streamed.shape == kept.shape and streamed.peak == kept.peak
    assert torch.equal(streamed.load(), kept.load())
    from lenssim import LensPSF
    from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
    from pipeline import WindowScheme, simulate_crops

    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    boxes = [(0, 48, 0, 48), (120, 168, 150, 198)]
    scheme = WindowScheme(128, 32, 64)
    a = simulate_crops(kept.load(), psf, 3000.0, boxes, seed=3, scheme=scheme, sensor=PAPER_CAMERA.sensor)
    b = simulate_crops(streamed, psf, 3000.0, boxes, seed=3, scheme=scheme, sensor=PAPER_CAMERA.sensor)
    for ra, rb in zip(a, b):
        assert ra.scores == rb.scores
        for k in ra.images:
            assert torch.equal(ra.images[k], rb.images[k]), k


def test_a_photo_in_memory_is_checked_as_a_scene():
    with pytest.raises(ValueError, match="is black"):
        Photo.of(torch.zeros(1, 3, 40, 40), "black")


_PEAK_RSS = """
import resource, sys
import numpy as np
import pipeline.io as pio
from pipeline.photo import open_photo
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
photo = open_photo(sys.argv[1], keep_bytes=0)          # every pixel checked, in bands
crop = photo.region(3990, 4118, 1000, 1128)            # a 128 px crop in the middle
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print((after - before) * 1024, photo.nbytes(), float(crop.mean()))
"""


def test_checking_and_cropping_a_large_photo_takes_bounded_memory(tmp_path):
    """A 8000 x 8000 grey PNG (256 MB as float32, a few hundred kB on disk): checking it whole and reading a crop
    raise the process's peak memory by far less than the frame, in a fresh process (peak RSS)."""
    import OpenImageIO as oiio

    path = tmp_path / "tall.png"
    n = 8000
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(n, n, 1, "uint8"))
    x = np.arange(n)
    for y in range(n):
        out.write_scanline(y, 0, ((((x // 64) + (y // 64)) % 2) * 128 + 64).astype(np.uint8)[:, None])
    out.close()
    r = subprocess.run([sys.executable, "-c", _PEAK_RSS, str(path)], capture_output=True, text=True, check=True)
    grown, frame, mean = (float(v) for v in r.stdout.split()[:3])
    assert frame == n * n * 4
    assert grown < 0.5 * pio.READ_BAND_BYTES + 0.25 * frame, (grown, frame)  # whole: >= frame
    assert 0 < mean < 1


def test_linear_values_beyond_the_half_float_range_are_refused_in_the_users_words(tmp_path, capsys):
    arr = np.random.default_rng(3).random((64, 64, 3)).astype(np.float32)
    arr[10, 20, 1] = 3e30  # finite, enormous
    path = _write(tmp_path / "big.exr", arr, "float")
    assert main(["simulate", path, "--design", "end_to_end_paper", "--crop", "32", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"photo {path!r} holds the value 3e+30 at row 10, column 20" in err[0]
    words = err[0].replace(path, "")  # no internal name (the former message named the tensor "test"), no NaN
    assert f"up to {MAX_LINEAR_VALUE:g}" in words and "NaN" not in words and "test" not in words
    assert not (tmp_path / "o").exists()


def test_psnr_table_checks_every_photo_before_the_first_computation(tmp_path, capsys, monkeypatch):
    good = _write(tmp_path / "good.png", np.random.default_rng(4).random((96, 96, 3)).astype(np.float32))
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)

    def boom(*a, **k):
        raise AssertionError("a photo was simulated before every photo was checked")

    monkeypatch.setattr(pipeline, "simulate_crops", boom)
    import lenssim_cli.camera as cam

    monkeypatch.setattr(cam, "simulate_crops", boom, raising=False)
    pixels_bad = _write(tmp_path / "nan.exr", np.full((96, 96, 3), np.nan, np.float32), "float")
    for second in (str(bad), pixels_bad):
        assert main(["psnr-table", good, second, "--designs", "end_to_end_paper", "--isos", "100", "--crop", "32",
                     "--out", str(tmp_path / "t")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and repr(second) in err[0], err
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("argv, match", [
    (["--rl", "0"], "--rl 0 is not allowed: a number of Richardson-Lucy iterations from 1 to 1000"),
    (["--rl", "100000000"], "--rl 100000000 is not allowed"),
    (["--restore", "richardson_lucy:iterations=0"], "iterations=0 is not allowed: an integer from 1 to 1000"),
    (["--restore", "richardson_lucy:iterations=100000000"], "iterations=100000000 is not allowed"),
])
def test_richardson_lucy_iterations_have_one_rule_however_given(tmp_path, capsys, argv, match):
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--crop", "32",
                 "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err


def test_simulate_reads_a_photo_too_large_to_keep_region_by_region(tmp_path, capsys, monkeypatch):
    """The command's crops of a photo read region by region equal those of the photo kept in memory."""
    import lenssim_cli.camera as cam

    path = _write(tmp_path / "p.png", np.random.default_rng(5).random((320, 400, 3)).astype(np.float32))
    argv = ["simulate", path, "--design", "end_to_end_paper", "--crop", "48", "--angles", "0", "0.5",
            "--scheme", "128", "32", "64"]
    assert main(argv + ["--out", str(tmp_path / "kept")]) == 0
    monkeypatch.setattr(cam, "PHOTO_KEEP_BYTES", 0)
    assert main(argv + ["--out", str(tmp_path / "streamed")]) == 0
    capsys.readouterr()
    a = json.loads((tmp_path / "kept" / "metrics.json").read_text())["crops"]
    b = json.loads((tmp_path / "streamed" / "metrics.json").read_text())["crops"]
    assert a == b


def test_a_design_whose_psf_outgrows_the_frame_is_refused_before_any_work(tmp_path, capsys):
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--focus_shift_um", "8000", "--crop",
                 "64", "--angles", "0", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "more than the 512 x 512 px frame" in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, match", [
    (["simulate", "--iso", "0", "--full-well", "1000", "--out", "o"], "--iso 0 and --full-well 1000 both set the full"),
    (["simulate", "--angles", "0", "-0", "--out", "o"], "--angles holds 0 more than once"),
    (["psnr-table", "--isos", "100", "100", "--out", "o"], "--isos holds 100 more than once"),
    (["evaluate", "--snr", "20", "20.0"], "--snr holds 20 more than once"),
    (["tolerance", "--design", "end_to_end_paper", "--worker-threads", "0", "--out", "o"],
     "--worker-threads 0 is not allowed: a number of threads >= 1"),
    (["tolerance", "--design", "end_to_end_paper", "--workers", "-1", "--out", "o"],
     "--workers -1 is not allowed: a number of local worker processes >= 1"),
])
def test_one_rule_for_repeated_values_counts_and_the_full_well(tmp_path, monkeypatch, capsys, argv, match):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err
    assert list(tmp_path.iterdir()) == []
