"""Issue 46, item 3: the restoration's speed levers judged against an exact reference, not against the paper's stride.

    python benchmarks/bench_restoration_reference.py [PHOTO ...] [--design end_to_end_paper] [--crop 512]
        [--angles 0 6 12] [--isos 400 100] [--levers zoned stride64 fit256 bank3 bank4 bank3l bank3x4]
        [--reference-stride 8] [--threads 2]
        [--colour]

The paper's restoration (the adaptive Wiener in windows at a stride of 32 px, 64 px cores) is itself an approximation
of the filter it stands for: each pixel restored with its own PSF's Wiener filter. The reference here is that filter
with the windows at ``--reference-stride`` px (8: cores of 16 px, 16x the paper's windows; a stride-16 run beside it
shows how far the reference itself still is from its limit: on the forest's axis crop, stride 16 was 82.9 dB from
stride 8, the paper's stride 73.2 dB, so 16 is reference enough where time is short). Each crop is blurred once at the paper's stride (the same
sensor image for every restoration: ``pipeline.simulate_crops`` with every restoration below as a method, so all see
the same noise), then restored by:

* ``reference``: the Wiener at the reference stride (core twice the stride, the paper's ratio) in the scheme's whole
  window (512 px) everywhere, not windows fitted to the PSF;
* ``stride16``: the same at 16 px (how converged the reference is);
* ``paper``: the paper's stride (32 px, cores of 64 px): what the project runs;
* the levers of ``--levers``: ``zoned`` (the blur's stride rings, :func:`pipeline.blur.choose_stride_zones` for the
  whole frame, applied to the restoration: twice the stride where the PSF varies slowly), ``stride64`` (64 px, cores of
  128 px everywhere), ``fit256`` (windows fitted to the PSF down to 256 px instead of
  :data:`pipeline.restoration.wiener.WIENER_FIT_LEAST_PX`), ``bankN`` (the bank evaluation, ``wiener:bank=N``: windows
  at twice the stride, statistics at half of it, N filters per window at Chebyshev-Gauss nodes in ``log K``),
  ``bankNl`` (the same at Chebyshev-Lobatto nodes, the span's ends included: the bank's first form), ``bankNxM`` (its
  windows at M times the stride, :data:`pipeline.restoration.wiener.WIENER_BANK_MULTIPLE` replaced).

Printed per crop and ISO: each restoration's PSNR and SSIM against the ideal image (sRGB), and its distance from the
reference: the PSNR difference (dB) and the PSNR of it against the reference restored image (dB: higher is closer).
The rule of the issue: a lever is kept where it is as close to the reference as the paper's stride is. Mono (the
photo's green channel) unless ``--colour``. Nothing is asserted; no time is reported (the reference is slow by design).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import torch

import pipeline.restoration.wiener as wiener_module
from lenssim import LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import crop_at_field_angle, simulate_crops
from pipeline.blur import PAPER_SCHEME, choose_stride_zones
from pipeline.photo import open_photo
from pipeline.quality import psnr_srgb
from pipeline.restoration import RESTORATION_METHODS, RestorationMethod, register

DEFAULT_PHOTOS = ("outdoor_misty_forest_6016x4016.jpg", "outdoor_pier_sunset_5470x3646.jpg")
"""The two test photos of docs/performance.md (in the shared photo folder beside the project)."""


def chebyshev_lobatto(n: int) -> tuple[float, ...]:
    """``n >= 2`` Chebyshev-Lobatto nodes on ``[0, 1]``, both ends included (the bank's first form)."""
    return tuple(0.5 - 0.5 * math.cos(math.pi * j / (n - 1)) for j in range(n))


def _variant(name: str, *, stride: int | None = None, zones=None, least_fit: int | None = None,
             fit: bool | None = None, bank: int = 0, multiple: int | None = None, nodes=None) -> str:
    """Register (once, for this run) a Wiener restoration at another stride, with zones, another least fit,
    (``fit=False``) the scheme's whole window everywhere, or the bank evaluation of ``bank`` filters."""
    key = f"bench_{name}"
    if key in RESTORATION_METHODS:
        return key

    def fn(observed, psf, *, noise, scheme, optical_center=None, region=None, progress=None):
        s = replace(scheme, stride=stride, core=2 * stride) if stride else scheme
        old = wiener_module.WIENER_FIT_LEAST_PX, wiener_module.WIENER_BANK_MULTIPLE, wiener_module.chebyshev_gauss
        if nodes is not None:
            wiener_module.chebyshev_gauss = nodes
        if least_fit is not None:
            wiener_module.WIENER_FIT_LEAST_PX = least_fit
        if multiple is not None:
            wiener_module.WIENER_BANK_MULTIPLE = multiple
        try:
            return wiener_module.wiener_windowed(observed, psf, noise=noise, scheme=s, optical_center=optical_center,
                                                 region=region, progress=progress, zones=zones, fit=fit, bank=bank)
        finally:
            wiener_module.WIENER_FIT_LEAST_PX, wiener_module.WIENER_BANK_MULTIPLE, wiener_module.chebyshev_gauss = old

    def margin(scheme):
        s = replace(scheme, stride=stride, core=2 * stride) if stride else scheme
        core = s.core * (max(zones.multiples) if zones is not None
                         else (multiple or wiener_module.WIENER_BANK_MULTIPLE) if bank else 1)
        return max(s.window // 2 + core, scheme.window // 2 + scheme.core)

    register(RestorationMethod(key, name, f"benchmark-only Wiener variant {name}", fn, (), margin=margin))
    return key


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photos", nargs="*")
    ap.add_argument("--design", default="end_to_end_paper")
    ap.add_argument("--crop", type=int, default=512)
    ap.add_argument("--angles", nargs="+", type=float, default=[0.0, 6.0, 12.0])
    ap.add_argument("--isos", nargs="+", type=int, default=[400, 100])
    ap.add_argument("--levers", nargs="*", default=["zoned", "stride64", "fit256", "bank3", "bank4"],
                    help="zoned, stride64, fit256 or bankN[l][xM] (the bank evaluation, N filters per window; l: at "
                         "Lobatto nodes; xM: windows at M times the stride)")
    ap.add_argument("--reference-stride", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--colour", action="store_true")
    args = ap.parse_args()
    if args.reference_stride < 1 or PAPER_SCHEME.stride % args.reference_stride:
        ap.error(f"--reference-stride {args.reference_stride}: a divisor of the paper's {PAPER_SCHEME.stride} px")
    torch.set_num_threads(args.threads)
    here = Path(__file__).resolve().parents[2] / "shared" / "photos"
    photos = args.photos or [str(here / p) for p in DEFAULT_PHOTOS]
    sensor = PAPER_CAMERA.sensor
    wells = [sensor.full_well_for_iso(i) for i in args.isos]
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS[args.design])
    summary: dict[str, list[tuple[float, float, float]]] = {}
    print(f"{'photo':<22} {'deg':>5} {'ISO':>4} {'restoration':<12} {'PSNR':>7} {'SSIM':>7} {'dPSNR_ref':>9} "
          f"{'vs_ref_dB':>9}", flush=True)
    for path in photos:
        photo = open_photo(path, PAPER_CAMERA)
        H, W = photo.shape[-2:]
        ideal = photo.region(0, H, 0, W)
        if not args.colour:
            ideal = ideal[:, 1:2].contiguous()
        names = {"reference": _variant(f"stride{args.reference_stride}", stride=args.reference_stride, fit=False)}
        if args.reference_stride != 16:
            names["stride16"] = _variant("stride16", stride=16, fit=False)
        names["paper"] = "wiener"
        for lever in args.levers:
            if lever == "zoned":
                z = choose_stride_zones(psf, ideal.shape, PAPER_SCHEME)
                names["zoned"] = (_variant(f"zoned_{Path(path).stem}", zones=z) if not z.uniform else "wiener")
                print(f"# {Path(path).stem}: zones {z.to_dict()}", flush=True)
            elif lever == "stride64":
                names["stride64"] = _variant("stride64", stride=64)
            elif lever.startswith("bank"):  # bankN[l][xM]: N filters (l: at Lobatto nodes), windows at M x the stride
                n, _, m = lever[4:].partition("x")
                names[lever] = _variant(lever, bank=int(n.rstrip("l")), multiple=int(m) if m else None,
                                        nodes=chebyshev_lobatto if n.endswith("l") else None)
            else:
                names["fit256"] = _variant("fit256", least_fit=256)
        methods = list(dict.fromkeys(names.values()))
        for angle in args.angles:
            try:
                box = crop_at_field_angle(ideal.shape, angle, args.crop, PAPER_CAMERA.geometry)
            except ValueError:
                continue
            res = simulate_crops(ideal, psf, wells, [box], methods=methods, sensor=sensor)
            for iso, r in zip(args.isos, res):
                c = r[0]
                ref_img = c.images[names["reference"]]
                ref_psnr = c.scores[names["reference"]]["psnr_db"]
                for label, key in [("sensor", "sensor")] + list(names.items()):
                    s = c.scores[key]
                    d = s["psnr_db"] - ref_psnr
                    agree = psnr_srgb(ref_img, c.images[key]) if label != "reference" else math.inf
                    summary.setdefault(label, []).append((s["psnr_db"], abs(d), agree))
                    print(f"{Path(path).stem[:22]:<22} {c.field_deg:5.1f} {iso:>4} {label:<12} {s['psnr_db']:7.3f} "
                          f"{s['ssim']:7.4f} {d:+9.4f} {agree:9.2f}", flush=True)
    print("\nmeans over the crop-ISOs: PSNR (dB), |PSNR - reference's| (dB; max), PSNR against the reference image "
          "(dB; min)")
    for label, rows in summary.items():
        n = len(rows)
        print(f"  {label:<12} {sum(r[0] for r in rows) / n:8.3f}  |d| mean {sum(r[1] for r in rows) / n:.4f} max "
              f"{max(r[1] for r in rows):.4f}  vs ref min {min(r[2] for r in rows):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
