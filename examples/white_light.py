"""The singlet in white light: PSFs and MTFs per colour channel, and colour fringing on a crop.

    python examples/white_light.py [PHOTO] [--glass N-BK7] [--spectrum "Nikon 5100 (NPL)"] [--out white_light]

The paper's end-to-end design (s = -0.775, Q_back = -2.4) made of a real glass, seen through a
camera's RGB channels under D65 (colour-science's data), each channel a spectrum of 16 wavelengths.
It first finds the best focus for MSE_R (the d-line focus is not it), then writes:

* ``psf_mtf.png``: per channel, the PSF at 0 and 8 degrees (log scale) and the radial MTF at 8 degrees;
* ``fringing.png``: a crop of the photo (default: the built-in scene, a Siemens star at 8 degrees),
  ideal | sensor | restored (per-channel adaptive Wiener), with PSNR / SSIM.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from lenssim import Camera, LensPSF, otf, psf_at, spectral_coefficients  # noqa: E402

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from lenssim.focus import best_focus  # noqa: E402
from lenssim.model.numerics import DEFAULT_NUMERICS  # noqa: E402
from lenssim.model.spectrum import channel_spectra  # noqa: E402
from lenssim.validate import ModelValidityWarning  # noqa: E402
from pipeline import crop_at_field_angle, load_photo, simulate_crops  # noqa: E402
from pipeline.figures import mosaic_figure  # noqa: E402
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM, REFERENCE_SNR_DB

COLOURS = ("tab:red", "tab:green", "tab:blue")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?")
    ap.add_argument("--glass", default="N-BK7")
    ap.add_argument("--spectrum", default="Nikon 5100 (NPL)")
    ap.add_argument("--angle", type=float, default=8.0)
    ap.add_argument("--out", default="white_light")
    args = ap.parse_args()
    warnings.simplefilter("ignore", ModelValidityWarning)  # the paper's 1.5625 um pixels undersample blue light
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lens = dataclasses.replace(PAPER_LENS, glass=args.glass)
    cam = Camera(lens, PAPER_CAMERA.sensor, channels=channel_spectra(args.spectrum), spectrum=PAPER_SPECTRUM)
    design = PAPER_DESIGNS["end_to_end_paper"]
    fr = best_focus(Camera(dataclasses.replace(PAPER_LENS, glass=args.glass, field_angles_deg=(0, 4, 8, 12)), PAPER_CAMERA.sensor,
                           channels=cam.channels, spectrum=PAPER_SPECTRUM), design, "mse_r", REFERENCE_SNR_DB, rho0=PAPER_RHO0)
    design = design.replace(focus_shift_um=round(fr.focus_shift_um, 1))
    print(f"{args.glass}, {args.spectrum}: best focus for MSE_R {fr.focus_shift_um:+.1f} um ({fr.evaluations} evaluations)")

    fig, axes = plt.subplots(3, 3, figsize=(11, 10), constrained_layout=True)
    for c, (sub, colour) in enumerate(zip(cam.with_quadrature(DEFAULT_NUMERICS.spectral_tol).channel_cameras(), COLOURS)):
        for j, a in enumerate((0.0, args.angle)):
            r = float(cam.geometry.image_height_mm(a))
            p, n = psf_at(sub, design, 0.0, r, n=256)
            win = p[n // 2 - 24:n // 2 + 24, n // 2 - 24:n // 2 + 24]
            im = axes[c, j].imshow(torch.log10(win.clamp_min(1e-6)).numpy(), cmap="magma", vmin=-6, vmax=-1,
                                   extent=[-24, 24, 24, -24])
            axes[c, j].set_title(f"{sub.spectrum.name.split(',')[0]}: PSF at {a:g} deg", fontsize=9)
            axes[c, j].set_xlabel("x [px of 1.5625 um]")
        H = otf(sub, spectral_coefficients(sub, design, [args.angle]), 512)[0].abs()
        f = torch.arange(257) / 512
        for ax in (axes[c, 2],):
            ax.plot(f, H[:257, 0], color=colour, label="radial")
            ax.plot(f, H[0, :257], ":", color=colour, label="tangential")
            ax.set_ylim(0, 1)
            ax.set_xlabel("frequency [cycles/pixel]")
            ax.set_ylabel(f"MTF at {args.angle:g} deg")
            ax.legend(fontsize=8)
    fig.colorbar(im, ax=axes[:, :2], shrink=0.6, label="log10 PSF (unit sum)")
    fig.suptitle(f"{args.glass} singlet, {design.label()}, {args.spectrum} under D65 "
                 f"({len(cam.channels[0])} wavelengths per channel)")
    fig.savefig(out / "psf_mtf.png", dpi=100)
    plt.close(fig)

    ideal, source = load_photo(args.photo, PAPER_CAMERA)
    box = crop_at_field_angle(ideal.shape, args.angle, 192, cam.geometry)
    res = simulate_crops(ideal, LensPSF(cam, design), cam.sensor.full_well_for_iso(100), [box], sensor=PAPER_SENSOR)
    mosaic_figure(res, ["wiener"], out / "fringing.png",
                  title=f"{source}: {args.glass}, {args.spectrum}, {design.label()}, ISO 100")
    s = res[0].scores
    print(f"crop at {res[0].field_deg:.2f} deg: sensor {s['sensor']['psnr_db']:.2f} dB -> restored "
          f"{s['wiener']['psnr_db']:.2f} dB; wrote {out}/psf_mtf.png and {out}/fringing.png")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown()  # no nanobind "leaked" noise at exit
