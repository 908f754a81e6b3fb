"""Issue 33, item 4: our spatially-variant blur side by side with deepinv's product-convolution and tiled blurs.

    python benchmarks/bench_deepinv.py [PHOTO] [--crop N] [--k 8 16 32] [--pc-spacing 250] [--tile-stride 257 129]
        [--repeat N]

Needs the ``bench`` extra (``pip install -c constraints.txt -e .[bench]``): deepinv is imported here only, never by
the library. The misty forest (default, ../shared/photos) or PHOTO, its green channel alone (mono, linear, peak 1),
the whole 24 MP frame or with ``--crop N`` its central N x N (each PSF still that of its true field position), the
paper's E2E design. Side by side in one process, each with its wall time (also in units of a fixed FFT workload timed
first: 200 float32 ``rfft2``/``irfft2`` pairs of 4 x 3 x 512 x 512, so machines compare; nothing is asserted):

* **ours, zoned**: :func:`pipeline.blur.blur_windowed` with the stride zones :func:`pipeline.blur.choose_stride_zones`
  picks (what ``blur_zones="auto"`` runs), the choice's time included;
* **ours, paper stride**: the same blur without zones (512 px windows fitted to the PSF, stride 32, core 64);
* **deepinv product convolution** (``deepinv.physics.SpaceVaryingBlur``, FFT convolutions, reflect padding) with K
  global eigen-PSFs, for each K of ``--k``: PSFs of 512 x 512 px sampled on deepinv's grid
  (``ProductConvolutionBlurGenerator`` with ``spacing``: ``H // spacing`` x ``W // spacing`` points from edge to edge
  of the frame), their SVD and the thin-plate-spline multipliers exactly as ``ProductConvolutionBlurGenerator.step``
  computes them, the spline evaluated in bands of pixels (in one piece it needs 37 GB at 24 MP). Multipliers after the
  convolutions (``mask_first=False``: each output pixel is blurred with the interpolated PSF of its own position, as
  the exact reference is; ``--pc-mask-first`` for deepinv's default, the PSF of the source pixel). The setup (PSFs,
  SVD, multipliers for the largest K, of which a smaller K takes the first components) is timed once apart;
* **deepinv tiled blur** (``deepinv.physics.TiledSpaceVaryingBlur``, FFT, linear blending), for each stride S of
  ``--tile-stride``: tiles of 2 S px (so the blending tents form the same partition of unity as our windows' at
  stride S), each with the 512 px PSF at its centre. It only offers ``'valid'`` padding: the frame is reflect-padded
  first. In one call it holds every tile's FFT and a (rows x H x cols x W) blending tensor at once (at 24 MP: 53 GB
  at stride 257, 214 GB at 129), so it is called on blocks of about 1040 px of output, each with its 511 px of
  context, on the frame's tile grid: a block's tiles are the frame's (deepinv draws a block's tents on a grid
  stretched by L / (L - 1) for L px: a fraction of a pixel). The blocks' context makes 1.4x (stride 257) to 1.6x
  (129) the tiles that one call over the frame would hold.

Agreement is 10 log10(1 / MSE) (dB, signal peak 1) against :func:`pipeline.blur.blur_exact` (each pixel with the PSF
of its own position, 512 px support) at 200 random pixels (seed 0) at least 256 px from the edges, and against ours at
the paper's stride over all pixels at least 256 px from the edges. The peak resident memory so far is given per line.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import time
from functools import partial
from pathlib import Path

import torch
import torch.nn.functional as F

from lenssim import LensPSF, frame_center
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import load_photo
from workload import agreement_db, reference_seconds
from pipeline.blur import blur_exact, blur_windowed, choose_stride_zones, window_count

PSF_N = 512
"""Support (px) of every PSF: the exact reference's, the eigen-PSFs' and the tiles'."""
MARGIN = PSF_N // 2
"""Pixels this far (px) from the edges are compared: boundary conventions stay out of the agreement."""
SAMPLES = 200
TILE_BLOCK_PX = 1040
"""Output size (px, about) of the blocks the tiled blur is called on (at stride 129 a call then holds 11 x 11 tiles and
takes about 3.5 GB)."""
TPS_CHUNK = 2**18
"""Pixels per band when evaluating the thin-plate-spline multipliers."""
PSF_BATCH = 16


def best_of(repeat: int, fn):
    """The result of the fastest of ``repeat`` runs of ``fn()`` and its wall time (s) (the machine may be shared)."""
    best, kept = math.inf, None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = fn()
        seconds = time.perf_counter() - t0
        if seconds < best:
            best, kept = seconds, out
        del out
    return kept, best


def _fmt(db: float) -> str:
    return "-" if math.isnan(db) else f"{db:.1f}"


def _peak_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # ru_maxrss: KiB on Linux


def import_deepinv():
    """Import deepinv (it imports torchvision first).

    PyPI's torchvision wheels for Linux are built against the CUDA build of torch: with the CPU build their C extension
    does not load, and torchvision then fails on its own import (its fake-tensor registration of ``torchvision::nms``
    and ``::qnms`` is not guarded as the others are). Where the extension does not load, the two operators' schemas
    are declared (no kernels; none of torchvision's operators is used here) so that the import goes through.
    """
    import importlib.util

    spec = importlib.util.find_spec("torchvision")
    if spec is None:
        raise SystemExit("deepinv is not installed: pip install -c constraints.txt -e .[bench]")
    try:
        torch.ops.load_library(os.path.join(os.path.dirname(spec.origin), "_C.so"))
    except OSError:
        lib = torch.library.Library("torchvision", "DEF")
        for op in ("nms", "qnms"):
            lib.define(f"{op}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
        import_deepinv.torchvision_stub = lib  # kept alive: the definitions go with the Library object
    import deepinv

    return deepinv


def _psfs(psf, rows, cols, center) -> torch.Tensor:
    """The provider's PSFs ``(P, 512, 512)`` float32 (centre at [256, 256]) at pixel positions, in batches."""
    rows, cols = torch.as_tensor(rows, dtype=torch.float64), torch.as_tensor(cols, dtype=torch.float64)
    return torch.cat([psf.psf_at_pixels(rows[k:k + PSF_BATCH], cols[k:k + PSF_BATCH], center, PSF_N,
                                        dtype=torch.float32).float() for k in range(0, rows.numel(), PSF_BATCH)])


def product_convolution_setup(deepinv, psf, shape, center, spacing: int, k_max: int):
    """deepinv's product-convolution parameters for ``k_max`` eigen-PSFs, as
    ``deepinv.physics.generator.ProductConvolutionBlurGenerator(..., spacing=(spacing, spacing)).step`` computes them
    from PSFs on its grid: ``filters`` ``(1, 1, k, 512, 512)``, ``multipliers`` ``(1, 1, k, H, W)``, the grid
    ``(rows, cols, row step, col step)`` and the seconds spent on the PSFs, the SVD and the multipliers."""
    from deepinv.physics.generator import ProductConvolutionBlurGenerator, PSFGenerator

    H, W = shape[-2:]
    gen = ProductConvolutionBlurGenerator(PSFGenerator(psf_size=(PSF_N, PSF_N)), img_size=(H, W), n_eigen_psf=k_max,
                                          spacing=(spacing, spacing))
    # its grid: gen.X, the control points in [0, 1]^2 (rows of H // spacing, row-major); gen.XX every pixel
    rows = gen.X[:, 0].double() * (H - 1)
    cols = gen.X[:, 1].double() * (W - 1)
    t0 = time.perf_counter()
    grid = psf(rows, cols)  # (n, 512, 512)
    t1 = time.perf_counter()
    psf_grid = grid.flatten(-2, -1)[None, None]  # 1 x 1 x n x (512 * 512), as in step()
    _, _, V = torch.linalg.svd(psf_grid, full_matrices=False)
    k = min(k_max, V.size(-2))
    V = V[..., :k, :]
    coeffs = torch.matmul(psf_grid, V.transpose(-1, -2))  # 1 x 1 x n x k
    filters = V.reshape(1, 1, k, PSF_N, PSF_N)
    t2 = time.perf_counter()
    gen.tps.fit(gen.X, coeffs)
    multipliers = torch.empty(1, 1, k, H * W)
    for a in range(0, H * W, TPS_CHUNK):
        multipliers[..., a:a + TPS_CHUNK] = gen.tps.transform(gen.XX[a:a + TPS_CHUNK]).transpose(-1, -2)
    t3 = time.perf_counter()
    n_r, n_c = H // spacing, W // spacing
    grid_info = (n_r, n_c, (H - 1) / max(n_r - 1, 1), (W - 1) / max(n_c - 1, 1))
    return filters, multipliers.reshape(1, 1, k, H, W), grid_info, (t1 - t0, t2 - t1, t3 - t2)


def tiled_blur(deepinv, image: torch.Tensor, psf, stride: int) -> tuple[torch.Tensor, float, int]:
    """deepinv's ``TiledSpaceVaryingBlur`` (tiles of ``2 stride`` px, linear blending, FFT) over ``image``
    ``(1, 1, H, W)``, called on blocks of the reflect-padded frame; ``psf(rows, cols)`` gives a tile's PSF at its
    centre. Returns the blurred frame, the seconds spent computing PSFs, and the number of tile convolutions."""
    from deepinv.physics import TiledSpaceVaryingBlur

    P, S = 2 * stride, stride
    H, W = image.shape[-2:]
    # 'valid' only: an output pixel i is the PSF centred on input pixel i + 255 ((h - 1) // 2 with deepinv's
    # convention for an even support), so 255 px before the frame and 256 after
    lo, hi = (PSF_N - 1) // 2, PSF_N // 2
    x = F.pad(image, (lo, hi, lo, hi), mode="reflect")
    Hx, Wx = x.shape[-2:]
    block = S * max(1, round(TILE_BLOCK_PX / S))
    ops, cache = {}, {}
    out = torch.empty_like(image)
    t_psf, n_conv = 0.0, 0
    for a in range(0, H, block):
        for b in range(0, W, block):
            xb = x[..., a:min(a + block + PSF_N - 1, Hx), b:min(b + block + PSF_N - 1, Wx)]
            nh, nw = TiledSpaceVaryingBlur.num_filters(tuple(xb.shape[-2:]), (P, P), (S, S))
            keys = [(a // S + i, b // S + j) for i in range(nh) for j in range(nw)]
            missing = [key for key in keys if key not in cache]
            if missing:
                t0 = time.perf_counter()
                # a tile covers input rows gi S .. gi S + P - 1, frame rows from gi S - 255: its centre
                centres = torch.tensor(missing, dtype=torch.float64) * S - lo + (P - 1) / 2
                cache.update(zip(missing, psf(centres[:, 0], centres[:, 1])))
                t_psf += time.perf_counter() - t0
            filters = torch.stack([cache[key] for key in keys])[None, None]  # 1 x 1 x K x 512 x 512
            op = ops.setdefault(tuple(xb.shape[-2:]), TiledSpaceVaryingBlur(patch_size=P, stride=S,
                                                                            blending_mode="linear", use_fft=True))
            yb = op.A(xb, filters=filters)
            out[..., a:a + yb.shape[-2], b:b + yb.shape[-1]] = yb
            n_conv += len(keys)
            del filters, yb
        for key in [key for key in cache if key[0] < (a + block) // S]:  # the next block row starts there
            del cache[key]
    return out, t_psf, n_conv


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--crop", type=int, help="the central N x N px of the frame")
    ap.add_argument("--k", type=int, nargs="+", default=[8, 16, 32], help="eigen-PSFs of the product convolution")
    ap.add_argument("--pc-spacing", type=int, default=250, help="the product convolution's PSF grid step (px)")
    ap.add_argument("--pc-mask-first", action="store_true", help="multipliers before the convolutions (deepinv's "
                    "default: the PSF of the source pixel)")
    ap.add_argument("--tile-stride", type=int, nargs="*", default=[257, 129],
                    help="strides of the tiled blur (px; tiles twice that: 129 and 257 give FFTs of 1280 and 1536 px)")
    ap.add_argument("--repeat", type=int, default=1, help="time each blur this many times, keep the least (the "
                    "product convolution's setup and the exact reference: once)")
    a = ap.parse_args()
    shared = Path(__file__).resolve().parents[1].parent / "shared" / "photos" / "outdoor_misty_forest_6016x4016.jpg"
    photo = a.photo or (str(shared) if shared.exists() else None)
    deepinv = import_deepinv()

    ref = reference_seconds()
    ideal, source = load_photo(photo, PAPER_CAMERA)
    full_shape = ideal.shape
    cy, cx = frame_center(full_shape)
    if a.crop:
        r0, c0 = (full_shape[-2] - a.crop) // 2, (full_shape[-1] - a.crop) // 2
        ideal = ideal[..., r0:r0 + a.crop, c0:c0 + a.crop]
        cy, cx = cy - r0, cx - c0
    ideal = ideal[:, 1:2].contiguous()
    center = (cy, cx)
    H, W = ideal.shape[-2:]
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    print(f"{source}: green channel, {W} x {H}{' (central crop)' if a.crop else ''}, optical axis at row {cy:.1f}, "
          f"col {cx:.1f}; deepinv {deepinv.__version__}, torch {torch.__version__}, {torch.get_num_threads()} threads; "
          f"reference workload {ref:.2f} s")

    g = torch.Generator().manual_seed(0)
    rows = torch.randint(MARGIN, H - MARGIN, (SAMPLES,), generator=g)
    cols = torch.randint(MARGIN, W - MARGIN, (SAMPLES,), generator=g)
    inner = (slice(None), slice(None), slice(MARGIN, H - MARGIN), slice(MARGIN, W - MARGIN))
    t0 = time.perf_counter()
    exact = blur_exact(ideal, psf, rows, cols, n=PSF_N, optical_center=center)
    t_exact = time.perf_counter() - t0

    def psfs_at(r, c):
        return _psfs(psf, r, c, center)

    # warm-up, untimed: the PSF model's cached pupil bases (float32, 512 px) and the FFT plans of a few windows
    psfs_at([cy], [cx])
    blur_windowed(ideal, psf, optical_center=center, region=(H // 2, H // 2 + 64, W // 2, W // 2 + 64))

    table = []

    def row(label, setup, apply, out=None, ours=None):
        total = setup + apply
        vs_exact = agreement_db(out[0, 0, rows, cols], exact[0, 0]) if out is not None else math.nan
        vs_ours = agreement_db(out[inner], ours[inner]) if (out is not None and ours is not None) else math.nan
        table.append((label, setup, apply, total, vs_exact, vs_ours, _peak_gib()))
        print(f"  {label:58s} setup {setup:6.1f} s, blur {apply:6.1f} s, total {total:6.1f} s = {total / ref:5.1f} x "
              f"ref; {_fmt(vs_exact)} dB vs exact, {_fmt(vs_ours)} dB vs ours; peak {_peak_gib():.2f} GiB", flush=True)

    row(f"exact reference, {SAMPLES} pixels", 0.0, t_exact)

    zones, t_zones = best_of(a.repeat, lambda: choose_stride_zones(psf, ideal.shape, optical_center=center))
    zoned, t_zoned = best_of(a.repeat, lambda: blur_windowed(ideal, psf, optical_center=center, zones=zones))
    ours, t_ours = best_of(a.repeat, lambda: blur_windowed(ideal, psf, optical_center=center))
    row(f"ours, zoned ({window_count(ideal.shape, optical_center=center, zones=zones)} windows)", t_zones, t_zoned,
        zoned, ours)
    row(f"ours, paper stride ({window_count(ideal.shape, optical_center=center)} windows)", 0.0, t_ours, ours)
    del zoned

    from deepinv.physics import SpaceVaryingBlur

    ks = sorted(set(a.k))
    t0 = time.perf_counter()
    filters, multipliers, (n_r, n_c, dy, dx), (t_psfs, t_svd, t_tps) = product_convolution_setup(
        deepinv, psfs_at, ideal.shape, center, a.pc_spacing, max(ks))
    t_pc = time.perf_counter() - t0
    print(f"  product convolution setup: {n_r} x {n_c} PSFs of {PSF_N} px, {dy:.1f} x {dx:.1f} px apart (spacing "
          f"{a.pc_spacing}) {t_psfs:.1f} s, their SVD {t_svd:.1f} s, thin-plate-spline multipliers for K = "
          f"{filters.shape[2]} {t_tps:.1f} s: {t_pc:.1f} s; peak {_peak_gib():.2f} GiB", flush=True)
    for k in ks:
        if k > filters.shape[2]:
            print(f"  K = {k}: more than the {filters.shape[2]} grid PSFs, skipped")
            continue
        op = SpaceVaryingBlur(filters=filters[:, :, :k], multipliers=multipliers[:, :, :k], padding="reflect",
                              use_fft=True, mask_first=a.pc_mask_first)
        out, t_apply = best_of(a.repeat, partial(op.A, ideal))
        row(f"deepinv product convolution, K = {k}", t_pc, t_apply, out, ours)
        del op, out
    del filters, multipliers

    for s in a.tile_stride:
        (out, t_psf, n_conv), t_all = best_of(a.repeat, lambda: tiled_blur(deepinv, ideal, psfs_at, s))
        row(f"deepinv tiled, stride {s}, tiles {2 * s} ({n_conv} tile convolutions)", t_psf, t_all - t_psf, out, ours)
        del out

    print(f"\n{source}, green channel, {W} x {H}; reference workload {ref:.2f} s; setup = zone choice (ours), PSFs + "
          "SVD + multipliers (product convolution, shared by every K), the tiles' PSFs (tiled)\n")
    print("| method | setup (s) | blur (s) | total (s) | total / ref | vs exact (dB) | vs ours (dB) | peak RSS (GiB) |")
    print("|---|---|---|---|---|---|---|---|")
    for label, setup, apply, total, ve, vo, peak in table:
        print(f"| {label} | {setup:.1f} | {apply:.1f} | {total:.1f} | {total / ref:.1f} | {_fmt(ve)} | {_fmt(vo)} | "
              f"{peak:.2f} |")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown(0)
