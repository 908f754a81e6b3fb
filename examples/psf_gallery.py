"""PSFs and MTFs across the field for the paper's two designs, as a figure.

    python examples/psf_gallery.py [--out psf_gallery.png]

Rows: the RMS_W design (s = -0.725, Q = -10) and the end-to-end design (s = -0.775, Q = -2.4);
columns: field angles 0, 4, 8, 12.7 degrees (12.7 is the corner of a 6000 x 4000 sensor). Each
PSF is computed at its image point on the sensor diagonal (exact pupil rotation), shown on a
common 64 x 64 pixel window (1.5625 um pixels), log scale. The last column shows the MTF along
the radial and tangential directions at 8 degrees.
"""

from __future__ import annotations

import argparse
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from lenssim import otf, psf_at, spectral_coefficients  # noqa: E402

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS

DESIGNS = {"RMS_W design": PAPER_DESIGNS["rms_w_paper"], "end-to-end": PAPER_DESIGNS["end_to_end_paper"]}
ANGLES = (0.0, 4.0, 8.0, 12.7)
DIAG = math.atan2(2000, 3000)  # azimuth of the 3:2 sensor's diagonal


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="psf_gallery.png")
    args = ap.parse_args()
    fig, axes = plt.subplots(2, len(ANGLES) + 1, figsize=(3.2 * (len(ANGLES) + 1), 6.4), constrained_layout=True)
    for row, (name, design) in enumerate(DESIGNS.items()):
        name = f"{name} ({design.label()})"
        for col, a in enumerate(ANGLES):
            r = float(PAPER_CAMERA.geometry.image_height_mm(a))
            p, n = psf_at(PAPER_CAMERA, design, r * math.cos(DIAG), r * math.sin(DIAG))
            c = n // 2
            win = p[c - 32:c + 32, c - 32:c + 32]
            ax = axes[row, col]
            im = ax.imshow(torch.log10(win.clamp_min(1e-6)).numpy(), cmap="magma", vmin=-6, vmax=-1,
                           extent=[-32, 32, 32, -32])
            ax.set_title(f"{a:g} deg (FFT {n})", fontsize=9)
            ax.set_xlabel("x [pixels of 1.5625 um]")
            if col == 0:
                ax.set_ylabel(f"{name}\ny [pixels]", fontsize=9)
        c8 = spectral_coefficients(PAPER_CAMERA, design, [8.0])
        H = otf(PAPER_CAMERA, c8, 512)[0].abs()
        f = torch.arange(257) / 512
        ax = axes[row, -1]
        ax.plot(f, H[:257, 0], label="radial (meridional)")
        ax.plot(f, H[0, :257], label="tangential (sagittal)")
        ax.set_xlabel("frequency [cycles/pixel]")
        ax.set_ylabel("MTF at 8 deg")
        ax.set_ylim(0, 1)
        ax.legend(fontsize=8)
    fig.colorbar(im, ax=axes[:, :-1], shrink=0.8, label="log10 PSF (unit sum)")
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    main()
    exit_without_teardown()  # no nanobind "leaked" noise at exit
