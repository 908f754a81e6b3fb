"""Labelled image mosaics: a picture that explains itself without the JSON beside it.

:func:`mosaic_figure` draws crops as rows (labelled with their field angle) and image kinds as
columns (ideal / sensor / one per restoration method, labelled), with PSNR and SSIM (sRGB, against
the ideal image) printed on every tile but the ideal one.
"""

from __future__ import annotations

from pathlib import Path

from lenssim.io.files import atomic_write

from .colour_space import linear_to_srgb
from .restoration import RESTORATION_METHODS

__all__ = ["mosaic_figure", "tile_label"]


def tile_label(score: dict) -> str:
    """``"31.2 dB / SSIM 0.842"`` (``"identical"`` for an infinite PSNR)."""
    p = score["psnr_db"]
    return ("identical" if p == float("inf") else f"{p:.1f} dB") + f" / SSIM {score['ssim']:.3f}"


def _column_title(kind: str) -> str:
    base, _, tag = kind.partition("@")  # METHOD@nominal, METHOD@calibrated: restored with whose PSFs
    if base in RESTORATION_METHODS:
        whose = {"nominal": " (nominal PSFs)", "calibrated": " (lens's own PSFs)"}.get(tag, "")
        return f"restored: {RESTORATION_METHODS[base].label}{whose}"
    return {"ideal": "ideal", "sensor": "sensor (blur + noise)", "blurred": "sensor, no noise"}.get(kind, kind)


def mosaic_figure(results, methods, path, *, title: str = "", dpi: int = 110) -> Path:
    """Write a labelled mosaic of :class:`pipeline.CropResult` rows (PNG, by the file's extension)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = ["ideal", "sensor", *methods]
    rows = len(results)
    fig, axes = plt.subplots(rows, len(kinds), figsize=(2.4 * len(kinds), 2.45 * rows + (0.5 if title else 0.2)),
                             squeeze=False, constrained_layout=True)
    for i, r in enumerate(results):
        for j, kind in enumerate(kinds):
            ax = axes[i, j]
            img = linear_to_srgb(r.images[kind].clamp(0, 1))[0]
            ax.imshow(img.permute(1, 2, 0).squeeze(-1).cpu().numpy(), cmap="gray" if img.shape[0] == 1 else None,
                      vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(_column_title(kind), fontsize=8)
            if j == 0:
                ax.set_ylabel(f"field {r.field_deg:.2f} deg", fontsize=8)
            if kind in r.scores:
                ax.text(0.02, 0.03, tile_label(r.scores[kind]), transform=ax.transAxes, color="yellow", fontsize=7,
                        backgroundcolor=(0, 0, 0, 0.55))
    if title:
        import textwrap

        fig.suptitle("\n".join(textwrap.wrap(title, 30 * len(kinds))), fontsize=9)
    out = Path(path)
    atomic_write(out, lambda tmp: fig.savefig(tmp, dpi=dpi))
    plt.close(fig)
    return out
