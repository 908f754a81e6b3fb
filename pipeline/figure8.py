"""A Fig. 8-style mosaic: crops at several field angles, two designs, three noise levels.

Columns (as the paper's Fig. 8): ideal | RMS_W design, noise-free sensor image | its restoration at
ISO 25 | end-to-end design, noise-free sensor image | its restorations at ISO 400, 100 and 25.
Each restored tile is labelled with its PSNR (dB, sRGB). Written as PNG and SVG (headless).
"""

from __future__ import annotations

from pathlib import Path

import torch

from lenssim.files import atomic_write

from .colour_space import linear_to_srgb
from .noise import full_well_for_iso
from .simulate import crop_at_field_angle, simulate_crops

__all__ = ["PAPER_FIG8_ANGLES", "figure8"]

PAPER_FIG8_ANGLES = (1.3, 2.1, 7.1, 3.4, 4.8, 8.8)


def figure8(ideal: torch.Tensor, out_dir, *, rms_w=(-0.725, -10.0), e2e=(-0.775, -2.4), angles=PAPER_FIG8_ANGLES,
            crop: int = 128, seed: int = 0) -> tuple[Path, list[dict]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    boxes = [crop_at_field_angle(ideal.shape, a, crop) for a in angles]
    runs = {("rms_w", 25): simulate_crops(ideal, *rms_w, full_well_for_iso(25), boxes, seed=seed)}
    isos = (400, 100, 25)
    per_iso = simulate_crops(ideal, *e2e, [full_well_for_iso(i) for i in isos], boxes, seed=seed)  # one blur
    runs.update({("e2e", iso): res for iso, res in zip(isos, per_iso)})
    cols = [("ideal", lambda i: runs[("e2e", 25)][i].ideal, None),
            ("RMS_W: sensor (no noise)", lambda i: runs[("rms_w", 25)][i].blurred, None),
            ("RMS_W: restored, ISO 25", lambda i: runs[("rms_w", 25)][i].restored, ("rms_w", 25)),
            ("end-to-end: sensor (no noise)", lambda i: runs[("e2e", 25)][i].blurred, None),
            ("end-to-end: restored, ISO 400", lambda i: runs[("e2e", 400)][i].restored, ("e2e", 400)),
            ("end-to-end: restored, ISO 100", lambda i: runs[("e2e", 100)][i].restored, ("e2e", 100)),
            ("end-to-end: restored, ISO 25", lambda i: runs[("e2e", 25)][i].restored, ("e2e", 25))]
    fig, axes = plt.subplots(len(boxes), len(cols), figsize=(2.0 * len(cols), 2.05 * len(boxes) + 0.6),
                             squeeze=False, constrained_layout=True)
    table = []
    for i, a in enumerate(angles):
        for j, (title, get, key) in enumerate(cols):
            ax = axes[i, j]
            img = linear_to_srgb(get(i).clamp(0, 1))[0]
            ax.imshow(img.permute(1, 2, 0).squeeze(-1).cpu().numpy(), cmap="gray" if img.shape[0] == 1 else None,
                      vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(title, fontsize=7)
            if j == 0:
                ax.set_ylabel(f"{runs[('e2e', 25)][i].field_deg:.1f} deg", fontsize=8)
            if key is not None:
                p = runs[key][i].psnr_restored_db
                ax.text(3, 12, f"{p:.1f} dB", color="yellow", fontsize=7, backgroundcolor=(0, 0, 0, 0.4))
                table.append({"field_deg": runs[key][i].field_deg, "design": key[0], "iso": key[1], "psnr_restored_db": p})
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png = out / "fig8_mosaic.png"
    for path in (png, out / "fig8_mosaic.svg"):
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=150))
    plt.close(fig)
    return png, table
