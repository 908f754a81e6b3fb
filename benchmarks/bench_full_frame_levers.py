"""Issue 33: the levers on the whole 24 MP frame, one by one, side by side in one process, each with its accuracy.

    python benchmarks/bench_full_frame_levers.py [PHOTO] [--mono]

The misty forest (default, ../shared/photos) or PHOTO, the paper's E2E design, ISO 100, the paper's scheme
(512/32/64, fitted blur windows), seed 0:

* **baseline**: today's frame before issue 33's levers: the blur at the scheme's stride, the adaptive Wiener
  restoration on 512 px windows everywhere;
* **lever 1, fitted restoration windows**: the same noisy frame restored with windows sized to the local PSF as the
  blur's but at least ``WIENER_FIT_LEAST_PX`` (``WindowScheme.fit``; :func:`pipeline.restoration.wiener.wiener_windowed`'s
  ``fit``): the restored PSNR and SSIM against the baseline's;
* **lever 2, blur zones**: the blur with a coarser stride where the PSF varies slowly
  (:func:`pipeline.blur.choose_stride_zones`): the blurred frame against the baseline's (dB), then the whole
  :func:`pipeline.simulate.simulate_frame` with both levers (its own noise draw; the scores against the baseline's).

Each time is also given in units of a fixed FFT workload timed in the same process first (200 float32
``rfft2``/``irfft2`` pairs of 4 x 3 x 512 x 512), so machines compare. No timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from lenssim import LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_SENSOR
from pipeline import load_photo
from workload import agreement_db, reference_seconds
from pipeline.blur import blur_windowed, choose_stride_zones, window_count
from pipeline.camera_chain import CameraChain
from pipeline.restoration.wiener import wiener_windowed
from pipeline.simulate import FrameResult, score_frame, simulate_frame

FULL_WELL = 3200.0
"""ISO 100's full well (e-), the paper's."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--mono", action="store_true", help="the green channel alone")
    a = ap.parse_args()
    shared = Path(__file__).resolve().parents[1].parent / "shared" / "photos" / "outdoor_misty_forest_6016x4016.jpg"
    photo = a.photo or (str(shared) if shared.exists() else None)
    ref = reference_seconds()
    ideal, source = load_photo(photo, PAPER_CAMERA)
    if a.mono:
        ideal = ideal[:, 1:2].contiguous()
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    H, W = ideal.shape[-2:]
    print(f"{source}: {W} x {H} x {ideal.shape[1]}; torch threads {torch.get_num_threads()}; reference workload "
          f"{ref:.2f} s")

    def line(label, seconds, extra=""):
        print(f"  {label:44s} {seconds:7.1f} s = {seconds / ref:5.1f} x ref{extra}")

    t0 = time.perf_counter()
    blurred0 = blur_windowed(ideal, psf)
    t_blur0 = time.perf_counter() - t0
    line(f"baseline blur ({window_count(ideal.shape)} windows)", t_blur0)
    e = FULL_WELL / float(blurred0.amax())
    chain = CameraChain(PAPER_SENSOR)
    noisy0 = chain.expose(blurred0, e, FULL_WELL, generator=torch.Generator().manual_seed(0))
    noise = chain.noise_model(e, FULL_WELL)
    t0 = time.perf_counter()
    restored0 = wiener_windowed(noisy0, psf, noise=noise, fit=False)
    t_rest0 = time.perf_counter() - t0
    line("baseline restoration (512 px windows)", t_rest0)
    s0 = score_frame(ideal, FrameResult(noisy0, restored0, "wiener", e, False, {}), psf.geometry)
    print(f"  baseline whole frame: PSNR sensor {s0['psnr_sensor_db']:.4f} dB -> restored "
          f"{s0['psnr_restored_db']:.4f} dB, SSIM {s0['ssim_sensor']:.4f} -> {s0['ssim_restored']:.4f}")

    t0 = time.perf_counter()
    restored1 = wiener_windowed(noisy0, psf, noise=noise, fit=True)
    t_rest1 = time.perf_counter() - t0
    s1 = score_frame(ideal, FrameResult(noisy0, restored1, "wiener", e, False, {}), psf.geometry)
    line("lever 1: fitted restoration windows", t_rest1,
         f"  ({t_rest0 / t_rest1:.2f}x); restored PSNR {s1['psnr_restored_db'] - s0['psnr_restored_db']:+.4f} dB, "
         f"SSIM {s1['ssim_restored'] - s0['ssim_restored']:+.5f}; the restored frames agree to "
         f"{agreement_db(restored1, restored0):.1f} dB")
    del restored1

    t0 = time.perf_counter()
    zones = choose_stride_zones(psf, ideal.shape)
    t_zones = time.perf_counter() - t0
    t0 = time.perf_counter()
    blurred2 = blur_windowed(ideal, psf, zones=zones)
    t_blur2 = time.perf_counter() - t0
    line(f"lever 2: choosing the zones {zones.to_dict()}", t_zones)
    line(f"lever 2: zoned blur ({window_count(ideal.shape, zones=zones)} windows)", t_blur2,
         f"  ({t_blur0 / (t_blur2 + t_zones):.2f}x with the choice); blurred frame {agreement_db(blurred2, blurred0):.1f} dB "
         "from the baseline's")
    del blurred2, blurred0, noisy0

    t0 = time.perf_counter()
    frame = simulate_frame(ideal, psf, FULL_WELL, seed=0, sensor=PAPER_SENSOR, blur_zones="auto")
    t_all = time.perf_counter() - t0
    s2 = score_frame(ideal, frame, psf.geometry)
    line("simulate_frame with both levers", t_all,
         f"  (baseline blur + restoration {t_blur0 + t_rest0:.1f} s: {(t_blur0 + t_rest0) / t_all:.2f}x); stages "
         + ", ".join(f"{k} {v:.1f} s" for k, v in frame.seconds.items()))
    print(f"  both levers, whole frame: PSNR sensor {s2['psnr_sensor_db']:.4f} dB -> restored "
          f"{s2['psnr_restored_db']:.4f} dB ({s2['psnr_restored_db'] - s0['psnr_restored_db']:+.4f}), SSIM "
          f"{s2['ssim_restored']:.4f} ({s2['ssim_restored'] - s0['ssim_restored']:+.5f}); its noise is another draw")
    print(f"  restored frames, both levers vs baseline: {agreement_db(frame.restored, restored0):.1f} dB")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown(0)
