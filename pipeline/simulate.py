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

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from lenssim import PAPER_LENS, ThinLens
from lenssim.files import atomic_write_text

from .blur import PAPER_SCHEME, WindowScheme, blur_windowed, window_count
from .noise import add_poisson_noise
from .quality import psnr_srgb, ssim_srgb
from .restoration import richardson_lucy_windowed, wiener_windowed

__all__ = ["CropResult", "FrameResult", "crop_at_field_angle", "simulate_crops", "simulate_frame", "crops_from_frame"]


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


def simulate_crops(ideal: torch.Tensor, s: float, Q: float, full_well, boxes, *, seed: int = 0,
                   lens: ThinLens = PAPER_LENS, scheme: WindowScheme = PAPER_SCHEME, rl_iterations: int = 0,
                   progress=None, dtype: torch.dtype = torch.float32):
    """Blur, noise and restore ``ideal`` (linear ``(1, C, H, W)``) at each box ``(r0, r1, c0, c1)``.

    ``full_well`` (electrons) is a number, giving a list of :class:`CropResult` (one per box), or a
    sequence of numbers (e.g. three ISOs), giving one such list per full well: the blur is computed
    once and shared. The noise of box ``k`` comes from ``seed + k`` at every full well.
    ``rl_iterations > 0`` also restores with windowed Richardson-Lucy (the non-linear comparison).
    ``dtype`` is the working precision (float32: ~1e-7 relative, far below the noise; float64 for
    reference runs); results come back in ``ideal``'s dtype.
    """
    several = not isinstance(full_well, (int, float))
    wells = [float(f) for f in (full_well if several else [full_well])]
    for f in wells:
        if not f > 0:
            raise ValueError(f"full_well={f!r} is not allowed: must be > 0 electrons")
    H, W = ideal.shape[-2:]
    centre = ((H - 1) / 2, (W - 1) / 2)
    margin = scheme.window // 2 + scheme.core
    peak = float(ideal.amax())
    out = [[] for _ in wells]
    for k, (r0, r1, c0, c1) in enumerate(boxes):
        # sub-array: crop + 2 margins (blur region = crop + 1 margin; restoration reads within it)
        R0, R1, C0, C1 = max(r0 - 2 * margin, 0), min(r1 + 2 * margin, H), max(c0 - 2 * margin, 0), min(c1 + 2 * margin, W)
        sub = ideal[..., R0:R1, C0:C1].to(dtype)
        oc = (centre[0] - R0, centre[1] - C0)
        br = (max(r0 - margin, R0) - R0, min(r1 + margin, R1) - R0, max(c0 - margin, C0) - C0, min(c1 + margin, C1) - C0)
        blurred = blur_windowed(sub, lens, s, Q, scheme=scheme, optical_center=oc, region=br, progress=progress)
        rr = (r0 - R0, r1 - R0, c0 - C0, c1 - C0)
        crop = lambda t: t[..., rr[0]:rr[1], rr[2]:rr[3]].to(ideal.dtype)  # noqa: E731
        ci = crop(sub)
        dist = math.hypot((r0 + r1 - 1) / 2 - centre[0], (c0 + c1 - 1) / 2 - centre[1]) * lens.pixel_pitch_um * 1e-3
        field = math.degrees(math.atan(dist / lens.focal_length_mm))
        for i, fwc in enumerate(wells):
            e = fwc / peak
            g = torch.Generator(device=blurred.device).manual_seed(seed + k)
            noisy = blurred.clone()
            reg = (slice(br[0], br[1]), slice(br[2], br[3]))
            counts = torch.poisson((blurred[..., reg[0], reg[1]] * e).clamp_min(0), generator=g)
            noisy[..., reg[0], reg[1]] = counts / e
            restored = wiener_windowed(noisy, lens, s, Q, electrons_per_unit=e, scheme=scheme, optical_center=oc,
                                       region=rr, progress=progress)
            cs_, cr = crop(noisy), crop(restored)
            res = CropResult((r0, r1, c0, c1), field, ci, cs_, cr, psnr_srgb(ci, cs_), psnr_srgb(ci, cr),
                             ssim_srgb(ci, cs_), ssim_srgb(ci, cr), blurred=crop(blurred))
            if rl_iterations > 0:
                rl = crop(richardson_lucy_windowed(noisy.clamp_min(0), lens, s, Q, iterations=rl_iterations,
                                                   scheme=scheme, optical_center=oc, region=rr, progress=progress))
                res.restored_rl, res.psnr_rl_db, res.ssim_rl = rl, psnr_srgb(ci, rl), ssim_srgb(ci, rl)
            out[i].append(res)
    return out if several else out[0]


@dataclass
class FrameResult:
    sensor: torch.Tensor  # (B, C, H, W) linear, blurred + Poisson noise
    restored: torch.Tensor  # (B, C, H, W) linear, adaptive local Wiener
    electrons_per_unit: float  # photo-electrons per unit of the linear image
    resumed: bool  # the sensor image came from the checkpoint
    seconds: dict  # wall-clock time of each stage run here


def _fingerprint(ideal: torch.Tensor, params: dict) -> str:
    h = hashlib.blake2b(json.dumps(params, sort_keys=True).encode(), digest_size=16)
    h.update(ideal.detach().to("cpu").contiguous().numpy().tobytes())
    return h.hexdigest()


def simulate_frame(ideal: torch.Tensor, s: float, Q: float, full_well: float, *, seed: int = 0,
                   lens: ThinLens = PAPER_LENS, scheme: WindowScheme = PAPER_SCHEME, progress=None,
                   dtype: torch.dtype = torch.float32, checkpoint=None) -> FrameResult:
    """The whole frame: blur, Poisson noise (seeded) and adaptive Wiener restoration.

    Two passes of ``ceil((H-1)/stride + 1) x ceil((W-1)/stride + 1)`` windows (23,688 each at
    6000 x 4000 with the paper's scheme); ``progress(k)`` is called after every ``k`` windows.
    ``dtype``: working precision, as in :func:`simulate_crops`; images come back in ``ideal``'s dtype.

    ``checkpoint`` (a folder): after the first pass the sensor image (float EXR) and a stamp of the
    input and parameters are written there atomically; a later call with the same input and
    parameters resumes from them and runs the restoration only.
    """
    from .io import read_image, write_image

    if ideal.ndim != 4 or ideal.shape[0] != 1:
        raise ValueError(f"ideal has shape {tuple(ideal.shape)}: expected (1, C, H, W)")
    seconds = {}
    params = {"s": float(s), "Q": float(Q), "full_well": float(full_well), "seed": int(seed), "lens": repr(lens),
              "scheme": [scheme.window, scheme.stride, scheme.core], "dtype": str(dtype), "shape": list(ideal.shape)}
    stamp_path = sensor_path = None
    if checkpoint is not None:
        ck = Path(checkpoint)
        stamp_path, sensor_path = ck / "stamp.json", ck / "sensor_linear.exr"
        t0 = time.perf_counter()
        key = _fingerprint(ideal, params)
        seconds["fingerprint"] = time.perf_counter() - t0
        if stamp_path.exists() and sensor_path.exists():
            stamp = json.loads(stamp_path.read_text())
            if stamp.get("key") == key:
                sensor, _ = read_image(sensor_path)
                if tuple(sensor.shape) == tuple(ideal.shape):
                    if progress is not None:
                        progress(window_count(ideal.shape, scheme))
                    return _restore_frame(sensor.to(device=ideal.device, dtype=dtype), ideal, s, Q, stamp["electrons_per_unit"], lens, scheme,
                                          progress, seconds, resumed=True)
    t0 = time.perf_counter()
    blurred = blur_windowed(ideal.to(dtype), lens, s, Q, scheme=scheme, progress=progress)
    seconds["blur"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    e = full_well / float(blurred.amax())
    noisy = add_poisson_noise(blurred.clamp_min(0), full_well, seed=seed)
    del blurred
    seconds["noise"] = time.perf_counter() - t0
    if checkpoint is not None:
        write_image(sensor_path, noisy, bits="float")
        atomic_write_text(stamp_path, json.dumps({"key": key, "electrons_per_unit": e, **params}, indent=2))
    return _restore_frame(noisy, ideal, s, Q, e, lens, scheme, progress, seconds, resumed=False)


def crops_from_frame(ideal: torch.Tensor, frame: FrameResult, boxes, lens: ThinLens = PAPER_LENS) -> list[CropResult]:
    """:class:`CropResult` for boxes ``(r0, r1, c0, c1)`` cut from a full-frame :class:`FrameResult`."""
    H, W = ideal.shape[-2:]
    out = []
    for r0, r1, c0, c1 in boxes:
        cut = lambda t: t[..., r0:r1, c0:c1]  # noqa: E731
        ci, cs_, cr = cut(ideal), cut(frame.sensor), cut(frame.restored)
        dist = math.hypot((r0 + r1 - 1) / 2 - (H - 1) / 2, (c0 + c1 - 1) / 2 - (W - 1) / 2) * lens.pixel_pitch_um * 1e-3
        out.append(CropResult((r0, r1, c0, c1), math.degrees(math.atan(dist / lens.focal_length_mm)), ci, cs_, cr,
                              psnr_srgb(ci, cs_), psnr_srgb(ci, cr), ssim_srgb(ci, cs_), ssim_srgb(ci, cr)))
    return out


def _restore_frame(noisy, ideal, s, Q, e, lens, scheme, progress, seconds, resumed) -> FrameResult:
    t0 = time.perf_counter()
    restored = wiener_windowed(noisy, lens, s, Q, electrons_per_unit=e, scheme=scheme, progress=progress)
    seconds["restore"] = time.perf_counter() - t0
    return FrameResult(noisy.to(ideal.dtype), restored.to(ideal.dtype), e, resumed, seconds)
