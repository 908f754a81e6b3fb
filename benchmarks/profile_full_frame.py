"""Issue 33, item 1: a stage-by-stage profile of the whole-frame simulation, mono and colour, with the time inside the
windowed passes split by what they do, as a ratio against a fixed FFT workload run in the same process.

    python benchmarks/profile_full_frame.py [PHOTO] [--mono-only | --colour-only] [--top 12]

For the photo (default the 24 MP misty forest in ../shared/photos, else the generated 6000 x 4000 scene), the
paper's E2E design, ISO 100, the paper's scheme (512/32/64, fitted blur windows), what ``lenssim simulate
--full-frame`` runs (``simulate_frame`` + ``score_frame``): read + linearise, blur, noise, restoration, scoring; per
stage its wall time and the peak resident memory while it ran (sampled from /proc every 20 ms), for the colour frame
and for its green channel alone (mono). Inside the blur and the restoration, cProfile's cumulative time of the
functions that matter (PSF computation, FFTs, the windows' blending, the Wiener statistics), so each lever of issue 33
can be sized before it is built. The reference workload: 200 batched float32 ``rfft2``/``irfft2`` pairs of 4 x 3 x
512 x 512, timed first; every stage is also printed in units of it, so machines compare. No timing is asserted.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import threading
import time
from pathlib import Path

import torch

from lenssim import LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import load_photo
from workload import reference_seconds
from pipeline.simulate import score_frame, simulate_frame

FULL_WELL = 3200.0
"""ISO 100's full well (e-), the paper's."""
INTERESTING = ("psf_at_pixels", "fft_rfft2", "fft_irfft2", "core_irfft2", "apply_windowed", "_psfs", "restore",
               "box_blur", "wiener_windowed", "blur_windowed", "expose", "encode_srgb", "scores_encoded",
               "linear_to_srgb", "srgb_to_linear", "read_image")


class PeakRSS:
    """The peak resident memory (GiB) of this process while the block runs (VmHWM reset where allowed, else sampled)."""

    def __enter__(self):
        self.peak = 0.0
        self._stop = False
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        return self

    def _run(self):
        while not self._stop:
            try:
                for line in Path("/proc/self/status").read_text().splitlines():
                    if line.startswith("VmRSS:"):
                        self.peak = max(self.peak, int(line.split()[1]) / 2**20)
            except OSError:
                return
            time.sleep(0.02)

    def __exit__(self, *exc):
        self._stop = True
        self._t.join()


def _profile_lines(prof: cProfile.Profile, top: int) -> list[str]:
    st = pstats.Stats(prof)
    rows = []
    for (file, line, name), (cc, nc, tt, ct, callers) in st.stats.items():
        if any(k in name for k in INTERESTING):
            rows.append((ct, nc, f"{Path(file).name}:{name}"))
    rows.sort(reverse=True)
    return [f"      {ct:8.1f} s cumulative  {nc:7d} calls  {label}" for ct, nc, label in rows[:top]]


def run(photo, mono: bool, ref: float, top: int) -> None:
    label = "mono (green channel)" if mono else "colour"
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    print(f"\n== {label} ==")
    stages = []
    with PeakRSS() as m:
        t0 = time.perf_counter()
        ideal, source = load_photo(photo, PAPER_CAMERA)
        if mono:
            ideal = ideal[:, 1:2].contiguous()
        stages.append(("read + linearise", time.perf_counter() - t0, m.peak))
    prof = cProfile.Profile()
    with PeakRSS() as m:
        t0 = time.perf_counter()
        prof.enable()
        frame = simulate_frame(ideal, psf, FULL_WELL, seed=0, sensor=PAPER_CAMERA.sensor)
        prof.disable()
        total = time.perf_counter() - t0
    for k, v in frame.seconds.items():
        stages.append((k, v, None))
    stages.append(("simulate_frame (all of the above)", total, m.peak))
    with PeakRSS() as m:
        t0 = time.perf_counter()
        scores = score_frame(ideal, frame, psf.geometry)
        stages.append(("scoring (sRGB, PSNR, SSIM, maps)", time.perf_counter() - t0, m.peak))
    H, W = ideal.shape[-2:]
    print(f"{source}: {W} x {H} x {ideal.shape[1]}; torch threads {torch.get_num_threads()}; reference workload "
          f"{ref:.2f} s")
    for name, dt, peak in stages:
        mem = "" if peak is None else f"  peak {peak:5.2f} GiB"
        print(f"  {name:36s} {dt:7.1f} s = {dt / ref:6.1f} x ref{mem}")
    print(f"  whole frame: PSNR sensor {scores['psnr_sensor_db']:.2f} dB -> restored {scores['psnr_restored_db']:.2f} dB")
    print("  inside simulate_frame (cProfile, cumulative):")
    print("\n".join(_profile_lines(prof, top)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--mono-only", action="store_true")
    ap.add_argument("--colour-only", action="store_true")
    ap.add_argument("--top", type=int, default=12)
    a = ap.parse_args()
    shared = Path(__file__).resolve().parents[1].parent / "shared" / "photos" / "outdoor_misty_forest_6016x4016.jpg"
    photo = a.photo or (str(shared) if shared.exists() else None)
    ref = reference_seconds()
    if not a.mono_only:
        run(photo, False, ref, a.top)
    if not a.colour_only:
        run(photo, True, ref, a.top)


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown(0)
