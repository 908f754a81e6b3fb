"""A generated test scene (the project's built-in default input; nothing is downloaded).

``resolution_scene`` draws, on a 1/f textured background, a grid of resolution targets spread
over the whole frame so that the field dependence of the lens shows: Siemens stars, bar groups at
several pitches (2-16 px periods), a grey step wedge, and fine random texture. In addition,
Siemens stars (0, 4, 8, 12 degrees) and bar groups (2, 6, 10 degrees) are centred on the frame
diagonal at those field angles of the paper's lens (at 6000 x 4000; the 12-degree tile sits in
the corner), where :func:`pipeline.simulate.crop_at_field_angle` puts its crops by default. Linear RGB in
[0.02, 0.95], ``(1, 3, H, W)`` float32, deterministic for a given ``seed``: it is computed in float64 and rounded
to float32 once, so the same on any CPU and thread count (float32 interpolation and trigonometry round
differently from one vector path to another, which moved crop scores by 1e-9).
"""

from __future__ import annotations
import math

import torch

from lenssim import FieldGeometry
from lenssim.torch_utils import HOST


__all__ = ["resolution_scene", "target_tile"]


def target_tile(size: int = 256, kind: int = 0) -> torch.Tensor:
    """One ``size x size`` grey target (values in [0, 1], float64): 0 Siemens star, 1 bar groups, 2 step wedge + texture."""
    y, x = torch.meshgrid(torch.arange(size, dtype=torch.float64, device=HOST) - size / 2 + 0.5,
                          torch.arange(size, dtype=torch.float64, device=HOST) - size / 2 + 0.5, indexing="ij")
    if kind == 0:
        theta = torch.atan2(y, x)
        star = (torch.sin(36 * theta) > 0).double()
        return torch.where(torch.hypot(x, y) < size * 0.47, star, torch.full_like(star, 0.5))
    if kind == 1:  # bar groups, periods 2..16 px, vertical and horizontal
        tile = torch.full((size, size), 0.5, dtype=torch.float64, device=HOST)
        q, h2 = size // 4, size // 2
        bh, bw = q - 8, h2 - 8
        for i, period in enumerate((2, 3, 4, 6, 8, 10, 12, 16)):
            r, c = divmod(i, 2)
            idx = torch.arange(bw if r % 2 == 0 else bh, device=HOST)
            bars = ((2 * idx // period) % 2).double()
            block = bars[None, :].expand(bh, -1) if r % 2 == 0 else bars[:, None].expand(-1, bw)
            tile[r * q + 4:r * q + 4 + bh, c * h2 + 4:c * h2 + 4 + bw] = block
        return tile
    steps = torch.linspace(0.05, 0.95, 8, dtype=torch.float64, device=HOST)  # grey wedge above, fine random texture below
    tile = steps[torch.arange(size, device=HOST) * 8 // size][None, :].repeat(size, 1)
    g = torch.Generator().manual_seed(7)
    tile[size // 2:] = torch.rand(size - size // 2, size, generator=g, device=HOST).double()
    return tile


def _diagonal_positions(height: int, width: int, tile: int, geometry: FieldGeometry, step_deg: float = 2.0):
    """Top-left corners and kinds of the tiles centred on the diagonal every ``step_deg`` degrees of field."""
    out, a = [], 0.0
    while True:
        # kept inside the frame exactly as crop_at_field_angle keeps its crops
        r0, _, c0, _ = geometry.box_at_field_angle((height, width), a, tile)
        if out and (r0, c0) == out[-1][:2] or geometry.radius_px(a) > math.hypot(height, width) / 2:
            return out
        out.append((r0, c0, 0 if round(a / step_deg) % 2 == 0 else 1))
        a += step_deg


def resolution_scene(height: int = 4000, width: int = 6000, *, seed: int = 0, tile: int = 256,
                     spacing: int = 640, geometry: FieldGeometry) -> torch.Tensor:
    """The default scene: linear RGB ``(1, 3, height, width)`` float32 (``geometry``, default the paper
    camera's, places the diagonal targets)."""
    if height < tile or width < tile:
        raise ValueError(f"scene {height}x{width} is smaller than one {tile}-px target")
    g = torch.Generator().manual_seed(seed)
    lo = torch.rand(1, 3, max(2, height // 64), max(2, width // 64), generator=g, device=HOST).double()
    bg = torch.nn.functional.interpolate(lo, size=(height, width), mode="bilinear", align_corners=False)
    fine = torch.rand(1, 1, height // 4, width // 4, generator=g, device=HOST).double()
    bg = 0.6 * bg + 0.25 * torch.nn.functional.interpolate(fine, size=(height, width), mode="bilinear",
                                                           align_corners=False) + 0.05
    img = bg
    tiles = [target_tile(tile, k) for k in range(3)]
    colours = torch.tensor([[1.0, 1.0, 1.0], [1.0, 0.85, 0.7], [0.7, 0.85, 1.0]], dtype=torch.float64, device=HOST)
    diagonal = _diagonal_positions(height, width, tile, geometry)
    clear = lambda r, c: all(abs(r - dr) >= tile + 8 or abs(c - dc) >= tile + 8 for dr, dc, _ in diagonal)  # noqa: E731
    k = 0
    for r in range(spacing // 2 - tile // 2, height - tile + 1, spacing):
        for c in range(spacing // 2 - tile // 2, width - tile + 1, spacing):
            if clear(r, c):  # grid tiles give way to the diagonal ones
                img[0, :, r:r + tile, c:c + tile] = colours[k % 3][:, None, None] * (0.05 + 0.9 * tiles[k % 3])
            k += 1
    for r, c, kind in diagonal:
        img[0, :, r:r + tile, c:c + tile] = colours[kind][:, None, None] * (0.05 + 0.9 * tiles[kind])
    return img.clamp(0.02, 0.95).to(torch.float32).contiguous()
