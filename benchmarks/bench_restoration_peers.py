"""Issue 45, item 5: the project's restoration methods beside train-free peers (scikit-image, deepinv, bm3d) on the
same noisy crops, per crop, in one process.

    python benchmarks/bench_restoration_peers.py PHOTO [PHOTO ...] [--designs end_to_end_paper rms_w_paper]
        [--isos 400 100] [--angles 0 5 10] [--crop 256] [--methods wiener richardson_lucy tikhonov ...]
        [--peers skimage_wiener_tv skimage_rl deepinv_admm_wavelet deepinv_hqs_tv bm3d_wiener ...]
        [--context 160] [--budget-s S] [--quick] [--csv PATH] [--threads 2]

Needs the ``bench`` extra (``pip install -c constraints.txt -e .[bench]``): the peers are imported here only, never
by the library. Each photo's ``--crop`` px crops at the given field angles (where the photo reaches them; the photo's
centre on the optical axis of the paper's camera) go through :func:`pipeline.simulate_crops` with the project's
methods of ``--methods`` (specs ``NAME[:key=value,...]``; the first is the baseline whose time the others' are divided
by), the paper's sensor (photon noise) at each ISO, noise seed ``seed + k`` for crop ``k`` as there. Every ``restore()``
call simulate_crops makes is timed where it is made (wall clock), and the first one of each crop and ISO also hands
over its input: the noisy sensor image around the crop. So every peer restores the same noisy pixels as the project's
methods:

* each peer is given the crop with ``--context`` px of the noisy sensor image around it (less at the frame's edges),
  the PSF at the crop's centre (the provider the project's methods restore with, pixel aperture included: one
  space-invariant PSF, odd size covering its support) and the RMS noise of each channel over that region (from the
  noise description the project's methods get, :meth:`pipeline.camera_chain.NoiseModel.variance` at the observed
  signal; a peer expects one Gaussian level); it returns the region restored, of which the crop is scored;
* each peer's settings are named constants below, tuned once (by hand, a few values each, on one crop: the pier
  sunset photo at 5 deg, the end_to_end_paper design, ISO 400 and 100) as multiples of the noise level, then fixed;
* scores are those simulate_crops gives the project's methods: PSNR (dB) and SSIM against the ideal crop, sRGB
  (:func:`pipeline.quality.psnr_srgb`, :func:`pipeline.quality.ssim_srgb`); the sensor image's beside.

The peers (:data:`PEERS`): scikit-image's Wiener deconvolution followed by its TV denoising (Chambolle), its
Richardson-Lucy; deepinv's ``optim`` (ADMM, HQS or PGD; a wavelet or a TV prior; the L2 data term on
``physics.BlurFFT``, circular, so the data term's proximal step is closed-form); BM3D denoising (``bm3d``) after the
Wiener deconvolution, and ``bm3d_deblurring`` (its RI + RWI deblurring; not run by default: on 2 CPU cores it takes
over 5 minutes per 128 px crop). A peer's time is its own call (the PSF, computed once per crop for all peers, is left out).

One line per crop and ISO (PSNR of each method, times as multiples of the baseline), then a table (markdown) of the
mean PSNR / SSIM per design and ISO, the time per crop and the crops restored below the sensor image, and with
``--csv`` every score in one row each. ``--budget-s``: no new crop is started after this many seconds (the crops not
run are named); ``--quick``: one photo, one angle, one design (the first of each), the sensor's first ISO, 128 px
crops. Nothing is asserted: a benchmark, not a test.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

import pipeline.simulate as simulate
from lenssim import LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import crop_at_field_angle
from pipeline.photo import open_photo
from pipeline.quality import psnr_srgb, ssim_srgb
from pipeline.restoration import parse_restoration

CONTEXT_PX = 160
"""Noisy pixels (px) a peer is given around the crop on every side (fewer where the frame ends)."""
QUICK_CROP_PX = 128
"""Crop size (px) of ``--quick``."""

# --- the peers' settings: tuned by hand on one crop (pier sunset, 5 deg, end_to_end_paper, ISO 400 and 100), fixed --
SK_WIENER_BALANCE_PER_VAR = 2.0e3
"""scikit-image ``wiener``'s ``balance`` (its Laplacian regulariser's weight) per unit of noise variance (the noise's
RMS squared, linear image units): the balance grows with the noise power as a Wiener filter's should. Tried 1e2, 5e2,
1e3, 2e3, 4e3, 1e4 with each TV weight: 2e3 with 0.5 best at both ISOs (32.54 / 33.93 dB), within 0.2 dB of 5e2-4e3."""
SK_TV_WEIGHT_PER_SIGMA = 0.5
"""``denoise_tv_chambolle``'s ``weight`` after the Wiener, in units of the noise's RMS (linear image units); tried
0.3, 0.5, 1, 1.5, 3."""
SK_RL_ITERATIONS = 20
"""scikit-image ``richardson_lucy``'s iterations (its only regulariser is stopping early); tried 5, 10, 20 (31.43 /
33.11 dB), 40 (29.30 / 32.92 dB)."""
DI_WAVELET = ("db8", 3)
"""deepinv ``WaveletPrior``'s wavelet and levels (its defaults)."""
DI_LAMBDA_PER_SIGMA = {"wavelet": 0.3, "tv": 0.3}
"""deepinv's regularisation weight ``lambda`` (the data term ``0.5 |A x - y|^2``) in units of the noise's RMS. Wavelet
(ADMM): tried 0.3 (32.05 / 33.35 dB), 1, 3 (31.29 / 32.06 dB). TV (HQS): 0.3 (28.82 / 29.09 dB), 1 (28.08 / 28.57 dB),
100-200 s per crop on the loaded machine: HQS + TV is not in :data:`DEFAULT_PEERS`."""
DI_STEPSIZE = {"ADMM": 1.0, "HQS": 1.0, "PGD": 1.0}
"""deepinv's ``stepsize`` per algorithm (PGD: below 2 / |A|^2 = 2 for a unit-sum PSF)."""
DI_ITERATIONS = 20
"""deepinv's iterations (``max_iter``; it stops earlier where the iterates settle)."""
DI_TV_INNER = 10
"""Iterations of deepinv's TV proximal step (``TVPrior(n_it_max=...)``, default 1000) per outer iteration."""
BM3D_WIENER_BALANCE_PER_VAR = 5.0e2
"""scikit-image ``wiener``'s balance before BM3D (a weaker regulariser than alone: BM3D removes the noise left); tried
2e2 and 5e2 (with a BM3D level of 4: 33.39 / 34.16 and 33.41 / 34.66 dB)."""
BM3D_SIGMA_FACTOR = 4.0
"""BM3D's ``sigma_psd`` after the Wiener, in units of the sensor noise's RMS (the deconvolution amplified it); tried 2
(32.98 / 33.84 dB) and 4."""
BM3D_MARGIN_PX = 24
"""Pixels around the crop BM3D denoises (its block matching looks this far, about: 39 px search window / 2)."""
BM3D_DEBLUR_SIGMA_FACTOR = 1.0
"""``bm3d_deblurring``'s ``sigma_psd`` in units of the sensor noise's RMS (the true level; not tuned: on the loaded 2-core
machine it did not finish one 128 px grey crop with a 64 px PSF in 340 s, where BM3D denoising of it took 3.4 s)."""


@dataclass(frozen=True)
class Peer:
    """A peer restoration: ``fn(observed (C, H, W) float64 array, psf (C or 1, n, n), sigma (C,), crop box in the
    region) -> restored (C, H, W)`` and where it comes from."""

    name: str
    label: str
    package: str
    fn: object


def _per_channel(fn, obs, psf, sigma):
    return np.stack([fn(obs[c], psf[min(c, len(psf) - 1)], float(sigma[c])) for c in range(obs.shape[0])])


def skimage_wiener_tv(obs, psf, sigma, box):
    from skimage.restoration import denoise_tv_chambolle, wiener

    def one(y, h, s):
        x = wiener(y, h, balance=SK_WIENER_BALANCE_PER_VAR * s * s, clip=False)
        return denoise_tv_chambolle(x, weight=SK_TV_WEIGHT_PER_SIGMA * s)

    return _per_channel(one, obs, psf, sigma)


def skimage_rl(obs, psf, sigma, box):
    from skimage.restoration import richardson_lucy

    return _per_channel(lambda y, h, s: richardson_lucy(y, h, num_iter=SK_RL_ITERATIONS, clip=False), obs, psf, sigma)


def bm3d_module():
    """``bm3d``, importable on numpy 2.4 (its engine calls ``np.trapz``, which numpy 2.4 removed: aliased to
    ``np.trapezoid``)."""
    if not hasattr(np, "trapz"):
        np.trapz = np.trapezoid
    import bm3d

    return bm3d


def bm3d_wiener(obs, psf, sigma, box):
    from skimage.restoration import wiener

    bm3d = bm3d_module()
    x = _per_channel(lambda y, h, s: wiener(y, h, balance=BM3D_WIENER_BALANCE_PER_VAR * s * s, clip=False),
                     obs, psf, sigma)
    r0, r1, c0, c1 = box
    H, W = obs.shape[-2:]
    a, b = max(r0 - BM3D_MARGIN_PX, 0), min(r1 + BM3D_MARGIN_PX, H)
    c, d = max(c0 - BM3D_MARGIN_PX, 0), min(c1 + BM3D_MARGIN_PX, W)
    s = BM3D_SIGMA_FACTOR * float(np.sqrt(np.mean(np.square(sigma))))
    part = x[:, a:b, c:d]
    if part.shape[0] == 3:
        den = np.moveaxis(bm3d.bm3d_rgb(np.moveaxis(part, 0, -1), s), -1, 0)
    else:
        den = np.stack([bm3d.bm3d(p, s) for p in part])
    x[:, a:b, c:d] = den
    return x


def bm3d_deblur(obs, psf, sigma, box):
    bm3d = bm3d_module()
    return _per_channel(lambda y, h, s: bm3d.bm3d_deblurring(y, BM3D_DEBLUR_SIGMA_FACTOR * s, h), obs, psf, sigma)


_DEEPINV = []


def deepinv_module():
    if not _DEEPINV:
        from bench_deepinv import import_deepinv  # the torchvision work-around of the earlier deepinv benchmark

        _DEEPINV.append(import_deepinv())
    return _DEEPINV[0]


def deepinv_peer(iteration: str, prior: str):
    def run(obs, psf, sigma, box):
        dinv = deepinv_module()
        from deepinv.optim import L2, TVPrior, WaveletPrior, optim_builder

        y = torch.from_numpy(obs)[None].float()
        h = torch.from_numpy(psf)[None].float()  # (1, 1 or C, n, n)
        physics = dinv.physics.BlurFFT(img_size=tuple(y.shape[1:]), filter=h)
        s = float(np.sqrt(np.mean(np.square(sigma))))
        pri = (WaveletPrior(wv=DI_WAVELET[0], level=DI_WAVELET[1]) if prior == "wavelet"
               else TVPrior(n_it_max=DI_TV_INNER))
        model = optim_builder(iteration=iteration, prior=pri, data_fidelity=L2(), max_iter=DI_ITERATIONS,
                              early_stop=True, params_algo={"stepsize": DI_STEPSIZE[iteration],
                                                            "lambda": DI_LAMBDA_PER_SIGMA[prior] * s})
        with torch.no_grad():
            return model(y, physics)[0].double().numpy()

    return run


PEERS = {p.name: p for p in (
    Peer("skimage_wiener_tv", "scikit-image Wiener + TV denoising", "scikit-image", skimage_wiener_tv),
    Peer("skimage_rl", f"scikit-image Richardson-Lucy ({SK_RL_ITERATIONS} it.)", "scikit-image", skimage_rl),
    Peer("deepinv_admm_wavelet", "deepinv ADMM + wavelet prior", "deepinv", deepinv_peer("ADMM", "wavelet")),
    Peer("deepinv_pgd_wavelet", "deepinv PGD + wavelet prior", "deepinv", deepinv_peer("PGD", "wavelet")),
    Peer("deepinv_hqs_tv", "deepinv HQS + TV prior", "deepinv", deepinv_peer("HQS", "tv")),
    Peer("deepinv_admm_tv", "deepinv ADMM + TV prior", "deepinv", deepinv_peer("ADMM", "tv")),
    Peer("bm3d_wiener", "scikit-image Wiener + BM3D denoising", "bm3d", bm3d_wiener),
    Peer("bm3d_deblurring", "bm3d_deblurring (RI + RWI)", "bm3d", bm3d_deblur),
)}
"""Every peer, by name (``--peers``)."""
DEFAULT_PEERS = ("skimage_wiener_tv", "skimage_rl", "deepinv_admm_wavelet", "bm3d_wiener")
"""The peers run unless ``--peers`` says otherwise (not ``bm3d_deblurring``: over 5 minutes per 128 px crop on 2
cores; not deepinv's TV: 3-4 dB below its wavelet prior on the tuning crop at 2x its time)."""


@dataclass
class Captured:
    """What the first restoration of a crop and ISO was given: the noisy region around the crop, the crop's box in
    it, the PSF at the crop's centre and the noise's RMS per channel."""

    observed: torch.Tensor
    box: tuple[int, int, int, int]
    psf: np.ndarray
    sigma: np.ndarray


def capture(noisy, psf, noise, optical_center, region, context: int) -> Captured:
    r0, r1, c0, c1 = region
    H, W = noisy.shape[-2:]
    R0, R1, C0, C1 = max(r0 - context, 0), min(r1 + context, H), max(c0 - context, 0), min(c1 + context, W)
    obs = noisy[0, :, R0:R1, C0:C1].double()
    at = [torch.tensor([v], dtype=torch.float64) for v in ((r0 + r1 - 1) / 2, (c0 + c1 - 1) / 2)]
    side = min(R1 - R0, C1 - C0)
    # odd (the centre on a pixel in every peer's convention), covering the support, at most the region
    n = min(int(psf.extent_px(*at, optical_center)) | 1, side if side % 2 else side - 1)
    p = psf.psf_at_pixels(*at, optical_center, n, dtype=torch.float64)[0]
    p = (p if p.ndim == 3 else p[None]).double()
    p = p / p.sum(dim=(-2, -1), keepdim=True)
    sigma = torch.stack([noise.variance(obs[c].clamp_min(0)).mean().sqrt() for c in range(obs.shape[0])])
    return Captured(obs.cpu(), (r0 - R0, r1 - R0, c0 - C0, c1 - C0), p.cpu().numpy(), sigma.cpu().numpy())


def _score(ideal, img) -> dict:
    return {"psnr_db": psnr_srgb(ideal, img), "ssim": ssim_srgb(ideal, img)}


SHORT = {"end_to_end_paper": "E2E", "rms_w_paper": "RMS_W"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photos", nargs="+")
    ap.add_argument("--designs", nargs="+", default=["end_to_end_paper", "rms_w_paper"], choices=list(PAPER_DESIGNS))
    ap.add_argument("--isos", nargs="+", type=int, default=[400, 100])
    ap.add_argument("--angles", nargs="+", type=float, default=[0.0, 5.0, 10.0])
    ap.add_argument("--crop", type=int, default=256)
    ap.add_argument("--methods", nargs="+", default=["wiener", "richardson_lucy", "tikhonov"])
    ap.add_argument("--peers", nargs="*", default=list(DEFAULT_PEERS), choices=list(PEERS))
    ap.add_argument("--context", type=int, default=CONTEXT_PX)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget-s", type=float, default=math.inf)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--csv")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    if args.quick:
        args.photos, args.designs, args.angles = args.photos[:1], args.designs[:1], args.angles[:1]
        args.isos, args.crop = args.isos[:1], QUICK_CROP_PX
    if args.context < 0 or args.crop < 16 or not args.budget_s > 0:
        ap.error("--context must be >= 0, --crop >= 16 and --budget-s > 0")
    torch.set_num_threads(args.threads)
    try:
        methods = [parse_restoration(m) for m in args.methods]
    except ValueError as e:
        ap.error(str(e))
    names = [m.name for m in methods]
    if len(set(names)) != len(names):
        ap.error(f"--methods names a method twice ({', '.join(names)}): one spec per method")
    peers = [PEERS[p] for p in dict.fromkeys(args.peers)]
    for pkg in {p.package for p in peers}:  # every peer importable before any work
        if pkg == "deepinv":
            deepinv_module()
        elif pkg == "bm3d":
            bm3d_module()
        else:
            import skimage.restoration  # noqa: F401
    sensor = PAPER_CAMERA.sensor
    wells = [sensor.full_well_for_iso(i) for i in args.isos]
    columns = names + [p.name for p in peers]
    times: list[tuple[str, float]] = []
    captured: list[Captured] = []
    inner = simulate.restore

    def timed(spec, noisy, psf, *a, noise, optical_center, region, **kw):
        if spec.name == names[0]:  # the same noisy image goes to every method of this crop and ISO
            captured.append(capture(noisy, psf, noise, optical_center, region, args.context))
        t0 = time.perf_counter()
        out = inner(spec, noisy, psf, *a, noise=noise, optical_center=optical_center, region=region, **kw)
        times.append((spec.name, time.perf_counter() - t0))
        return out

    simulate.restore = timed
    rows = []  # per crop and ISO: photo, design, deg, iso, sensor score, {column: score}, {column: s}
    short = [c[:12] for c in columns]
    print(f"{'photo':<20} {'design':<6} {'deg':>5} {'ISO':>4} {'sensor':>7} " + " ".join(f"{s:>12}" for s in short)
          + "   time / " + names[0], flush=True)
    t_start, skipped = time.perf_counter(), []
    photos = {path: open_photo(path, PAPER_CAMERA) for path in args.photos}  # read where the crops reach, later
    lenses = {design: LensPSF(PAPER_CAMERA, PAPER_DESIGNS[design]) for design in args.designs}
    # the angles outermost: a budget that runs out drops the outer crops of every photo, both designs of each crop
    for angle in args.angles:
        for path, photo in photos.items():
            try:
                box = crop_at_field_angle(photo.shape, angle, args.crop, PAPER_CAMERA.geometry)
            except ValueError:  # the photo does not reach this angle
                continue
            if time.perf_counter() - t_start > args.budget_s:
                skipped.append(f"{Path(path).stem} at {angle:g} deg")
                continue
            for design, psf in lenses.items():
                times.clear()
                captured.clear()
                res = simulate.simulate_crops(photo, psf, wells, [box], seed=args.seed, methods=methods, sensor=sensor)
                per: dict[str, list[float]] = {}
                for name, t in times:
                    per.setdefault(name, []).append(t)
                for j, (iso, r, cap) in enumerate(zip(args.isos, res, captured)):
                    c = r[0]
                    scores = {n: c.scores[n] for n in names}
                    secs = {n: per[n][j] for n in names}
                    r0, r1, c0, c1 = cap.box
                    for p in peers:
                        t0 = time.perf_counter()
                        out = p.fn(cap.observed.numpy(), cap.psf, cap.sigma, cap.box)
                        secs[p.name] = time.perf_counter() - t0
                        img = torch.from_numpy(np.ascontiguousarray(out[:, r0:r1, c0:c1]))[None].to(c.ideal.dtype)
                        if not torch.isfinite(img).all():  # never a wrong number in the table
                            ap.exit(2, f"bench_restoration_peers: error: the peer {p.name} gave a non-finite image "
                                    f"({Path(path).stem}, {design}, {angle:g} deg, ISO {iso})\n")
                        scores[p.name] = _score(c.ideal, img)
                    rows.append((Path(path).stem, design, c.field_deg, iso, c.scores["sensor"], scores, secs))
                    print(f"{Path(path).stem[:20]:<20} {SHORT.get(design, design)[:6]:<6} {c.field_deg:5.1f} {iso:>4} "
                          f"{c.scores['sensor']['psnr_db']:7.2f} " + " ".join(f"{scores[k]['psnr_db']:12.2f}"
                                                                               for k in columns)
                          + "   " + " ".join(f"{secs[k] / secs[names[0]]:.2f}" for k in columns[1:]), flush=True)
    if skipped:
        print(f"budget of {args.budget_s:g} s reached: not run: {'; '.join(skipped)}")
    if not rows:
        print("no crop was run")
        return 0
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["photo", "design", "field_deg", "iso", "method", "source", "psnr_db", "ssim", "seconds",
                        "sensor_psnr_db", "sensor_ssim"])
            for ph, design, deg, iso, sens, scores, secs in rows:
                for k in columns:
                    w.writerow([ph, design, f"{deg:.2f}", iso, k, "project" if k in names else PEERS[k].package,
                                f"{scores[k]['psnr_db']:.4f}", f"{scores[k]['ssim']:.5f}", f"{secs[k]:.3f}",
                                f"{sens['psnr_db']:.4f}", f"{sens['ssim']:.5f}"])
    groups = [(d, i) for d in args.designs for i in args.isos if any(r[1] == d and r[3] == i for r in rows)]
    n_crops = {g: sum(1 for r in rows if (r[1], r[3]) == g) for g in groups}
    base_t = sum(r[6][names[0]] for r in rows) / len(rows)

    def mean(sel, key):
        return sum(key(r) for r in sel) / len(sel)

    print(f"\nmean PSNR (dB) / SSIM, sRGB, over {', '.join(f'{n_crops[g]}' for g in groups)} crops per column; "
          f"{torch.get_num_threads()} threads\n")
    print("| method | " + " | ".join(f"{SHORT.get(d, d)} ISO {i}" for d, i in groups)
          + f" | s per crop | x {names[0]} | below sensor |")
    print("|---|" + "---|" * (len(groups) + 3))
    for k in columns:
        label = f"`{k}`" if k in names else PEERS[k].label
        cells = []
        for g in groups:
            sel = [r for r in rows if (r[1], r[3]) == g]
            cells.append(f"{mean(sel, lambda r: r[5][k]['psnr_db']):.2f} / {mean(sel, lambda r: r[5][k]['ssim']):.3f}")
        t = mean(rows, lambda r: r[6][k])
        below = sum(r[5][k]["psnr_db"] < r[4]["psnr_db"] for r in rows)
        print(f"| {label} | " + " | ".join(cells) + f" | {t:.1f} | {t / base_t:.2f} | {below} of {len(rows)} |")
    cells = []
    for g in groups:
        sel = [r for r in rows if (r[1], r[3]) == g]
        cells.append(f"{mean(sel, lambda r: r[4]['psnr_db']):.2f} / {mean(sel, lambda r: r[4]['ssim']):.3f}")
    print("| sensor image, no restoration | " + " | ".join(cells) + " | - | - | - |")
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    rc = main()
    exit_without_teardown(rc)
