"""Camera-pipeline stage timings and a side-by-side ratio against a straightforward baseline.

    python benchmarks/bench_pipeline.py [PHOTO] [--region 256] [--angle 8]

Input: the 24 MP photo in ../shared/photos when present (else the generated 6000 x 4000 scene).
Times read + linearise on the whole frame, then, on a ``region`` x ``region`` crop at ``angle``
degrees: the windowed blur (512/32/64), Poisson noise and the adaptive Wiener restoration, and
side by side on the same windows the baseline a user would write first: a Python loop of
``scipy.signal.fftconvolve`` per window and channel with each window's PSF. Prints the ratio, the
per-window costs, the full-frame estimate (23,688 windows per pass at 6000 x 4000) and peak RSS.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np
import torch

from lenssim import PAPER_LENS
from pipeline import add_poisson_noise
from pipeline.blur import PAPER_SCHEME, _psfs_at_pixels, blur_windowed, tent_weights, window_centres
from pipeline.cli import load_photo
from pipeline.restoration import wiener_windowed
from pipeline.simulate import crop_at_field_angle

S, Q = -0.775, -2.4


def baseline_blur(img: torch.Tensor, region, center) -> tuple[np.ndarray, int]:
    """Per-window scipy.signal.fftconvolve with per-window PSFs, tent-blended cores (same scheme)."""
    from scipy.signal import fftconvolve

    x = img[0].double().numpy()
    C, H, W = x.shape
    win, core, stride = PAPER_SCHEME.window, PAPER_SCHEME.core, PAPER_SCHEME.stride
    half = win // 2
    r0, r1, c0, c1 = region
    cy, cx = window_centres(H, stride), window_centres(W, stride)
    cy = cy[(cy + core // 2 > r0) & (cy - core // 2 < r1)].tolist()
    cx = cx[(cx + core // 2 > c0) & (cx - core // 2 < c1)].tolist()
    pad = half + core
    xp = np.pad(x, ((0, 0), (pad, pad), (pad, pad)), mode="reflect")
    out = np.zeros((C, H + 2 * core, W + 2 * core))
    wsum = np.zeros((H + 2 * core, W + 2 * core))
    t = tent_weights(core).numpy()
    t2 = t[:, None] * t[None, :]
    n = 0
    for y in cy:
        for xx in cx:
            psf = _psfs_at_pixels(PAPER_LENS, S, Q, torch.tensor([y]), torch.tensor([xx]), center, win)[0].numpy()
            psf = psf[1:, 1:]  # odd size: 'same' mode centres a 511-px kernel on its index 255 = our PSF centre
            patch = xp[:, y + pad - half:y + pad + half, xx + pad - half:xx + pad + half]
            for c in range(C):
                conv = fftconvolve(patch[c], psf, mode="same")
                out[c, y + core - core // 2:y + core + core // 2, xx + core - core // 2:xx + core + core // 2] += \
                    conv[half - core // 2:half + core // 2, half - core // 2:half + core // 2] * t2
            wsum[y + core - core // 2:y + core + core // 2, xx + core - core // 2:xx + core + core // 2] += t2
            n += 1
    res = out[:, core:core + H, core:core + W] / np.maximum(wsum[core:core + H, core:core + W], 1e-300)
    return res[:, r0:r1, c0:c1], n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--region", type=int, default=256)
    ap.add_argument("--angle", type=float, default=8.0)
    args = ap.parse_args()
    shared = Path(__file__).resolve().parents[1].parent / "shared" / "photos" / "outdoor_misty_forest_6016x4016.jpg"
    photo = args.photo or (str(shared) if shared.exists() else None)
    t0 = time.perf_counter()
    ideal, source = load_photo(photo)
    t_read = time.perf_counter() - t0
    H, W = ideal.shape[-2:]
    box = crop_at_field_angle(ideal.shape, args.angle, args.region)
    margin = PAPER_SCHEME.window // 2 + PAPER_SCHEME.core
    R0, R1, C0, C1 = max(box[0] - 2 * margin, 0), min(box[1] + 2 * margin, H), max(box[2] - 2 * margin, 0), min(box[3] + 2 * margin, W)
    sub = ideal[..., R0:R1, C0:C1].float()
    center = ((H - 1) / 2 - R0, (W - 1) / 2 - C0)
    reg = (box[0] - R0, box[1] - R0, box[2] - C0, box[3] - C0)
    count = [0]
    t0 = time.perf_counter()
    ours = blur_windowed(sub, PAPER_LENS, S, Q, optical_center=center, region=reg, progress=lambda k: count.__setitem__(0, count[0] + k))
    t_blur = time.perf_counter() - t0
    nwin = count[0]
    t0 = time.perf_counter()
    base, nb = baseline_blur(sub, reg, center)
    t_base = time.perf_counter() - t0
    diff = np.abs(ours[0, :, reg[0]:reg[1], reg[2]:reg[3]].numpy() - base).max()
    t0 = time.perf_counter()
    noisy = add_poisson_noise(ours.clamp_min(0), 3200.0, seed=0)
    t_noise = time.perf_counter() - t0
    t0 = time.perf_counter()
    wiener_windowed(noisy, PAPER_LENS, S, Q, electrons_per_unit=3200.0 / float(ours.amax()), optical_center=center, region=reg)
    t_wiener = time.perf_counter() - t0
    full = len(window_centres(4000, 32)) * len(window_centres(6000, 32))
    per_blur, per_wiener = t_blur / nwin, t_wiener / nwin
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(f"input: {source} ({W}x{H}); read + linearise {t_read:.1f} s; torch threads {torch.get_num_threads()}")
    print(f"region {args.region} px at {args.angle:g} deg: {nwin} windows of 512 px, 3 channels")
    print(f"  blur (lenssim PSF per window + batched rfft2): {t_blur:.1f} s = {1e3 * per_blur:.0f} ms/window")
    print(f"  baseline (scipy fftconvolve loop, same PSFs): {t_base:.1f} s = {1e3 * t_base / nb:.0f} ms/window; "
          f"ratio {t_base / t_blur:.2f}x; max |difference| {diff:.1e}")
    print(f"  Poisson noise: {t_noise:.2f} s; adaptive Wiener: {t_wiener:.1f} s = {1e3 * per_wiener:.0f} ms/window")
    print(f"full frame estimate (6000x4000, {full} windows per pass): blur {full * per_blur / 60:.0f} min + "
          f"Wiener {full * per_wiener / 60:.0f} min; peak RSS so far {peak:.2f} GiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
