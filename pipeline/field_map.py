"""PSNR over the field of a whole frame: per-tile maps and PSNR against field angle (a figure).

For a full-frame simulation the restored image's quality varies with the field, as the lens's
aberrations do. :func:`field_psnr` cuts the frame into ``tile`` x ``tile`` blocks, computes the
sRGB PSNR of the sensor and restored images in each, and the field angle (degrees) of each
block's centre in the camera's field geometry (optical axis at the frame centre);
:func:`plot_field_psnr` draws the maps (the sensor image's and each restored frame's) on one colour scale and
PSNR against field angle.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from lenssim import FieldGeometry

from lenssim.io.files import atomic_write

from .quality import encode_srgb, scores_encoded

__all__ = ["tile_field_angles", "field_psnr", "plot_field_psnr"]


def tile_field_angles(shape, tile: int = 256, *, geometry: FieldGeometry) -> torch.Tensor:
    """Field angle (deg) of each ``tile`` x ``tile`` block's centre, ``(rows, cols)`` float64, for ``shape`` ``(..., H, W)``.

    Blocks as in :func:`pipeline.quality.psnr_map_srgb`; optical axis at the frame centre.
    """
    return geometry.tile_field_angles(shape, tile)


def field_psnr(ideal: torch.Tensor, sensor: torch.Tensor, restored: torch.Tensor, *, tile: int = 256,
               geometry: FieldGeometry) -> dict:
    """``{"sensor_db", "restored_db", "field_deg"}``: ``(rows, cols)`` float64 tensors, one entry per tile."""
    for name, t in (("sensor", sensor), ("restored", restored)):
        if t.shape != ideal.shape or ideal.ndim != 4 or ideal.shape[0] != 1:
            raise ValueError(f"{name} has shape {tuple(t.shape)}, ideal {tuple(ideal.shape)}: expected equal (1, C, H, W)")
    ref = encode_srgb(ideal)  # once for both comparisons
    m_s = scores_encoded(ref, encode_srgb(sensor), tile=tile, ssim=False)["psnr_map_db"]
    m_r = scores_encoded(ref, encode_srgb(restored), tile=tile, ssim=False)["psnr_map_db"]
    return {"sensor_db": m_s, "restored_db": m_r, "field_deg": tile_field_angles(ideal.shape, tile, geometry=geometry)}


def plot_field_psnr(maps: dict, path, *, title: str = "", labels: dict | None = None) -> Path:
    """Write the figure (PNG, plus SVG beside it) for the output of :func:`field_psnr` or
    :func:`pipeline.simulate.score_frame`; returns the PNG path.

    Every map ``KIND_db`` of ``maps`` (the sensor image's first, then each restored frame's: ``restored_db``, or
    ``restored_TAG_db`` for a frame restored with several PSF providers) gets a panel on one colour scale, and a
    curve of PSNR against field angle. ``labels`` ``{KIND: label}`` names them (default: "sensor image", "restored
    image", "restored image (TAG)")."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = sorted((k[:-3] for k in maps if k.endswith("_db")), key=lambda k: k != "sensor")
    default = {"sensor": "sensor image", "restored": "restored image"}
    names = {k: (labels or {}).get(k) or default.get(k) or f"restored image ({k.removeprefix('restored_')})"
             for k in kinds}
    vals = {k: maps[f"{k}_db"].numpy() for k in kinds}
    a = maps["field_deg"].numpy()
    finite = [v[torch.isfinite(torch.from_numpy(v)).numpy()] for v in vals.values()]
    lo = math.floor(min(float(f.min()) for f in finite if f.size))
    hi = math.ceil(max(float(f.max()) for f in finite if f.size))
    n = len(kinds)
    fig, axes = plt.subplots(1, n + 1, figsize=(5 * (n + 1), 4.2), constrained_layout=True)
    for ax, k in zip(axes[:n], kinds):
        im = ax.imshow(vals[k], vmin=lo, vmax=hi, cmap="viridis", interpolation="nearest")
        ax.set_title(f"PSNR per tile, {names[k]} [dB]")
        ax.set_xlabel("tile column")
        ax.set_ylabel("tile row")
    fig.colorbar(im, ax=axes[:n], shrink=0.9, label="PSNR (sRGB) [dB]")
    for k in kinds:
        axes[n].plot(a.ravel(), vals[k].ravel(), ".", ms=4, label=names[k])
    axes[n].set_xlabel("field angle of the tile centre [deg]")
    axes[n].set_ylabel("PSNR (sRGB) [dB]")
    axes[n].set_title("PSNR against field angle")
    axes[n].grid(alpha=0.3)
    axes[n].legend()
    if title:
        fig.suptitle(title)
    png = Path(path)
    for p in (png, png.with_suffix(".svg")):
        atomic_write(p, lambda tmp: fig.savefig(tmp, dpi=120))
    plt.close(fig)
    return png
