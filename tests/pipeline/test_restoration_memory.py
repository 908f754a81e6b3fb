"""Issue 45: each restoration declares the memory it holds beyond the adaptive Wiener (its ``WorkingMemory``), the
whole frame's plan adds it, and ``simulate --full-frame`` refuses a frame too large for the method asked for before
any work, while the same frame passes with the Wiener."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

import pipeline.simulate
from lenssim_cli.main import main
from pipeline.blur import PAPER_SCHEME, WindowScheme
from pipeline.blur_operator import OPERATOR_OTF_BYTES
from pipeline.restoration import OPERATOR_PADDED_COPIES, RESTORATION_METHODS, Restoration, WorkingMemory
from pipeline.restoration.pnp import PNP_DENOISERS, PNP_MEMORY
from pipeline.simulate import FRAME_WORKING_COPIES, frame_memory_bytes

FRAME = (1, 3, 4000, 6000)  # a 24 MP colour frame


def test_every_registered_method_declares_its_memory():
    for name in RESTORATION_METHODS:
        need = Restoration(name).memory_bytes(FRAME, PAPER_SCHEME)
        assert isinstance(need, int) and need >= 0, name
    assert Restoration("wiener").memory_bytes(FRAME, PAPER_SCHEME) == 0  # what the plan was measured with
    assert 0 < Restoration("tikhonov").memory_bytes(FRAME, PAPER_SCHEME) < OPERATOR_OTF_BYTES  # the same windowed pass
    for name in ("richardson_lucy", "tv", "pnp"):  # on the blur's operator: its kept OTFs and frame-sized buffers
        assert Restoration(name).memory_bytes(FRAME, PAPER_SCHEME) > OPERATOR_OTF_BYTES + 4 * math.prod(FRAME)


def test_the_working_memory_arithmetic_against_a_written_out_count():
    scheme = WindowScheme(512, 32, 64)  # 256 + 64 = 320 px read beyond the frame each side
    written = 4 * (2.5 * 3 * 4000 * 6000 + 1.5 * 3 * (4000 + 640) * (6000 + 640))
    assert WorkingMemory(copies=2.5, padded=1.5).bytes(FRAME, scheme) == math.ceil(written)
    # on the blur's operator: its padded buffers and at most 1 GiB of kept OTFs besides
    operator = 4 * OPERATOR_PADDED_COPIES * 3 * (4000 + 640) * (6000 + 640) + 2**30
    assert WorkingMemory(copies=2.5, padded=1.5, operator=True).bytes(FRAME, scheme) == math.ceil(written + operator)
    assert WorkingMemory().bytes(FRAME, scheme) == 0
    with pytest.raises(ValueError, match="copies"):
        WorkingMemory(copies=-1)
    with pytest.raises(ValueError, match="padded"):
        WorkingMemory(padded=math.nan)


@pytest.mark.parametrize("spec", ["richardson_lucy", "tv", "pnp", "pnp:denoiser=wavelet", "pnp:denoiser=nlm",
                                  "pnp:denoiser=bm3d"])
def test_the_frame_plan_adds_the_method_once(spec):
    if "bm3d" in spec:
        pytest.importorskip("bm3d")
    r = Restoration.of(spec)
    wiener = frame_memory_bytes(FRAME)
    assert wiener == FRAME_WORKING_COPIES * 4 * math.prod(FRAME)  # as before the methods declared their memory
    assert frame_memory_bytes(FRAME, 1, r, PAPER_SCHEME) == wiener + r.memory_bytes(FRAME, PAPER_SCHEME)
    # a second restored frame (--as-built) adds its frame; the method's buffers are freed between the two
    assert frame_memory_bytes(FRAME, 2, r) - frame_memory_bytes(FRAME, 1, r) == 4 * math.prod(FRAME)


def test_the_pnp_denoisers_declare_their_own_memory():
    assert set(PNP_MEMORY) == set(PNP_DENOISERS)
    need = {d: m.bytes(FRAME, PAPER_SCHEME) for d, m in PNP_MEMORY.items()}
    assert need["nlm"] > need["wavelet"] and need["bm3d"] > need["wavelet"], need  # the host's float64 copies
    for d in ("wavelet", "tv", "nlm"):
        assert Restoration("pnp", {"denoiser": d}).memory_bytes(FRAME, PAPER_SCHEME) == need[d]


# --- the declaration against a measured peak ----------------------------------------------------------------------

PROBE = r"""
import json, sys
import torch
from lenssim import FunctionPSF
from lenssim_studies.paper import PAPER_CAMERA
import pipeline.blur_operator as BO
from pipeline import NoiseModel
from pipeline.blur import WindowScheme
from pipeline.restoration import restore

def rss(key):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith(key + ":"))

def gauss(x, y, m):
    r = torch.arange(m, dtype=torch.float64) - m // 2
    k = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * 1.5 ** 2))
    return (k / k.sum()).expand(len(x), m, m)

class WithPedestal(FunctionPSF):  # as a lens's PSFs: light spread over the window, which the operator box-filters
    def pedestal_fractions(self, n):
        return (0.02,) * self.channels

spec, size, scheme = sys.argv[1], int(sys.argv[2]), WindowScheme(*map(int, sys.argv[3].split(",")))
psf, noise = WithPedestal(gauss, PAPER_CAMERA.geometry), NoiseModel(1000.0)
x = 0.1 + 0.5 * torch.rand(1, 3, size, size, generator=torch.Generator().manual_seed(0))
restore(spec, x[..., :96, :96].clone(), psf, noise=noise, scheme=scheme)  # the imports and first calls, not counted
otf = [0]
kept = BO.BlurOperator._windows
def spy(self, t):  # the OTFs the operator keeps (declared apart: at most OPERATOR_OTF_BYTES)
    found = kept(self, t)
    if isinstance(found[0], list):
        otf[0] = max(otf[0], sum(o.nbytes for *_, o in found[0]) + sum(c.nbytes for c in found[2]))
    return found
BO.BlurOperator._windows = spy
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # the peak resident set starts again from here
before = rss("VmRSS")
restore(spec, x, psf, noise=noise, scheme=scheme)
print(json.dumps({"peak": rss("VmHWM") - before, "otf": otf[0]}))
"""


def _peak(spec, size, scheme) -> dict:
    """The peak resident memory (bytes) a restoration adds, measured in a fresh process (torch's allocations are
    invisible to tracemalloc), and the OTF bytes its operator kept."""
    # glibc's mmap threshold fixed: freed buffers leave the resident set, as a large frame's (above the threshold's
    # 32 MiB ceiling) do anyway; else a small frame's peak counts freed buffers the heap keeps
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "65536",
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[2]), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", PROBE, spec, str(size), ",".join(map(str, scheme))], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not os.access("/proc/self/clear_refs", os.W_OK), reason="needs Linux's resettable peak RSS")
def test_the_declared_memory_bounds_a_measured_peak():
    """pnp (its default denoiser, the most of the default methods) on a 256 px colour frame: what it holds beyond the
    Wiener's peak, less the OTFs its operator kept, within its declared buffers."""
    scheme, size = (64, 16, 32), 256
    wiener = _peak("wiener:stats=64", size, scheme)
    pnp = _peak("pnp:iterations=2", size, scheme)
    declared = Restoration.of("pnp").memory_bytes((1, 3, size, size), WindowScheme(*scheme)) - OPERATOR_OTF_BYTES
    assert 0 < pnp["otf"] <= OPERATOR_OTF_BYTES
    assert pnp["peak"] - pnp["otf"] - wiener["peak"] <= declared, (pnp, wiener, declared)


# --- the command refuses before any work -------------------------------------------------------------------------

def _photo(path, h=288, w=320):
    """A small grey photo: the camera man cut down."""
    import torch
    from skimage import data

    from pipeline.io import write_image

    cam = torch.from_numpy(data.camera()[:h, 96:96 + w].astype("float32") / 255.0)
    write_image(path, cam[None, None])
    return path


class _Started(BaseException):
    """Raised where the work would start: the run got past every check."""


def test_full_frame_pnp_is_refused_at_a_limit_that_passes_the_wiener(tmp_path, capsys, monkeypatch):
    photo = _photo(tmp_path / "camera.png")
    shape, scheme = (1, 1, 288, 320), WindowScheme(256, 32, 64)
    limit = frame_memory_bytes(shape) + OPERATOR_OTF_BYTES // 2  # between the Wiener's plan and pnp's
    assert frame_memory_bytes(shape, 1, "pnp", scheme) > limit
    argv = ["simulate", str(photo), "--design", "end_to_end_paper", "--full-frame", "--scheme", "256", "32", "64",
            "--angles", "0", "--crop", "64", "--memory-limit", f"{limit / 2**30:.6g}"]

    def started(*args, **kwargs):
        raise _Started

    monkeypatch.setattr(pipeline.simulate, "simulate_frame", started)
    out = tmp_path / "pnp"
    assert main([*argv, "--restore", "pnp", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert (f"--full-frame on the 320 x 288 photo {str(photo)!r} restored with pnp needs about" in err
            and "raise it with --memory-limit GIB" in err), err
    assert not out.exists()
    with pytest.raises(_Started):  # the Wiener at the same limit gets past the check, to the work
        main([*argv, "--restore", "wiener", "--out", str(tmp_path / "wiener")])
