"""Field geometry, in one place: sensor pixels <-> image-plane mm <-> field angle (degrees).

The optical axis meets the sensor at the frame centre ``((H - 1) / 2, (W - 1) / 2)`` (rows, cols)
unless an ``optical_center`` is given. Image rows/columns are the image-plane ``y``/``x`` axes; a
pixel offset ``d`` (px) from the axis is ``d * pitch`` mm; the field angle of an image point at
radius ``r`` mm is ``atan(r / f)`` (paraxial, object at infinity), so the radius of field angle
``alpha`` is ``f tan(alpha)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..torch_utils import HOST, as_tensor, tensor_of

__all__ = ["FieldGeometry", "frame_center"]


def frame_center(shape) -> tuple[float, float]:
    """The optical axis of a frame ``(..., H, W)``: ``((H - 1) / 2, (W - 1) / 2)`` (rows, cols)."""
    H, W = shape[-2:]
    return (H - 1) / 2, (W - 1) / 2


@dataclass(frozen=True)
class FieldGeometry:
    """Focal length (mm) and pixel pitch (um): every conversion between pixels, mm and degrees."""

    focal_length_mm: float
    pixel_pitch_um: float

    @property
    def pitch_mm(self) -> float:
        return self.pixel_pitch_um * 1e-3

    # ---- mm <-> degrees ---------------------------------------------------------------
    def field_angle_deg(self, x_mm, y_mm) -> torch.Tensor:
        """Field angle (deg) of the image point ``(x, y)`` (mm from the optical axis)."""
        r = torch.hypot(as_tensor(x_mm), as_tensor(y_mm))
        return torch.rad2deg(torch.atan(r / self.focal_length_mm))

    def image_height_mm(self, alpha_deg) -> torch.Tensor:
        """Paraxial image height ``f tan(alpha)`` in mm (magnitude; the image is inverted)."""
        return self.focal_length_mm * torch.tan(torch.deg2rad(as_tensor(alpha_deg)))

    # ---- pixels <-> mm ----------------------------------------------------------------
    def offsets_mm(self, rows, cols, optical_center) -> tuple[torch.Tensor, torch.Tensor]:
        """Image-plane ``(x_mm, y_mm)`` (float64) of pixel positions ``(rows, cols)`` of an array whose
        optical axis is at ``optical_center`` (rows, cols, px)."""
        y = (tensor_of(rows, torch.float64) - optical_center[0]) * self.pitch_mm
        x = (tensor_of(cols, torch.float64) - optical_center[1]) * self.pitch_mm
        return x, y

    def radius_px(self, alpha_deg: float) -> float:
        """Distance (px) from the optical axis of the image points at field angle ``alpha_deg``."""
        return self.focal_length_mm * math.tan(math.radians(alpha_deg)) / self.pitch_mm

    def field_angle_at(self, row: float, col: float, optical_center) -> float:
        """Field angle (deg) of the pixel position ``(row, col)``."""
        dist = math.hypot(row - optical_center[0], col - optical_center[1]) * self.pitch_mm
        return math.degrees(math.atan(dist / self.focal_length_mm))

    # ---- frames, boxes and tiles ----------------------------------------------------------
    def max_field_angle_deg(self, shape) -> float:
        """Field angle (deg) of the frame's corners."""
        cy, cx = frame_center(shape)
        return self.field_angle_at(0.0, 0.0, (cy, cx))

    def box_at_field_angle(self, shape, alpha_deg: float, size: int, azimuth_deg: float | None = None):
        """Box ``(r0, r1, c0, c1)`` of ``size`` px centred at field angle ``alpha_deg`` (default: along the
        frame diagonal, towards the bottom right), moved inside the frame where it would stick out."""
        H, W = shape[-2:]
        az = math.atan2(H, W) if azimuth_deg is None else math.radians(azimuth_deg)
        r_px = self.radius_px(alpha_deg)
        cy, cx = (H - 1) / 2 + r_px * math.sin(az), (W - 1) / 2 + r_px * math.cos(az)
        r0 = min(max(int(round(cy - size / 2)), 0), H - size)
        c0 = min(max(int(round(cx - size / 2)), 0), W - size)
        return r0, r0 + size, c0, c0 + size

    def box_field_angle(self, shape, box) -> float:
        """Field angle (deg) of the centre of box ``(r0, r1, c0, c1)`` in a frame of ``shape``."""
        r0, r1, c0, c1 = box
        return self.field_angle_at((r0 + r1 - 1) / 2, (c0 + c1 - 1) / 2, frame_center(shape))

    def tile_field_angles(self, shape, tile: int) -> torch.Tensor:
        """Field angle (deg) of each ``tile`` x ``tile`` block's centre, ``(rows, cols)`` float64 (blocks from
        the top-left corner; a narrower remainder at the right or bottom is left out)."""
        H, W = shape[-2:]
        cy = torch.arange(H // tile, dtype=torch.float64, device=HOST) * tile + (tile - 1) / 2 - (H - 1) / 2
        cx = torch.arange(W // tile, dtype=torch.float64, device=HOST) * tile + (tile - 1) / 2 - (W - 1) / 2
        r_mm = torch.hypot(cy[:, None], cx[None, :]) * self.pitch_mm
        return torch.rad2deg(torch.atan(r_mm / self.focal_length_mm))
