"""Camera-pipeline benchmark: every stage of the full-frame run, and a ratio against a baseline.

    python benchmarks/bench_pipeline.py [PHOTO] [--region 256] [--angle 8] [--no-full] [--device auto]

Input: the 24 MP photo in ../shared/photos when present, else the generated 6000 x 4000 scene.

1. Side by side on the same windows of a ``region`` x ``region`` crop at ``angle`` degrees: our
   windowed blur (512/32/64) against the baseline a user would write first, a Python loop of
   ``scipy.signal.fftconvolve`` per window and channel with each window's PSF (the same float32
   PSFs, so the ratio measures the convolution machinery). Prints the ratio and the agreement.
2. Side by side on a small frame (``--frame 1536 1024``, optical axis at its centre): blur + Poisson
   noise + adaptive Wiener with the window grid of the first version (``anchor="origin"``, one PSF
   computation per window and pass) against today's default (``anchor="axis"``: one PSF per mirror
   group of up to 8 windows). Prints the ratio and how far apart the two restored frames are (PSNR).
   Then the blur alone on that frame: the machinery before issue 11's second round, today's with every
   window 512 px (the same numbers: prints whether the frames are identical) and today's default, windows
   fitted to the local PSF (prints the agreement in dB). ``--full-blur-side-by-side``: the same 512 px
   against fitted comparison on the whole frame.
3. Unless ``--no-full``: the paper-faithful full-frame run, stage by stage (read + linearise,
   blur, Poisson noise at ISO 100, adaptive Wiener, sRGB PSNR), with the wall time and the peak
   resident memory of each stage (sampled from /proc every 20 ms) and of the whole run.
   Targets on the 2-core CPU machine: < 10 min and < 6 GiB; on one H200: < 20 s.
"""

from __future__ import annotations

import argparse
import math
import resource
import threading
import time
from pathlib import Path

import numpy as np
import torch

from lenssim import LensPSF, select_device

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import NoiseModel, add_poisson_noise, load_photo
from pipeline.blur import (PAPER_SCHEME, WindowScheme, blur_windowed, box_mean, tent_weights, window_centres,
                           window_count)
from pipeline.quality import psnr_srgb
from pipeline.restoration import wiener_windowed
from pipeline.simulate import crop_at_field_angle

DESIGN = PAPER_DESIGNS["end_to_end_paper"]
PSF = LensPSF(PAPER_CAMERA, DESIGN)
FULL_WELL = PAPER_CAMERA.sensor.full_well_for_iso(100)


class PeakRSS:
    """Peak resident set size (GiB) while the ``with`` block runs, sampled from /proc/self/statm."""

    def __enter__(self):
        self.peak, self._stop = self._rss(), threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        return self

    @staticmethod
    def _rss() -> float:
        try:
            with open("/proc/self/statm") as f:
                return int(f.read().split()[1]) * resource.getpagesize() / 2**30
        except OSError:  # not Linux: the process-wide high-water mark
            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20

    def _run(self):
        while not self._stop.wait(0.02):
            self.peak = max(self.peak, self._rss())

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, self._rss())


def stage(name: str, rows: list, fn):
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    with PeakRSS() as mem:
        t0 = time.perf_counter()
        out = fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        dt = time.perf_counter() - t0
    rows.append((name, dt, mem.peak))
    print(f"  {name:<28} {dt:8.1f} s   peak RSS {mem.peak:5.2f} GiB", flush=True)
    return out


def baseline_blur(img: torch.Tensor, region, center) -> tuple[np.ndarray, int]:
    """Per-window ``scipy.signal.fftconvolve`` with per-window PSFs, tent-blended cores (same scheme)."""
    from scipy.signal import fftconvolve

    x = img[0].float().numpy()
    C, H, W = x.shape
    win, core, stride = PAPER_SCHEME.window, PAPER_SCHEME.core, PAPER_SCHEME.stride
    half = win // 2
    r0, r1, c0, c1 = region
    cy, cx = window_centres(H, stride), window_centres(W, stride)
    cy = cy[(cy + core // 2 > r0) & (cy - core // 2 < r1)].tolist()
    cx = cx[(cx + core // 2 > c0) & (cx - core // 2 < c1)].tolist()
    pad = half + core
    xp = np.pad(x, ((0, 0), (pad, pad), (pad, pad)), mode="reflect")
    out = np.zeros((C, H + 2 * core, W + 2 * core), np.float32)
    wsum = np.zeros((H + 2 * core, W + 2 * core), np.float32)
    t = tent_weights(core, torch.float32).numpy()
    t2 = t[:, None] * t[None, :]
    n = 0
    for y in cy:
        for xx in cx:
            psf = PSF.psf_at_pixels(torch.tensor([y]), torch.tensor([xx]), center, win, dtype=torch.float32)[0].numpy()
            psf = psf[1:, 1:]  # odd size: 'same' mode centres a 511-px kernel on its index 255 = our PSF centre
            patch = xp[:, y + pad - half:y + pad + half, xx + pad - half:xx + pad + half]
            cy0, cx0 = y + core - core // 2, xx + core - core // 2
            for c in range(C):
                conv = fftconvolve(patch[c], psf, mode="same")
                out[c, cy0:cy0 + core, cx0:cx0 + core] += \
                    conv[half - core // 2:half + core // 2, half - core // 2:half + core // 2] * t2
            wsum[cy0:cy0 + core, cx0:cx0 + core] += t2
            n += 1
    res = out[:, core:core + H, core:core + W] / np.maximum(wsum[core:core + H, core:core + W], 1e-30)
    return res[:, r0:r1, c0:c1], n


def side_by_side(ideal: torch.Tensor, region: int, angle: float) -> None:
    H, W = ideal.shape[-2:]
    box = crop_at_field_angle(ideal.shape, angle, region, PAPER_CAMERA.geometry)
    margin = PAPER_SCHEME.window // 2 + PAPER_SCHEME.core
    R0, R1 = max(box[0] - 2 * margin, 0), min(box[1] + 2 * margin, H)
    C0, C1 = max(box[2] - 2 * margin, 0), min(box[3] + 2 * margin, W)
    sub = ideal[..., R0:R1, C0:C1].float()
    center = ((H - 1) / 2 - R0, (W - 1) / 2 - C0)
    reg = (box[0] - R0, box[1] - R0, box[2] - C0, box[3] - C0)
    blur_windowed(sub, PSF, optical_center=center, region=(reg[0], reg[0] + 1, reg[2], reg[2] + 1))
    count = [0]
    t0 = time.perf_counter()
    ours = blur_windowed(sub, PSF, optical_center=center, region=reg,
                         progress=lambda k: count.__setitem__(0, count[0] + k))
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    base, nb = baseline_blur(sub, reg, center)
    t_base = time.perf_counter() - t0
    diff = float(np.abs(ours[0, :, reg[0]:reg[1], reg[2]:reg[3]].numpy() - base).max())
    print(f"side by side, {region} px crop at {angle:g} deg ({count[0]} windows of 512 px, "
          f"{ideal.shape[1]} channels):")
    print(f"  ours:     {t_ours:6.1f} s = {1e3 * t_ours / count[0]:5.1f} ms/window")
    print(f"  baseline: {t_base:6.1f} s = {1e3 * t_base / nb:5.1f} ms/window (scipy fftconvolve loop, same PSFs)")
    print(f"  ratio {t_base / t_ours:.2f}x; max |difference| {diff:.1e}")


def grid_side_by_side(ideal: torch.Tensor, size) -> None:
    """Blur + noise + Wiener of a ``size = (W, H)`` frame cut from the photo, origin grid vs axis grid."""
    W, H = size
    H0, W0 = ideal.shape[-2:]
    frame = ideal[..., (H0 - H) // 2:(H0 - H) // 2 + H, (W0 - W) // 2:(W0 - W) // 2 + W].float().contiguous()
    out, times = {}, {}
    for anchor in ("origin", "axis", "origin", "axis"):  # twice each, interleaved: the machine's load shared
        scheme = WindowScheme(anchor=anchor)
        t0 = time.perf_counter()
        blurred = blur_windowed(frame, PSF, scheme=scheme)
        e = FULL_WELL / float(blurred.amax())
        noisy = add_poisson_noise(blurred.clamp_min(0), FULL_WELL, seed=0)
        out[anchor] = wiener_windowed(noisy, PSF, noise=NoiseModel(e), scheme=scheme)
        times.setdefault(anchor, []).append(time.perf_counter() - t0)
    t_old, t_new = min(times["origin"]), min(times["axis"])
    n_old, n_new = window_count(frame.shape, WindowScheme(anchor="origin")), window_count(frame.shape)
    print(f"side by side, {W}x{H} frame, blur + noise + Wiener (best of 2 each):")
    print(f"  origin grid (first version): {t_old:6.1f} s = {1e3 * t_old / n_old:5.2f} ms/window ({n_old} windows)")
    print(f"  axis grid (default):         {t_new:6.1f} s = {1e3 * t_new / n_new:5.2f} ms/window ({n_new} windows)")
    print(f"  ratio {t_old / t_new:.2f}x; restored frames agree to "
          f"{psnr_srgb(out['origin'], out['axis']):.1f} dB PSNR (sRGB)")


def core_irfft2_before(spectrum: torch.Tensor, window: int, core: int) -> torch.Tensor:
    """The pruned inverse as it was before issue 11's second round (the row transform on the strided slice)."""
    lo = window // 2 - core // 2
    rows = torch.fft.ifft(spectrum, dim=-2)[..., lo:lo + core, :]
    return torch.fft.irfft(rows, n=window, dim=-1)[..., lo:lo + core]


def blur_side_by_side(ideal: torch.Tensor, size) -> None:
    """The blur of a ``size = (W, H)`` frame, interleaved twice in this process: the machinery before issue 11's
    second round (pruned inverse on a strided slice, product not in place, every window 512 px), today's with
    every window 512 px (``fit=False``: the same numbers), and today's default (windows fitted to the PSF)."""
    import pipeline.blur as blur_module
    from pipeline.blur import apply_windowed

    W, H = size
    H0, W0 = ideal.shape[-2:]
    frame = ideal[..., (H0 - H) // 2:(H0 - H) // 2 + H, (W0 - W) // 2:(W0 - W) // 2 + W].float().contiguous()
    current = blur_module.core_irfft2
    full = WindowScheme(fit=False)

    def before():
        blur_module.core_irfft2 = core_irfft2_before
        try:
            out = apply_windowed(frame, PSF, lambda p, otf, core: torch.fft.rfft2(p) * otf, pedestal=True)
            return out + box_mean(frame, full.window) * PSF.pedestal_fractions(full.window)[0]
        finally:
            blur_module.core_irfft2 = current

    times, out = {}, {}
    for name, fn in (("before", before), ("full", lambda: blur_windowed(frame, PSF, scheme=full)),
                     ("fitted", lambda: blur_windowed(frame, PSF))) * 2:
        t0 = time.perf_counter()
        out[name] = fn()
        times.setdefault(name, []).append(time.perf_counter() - t0)
    t = {k: min(v) for k, v in times.items()}
    print(f"side by side, {W}x{H} frame (optical axis at its centre), blur (best of 2 each, interleaved):")
    print(f"  before the second round: {t['before']:6.1f} s;  now, 512 px windows: {t['full']:6.1f} s "
          f"({t['before'] / t['full']:.2f}x; identical: {torch.equal(out['before'], out['full'])})")
    print(f"  now, windows fitted to the PSF (default): {t['fitted']:6.1f} s ({t['full'] / t['fitted']:.2f}x against "
          f"512 px; the two agree to {_snr_db(out['full'], out['fitted']):.1f} dB)")
    t0 = time.perf_counter()
    box_mean(frame, PAPER_SCHEME.window)
    print(f"  of which the PSF pedestal's {PAPER_SCHEME.window} px box mean (issue 19): "
          f"{time.perf_counter() - t0:.2f} s")


def _snr_db(ref: torch.Tensor, x: torch.Tensor) -> float:
    """``10 log10(sum ref^2 / sum (ref - x)^2)`` (dB)."""
    return 10 * math.log10(float((ref.double() ** 2).sum() / ((ref.double() - x.double()) ** 2).sum()))


def full_blur_side_by_side(photo, device: torch.device) -> None:
    """The whole frame's blur, every window 512 px against windows fitted to the PSF, one after the other."""
    ideal, _ = load_photo(photo, PAPER_CAMERA)
    ideal = ideal.to(device)
    times, out = {}, {}
    for name, scheme in (("full", WindowScheme(fit=False)), ("fitted", PAPER_SCHEME)):
        t0 = time.perf_counter()
        out[name] = blur_windowed(ideal, PSF, scheme=scheme)
        times[name] = time.perf_counter() - t0
    print(f"side by side, the whole {ideal.shape[-1]}x{ideal.shape[-2]} frame's blur: 512 px windows "
          f"{times['full']:.1f} s, fitted {times['fitted']:.1f} s ({times['full'] / times['fitted']:.2f}x); "
          f"they agree to {_snr_db(out['full'], out['fitted']):.1f} dB")


def full_frame(photo, device: torch.device) -> None:
    rows: list = []
    print(f"full frame, paper scheme 512/32/64, {DESIGN.label()}, ISO 100, device {device}:")
    with PeakRSS() as total:
        t_start = time.perf_counter()
        ideal, source = stage("read + linearise", rows, lambda: load_photo(photo, PAPER_CAMERA))
        ideal = ideal.to(device)
        H, W = ideal.shape[-2:]
        n = window_count(ideal.shape)
        blurred = stage(f"blur ({n} windows)", rows, lambda: blur_windowed(ideal, PSF))
        e = FULL_WELL / float(blurred.amax())
        noisy = stage("Poisson noise", rows, lambda b=blurred: add_poisson_noise(b.clamp_min(0), FULL_WELL, seed=0))
        del blurred
        restored = stage(f"adaptive Wiener ({n} windows)", rows,
                         lambda: wiener_windowed(noisy, PSF, noise=NoiseModel(e)))
        p = stage("sRGB PSNR (whole frame)", rows, lambda: (psnr_srgb(ideal.cpu(), noisy.cpu()),
                                                            psnr_srgb(ideal.cpu(), restored.cpu())))
        t_total = time.perf_counter() - t_start
    core = sum(dt for name, dt, _ in rows if name.startswith(("blur", "Poisson", "adaptive")))
    print(f"  input: {source} ({W}x{H}); torch threads {torch.get_num_threads()}")
    print(f"  blur + noise + restore: {core:.1f} s = {core / 60:.2f} min; whole run {t_total:.1f} s; "
          f"peak RSS {total.peak:.2f} GiB")
    print(f"  PSNR (sRGB, whole frame): sensor {p[0]:.2f} dB -> restored {p[1]:.2f} dB")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--region", type=int, default=256)
    ap.add_argument("--angle", type=float, default=8.0)
    ap.add_argument("--frame", type=int, nargs=2, default=[1536, 1024], metavar=("W", "H"),
                    help="size of the frame for the grid side by side (0 0: skip)")
    ap.add_argument("--no-crop", action="store_true", help="skip the crop side by side against scipy")
    ap.add_argument("--no-full", action="store_true", help="skip the full-frame run")
    ap.add_argument("--device", default="auto", help="auto, cpu or cuda (full-frame run)")
    ap.add_argument("--full-blur-side-by-side", action="store_true",
                    help="also time the whole frame's blur with 512 px windows against fitted ones (~1.5 min here)")
    args = ap.parse_args()
    shared = Path(__file__).resolve().parents[1].parent / "shared" / "photos" / "outdoor_misty_forest_6016x4016.jpg"
    photo = args.photo or (str(shared) if shared.exists() else None)
    device = select_device(args.device)
    ideal, _ = load_photo(photo, PAPER_CAMERA)
    if not args.no_crop:
        side_by_side(ideal, args.region, args.angle)
    if min(args.frame) > 0:
        grid_side_by_side(ideal, args.frame)
        blur_side_by_side(ideal, args.frame)
    del ideal
    if args.full_blur_side_by_side:
        full_blur_side_by_side(photo, device)
    if not args.no_full:
        full_frame(photo, device)
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())  # no nanobind "leaked" noise at exit
