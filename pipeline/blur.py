"""Spatially-variant blur by local convolutions in overlapping windows (paper Section 3.3).

Window centres lie on a grid of step ``stride`` (pixels). Around each centre a ``window`` x
``window`` patch of the (reflect-padded) image is convolved, by FFT, with the PSF *at that centre*
(from :func:`lenssim.psf_at`, exact pupil rotation); only the central ``core`` x ``core`` of the
result is kept, weighted by a separable tent of half-width ``core / 2`` and blended with its
neighbours. With the paper's scheme (512, 32, 64) the tents form a partition of unity, so every
pixel is a linear interpolation of the 2 x 2 nearest local convolutions. Weights are normalised by
their sum in any case. The PSF must fit in the window: its extent plus the core must stay within
``window`` or the circular convolution would wrap into the core (checked).

Geometry: image rows/columns are ``y``/``x`` in the image plane, pixel pitch ``lens.pixel_pitch_um``;
``optical_center`` (row, col) in pixels of this array, default the array centre. Crops of a
larger frame pass the crop's offset so each window gets the PSF of its true field position.

Tensor contract: ``(B, C, H, W)`` linear float in, same shape out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lenssim import ThinLens, max_wavefront_slope, psf_at, wavefront_coefficients

__all__ = ["WindowScheme", "PAPER_SCHEME", "window_centres", "window_count", "tent_weights", "core_irfft2", "apply_windowed",
           "blur_windowed", "blur_exact"]


@dataclass(frozen=True)
class WindowScheme:
    """Local-convolution windows: ``window`` (px, even), centre ``stride`` (px) and blended ``core`` (px)."""

    window: int = 512
    stride: int = 32
    core: int = 64

    def __post_init__(self):
        for name in ("window", "stride", "core"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v > 0 and v % 2 == 0):
                raise ValueError(f"{name}={v!r} is not allowed: a positive even number of pixels")
        if not self.stride <= self.core <= self.window:
            raise ValueError(f"stride={self.stride}, core={self.core}, window={self.window}: need stride <= core <= window")


PAPER_SCHEME = WindowScheme()


def window_centres(length: int, stride: int) -> torch.Tensor:
    """Centres ``0, stride, 2 stride, ...`` up to the first one at or beyond ``length - 1``."""
    return torch.arange(0, (length - 1) + stride, stride)[: int(math.ceil((length - 1) / stride)) + 1]


def window_count(shape, scheme: WindowScheme | None = None) -> int:
    """Number of windows over an image of ``shape`` ``(..., H, W)`` (one pass of :func:`apply_windowed`)."""
    stride = (scheme or PAPER_SCHEME).stride
    return len(window_centres(shape[-2], stride)) * len(window_centres(shape[-1], stride))


def tent_weights(core: int, dtype=torch.float64) -> torch.Tensor:
    """1-D tent over the core: ``1 - |d| / (core/2)`` at offsets ``d = -core/2 .. core/2 - 1``."""
    d = torch.arange(-core // 2, core // 2, dtype=dtype)
    return (1 - d.abs() / (core / 2)).clamp_min(0)


def _check_image(image: torch.Tensor) -> None:
    if not isinstance(image, torch.Tensor) or image.ndim != 4 or not image.is_floating_point():
        shape = tuple(image.shape) if isinstance(image, torch.Tensor) else type(image).__name__
        raise ValueError(f"image has shape {shape}: expected a floating tensor (B, C, H, W)")


def _pad(image: torch.Tensor, p: int) -> torch.Tensor:
    """Reflect padding (edge replication where the image is smaller than the pad)."""
    mode = "reflect" if p < min(image.shape[-2:]) else "replicate"
    return torch.nn.functional.pad(image, (p, p, p, p), mode=mode)


def _psfs_at_pixels(lens, s, Q, rows, cols, center, n, *, centered: bool = True, dtype=None, device=None):
    """PSFs ``(P, n, n)`` at pixel positions ``(rows, cols)`` of the array (``dtype``: see :func:`lenssim.psf`)."""
    pitch_mm = lens.pixel_pitch_um * 1e-3
    y_mm = (rows.to(dtype=torch.float64, device=device) - center[0]) * pitch_mm
    x_mm = (cols.to(dtype=torch.float64, device=device) - center[1]) * pitch_mm
    p, _ = psf_at(lens, torch.full_like(y_mm, s), torch.full_like(y_mm, Q), x_mm, y_mm, n=n, centered=centered,
                  dtype=dtype)
    return p


def _required_size(lens, s, Q, rows, cols, center, margin_px: int = 16) -> int:
    """Largest PSF diameter (px) over the given positions: geometric ``2 G lambda f / (y Delta)`` + margin."""
    pitch_mm = lens.pixel_pitch_um * 1e-3
    r = torch.hypot((rows.double() - center[0]) * pitch_mm, (cols.double() - center[1]) * pitch_mm)
    a = torch.rad2deg(torch.atan(r / lens.focal_length_mm))
    c = wavefront_coefficients(lens, torch.full_like(a, s), torch.full_like(a, Q), a, elementwise=True)
    G = float(max_wavefront_slope(c).max())
    half = G * lens.wavelength_um * lens.focal_length_mm / (lens.pupil_radius_mm * lens.pixel_pitch_um)
    return int(math.ceil(2 * half)) + margin_px


def core_irfft2(spectrum: torch.Tensor, window: int, core: int) -> torch.Tensor:
    """The central ``core x core`` of ``irfft2(spectrum, s=(window, window))``, ``(*, core, core)``.

    Pruned inverse: the row transform runs on all columns but only the ``core`` rows that are kept go
    through the column transform (~3x faster than the full inverse for the paper's 512 / 64).
    """
    lo = window // 2 - core // 2
    rows = torch.fft.ifft(spectrum, dim=-2)[..., lo:lo + core, :]
    return torch.fft.irfft(rows, n=window, dim=-1)[..., lo:lo + core]


def apply_windowed(image: torch.Tensor, lens: ThinLens, s: float, Q: float, op, *, scheme: WindowScheme = PAPER_SCHEME,
                   optical_center=None, region=None, chunk: int | None = None, progress=None, psf_fn=None) -> torch.Tensor:
    """Run ``op(patches, otf)`` in every window and blend the cores (the machinery of :func:`blur_windowed`).

    ``patches`` is ``(k, B, C, window, window)`` (image rows ``y - window/2 .. y + window/2 - 1`` around each
    centre ``y``), ``otf`` is ``(k, window, window/2 + 1)`` (``rfft2`` of the centred PSF at the centre);
    ``op`` returns either processed patches of the same shape (real), whose central ``core`` is kept, or
    their spectra (complex, ``rfft2`` layout), of which only the core is inverse transformed
    (:func:`core_irfft2`).
    """
    _check_image(image)
    B, C, H, W = image.shape
    center = (optical_center if optical_center is not None else ((H - 1) / 2, (W - 1) / 2))
    r0, r1, c0, c1 = region if region is not None else (0, H, 0, W)
    win, half, core = scheme.window, scheme.window // 2, scheme.core
    cy, cx = window_centres(H, scheme.stride), window_centres(W, scheme.stride)
    cy = cy[(cy + core // 2 > r0) & (cy - core // 2 < r1)]
    cx = cx[(cx + core // 2 > c0) & (cx - core // 2 < c1)]
    Y, X = torch.meshgrid(cy, cx, indexing="ij")
    Y, X = Y.flatten(), X.flatten()
    need = _required_size(lens, s, Q, Y, X, center) if psf_fn is None else 0
    if need + core > win:
        raise ValueError(f"the PSF spans {need} px but window={win} leaves room for only {win - core} beside the "
                         f"{core}-px core: use a larger window")
    if chunk is None:  # windows per batch: enough to fill a GPU, few enough for a CPU's caches
        chunk = 32 if image.device.type == "cuda" else 8
    pad = half + core
    padded = _pad(image, pad)
    out = torch.zeros(B, C, H + 2 * core, W + 2 * core, dtype=image.dtype, device=image.device)
    wsum = torch.zeros(H + 2 * core, W + 2 * core, dtype=image.dtype, device=image.device)
    tent = tent_weights(core, image.dtype).to(image.device)
    tent2 = tent[:, None] * tent[None, :]
    for k in range(0, Y.numel(), chunk):
        ys, xs = Y[k:k + chunk], X[k:k + chunk]
        if psf_fn is not None:
            psfs = torch.fft.ifftshift(psf_fn(ys, xs, win).to(dtype=image.dtype, device=image.device), dim=(-2, -1))
        else:  # the model's PSF with its centre at [0, 0], computed in the image's precision
            psfs = _psfs_at_pixels(lens, s, Q, ys, xs, center, win, centered=False, dtype=image.dtype,
                                   device=image.device)
        otf = torch.fft.rfft2(psfs)
        patches = torch.stack([padded[:, :, y + pad - half: y + pad + half, x + pad - half: x + pad + half]
                               for y, x in zip(ys.tolist(), xs.tolist())])  # (k, B, C, win, win)
        res = op(patches, otf)
        if res.is_complex():
            cores = core_irfft2(res, win, core)
        else:
            cores = res[..., half - core // 2: half + core // 2, half - core // 2: half + core // 2]
        for j, (y, x) in enumerate(zip(ys.tolist(), xs.tolist())):
            sl = (slice(y + core - core // 2, y + core + core // 2), slice(x + core - core // 2, x + core + core // 2))
            out[:, :, sl[0], sl[1]] += cores[j] * tent2
            wsum[sl[0], sl[1]] += tent2
        if progress is not None:
            progress(len(ys))
    out = out[:, :, core:core + H, core:core + W]
    wsum = wsum[core:core + H, core:core + W]
    result = torch.zeros_like(image)
    result[:, :, r0:r1, c0:c1] = out[:, :, r0:r1, c0:c1] / wsum[r0:r1, c0:c1]
    return result


def blur_windowed(image: torch.Tensor, lens: ThinLens, s: float, Q: float, *, scheme: WindowScheme = PAPER_SCHEME,
                  optical_center=None, region=None, chunk: int | None = None, progress=None, psf_fn=None) -> torch.Tensor:
    """Blur ``image`` ``(B, C, H, W)`` with the lens ``(s, Q)``'s spatially-variant PSF.

    ``region = (r0, r1, c0, c1)`` computes only those output pixels (others are zero), using only
    the windows whose cores touch it. ``progress(k)`` is called after each chunk of ``k`` windows
    (``chunk``: default 8 on a CPU, 32 on a GPU). Runs on ``image``'s device and in its dtype.
    ``psf_fn(rows, cols, n) -> (P, n, n)`` replaces the lens model (e.g. measured PSFs; centred,
    unit sum); ``lens``, ``s``, ``Q`` then only set the pixel pitch.
    """
    def convolve(patches, otf):
        return torch.fft.rfft2(patches) * otf[:, None, None]

    return apply_windowed(image, lens, s, Q, convolve, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress, psf_fn=psf_fn)


def blur_exact(image: torch.Tensor, lens: ThinLens, s: float, Q: float, rows, cols, *, n: int = 512,
               optical_center=None, psf_fn=None) -> torch.Tensor:
    """Reference: each listed output pixel with the PSF of its own position (``(B, C, P)``).

    ``out(p) = sum_d PSF_p(d) x(p - d)`` over the ``n x n`` PSF support, reflect padding at the edges.
    """
    _check_image(image)
    B, C, H, W = image.shape
    center = (optical_center if optical_center is not None else ((H - 1) / 2, (W - 1) / 2))
    rows, cols = torch.as_tensor(rows), torch.as_tensor(cols)
    c = n // 2
    padded = _pad(image, c)
    out = torch.empty(B, C, rows.numel(), dtype=image.dtype, device=image.device)
    for k in range(0, rows.numel(), 16):
        rr, cc = rows[k:k + 16], cols[k:k + 16]
        psfs = (psf_fn(rr, cc, n) if psf_fn is not None else _psfs_at_pixels(lens, s, Q, rr, cc, center, n))
        psfs = psfs.to(dtype=image.dtype, device=image.device)
        for j, (r, q) in enumerate(zip(rr.tolist(), cc.tolist())):
            # x(p - d) for d = (i - c, j - c): the patch rows r + c - (i - c) = r + 2c - i, i = 0..n-1
            patch = padded[:, :, r + 1: r + n + 1, q + 1: q + n + 1].flip(-2, -1)
            out[:, :, k + j] = (patch * psfs[j]).sum(dim=(-2, -1))
    return out
