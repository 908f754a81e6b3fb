"""Camera simulation: ideal linear image -> sensor image (blur + Poisson noise) -> restored image.

``simulate_crops`` runs the paper's chain on crops at chosen image points of a full frame (fast:
only the windows that reach each crop are computed); ``simulate_frame`` runs it on the whole
frame. The optical axis is at the frame centre; pixel pitch ``lambda f# / 2`` (1.5625 um).

Noise scaling: the blurred image's maximum maps to the full-well capacity (paper). For crops the
frame's blurred maximum is not computed; the ideal image's maximum stands in for it (blurring
with a unit-sum PSF cannot raise the maximum, so the photon counts are at most those of the
paper's scaling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lenssim import PAPER_LENS, ThinLens

from .blur import PAPER_SCHEME, WindowScheme, blur_windowed
from .noise import add_poisson_noise
from .quality import psnr_srgb, ssim_srgb
from .restoration import richardson_lucy_windowed, wiener_windowed

__all__ = ["CropResult", "crop_at_field_angle", "simulate_crops", "simulate_frame"]


@dataclass
class CropResult:
    box: tuple[int, int, int, int]  # (r0, r1, c0, c1) in the frame
    field_deg: float
    ideal: torch.Tensor
    sensor: torch.Tensor
    restored: torch.Tensor
    psnr_sensor_db: float
    psnr_restored_db: float
    ssim_sensor: float
    ssim_restored: float
    blurred: torch.Tensor | None = None  # noise-free sensor image
    restored_rl: torch.Tensor | None = None
    psnr_rl_db: float | None = None
    ssim_rl: float | None = None


def crop_at_field_angle(shape, alpha_deg: float, size: int = 256, lens: ThinLens = PAPER_LENS,
                        azimuth_deg: float | None = None) -> tuple[int, int, int, int]:
    """Box of ``size`` px centred at field angle ``alpha_deg`` (default: along the frame diagonal)."""
    H, W = shape[-2:]
    az = math.atan2(H, W) if azimuth_deg is None else math.radians(azimuth_deg)
    r_px = lens.focal_length_mm * math.tan(math.radians(alpha_deg)) / (lens.pixel_pitch_um * 1e-3)
    cy, cx = (H - 1) / 2 + r_px * math.sin(az), (W - 1) / 2 + r_px * math.cos(az)
    r0 = int(round(cy - size / 2))
    c0 = int(round(cx - size / 2))
    r0, c0 = min(max(r0, 0), H - size), min(max(c0, 0), W - size)
    return r0, r0 + size, c0, c0 + size


def simulate_crops(ideal: torch.Tensor, s: float, Q: float, full_well: float, boxes, *, seed: int = 0,
                   lens: ThinLens = PAPER_LENS, scheme: WindowScheme = PAPER_SCHEME, rl_iterations: int = 0,
                   progress=None, dtype: torch.dtype = torch.float32) -> list[CropResult]:
    """Blur, noise and restore ``ideal`` (linear ``(1, C, H, W)``) at each box ``(r0, r1, c0, c1)``.

    ``rl_iterations > 0`` also restores with windowed Richardson-Lucy (the non-linear comparison).
    ``dtype`` is the working precision (float32: ~1e-7 relative, far below the noise; float64 for
    reference runs); results come back in ``ideal``'s dtype.
    """
    H, W = ideal.shape[-2:]
    centre = ((H - 1) / 2, (W - 1) / 2)
    margin = scheme.window // 2 + scheme.core
    e = full_well / float(ideal.amax())
    out = []
    for k, (r0, r1, c0, c1) in enumerate(boxes):
        # sub-array: crop + 2 margins (blur region = crop + 1 margin; restoration reads within it)
        R0, R1, C0, C1 = max(r0 - 2 * margin, 0), min(r1 + 2 * margin, H), max(c0 - 2 * margin, 0), min(c1 + 2 * margin, W)
        sub = ideal[..., R0:R1, C0:C1].to(dtype)
        oc = (centre[0] - R0, centre[1] - C0)
        br = (max(r0 - margin, R0) - R0, min(r1 + margin, R1) - R0, max(c0 - margin, C0) - C0, min(c1 + margin, C1) - C0)
        blurred = blur_windowed(sub, lens, s, Q, scheme=scheme, optical_center=oc, region=br, progress=progress)
        g = torch.Generator().manual_seed(seed + k)
        noisy = blurred.clone()
        reg = (slice(br[0], br[1]), slice(br[2], br[3]))
        counts = torch.poisson((blurred[..., reg[0], reg[1]] * e).clamp_min(0), generator=g)
        noisy[..., reg[0], reg[1]] = counts / e
        rr = (r0 - R0, r1 - R0, c0 - C0, c1 - C0)
        restored = wiener_windowed(noisy, lens, s, Q, electrons_per_unit=e, scheme=scheme, optical_center=oc,
                                   region=rr, progress=progress)
        crop = lambda t: t[..., rr[0]:rr[1], rr[2]:rr[3]].to(ideal.dtype)  # noqa: E731
        ci, cs_, cr = crop(sub), crop(noisy), crop(restored)
        dist = math.hypot((r0 + r1 - 1) / 2 - centre[0], (c0 + c1 - 1) / 2 - centre[1]) * lens.pixel_pitch_um * 1e-3
        res = CropResult((r0, r1, c0, c1), math.degrees(math.atan(dist / lens.focal_length_mm)), ci, cs_, cr,
                         psnr_srgb(ci, cs_), psnr_srgb(ci, cr), ssim_srgb(ci, cs_), ssim_srgb(ci, cr), blurred=crop(blurred))
        if rl_iterations > 0:
            rl = crop(richardson_lucy_windowed(noisy.clamp_min(0), lens, s, Q, iterations=rl_iterations, scheme=scheme,
                                               optical_center=oc, region=rr, progress=progress))
            res.restored_rl, res.psnr_rl_db, res.ssim_rl = rl, psnr_srgb(ci, rl), ssim_srgb(ci, rl)
        out.append(res)
    return out


def simulate_frame(ideal: torch.Tensor, s: float, Q: float, full_well: float, *, seed: int = 0,
                   lens: ThinLens = PAPER_LENS, scheme: WindowScheme = PAPER_SCHEME, progress=None,
                   dtype: torch.dtype = torch.float32):
    """The whole frame: ``(sensor, restored)`` linear images ``(B, C, H, W)`` in ``ideal``'s dtype.

    Two passes of ``ceil((H-1)/stride + 1) x ceil((W-1)/stride + 1)`` windows (23,688 each at
    6000 x 4000 with the paper's scheme). ``dtype``: working precision, as in :func:`simulate_crops`.
    """
    x = ideal.to(dtype)
    blurred = blur_windowed(x, lens, s, Q, scheme=scheme, progress=progress)
    e = full_well / float(blurred.amax())
    noisy = add_poisson_noise(blurred.clamp_min(0), full_well, seed=seed)
    del blurred
    restored = wiener_windowed(noisy, lens, s, Q, electrons_per_unit=e, scheme=scheme, progress=progress)
    return noisy.to(ideal.dtype), restored.to(ideal.dtype)
