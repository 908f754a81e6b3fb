"""Camera simulation: ideal linear image -> sensor image (blur + noise) -> restored image(s).

``simulate_crops`` runs the paper's chain on crops at chosen image points of a full frame (fast:
only the windows that reach each crop are computed); ``simulate_frame`` runs it on the whole
frame. The optics come as a PSF provider (:class:`lenssim.LensPSF` for the model), whose field
geometry places every window; the optical axis is at the frame centre.

Noise scaling: the blurred image's maximum maps to the full-well capacity (paper). For crops the
frame's blurred maximum is not computed; the ideal image's maximum stands in for it (blurring
with a unit-sum PSF cannot raise the maximum, so the photon counts are at most those of the
paper's scaling). Crops and frames draw their noise through one forward model, the camera chain
(:class:`pipeline.camera_chain.CameraChain`; a :class:`lenssim.Sensor` is the chain with its defaults, the paper's sensor
photon noise only), and every restoration is given that chain's noise description
(:meth:`pipeline.camera_chain.CameraChain.noise_model`).
Restoration methods come from :data:`pipeline.restoration.RESTORATION_METHODS` (a name, ``"NAME:key=value"``
or a :class:`pipeline.restoration.Restoration`); results carry images and scores keyed by method name.

The image is blurred with one PSF provider (the lens that made it) and restored with another
(``restoration_psf``, default the same: the camera calibrated on its own lens); giving another one
simulates a restoration built for a lens that is not the one in the camera (e.g. the nominal design
restoring an as-built lens).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from lenssim import FieldGeometry, PSFProvider, Sensor, frame_center

from lenssim.io.files import atomic_write_text
from lenssim.torch_utils import HOST
from lenssim.validate import ResumeWarning, check_int, check_real, warn_model

from .blur import (PAPER_SCHEME, ZONE_MULTIPLES, StrideZones, WindowScheme, blur_windowed, choose_stride_zones,
                   largest_window, window_count)
from .camera_chain import CameraChain, NoiseModel, PlanePSF
from .checks import check_boxes, check_full_well, check_provider, check_scene
from .photo import Photo
from .quality import psnr_srgb, ssim_srgb
from .restoration import Restoration, restore
from .restoration.wiener import WIENER_BANK_LEVELS

__all__ = ["CropResult", "FrameResult", "crop_at_field_angle", "simulate_crops", "simulate_frame", "crops_from_frame",
           "DEFAULT_METHODS", "score_frame", "frame_memory_bytes", "FRAME_WORKING_COPIES", "MAP_TILE_PX",
           "largest_crop_angle_deg", "fitting_angles", "FRAME_METHOD"]

DEFAULT_METHODS = ("wiener",)

FRAME_METHOD = f"wiener:bank={WIENER_BANK_LEVELS}"
"""The whole frame's restoration unless one is named: the paper's adaptive Wiener filter in its bank evaluation
(:func:`pipeline.restoration.wiener.wiener_windowed`, option ``bank``), nearer the filter than the paper's own stride
on every crop measured (docs/performance.md) and half its work. Crops keep the paper's evaluation (``wiener``)."""


@dataclass
class CropResult:
    """One crop: its box ``(r0, r1, c0, c1)`` in the frame, field angle (deg), images and scores.

    ``images``: ``"ideal"``, ``"blurred"`` (noise-free sensor image), ``"sensor"`` and one entry per
    restoration method (linear ``(1, C, h, w)``); ``scores``: ``"sensor"`` and one entry per method,
    each ``{"psnr_db": ..., "ssim": ...}`` against the ideal image in sRGB.
    """

    box: tuple[int, int, int, int]
    field_deg: float
    images: dict = field(default_factory=dict)
    scores: dict = field(default_factory=dict)

    @property
    def ideal(self) -> torch.Tensor:
        return self.images["ideal"]

    @property
    def sensor(self) -> torch.Tensor:
        return self.images["sensor"]

    @property
    def methods(self) -> tuple[str, ...]:
        return tuple(k for k in self.scores if k != "sensor")


def _score(ideal, img) -> dict:
    return {"psnr_db": psnr_srgb(ideal, img), "ssim": ssim_srgb(ideal, img)}


CHECKPOINT_EXR_COMPRESSION = "none"
"""Compression of the full frame's checkpoint (the float sensor image, deleted when the run ends). A noisy float
image hardly compresses: on the forest's 24 MP sensor image zip wrote 239 MB in 2.5 s, none 290 MB in 0.57 s
(measured on 2 cores), on every full-frame run."""

CROP_SHIFT_WARN_DEG = 0.25
"""A crop moved inside the frame by more than this (degrees of field) is reported with a warning."""


def largest_crop_angle_deg(shape, size: int, geometry: FieldGeometry) -> float:
    """The largest field angle (deg) at which a ``size`` px crop centred on the frame's diagonal (as
    :func:`crop_at_field_angle` places it) lies wholly inside a frame of ``shape`` ``(..., H, W)``; 0 if none but
    the centre's."""
    H, W = shape[-2:]
    hy, hx = H / 2, W / 2
    t = max(0.0, min((hy - size / 2) / hy, (hx - size / 2) / hx))  # fraction of the half-diagonal
    r_px = t * math.hypot(hy, hx)
    return math.degrees(math.atan(r_px * geometry.pitch_mm / geometry.focal_length_mm))


def fitting_angles(shape, size: int, geometry: FieldGeometry, preferred, count: int = 4) -> tuple[float, ...]:
    """Crop field angles (deg) that fit a frame of ``shape``: those of ``preferred`` whose crop lies inside it (or
    needs moving inside by at most :data:`CROP_SHIFT_WARN_DEG`, as :func:`crop_at_field_angle` does without a
    warning), or, if fewer than two do, ``count`` angles evenly from the axis to :func:`largest_crop_angle_deg`
    (rounded down to 0.01 deg; just the axis if nothing else fits)."""
    edge = largest_crop_angle_deg(shape, size, geometry)
    limit = min(edge + CROP_SHIFT_WARN_DEG, geometry.max_field_angle_deg(shape))
    fit = tuple(float(a) for a in preferred if a <= limit)
    if len(fit) >= 2:
        return fit
    if edge < 0.01:
        return (0.0,)
    top = math.floor(edge * 100) / 100
    return tuple(round(top * k / (count - 1), 2) for k in range(count))


def crop_at_field_angle(shape, alpha_deg: float, size: int, geometry: FieldGeometry,
                        azimuth_deg: float | None = None) -> tuple[int, int, int, int]:
    """Box of ``size`` px centred at field angle ``alpha_deg`` (default: along the frame diagonal), in the
    field geometry of ``geometry`` (a camera's ``geometry``).

    The angle must lie within the frame (0 up to its corners' field angle) and the box inside it; a
    box near the edge is moved inside, and if that moves its centre by more than
    :data:`CROP_SHIFT_WARN_DEG` a :class:`lenssim.validate.ModelValidityWarning` gives its true angle.
    """
    H, W = shape[-2:]
    size = check_int("crop size", size, 1, min(H, W))
    edge = geometry.max_field_angle_deg(shape)
    alpha = check_real("field angle", alpha_deg, 0.0, edge, unit="deg")
    box = geometry.box_at_field_angle(shape, alpha, size, azimuth_deg)
    actual = geometry.box_field_angle(shape, box)
    if abs(actual - alpha) > CROP_SHIFT_WARN_DEG:
        warn_model(f"the {size}-px crop at {alpha:g} deg does not fit in the {W} x {H} frame there; it was moved "
                   f"inside, to {actual:.2f} deg")
    return box


def crop_at_pixel(shape, row: int, col: int, size: int) -> tuple[int, int, int, int]:
    """Box ``(r0, r1, c0, c1)`` of ``size`` px centred as near the pixel (``row``, ``col``; from the frame's top-left
    corner) as fits the frame of ``shape``: a box that would cross an edge is moved inside."""
    H, W = shape[-2:]
    size = check_int("crop size", size, 1, min(H, W))
    row = check_int("crop centre row", row, 0, H - 1)
    col = check_int("crop centre column", col, 0, W - 1)
    r0 = min(max(row - size // 2, 0), H - size)
    c0 = min(max(col - size // 2, 0), W - size)
    return (r0, r0 + size, c0, c0 + size)


def check_methods(methods, method_options: dict | None = None, scheme: WindowScheme | None = None
                  ) -> tuple[Restoration, ...]:
    """Restorations from names, ``"NAME:key=value,..."`` specs or :class:`Restoration` objects, with
    ``method_options`` ``{name: {option: value}}`` merged in; checked, one per name, and with the window
    ``scheme`` when given."""
    if isinstance(methods, (str, Restoration)):
        methods = (methods,)
    specs = [Restoration.of(m) for m in methods]
    if not specs:
        raise ValueError("no restoration method given")
    names = [r.name for r in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"restoration method(s) {dup} given more than once (their results are filed by name)")
    opts = dict(method_options or {})
    for m in opts:
        if m not in names:
            raise ValueError(f"options given for restoration method {m!r}, which is not run; run: {names}")
    out = tuple(Restoration(r.name, {**r.options, **opts.get(r.name, {})}) for r in specs)
    for r in out:
        r.check(scheme)
    return out


def resolve_blur_zones(blur_zones, psf: PSFProvider, shape, scheme: WindowScheme, region=None) -> StrideZones | None:
    """``blur_zones`` as :class:`pipeline.blur.StrideZones` (``"auto"``: chosen for a frame of ``shape``, estimated
    only where ``region`` reaches if given), or None for the scheme's stride everywhere (also when the choice is
    that)."""
    if blur_zones is None:
        return None
    if isinstance(blur_zones, str):
        if blur_zones != "auto":
            raise ValueError(f"blur_zones={blur_zones!r} is not allowed: 'auto', None or a StrideZones")
        blur_zones = choose_stride_zones(psf, shape, scheme, region=region)
    if not isinstance(blur_zones, StrideZones):
        raise ValueError(f"blur_zones is a {type(blur_zones).__name__}: expected 'auto', None or a StrideZones")
    if max(blur_zones.multiples) * scheme.core > scheme.window:
        raise ValueError(f"blur zones {blur_zones.multiples}: a core of {max(blur_zones.multiples) * scheme.core} px "
                         f"is more than the {scheme.window}-px window")
    return None if blur_zones.uniform else blur_zones


def simulate_crops(ideal: torch.Tensor, psf: PSFProvider, full_well, boxes, *, seed: int = 0,
                   scheme: WindowScheme = PAPER_SCHEME, methods=DEFAULT_METHODS, method_options: dict | None = None,
                   sensor: Sensor | CameraChain, progress=None, dtype: torch.dtype = torch.float32,
                   restoration_psf: PSFProvider | None = None, blur_cache: dict | None = None,
                   blur_zones: StrideZones | str | None = None, progress_total=None):
    """Blur, noise and restore ``ideal`` (linear ``(1, C, H, W)``, or a :class:`pipeline.photo.Photo`, read only
    where the crops reach) at each box ``(r0, r1, c0, c1)``.

    ``full_well`` (electrons) is a number, giving a list of :class:`CropResult` (one per box), or a
    sequence of numbers (e.g. three ISOs), giving one such list per full well: the blur is computed
    once and shared. The noise of box ``k`` comes from ``seed + k`` at every full well. Each of ``methods`` (names,
    ``"NAME:key=value,..."`` or :class:`pipeline.restoration.Restoration`; ``method_options``
    ``{method: {option: value}}``) restores the crop, with the PSFs of ``restoration_psf`` (default ``psf``).
    ``dtype`` is the working precision (float32: ~1e-7 relative, far below the noise; float64 for reference
    runs); results come back in ``ideal``'s dtype.

    ``sensor``: a :class:`lenssim.Sensor` (the camera chain with its defaults: :meth:`CameraChain.of`; the paper's
    sensor draws photon noise only) or a :class:`pipeline.camera_chain.CameraChain`. The crop is exposed through the
    chain (:meth:`CameraChain.expose`; the fixed-pattern noise follows each crop's place in the frame) and restored
    with the chain's noise description (:meth:`CameraChain.noise_model`). A chain that develops its raw data
    (:attr:`CameraChain.develops`: a CFA, white balance or colour correction) runs the whole camera: the scene in the
    camera's RGB, blurred, captured (CFA, noise, ADC: its ``"raw"`` image, DN), developed by the ISP (the ``"sensor"``
    image) and restored where the chain says; the CFA's phase follows the crop's place in the frame.

    ``blur_cache`` (a dict the caller keeps, e.g. an interactive explorer): the blurred region of each box is kept
    there under the blur provider, the box, the window scheme, the working precision and the chain's colour matrix
    and pixel aperture, and taken from there by a later call with the same ones (a new ISO, seed, chain or restoration
    of the same crop then skips the blur). The caller keeps the photo unchanged while it keeps the dict.

    ``blur_zones``: the blur's windows coarser where the PSF varies slowly (:class:`pipeline.blur.StrideZones`, or
    ``"auto"``: :func:`pipeline.blur.choose_stride_zones` for the frame; None: the scheme's stride everywhere).

    ``progress(k)`` is called after each ``k`` windows blurred or restored; ``progress_total(n)`` (optional) once,
    before any work, with the number ``n`` of windows they will add up to (a progress bar's total).
    """
    if isinstance(ideal, Photo):  # read region by region (a photo too large to keep decodes only what it needs)
        shape, peak, read, out_dtype = ideal.shape, ideal.peak, ideal.region, ideal.dtype
    else:
        check_scene(ideal, "ideal")
        shape, peak, out_dtype = ideal.shape, float(ideal.amax()), ideal.dtype
        read = lambda R0, R1, C0, C1: ideal[..., R0:R1, C0:C1]  # noqa: E731
    check_provider(psf)
    restoration_psf = psf if restoration_psf is None else check_provider(restoration_psf, "restoration_psf")
    chain = CameraChain.of(sensor)
    if blur_zones is not None and not (blur_zones == "auto" or isinstance(blur_zones, StrideZones)):
        resolve_blur_zones(blur_zones, psf, shape, scheme)  # refused in one line, before any work
    zones = None if blur_zones == "auto" else resolve_blur_zones(blur_zones, psf, shape, scheme)  # "auto": per crop
    coarsest = max((zones or StrideZones((), (1,))).multiples + ((max(ZONE_MULTIPLES),) if blur_zones == "auto" else ()))
    blur_key = (id(psf), scheme, dtype, chain.sensor.colour_matrix, chain.sensor.fill_factor,
                blur_zones if isinstance(blur_zones, str) else zones)
    psf, restoration_psf = _with_pixel_aperture(chain, psf), _with_pixel_aperture(chain, restoration_psf)
    specs = check_methods(methods, method_options)
    several = not isinstance(full_well, (int, float))
    wells = [check_full_well(f) for f in (full_well if several else [full_well])]
    boxes = check_boxes(boxes, shape)
    for r in specs:  # the options against the windows, after the other arguments, before any work
        r.check(scheme)
    if chain.cfa is not None and shape[1] != 3:
        raise ValueError(f"the sensor's {chain.cfa} colour filter array samples an RGB image; this one has "
                         f"{shape[1]} channel(s)")
    H, W = shape[-2:]
    centre = frame_center(shape)
    providers = {id(psf): psf, id(restoration_psf): restoration_psf}.values()

    def crop_margin(r0, r1, c0, c1) -> int:
        """What the passes read beyond the crop (px): half a window and a core, the windows as large as the largest
        within that reach (larger than the scheme's where a PSF outgrows it), found by widening until it holds."""
        w = scheme.window
        while True:
            reach = replace(scheme, window=w)
            m = max([reach.window // 2 + reach.core * coarsest]
                    + [r.margin(reach) for r in specs])
            near = (max(r0 - m, 0), min(r1 + m, H), max(c0 - m, 0), min(c1 + m, W))
            most = max(largest_window(p, shape, scheme, region=near) for p in providers)
            if most <= w:
                return m
            w = most

    # the blur region = crop + what the restorations read beyond it; the sub-array = that + the blur's own reach
    # (every crop's, before any work: a PSF too large for any window stops the run here)
    for r0, r1, c0, c1 in boxes:  # a PSF wider than the photo leaves nothing of the scene resolved
        y, x = (torch.tensor([v], dtype=torch.float64, device=HOST) for v in ((r0 + r1 - 1) / 2, (c0 + c1 - 1) / 2))
        support = max(int(p.extents_px(y, x, centre).max()) for p in providers)
        if support > max(H, W):
            raise ValueError(f"the PSF at the crop {(r0, r1, c0, c1)} spans about {support} px, more than the {W} x {H} "
                             "px frame: nothing of the scene would remain resolved (give a sharper design, or a "
                             "larger photo)")
    plans = []  # per box: the sub-array read, the blur region in it, the crop in it, its optical centre, the zones
    for box, margin in zip(boxes, (crop_margin(*box) for box in boxes)):
        r0, r1, c0, c1 = box
        R0, R1, C0, C1 = max(r0 - 2 * margin, 0), min(r1 + 2 * margin, H), max(c0 - 2 * margin, 0), min(c1 + 2 * margin, W)
        br = (max(r0 - margin, R0) - R0, min(r1 + margin, R1) - R0, max(c0 - margin, C0) - C0, min(c1 + margin, C1) - C0)
        key = blur_key + ((R0, R1, C0, C1), br)
        cached = blur_cache is not None and (key in blur_cache or any(key == p[4] for p in plans))
        z = zones if blur_zones != "auto" else "auto" if cached else resolve_blur_zones(  # over this crop's blur
            "auto", psf, shape, scheme, region=(br[0] + R0, br[1] + R0, br[2] + C0, br[3] + C0))  # region only
        plans.append(((R0, R1, C0, C1), br, (r0 - R0, r1 - R0, c0 - C0, c1 - C0), (centre[0] - R0, centre[1] - C0),
                       key, z, not cached))
    if progress_total is not None:
        progress_total(_crop_windows(plans, scheme, len(wells) * len(specs), chain))
    out = [[] for _ in wells]
    for k, ((r0, r1, c0, c1), ((R0, R1, C0, C1), br, rr, oc, key, z, _)) in enumerate(zip(boxes, plans)):
        sub = chain.scene_to_camera(read(R0, R1, C0, C1).to(dtype))
        blurred = None if blur_cache is None else blur_cache.get(key)
        if blurred is None:
            if isinstance(z, str):  # "auto", cached when planned and gone since: its zones chosen now
                z = resolve_blur_zones("auto", psf, shape, scheme, region=(br[0] + R0, br[1] + R0, br[2] + C0, br[3] + C0))
            blurred = blur_windowed(sub, psf, scheme=scheme, optical_center=oc, region=br, progress=progress, zones=z)
            if blur_cache is not None:
                blur_cache[key] = blurred
        crop = lambda t: t[..., rr[0]:rr[1], rr[2]:rr[3]].to(out_dtype)  # noqa: E731
        ci = crop(sub)
        field_deg = psf.geometry.box_field_angle(shape, (r0, r1, c0, c1))
        for i, fwc in enumerate(wells):
            e = fwc / peak
            g = torch.Generator(device=blurred.device).manual_seed(seed + k)
            if chain.develops:
                out[i].append(_chain_crop(chain, blurred, br, rr, (R0, C0), oc, e, fwc, g, crop, ci,
                                          (r0, r1, c0, c1), field_deg, specs, restoration_psf, scheme, progress, dtype))
                continue
            # the sensor image is the exposure itself: restored on the sub-array, the exposed blur region in it
            noisy = blurred.clone()
            reg = (slice(br[0], br[1]), slice(br[2], br[3]))
            noisy[..., reg[0], reg[1]] = chain.expose(blurred[..., reg[0], reg[1]], e, fwc, generator=g,
                                                      origin=(R0 + br[0], C0 + br[2]))
            cs_ = crop(noisy)
            res = CropResult((r0, r1, c0, c1), field_deg, {"ideal": ci, "blurred": crop(blurred), "sensor": cs_},
                             {"sensor": _score(ci, cs_)})
            noise = chain.noise_model(e, fwc)
            for spec in specs:
                restored = crop(restore(spec, noisy, restoration_psf, noise=noise, scheme=scheme, optical_center=oc,
                                        region=rr, progress=progress))
                res.images[spec.name], res.scores[spec.name] = restored, _score(ci, restored)
            out[i].append(res)
    return out if several else out[0]


def _crop_windows(plans, scheme: WindowScheme, restorations: int, chain: CameraChain) -> int:
    """The windows :func:`simulate_crops` will blur and restore for its ``plans`` (its ``progress`` adds up to this):
    each box's blur region (unless its blur is cached), and ``restorations`` times (full wells x methods) its crop, in
    the sub-array's pixels, in the camera chain's developed region, or in each of its four CFA planes
    (:meth:`pipeline.camera_chain.CameraChain.develop`, :func:`_chain_restorer`)."""
    n = 0
    for (R0, R1, C0, C1), br, rr, oc, key, z, blurs in plans:
        shape = (R1 - R0, C1 - C0)
        if blurs:
            n += window_count(shape, scheme, oc, zones=z, region=br)
        if not chain.develops:
            n += restorations * window_count(shape, scheme, oc, region=rr)
            continue
        h, w = br[1] - br[0], br[3] - br[2]
        ocb = (oc[0] - br[0], oc[1] - br[2])
        rb = (rr[0] - br[0], rr[1] - br[0], rr[2] - br[2], rr[3] - br[2])
        if chain.restore_on != "mosaic":
            n += restorations * window_count((h, w), scheme, ocb, region=rb)
            continue
        for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1)):
            ph, pw = (h - dy + 1) // 2, (w - dx + 1) // 2
            n += restorations * window_count((ph, pw), scheme, ((ocb[0] - dy) / 2, (ocb[1] - dx) / 2),
                                             region=_plane_region(rb, dy, dx, ph, pw))
    return n


def _plane_region(region, dy: int, dx: int, h: int, w: int):
    """The rows and columns ``region`` ``(r0, r1, c0, c1)`` of a frame covers in its CFA plane of offsets ``(dy, dx)``
    (``h`` x ``w`` plane pixels), a plane pixel of slack each side (which demosaicing reads)."""
    if region is None:
        return None
    return (max(-(-(region[0] - dy) // 2) - 1, 0), min(-(-(region[1] - dy) // 2) + 1, h),
            max(-(-(region[2] - dx) // 2) - 1, 0), min(-(-(region[3] - dx) // 2) + 1, w))


def _with_pixel_aperture(chain: CameraChain, psf: PSFProvider) -> PSFProvider:
    """``psf`` integrated over the chain's pixel aperture (its sensor's ``fill_factor``), for the blur and the
    restoration alike; unchanged without one."""
    if chain.sensor.fill_factor is None:
        return psf
    from lenssim.optics.pixel_aperture import PixelAperturePSF

    return PixelAperturePSF(psf, chain.sensor.fill_factor)


def _chain_restorer(chain: CameraChain, spec, psf, noise: NoiseModel, scheme, oc, region, progress, dtype):
    """``restore(image, plane)`` for :meth:`CameraChain.develop`: ``spec`` with ``psf`` on the RGB image (its optical
    centre ``oc`` and ``region`` in the array's pixels), or on a CFA plane with :class:`PlanePSF` (the same windows in
    the plane's pixels), the plane's centre and region (a plane pixel of slack each side, which demosaicing reads)."""
    def run(x, plane):
        if plane is None:
            return restore(spec, x.to(dtype), psf, noise=noise, scheme=scheme, optical_center=oc, region=region,
                           progress=progress).to(x.dtype)
        dy, dx, c = plane
        pr = _plane_region(region, dy, dx, *x.shape[-2:])
        pp = PlanePSF(psf, dy, dx, c if psf.channels > 1 else 0)
        return restore(spec, x.to(dtype), pp, noise=noise, scheme=scheme,
                       optical_center=((oc[0] - dy) / 2, (oc[1] - dx) / 2), region=pr, progress=progress).to(x.dtype)
    return run


def _chain_crop(chain, blurred, br, rr, corner, oc, e, fwc, g, crop, ci, box, field_deg, specs, restoration_psf,
                scheme, progress, dtype) -> "CropResult":
    """One crop through the camera chain: the blur region ``br`` of the sub-array (its corner ``corner`` in the
    frame) captured, developed and restored; ``rr`` the crop in the sub-array."""
    work = blurred[..., br[0]:br[1], br[2]:br[3]]
    origin = (corner[0] + br[0], corner[1] + br[2])
    raw = chain.capture(work, e, fwc, generator=g, origin=origin)
    units = chain.linearise(raw, e, fwc, origin=origin)
    gains = chain.white_balance_gains(units, origin=origin, channels=blurred.shape[1])
    ocb = (oc[0] - br[0], oc[1] - br[2])
    rb = (rr[0] - br[0], rr[1] - br[0], rr[2] - br[2], rr[3] - br[2])
    cut = lambda t: t[..., rb[0]:rb[1], rb[2]:rb[3]].to(ci.dtype)  # noqa: E731
    sensor_img = cut(chain.develop(units, gains=gains, origin=origin))
    res = CropResult(box, field_deg, {"ideal": ci, "blurred": crop(blurred), "sensor": sensor_img,
                                      "raw": raw[..., rb[0]:rb[1], rb[2]:rb[3]]}, {"sensor": _score(ci, sensor_img)})
    noise = chain.noise_model(e, fwc)
    for spec in specs:
        run = _chain_restorer(chain, spec, restoration_psf, noise, scheme, ocb, rb, progress, dtype)
        restored = cut(chain.develop(units, gains=gains, origin=origin, restore=run))
        res.images[spec.name], res.scores[spec.name] = restored, _score(ci, restored)
    return res


@dataclass
class FrameResult:
    sensor: torch.Tensor  # (B, C, H, W) linear, blurred + noise
    restored: torch.Tensor  # (B, C, H, W) linear, restored by `method` (with the first restoration provider)
    method: str  # restoration method (registry name)
    electrons_per_unit: float  # photo-electrons per unit of the linear image
    resumed: bool  # the sensor image came from the checkpoint
    seconds: dict  # wall-clock time of each stage run here
    restorations: dict = field(default_factory=dict)
    """``{tag: (B, C, H, W)}``: the frame restored with each provider of a ``restoration_psf`` mapping ``{tag:
    provider}`` (:func:`simulate_frame`), in its order, all from the one :attr:`sensor` image (the first is also
    :attr:`restored`); empty for one restoration provider."""
    raw: torch.Tensor | None = None
    """The camera chain's raw data (DN, ``(B, 1, H, W)`` under a CFA; electrons without an ADC) where the chain develops
    it (:attr:`pipeline.camera_chain.CameraChain.develops`); None where the sensor image is the exposure itself (the
    paper's sensor)."""

    def restored_images(self) -> dict:
        """The restored frames by image kind: ``{"restored": ...}``, or ``{"restored_TAG": ...}`` per tag of
        :attr:`restorations` (the names of their files and scores)."""
        if not self.restorations:
            return {"restored": self.restored}
        return {f"restored_{tag}": img for tag, img in self.restorations.items()}

    def restored_by_method(self) -> dict:
        """The restored frames keyed as crops key theirs: ``{method: ...}``, or ``{"METHOD@TAG": ...}`` per tag."""
        if not self.restorations:
            return {self.method: self.restored}
        return {f"{self.method}@{tag}": img for tag, img in self.restorations.items()}


def _fingerprint(ideal: torch.Tensor, params: dict) -> str:
    h = hashlib.blake2b(json.dumps(params, sort_keys=True).encode(), digest_size=16)
    h.update(ideal.detach().to("cpu").contiguous().numpy().tobytes())
    return h.hexdigest()


def _file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _provider_key(psf: PSFProvider):
    """A stable description of the provider's PSFs, or None if it has none (no resuming then)."""
    key = getattr(psf, "fingerprint", None)
    return key() if callable(key) else None


def simulate_frame(ideal: torch.Tensor, psf: PSFProvider, full_well: float, *, seed: int = 0,
                   scheme: WindowScheme = PAPER_SCHEME, method=FRAME_METHOD, sensor: Sensor | CameraChain,
                   progress=None, dtype: torch.dtype = torch.float32, checkpoint=None,
                   restoration_psf: PSFProvider | dict | None = None,
                   blur_zones: StrideZones | str | None = None) -> FrameResult:
    """The whole frame: blur with ``psf``, noise (seeded) and restoration by ``method`` (a name,
    ``"NAME:key=value,..."`` or a :class:`pipeline.restoration.Restoration`, as for crops; default
    :data:`FRAME_METHOD`) with the PSFs of ``restoration_psf`` (default ``psf``).

    ``restoration_psf`` may also be a mapping ``{tag: provider}`` (tags: letters, digits, ``_``; e.g.
    ``{"nominal": LensPSF(...), "calibrated": as_built}``): the frame is blurred and exposed once and the one
    noisy frame restored with each provider in turn (:attr:`FrameResult.restorations`; the first is also
    :attr:`FrameResult.restored`), each restoration equal to that of a run with that provider alone.

    Two passes of ``ceil((H-1)/stride + 1) x ceil((W-1)/stride + 1)`` windows (23,688 each at
    6000 x 4000 with the paper's scheme; one more restoration pass per further provider); ``progress(k)`` is
    called after every ``k`` windows.
    ``dtype``: working precision, as in :func:`simulate_crops`; images come back in ``ideal``'s dtype.

    ``checkpoint`` (a folder): after the first pass the sensor image (float EXR) and a stamp of the
    input and parameters are written there atomically; a later call with the same input and
    parameters resumes from them and runs the restoration only (not for providers without a
    :meth:`fingerprint`, e.g. :class:`lenssim.FunctionPSF`). The stamp holds the blur provider's fingerprint (for
    :class:`lenssim.AsBuiltPSF` the sampled lens's errors), so a sensor image is never taken from another lens; the
    restorations are always run again.

    ``sensor`` (a :class:`lenssim.Sensor` or a :class:`pipeline.camera_chain.CameraChain`) as for
    :func:`simulate_crops`: a chain that develops its raw data keeps them (:attr:`FrameResult.raw`) and its checkpoint
    holds them, developed again on resuming.

    ``blur_zones``: as for :func:`simulate_crops` (the blur only; the restoration keeps the scheme's stride).
    """
    from .io import ImageFileError, read_image, write_image

    check_scene(ideal, "ideal")
    check_provider(psf)
    chain = CameraChain.of(sensor)
    restoration_psf = _restoration_providers(psf, restoration_psf)
    psf = _with_pixel_aperture(chain, psf)
    restoration_psf = ({t: _with_pixel_aperture(chain, p) for t, p in restoration_psf.items()}
                       if isinstance(restoration_psf, dict) else _with_pixel_aperture(chain, restoration_psf))
    (method,) = check_methods((method,))
    full_well = check_full_well(full_well)
    method.check(scheme)
    if chain.cfa is not None and ideal.shape[1] != 3:
        raise ValueError(f"the sensor's {chain.cfa} colour filter array samples an RGB image; this one has "
                         f"{ideal.shape[1]} channel(s)")
    seconds = {}
    zones = resolve_blur_zones(blur_zones, psf, ideal.shape, scheme)
    pkey = _provider_key(psf)
    # the chain by its names where it does more than the sensor's read noise and ADC (the stamps of the paper's runs,
    # made before the chain was its one forward model, hold)
    params = {"psf": pkey, "full_well": float(full_well), "seed": int(seed), "sensor": chain.sensor.to_dict(),
              **({"chain": chain.to_dict()} if chain.develops or chain.sensor.chain_terms else {}),
              **({} if zones is None else {"blur_zones": zones.to_dict()}),
              "scheme": [scheme.window, scheme.stride, scheme.core, scheme.anchor, scheme.fit], "dtype": str(dtype),
              "shape": list(ideal.shape)}
    stamp_path = sensor_path = None
    if checkpoint is not None and pkey is not None:
        ck = Path(checkpoint)
        stamp_path, sensor_path = ck / "stamp.json", ck / "sensor_linear.exr"
        t0 = time.perf_counter()
        key = _fingerprint(ideal, params)
        seconds["fingerprint"] = time.perf_counter() - t0
        for stale in ck.glob(".*") if ck.exists() else []:  # temporaries of a killed run
            stale.unlink(missing_ok=True)
        if stamp_path.exists() and sensor_path.exists():
            try:
                stamp = json.loads(stamp_path.read_text())
            except (ValueError, OSError):
                stamp = {}
            stamp = stamp if isinstance(stamp, dict) else {}
            e_stamp = stamp.get("electrons_per_unit")
            if stamp.get("key") == key:
                if stamp.get("sensor_sha256") != _file_sha256(sensor_path):
                    warnings.warn(f"checkpoint {str(sensor_path)!r} does not match its stamp (changed or corrupted); "
                                  "computing the sensor image again", ResumeWarning, stacklevel=2)
                elif isinstance(e_stamp, bool) or not isinstance(e_stamp, (int, float)) or not (
                        math.isfinite(e_stamp) and e_stamp > 0):
                    warnings.warn(f"checkpoint stamp {str(stamp_path)!r} makes no sense (electrons_per_unit "
                                  f"{e_stamp!r}, not a positive number); computing the sensor image again",
                                  ResumeWarning, stacklevel=2)
                else:
                    try:
                        noisy, _ = read_image(sensor_path, what="checkpoint")
                    except ImageFileError as exc:  # unreadable now (e.g. the disk failed): computed again
                        warnings.warn(f"{exc}; computing the sensor image again", ResumeWarning, stacklevel=2)
                        noisy = torch.empty(0, device=HOST)
                    if chain.develops and tuple(noisy.shape) == _raw_shape(ideal.shape, chain):
                        if progress is not None:
                            progress(window_count(ideal.shape, scheme, zones=zones))
                        return _develop_frame(noisy.to(device=ideal.device, dtype=torch.float64), ideal, restoration_psf,
                                              method, chain, stamp["electrons_per_unit"], full_well, scheme, progress,
                                              seconds, dtype, resumed=True)
                    if not chain.develops and tuple(noisy.shape) == tuple(ideal.shape):
                        if progress is not None:
                            progress(window_count(ideal.shape, scheme, zones=zones))
                        return _restore_frame(noisy.to(device=ideal.device, dtype=dtype), ideal, restoration_psf, method,
                                              chain.noise_model(e_stamp, full_well), e_stamp, scheme, progress, seconds,
                                              resumed=True)
    t0 = time.perf_counter()
    scene = chain.scene_to_camera(ideal.to(dtype))
    blurred = blur_windowed(scene, psf, scheme=scheme, progress=progress, zones=zones)
    del scene
    seconds["blur"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    e = full_well / float(blurred.amax())
    g = torch.Generator(device=blurred.device).manual_seed(int(seed))
    if chain.develops:
        raw = chain.capture(blurred, e, full_well, generator=g)
        del blurred
        seconds["noise"] = time.perf_counter() - t0
        if sensor_path is not None:
            write_image(sensor_path, raw.to(torch.float32), bits="float", exr_compression=CHECKPOINT_EXR_COMPRESSION)
            atomic_write_text(stamp_path, json.dumps({"key": key, "electrons_per_unit": e,
                                                      "sensor_sha256": _file_sha256(sensor_path), **params}, indent=2))
        return _develop_frame(raw, ideal, restoration_psf, method, chain, e, full_well, scheme, progress, seconds,
                              dtype, resumed=False)
    noisy = chain.expose(blurred, e, full_well, generator=g)
    del blurred
    seconds["noise"] = time.perf_counter() - t0
    if sensor_path is not None:
        write_image(sensor_path, noisy, bits="float", exr_compression=CHECKPOINT_EXR_COMPRESSION)
        atomic_write_text(stamp_path, json.dumps({"key": key, "electrons_per_unit": e,
                                                  "sensor_sha256": _file_sha256(sensor_path), **params}, indent=2))
    return _restore_frame(noisy, ideal, restoration_psf, method, chain.noise_model(e, full_well), e, scheme, progress,
                          seconds, resumed=False)


def crops_from_frame(ideal: torch.Tensor, frame: FrameResult, boxes, geometry: FieldGeometry) -> list[CropResult]:
    """:class:`CropResult` for boxes ``(r0, r1, c0, c1)`` cut from a full-frame :class:`FrameResult`: the restored
    images keyed by the method's name, or ``METHOD@TAG`` per restoration provider of a tagged frame
    (:meth:`FrameResult.restored_by_method`), and the frame's raw data under the box (``"raw"``, as
    :func:`simulate_crops` gives it) when the frame has a camera chain's."""
    out = []
    for box in boxes:
        r0, r1, c0, c1 = box
        cut = lambda t: t[..., r0:r1, c0:c1]  # noqa: E731
        ci, cs_ = cut(ideal), cut(frame.sensor)
        res = CropResult(tuple(box), geometry.box_field_angle(ideal.shape, box), {"ideal": ci, "sensor": cs_},
                         {"sensor": _score(ci, cs_)})
        if frame.raw is not None:
            res.images["raw"] = cut(frame.raw)
        for kind, img in frame.restored_by_method().items():
            res.images[kind] = cr = cut(img)
            res.scores[kind] = _score(ci, cr)
        out.append(res)
    return out


def _restoration_providers(psf: PSFProvider, restoration_psf) -> PSFProvider | dict:
    """``restoration_psf`` checked: ``psf`` when None, a provider, or a non-empty mapping ``{tag: provider}`` whose
    tags are file-name parts (letters, digits, ``_``)."""
    if restoration_psf is None:
        return psf
    if not isinstance(restoration_psf, Mapping):
        return check_provider(restoration_psf, "restoration_psf")
    if not restoration_psf:
        raise ValueError("restoration_psf is an empty mapping: give at least one {tag: provider}")
    out = {}
    for tag, prov in restoration_psf.items():
        if not isinstance(tag, str) or not tag or not all(ch.isascii() and (ch.isalnum() or ch == "_") for ch in tag):
            raise ValueError(f"restoration_psf tag {tag!r} is not allowed: letters, digits and _ (it names files)")
        out[tag] = check_provider(prov, f"restoration_psf[{tag!r}]")
    return out


def _restore_frame(noisy, ideal, psf, method, noise: NoiseModel, e, scheme, progress, seconds, resumed) -> FrameResult:
    """Restore the one noisy frame with ``psf`` (a provider, or ``{tag: provider}``: each in turn), assuming ``noise``."""
    t0 = time.perf_counter()
    several = isinstance(psf, dict)
    restored = {}
    for tag, prov in (psf.items() if several else [("", psf)]):
        restored[tag] = restore(method, noisy, prov, noise=noise, scheme=scheme, progress=progress).to(ideal.dtype)
    seconds["restore"] = time.perf_counter() - t0
    first = next(iter(restored.values()))
    return FrameResult(noisy.to(ideal.dtype), first, method.name, e, resumed, seconds,
                       restored if several else {})


def _raw_shape(shape, chain: CameraChain) -> tuple:
    """The shape of a chain's raw data for an image of ``shape`` ``(B, C, H, W)``."""
    return (shape[0], 1 if chain.cfa else shape[1], *shape[-2:])


def _develop_frame(raw, ideal, psf, method, chain: CameraChain, e, full_well, scheme, progress, seconds, dtype,
                   resumed) -> FrameResult:
    """The chain's raw frame developed (the sensor image) and developed with restoration by each provider."""
    t0 = time.perf_counter()
    units = chain.linearise(raw, e, full_well)
    gains = chain.white_balance_gains(units, channels=ideal.shape[1])
    sensor_img = chain.develop(units, gains=gains).to(ideal.dtype)
    seconds["develop"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    noise = chain.noise_model(e, full_well)
    several = isinstance(psf, dict)
    restored = {}
    for tag, prov in (psf.items() if several else [("", psf)]):
        run = _chain_restorer(chain, method, prov, noise, scheme, None, None, progress, dtype)
        restored[tag] = chain.develop(units, gains=gains, restore=run).to(ideal.dtype)
    seconds["restore"] = time.perf_counter() - t0
    first = next(iter(restored.values()))
    return FrameResult(sensor_img, first, method.name, e, resumed, seconds, restored if several else {}, raw=raw)


FRAME_WORKING_COPIES = 12
"""Frame-sized float32 buffers a whole-frame simulation and its scoring hold at their peak (measured 3.4 GiB at
24 MP, 3 channels)."""

FRAME_COPIES_PER_EXTRA_RESTORATION = 1
"""Frame-sized float32 buffers each further restored frame adds (``restoration_psf`` as a mapping): the restored
frame, held while the next restoration runs and until it is scored; the restoration's own working buffers are
freed between restorations."""

MAP_TILE_PX = 256
"""Side (px) of the tiles of a frame's PSNR map."""


def frame_memory_bytes(shape, restorations: int = 1, method="wiener", scheme: WindowScheme = PAPER_SCHEME) -> int:
    """Memory (bytes) that :func:`simulate_frame` and :func:`score_frame` plan for an ideal image of ``shape``
    ``(B, C, H, W)`` in float32, with ``restorations`` restored frames (the providers of ``restoration_psf``) by
    ``method`` (as for :func:`simulate_frame`) in the windows of ``scheme``: :data:`FRAME_WORKING_COPIES` (measured
    with the adaptive Wiener) plus what the method holds beyond the Wiener
    (:meth:`pipeline.restoration.Restoration.memory_bytes`; once: the restorations run in turn, each freeing its
    working buffers). A method restores the whole frame at once (its region is the frame: no tiles), so an iterative
    method on the blur's operator holds image-sized buffers and the operator's kept OTFs (up to 1 GiB).

    Measured on ``lenssim simulate --full-frame --restore NAME`` (E2E design, colour, paper windows 512/32/64; a fresh
    process per method; the peak resident set during the restoration over that at its start, beyond the Wiener's, MiB)
    against the method's plan: at 512 x 512 px Richardson-Lucy 212.6 (planned 1173), tv 229.6 (1197), pnp 314.1
    (1215), pnp wavelet 258.6 (1191), Tikhonov -4.2 (15); at 1024 x 1024 Richardson-Lucy 926.6 (1357; its kept OTFs
    554), tv 997.8 (1453); at 2048 x 2048 (the OTFs made again on every pass, kept none) Richardson-Lucy 841.3 (1960;
    2 iterations), pnp 1326.4 (2632; 1 iteration; 1608 without the OTFs' allowance). Below glibc's 32 MiB mmap
    ceiling (frames under ~2.8 MP in colour) freed frame-sized buffers stay resident, which the operator's 1 GiB
    allowance covered at these sizes; the methods' own buffers were measured with the threshold fixed (their
    docstrings), as large frames' buffers behave."""
    restorations = check_int("restorations", restorations, 1)
    n = math.prod(int(v) for v in shape)
    copies = FRAME_WORKING_COPIES + FRAME_COPIES_PER_EXTRA_RESTORATION * (restorations - 1)
    return copies * n * 4 + Restoration.of(method).memory_bytes(shape, scheme)


def score_frame(ideal: torch.Tensor, frame: FrameResult, geometry: FieldGeometry, *, tile: int = MAP_TILE_PX,
                on_encoded=None) -> dict:
    """Whole-frame scores of a :class:`FrameResult` against ``ideal`` (linear ``(1, C, H, W)``): PSNR and SSIM in
    sRGB of the sensor and the restored images, their PSNR maps over ``tile`` px tiles and the tiles' field
    angles (deg, in ``geometry``). Each image is sRGB-encoded once; ``on_encoded(kind, encoded, linear)`` (kind
    ``"sensor"`` or ``"restored"``, encoded ``(1, C, H, W)`` float32 on the device) may write it meanwhile: it runs in a
    worker thread while that image is scored (one image at a time; an error it raises is raised here). Returns
    ``{"psnr_sensor_db", "psnr_restored_db", "ssim_sensor", "ssim_restored", "maps": {"sensor_db", "restored_db",
    "field_deg"}, "seconds": {"write", "metrics"}}`` (``write``: the callbacks' own time, overlapping the metrics'). A
    frame restored with several providers (:attr:`FrameResult.restorations`) has kind ``"restored_TAG"`` for each in
    place of ``"restored"``: ``psnr_restored_TAG_db``, ``ssim_restored_TAG`` and the map ``restored_TAG_db``.
    """
    from concurrent.futures import ThreadPoolExecutor

    from .quality import encode_srgb, scores_encoded

    if min(ideal.shape[-2:]) < tile:
        raise ValueError(f"a frame of {ideal.shape[-1]} x {ideal.shape[-2]} px is smaller than one {tile}-px tile of "
                         "the PSNR map")
    seconds = {"write": 0.0, "metrics": 0.0}

    def timed_write(kind, enc, img):
        t0 = time.perf_counter()
        on_encoded(kind, enc, img)
        seconds["write"] += time.perf_counter() - t0

    ref = encode_srgb(ideal)
    scores = {}
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="write") as pool:
        writing = None
        for kind, img in {"sensor": frame.sensor, **frame.restored_images()}.items():
            enc = encode_srgb(img)
            if on_encoded is not None:  # written (PNG compression, one core) while the scores run on the others
                writing = pool.submit(timed_write, kind, enc, img)
            t1 = time.perf_counter()
            scores[kind] = scores_encoded(ref, enc, tile=tile)
            seconds["metrics"] += time.perf_counter() - t1
            del enc
            if writing is not None:  # before the next image is encoded: at most one encoded frame being written
                writing.result()
    return {**{f"psnr_{k}_db": v["psnr_db"] for k, v in scores.items()},
            **{f"ssim_{k}": v["ssim"] for k, v in scores.items()},
            "maps": {**{f"{k}_db": v["psnr_map_db"] for k, v in scores.items()},
                     "field_deg": geometry.tile_field_angles(ideal.shape, tile)},
            "seconds": seconds}
