"""kornia in the image pipeline, each use side by side with the code it would replace (issue 20).

Same inputs, one process, interleaved, best of ``--repeat``:

1. scoring: sRGB encoding + PSNR + SSIM + the PSNR map of a frame, kornia on the device (``scorer="kornia"``)
   against scikit-image + colour-science on the host (``scorer="skimage"``); the numbers they give;
2. the windows: cutting the overlapping windows and blending their tent-weighted cores with
   ``kornia.contrib.extract_tensor_patches`` / ``combine_tensor_patches`` against the pipeline's slicing and
   accumulation (:func:`pipeline.blur.apply_windowed`), on the same blur;
3. the Wiener filter's local statistics: ``wiener`` (per-window mean and variance, the paper's) against
   ``wiener:local=pixel`` (kornia ``box_blur`` maps, a per-pixel adaptive signal variance): time and PSNR on the
   shared photos.

Usage: ``python benchmarks/bench_kornia.py [PHOTO] [--frame W H] [--repeat N] [--only scoring|windows|stats]``.
A use more than 10% slower than today's code is not adopted (docs/architecture.md says which).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from lenssim import LensPSF, select_device
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import load_photo

PSF = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "photos"


def _best(fns: dict, repeat: int) -> tuple[dict, dict]:
    """Each callable ``repeat`` times, interleaved; the best time (s) and the last result of each."""
    times, out = {}, {}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            out[name] = fn()
            times.setdefault(name, []).append(time.perf_counter() - t0)
    return {k: min(v) for k, v in times.items()}, out


def _frame(photo, size, device) -> torch.Tensor:
    ideal, _ = load_photo(photo, PAPER_CAMERA)
    if size is not None:
        W, H = size
        H0, W0 = ideal.shape[-2:]
        ideal = ideal[..., (H0 - H) // 2:(H0 - H) // 2 + H, (W0 - W) // 2:(W0 - W) // 2 + W]
    return ideal.contiguous().to(device)


def scoring(ideal: torch.Tensor, repeat: int) -> None:
    from pipeline.quality import encode_srgb, scores_encoded

    g = torch.Generator(device=ideal.device).manual_seed(0)
    test = (ideal + 0.02 * torch.randn(ideal.shape, generator=g, device=ideal.device)).clamp(0, 1)

    def run(scorer):
        ref, enc = encode_srgb(ideal, scorer=scorer), encode_srgb(test, scorer=scorer)
        return scores_encoded(ref, enc, tile=256, scorer=scorer)

    t, out = _best({"skimage": lambda: run("skimage"), "kornia": lambda: run("kornia")}, repeat)
    H, W = ideal.shape[-2:]
    print(f"scoring a {W} x {H} frame ({ideal.device}): encode both + PSNR + SSIM + 256 px PSNR map")
    print(f"  scikit-image + colour-science (host): {t['skimage']:6.2f} s;  kornia: {t['kornia']:6.2f} s "
          f"({t['skimage'] / t['kornia']:.2f}x)")
    a, b = out["skimage"], out["kornia"]
    dm = float((a["psnr_map_db"] - b["psnr_map_db"]).abs().max())
    print(f"  PSNR {a['psnr_db']:.6f} / {b['psnr_db']:.6f} dB, SSIM {a['ssim']:.7f} / {b['ssim']:.7f}, "
          f"map max diff {dm:.1e} dB")


def windows(frame: torch.Tensor, repeat: int) -> None:
    """Cutting the 512 px windows (stride 32) of a frame and blending 64 px tent-weighted cores, the origin grid:
    the pipeline's slices and slice-adds (:func:`pipeline.blur.apply_windowed`) against kornia's
    ``extract_tensor_patches`` (one row of windows at a time: a band, bounded memory) and ``combine_tensor_patches``
    (it averages overlaps; times the overlap count it is the sum the tents need). The transforms between are left
    out: they are the same in both."""
    from kornia.contrib import combine_tensor_patches, extract_tensor_patches

    from pipeline.blur import _pad, tent_weights, window_centres

    win, stride, core = 512, 32, 64
    half, pad = win // 2, win // 2 + core
    B, C, H, W = frame.shape
    padded = _pad(frame, pad)
    ys, xs = window_centres(H, stride).tolist(), window_centres(W, stride).tolist()
    g = torch.Generator(device=frame.device).manual_seed(0)
    cores = torch.rand(len(ys), len(xs), B, C, core, core, generator=g, device=frame.device)
    tent = tent_weights(core, frame.dtype).to(frame.device)
    tent2 = tent[:, None] * tent[None, :]
    chunk = 3

    def today():
        acc = torch.zeros((), dtype=torch.float64)
        for y in ys:  # the chunks of apply_windowed: a few windows stacked from slices
            for k in range(0, len(xs), chunk):
                p = torch.stack([padded[:, :, y + pad - half:y + pad + half, x + pad - half:x + pad + half]
                                 for x in xs[k:k + chunk]])
                acc += p[..., 0, 0].sum()
        out = torch.zeros(B, C, H + 2 * core, W + 2 * core, device=frame.device)
        for i, y in enumerate(ys):
            for j, x in enumerate(xs):
                out[:, :, y + core - core // 2:y + core + core // 2, x + core - core // 2:x + core + core // 2] += \
                    cores[i, j] * tent2
        return acc, out

    def with_kornia():
        acc = torch.zeros((), dtype=torch.float64)
        x0 = pad - half + xs[0]
        for y in ys:  # one row of windows: extract_tensor_patches on the band, then the same chunks
            band = padded[:, :, y + pad - half:y + pad + half, x0:x0 + (len(xs) - 1) * stride + win]
            p = extract_tensor_patches(band, win, stride)  # (B, N, C, win, win)
            for k in range(0, len(xs), chunk):
                acc += p[:, k:k + chunk, :, 0, 0].sum()
        out = torch.zeros(B, C, H + 2 * core, W + 2 * core, device=frame.device)
        width = (len(xs) - 1) * stride + core
        count = torch.full((width,), 2.0, device=frame.device)
        count[:stride], count[-stride:] = 1, 1  # combine_tensor_patches divides by how many cores overlap
        for i, y in enumerate(ys):
            row = combine_tensor_patches((cores[i] * tent2).permute(1, 0, 2, 3, 4), (core, width), core, stride)
            out[:, :, y + core - core // 2:y + core + core // 2, xs[0] + core - core // 2:xs[0] + core - core // 2 + width] += \
                row * count
        return acc, out

    t, out = _best({"today": today, "kornia": with_kornia}, repeat)
    n = len(ys) * len(xs)
    same = float((out["today"][1] - out["kornia"][1]).abs().max())
    print(f"windows of a {W} x {H} frame ({n} windows of {win} px, cores of {core}; cut + blend only):")
    print(f"  slices and slice-adds: {t['today']:.2f} s;  kornia extract/combine: {t['kornia']:.2f} s "
          f"({t['kornia'] / t['today']:.2f}x the time); cut sums equal: {bool(out['today'][0] == out['kornia'][0])}, "
          f"blends differ by {same:.1e}")


def stats(photos, repeat: int, device) -> None:
    """``wiener`` against ``wiener:local=pixel`` on 512 px crops at 0, 4, 8 deg (or what fits) of each photo, ISO 100
    and 400: time (restoration only, best of ``repeat``) and sRGB PSNR; and the per-window statistics themselves, as
    kornia ``box_blur`` maps over a frame against the per-window means the filter takes today."""
    from kornia.filters import box_blur

    from lenssim_studies.paper import PAPER_SENSOR
    from pipeline.restoration.wiener import WIENER_STATS_PX
    from pipeline.simulate import crop_at_field_angle, fitting_angles, simulate_crops

    geom = PAPER_CAMERA.geometry
    print("Wiener local statistics: per window (the paper) vs per pixel (kornia box_blur maps, a filter bank)")
    rows = []
    for photo in photos:
        ideal, source = load_photo(str(photo), PAPER_CAMERA)
        ideal = ideal.to(device)
        size = min(512, *ideal.shape[-2:])
        boxes = [crop_at_field_angle(ideal.shape, a, size, geom) for a in fitting_angles(ideal.shape, size, geom,
                                                                                         (0.0, 4.0, 8.0))]
        for fwc in (PAPER_SENSOR.full_well_for_iso(100), PAPER_SENSOR.full_well_for_iso(400)):
            t, out = _best({m: (lambda m=m: simulate_crops(ideal, PSF, fwc, boxes, methods=(m,), sensor=PAPER_SENSOR))
                            for m in ("wiener", "wiener:local=pixel")}, repeat)
            for k, box in enumerate(boxes):
                a, b = out["wiener"][k], out["wiener:local=pixel"][k]
                rows.append((Path(source).name, fwc, a.field_deg, a.scores["wiener"]["psnr_db"],
                             b.scores["wiener"]["psnr_db"]))
            print(f"  {Path(source).name[:32]:32s} {fwc:6.0f} e-: blur + noise + restore {t['wiener']:.2f} s (window) "
                  f"vs {t['wiener:local=pixel']:.2f} s (pixel): {t['wiener:local=pixel'] / t['wiener']:.2f}x")
    print("  photo                             full well  field   PSNR window  PSNR pixel  [dB]")
    for name, fwc, f, pa, pb in rows:
        print(f"  {name[:32]:32s} {fwc:8.0f} {f:6.2f}   {pa:10.2f}  {pb:10.2f}  ({pb - pa:+.2f})")
    gain = [pb - pa for *_, pa, pb in rows]
    print(f"  mean change {sum(gain) / len(gain):+.3f} dB (min {min(gain):+.2f}, max {max(gain):+.2f})")
    # the statistics alone: maps over a 1536 x 1024 frame vs the means of the windows' central squares
    frame = _frame(str(photos[0]), (1536, 1024), device)
    s = WIENER_STATS_PX
    ys, xs = torch.arange(256, 1024 - 256, 32), torch.arange(256, 1536 - 256, 32)

    def per_window():
        return torch.stack([torch.stack([frame[..., y - s // 2:y + s // 2, x - s // 2:x + s // 2].mean(dim=(-2, -1))
                                         for x in xs.tolist()], -1) for y in ys.tolist()], -2)

    def maps():
        return box_blur(frame, s, border_type="reflect")[..., ys[:, None], xs[None, :]]

    t, out = _best({"window": per_window, "kornia": maps}, repeat)
    # box_blur centres an even box one px off the window's central square
    print(f"  local means of {len(ys) * len(xs)} windows ({s} px squares, 1536 x 1024): slices {t['window']:.3f} s, "
          f"kornia box_blur map {t['kornia']:.3f} s ({t['kornia'] / t['window']:.1f}x the time)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--frame", type=int, nargs=2, default=None, metavar=("W", "H"),
                    help="centre crop of the photo (default: the whole photo)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--only", choices=("scoring", "windows", "stats"), default=None)
    ap.add_argument("--device", default="auto")
    args = ap.parse_args()
    photo = args.photo or (str(SHARED / "outdoor_misty_forest_6016x4016.jpg")
                           if (SHARED / "outdoor_misty_forest_6016x4016.jpg").exists() else None)
    device = select_device(args.device)
    torch.set_num_threads(torch.get_num_threads())
    print(f"torch threads {torch.get_num_threads()}, device {device}")
    if args.only in (None, "scoring"):
        scoring(_frame(photo, args.frame, device), args.repeat)
    if args.only in (None, "windows"):
        windows(_frame(photo, args.frame or (1536, 1024), device), args.repeat)
    if args.only in (None, "stats"):
        photos = [photo] if args.photo else sorted(SHARED.glob("*.jpg")) or [None]
        stats(photos, args.repeat, device)
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())
