"""Spatially-variant blur by local convolutions in overlapping windows (paper Section 3.3).

Window centres lie on a grid of step ``stride`` (pixels). Around each centre a ``window`` x
``window`` patch of the (reflect-padded) image is convolved, by FFT, with the PSF *at that centre*
(from a PSF provider, :mod:`lenssim.psf_provider`: the lens model with exact pupil rotation, or
measured PSFs); only the central ``core`` x ``core`` of the
result is kept, weighted by a separable tent of half-width ``core / 2`` and blended with its
neighbours. With the paper's scheme (512, 32, 64) the tents form a partition of unity, so every
pixel is a linear interpolation of the 2 x 2 nearest local convolutions. Weights are normalised by
their sum in any case. The PSF must fit in the window: its extent plus the core must stay within
``window`` or the circular convolution would wrap into the core (checked).

Geometry: image rows/columns are ``y``/``x`` in the image plane (:class:`lenssim.FieldGeometry`);
``optical_center`` (row, col) in pixels of this array, default the array centre. Crops of a
larger frame pass the crop's offset so each window gets the PSF of its true field position. A
provider may give one PSF for all channels or one per channel (``(P, C, n, n)``, e.g. colour).

Tensor contract: ``(B, C, H, W)`` linear float in, same shape out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lenssim import PSFProvider, frame_center

from .checks import check_image, check_provider

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


def _pad(image: torch.Tensor, p: int) -> torch.Tensor:
    """Reflect padding (edge replication where the image is smaller than the pad)."""
    mode = "reflect" if p < min(image.shape[-2:]) else "replicate"
    return torch.nn.functional.pad(image, (p, p, p, p), mode=mode)


def core_irfft2(spectrum: torch.Tensor, window: int, core: int) -> torch.Tensor:
    """The central ``core x core`` of ``irfft2(spectrum, s=(window, window))``, ``(*, core, core)``.

    Pruned inverse: the row transform runs on all columns but only the ``core`` rows that are kept go
    through the column transform (~3x faster than the full inverse for the paper's 512 / 64).
    """
    lo = window // 2 - core // 2
    rows = torch.fft.ifft(spectrum, dim=-2)[..., lo:lo + core, :]
    return torch.fft.irfft(rows, n=window, dim=-1)[..., lo:lo + core]


def apply_windowed(image: torch.Tensor, psf: PSFProvider, op, *, scheme: WindowScheme = PAPER_SCHEME,
                   optical_center=None, region=None, chunk: int | None = None, progress=None) -> torch.Tensor:
    """Run ``op(patches, otf)`` in every window and blend the cores (the machinery of :func:`blur_windowed`).

    ``patches`` is ``(k, B, C, window, window)`` (image rows ``y - window/2 .. y + window/2 - 1`` around each
    centre ``y``), ``otf`` is ``(k, 1, 1 or C, window, window/2 + 1)`` (``rfft2`` of the PSF at the centre,
    moved to ``[0, 0]``; one for all channels or one per channel), broadcasting against the patches;
    ``op`` returns either processed patches of the same shape (real), whose central ``core`` is kept, or
    their spectra (complex, ``rfft2`` layout), of which only the core is inverse transformed
    (:func:`core_irfft2`).
    """
    check_image(image)
    check_provider(psf)
    B, C, H, W = image.shape
    if psf.channels not in (1, C):
        raise ValueError(f"the PSF provider has {psf.channels} channels and the image {C}: expected 1 or {C}")
    center = optical_center if optical_center is not None else frame_center(image.shape)
    r0, r1, c0, c1 = region if region is not None else (0, H, 0, W)
    win, half, core = scheme.window, scheme.window // 2, scheme.core
    cy, cx = window_centres(H, scheme.stride), window_centres(W, scheme.stride)
    cy = cy[(cy + core // 2 > r0) & (cy - core // 2 < r1)]
    cx = cx[(cx + core // 2 > c0) & (cx - core // 2 < c1)]
    Y, X = torch.meshgrid(cy, cx, indexing="ij")
    Y, X = Y.flatten(), X.flatten()
    need = psf.extent_px(Y, X, center)
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
        # the PSFs with their centre at [0, 0], computed in the image's precision
        psfs = psf.psf_at_pixels(ys, xs, center, win, centered=False, dtype=image.dtype, device=image.device)
        otf = torch.fft.rfft2(psfs.to(dtype=image.dtype, device=image.device))
        otf = otf[:, None, None] if otf.ndim == 3 else otf[:, None]  # (k, 1, 1 or C, win, win/2+1)
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


def blur_windowed(image: torch.Tensor, psf: PSFProvider, *, scheme: WindowScheme = PAPER_SCHEME,
                  optical_center=None, region=None, chunk: int | None = None, progress=None) -> torch.Tensor:
    """Blur ``image`` ``(B, C, H, W)`` with the spatially-variant PSF of the provider ``psf``.

    ``region = (r0, r1, c0, c1)`` computes only those output pixels (others are zero), using only
    the windows whose cores touch it. ``progress(k)`` is called after each chunk of ``k`` windows
    (``chunk``: default 8 on a CPU, 32 on a GPU). Runs on ``image``'s device and in its dtype.
    """
    def convolve(patches, otf):
        return torch.fft.rfft2(patches) * otf

    return apply_windowed(image, psf, convolve, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress)


def blur_exact(image: torch.Tensor, psf: PSFProvider, rows, cols, *, n: int = 512, optical_center=None) -> torch.Tensor:
    """Reference: each listed output pixel with the PSF of its own position (``(B, C, P)``).

    ``out(p) = sum_d PSF_p(d) x(p - d)`` over the ``n x n`` PSF support, reflect padding at the edges.
    """
    check_image(image)
    check_provider(psf)
    B, C, H, W = image.shape
    center = optical_center if optical_center is not None else frame_center(image.shape)
    rows, cols = torch.as_tensor(rows), torch.as_tensor(cols)
    c = n // 2
    padded = _pad(image, c)
    out = torch.empty(B, C, rows.numel(), dtype=image.dtype, device=image.device)
    for k in range(0, rows.numel(), 16):
        rr, cc = rows[k:k + 16], cols[k:k + 16]
        psfs = psf.psf_at_pixels(rr, cc, center, n).to(dtype=image.dtype, device=image.device)
        if psfs.ndim == 3:
            psfs = psfs[:, None]  # (P, 1 or C, n, n)
        for j, (r, q) in enumerate(zip(rr.tolist(), cc.tolist())):
            # x(p - d) for d = (i - c, j - c): the patch rows r + c - (i - c) = r + 2c - i, i = 0..n-1
            patch = padded[:, :, r + 1: r + n + 1, q + 1: q + n + 1].flip(-2, -1)
            out[:, :, k + j] = (patch * psfs[j]).sum(dim=(-2, -1))  # psfs[j]: (1 or C, n, n)
    return out
