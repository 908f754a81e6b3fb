"""Image quality against the ideal image, in the gamma-encoded (sRGB) space as the paper reports.

PSNR and SSIM with scikit-image's definitions (``data_range = 1``; SSIM over 7 x 7 uniform windows with the sample
covariance, the 3 px border left out, the mean over channels), over the whole frame or a crop ``(r0, r1, c0, c1)``.
Inputs are linear ``(1, C, H, W)`` tensors in [0, 1], clipped to [0, 1] and sRGB-encoded first.

Two scorers compute them (:data:`SCORERS`, chosen with :func:`validate_scorer`):

* ``"kornia"`` (default): on the images' own device, with kornia (``kornia.color.linear_rgb_to_rgb`` for the sRGB
  curve; SSIM's local moments as box sums of shifted tensor views, PSNR's MSE in float64), so a CUDA run never copies
  a frame to the host to score it. Equal to scikit-image's numbers to float32 rounding (tested: PSNR 1e-6 dB relative,
  SSIM 2e-6); measured faster on this CPU too (``benchmarks/bench_kornia.py``).
* ``"skimage"``: scikit-image's ``peak_signal_noise_ratio`` / ``structural_similarity`` on host arrays encoded by
  colour-science (:func:`pipeline.colour_space.linear_to_srgb`): the reference.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from lenssim.registry import Registry

from .checks import check_image
from .colour_space import linear_to_srgb

__all__ = ["SCORERS", "DEFAULT_SCORER", "Scorer", "validate_scorer", "encode_srgb", "psnr_srgb", "ssim_srgb",
           "psnr_map_srgb", "scores_encoded", "SSIM_WINDOW_PX", "SSIM_K1", "SSIM_K2"]

SSIM_WINDOW_PX = 7
"""SSIM's uniform window (px): scikit-image's default (its ``win_size``)."""

SSIM_K1, SSIM_K2 = 0.01, 0.03
"""SSIM's constants: ``C1 = (K1 L)^2``, ``C2 = (K2 L)^2`` with the data range ``L = 1`` (Wang et al. 2004)."""

SSIM_BAND_ROWS = 128
"""Rows per band of the kornia scorer's encoding, PSNR and SSIM (each SSIM band carries the window's 3 px halo): their
temporaries stay a band's size on 24 MP frames (about 150 MB in colour for SSIM). Measured on a 24 MP colour pair here: SSIM 2.8 s in
128-row bands, 3.1 s in 256, 4.2 s in 512 (the smaller bands stay in cache)."""


SSIM_FLOAT64_MAX_VALUES = 2**23
"""Images of at most this many values (about 2.8 MP in colour: every crop) get SSIM's moments in float64; larger
frames in float32 bands (2.2x faster here), about each band's mean (within 2e-9 of float64, tested)."""


@dataclass(frozen=True)
class Scorer:
    """How images are encoded and scored: ``encode(linear (1, C, H, W)) -> sRGB (1, C, H, W) float32`` on the image's
    device, ``psnr(a, b) -> dB``, ``ssim(a, b)`` and ``mse_tiles(a, b, tile) -> (rows, cols) float64`` on encoded
    images."""

    name: str
    encode: Callable
    psnr: Callable
    ssim: Callable
    mse_tiles: Callable
    description: str = ""


SCORERS = Registry("scorer")
"""Scorers by name: ``kornia`` (on the device) and ``skimage`` (the reference, on the host)."""

DEFAULT_SCORER = "kornia"
"""The scorer used unless one is named (measured: ``benchmarks/bench_kornia.py``)."""


def validate_scorer(name: str | None) -> Scorer:
    """The scorer ``name`` (``None``: :data:`DEFAULT_SCORER`); ``ValueError`` listing the valid names otherwise."""
    return SCORERS.validate(DEFAULT_SCORER if name is None else name)


# -- kornia: on the device --------------------------------------------------------------------------------------


def _encode_kornia(x: torch.Tensor) -> torch.Tensor:
    """kornia's sRGB curve in bands of :data:`SSIM_BAND_ROWS` rows (its temporaries stay a band's size)."""
    from kornia.color import linear_rgb_to_rgb

    B, C, H, W = x.shape
    out = torch.empty(x.shape, dtype=torch.float32, device=x.device)
    for r0 in range(0, H, SSIM_BAND_ROWS):
        band = x[:, :, r0:r0 + SSIM_BAND_ROWS].clamp(0, 1).to(torch.float32)
        if C == 3:
            out[:, :, r0:r0 + SSIM_BAND_ROWS] = linear_rgb_to_rgb(band)
        else:  # the curve is per value: any channel count through kornia's 3-channel function
            h = band.shape[-2]
            out[:, :, r0:r0 + SSIM_BAND_ROWS] = linear_rgb_to_rgb(
                band.reshape(B * C, 1, h, W).expand(-1, 3, -1, -1))[:, :1].reshape(B, C, h, W)
    return out


def _psnr_kornia(a: torch.Tensor, b: torch.Tensor) -> float:
    """``10 log10(1 / MSE)``, the MSE accumulated in float64 (``kornia.metrics.psnr`` averages in the images' float32:
    its last digits moved with the thread count, past the regression pins' tolerance)."""
    if torch.equal(a, b):
        return float("inf")
    sse = sum(float((a[..., r0:r0 + SSIM_BAND_ROWS, :] - b[..., r0:r0 + SSIM_BAND_ROWS, :]).square_()
                    .sum(dtype=torch.float64)) for r0 in range(0, a.shape[-2], SSIM_BAND_ROWS))  # no frame-sized copy
    return 10 * math.log10(a.numel() / sse)


def _box_sum_valid(x: torch.Tensor, k: int, dim: int) -> torch.Tensor:
    """Sums of ``k`` consecutive values along ``dim`` where the window fits (``n - k + 1`` of them): ``k`` shifted views
    added in place (2.2x kornia's pooled ``box_blur`` on this CPU)."""
    n = x.shape[dim] - k + 1
    out = x.narrow(dim, 0, n).clone()
    for i in range(1, k):
        out.add_(x.narrow(dim, i, n))
    return out


def _ssim_kornia(a: torch.Tensor, b: torch.Tensor) -> float:
    """scikit-image's SSIM (uniform 7 x 7 windows, sample covariance, 3 px border left out, mean over channels) in
    bands of :data:`SSIM_BAND_ROWS` rows on the images' device. The local means are box sums of shifted views over the
    windows that fit (the border's reflected windows are left out anyway), the formula evaluated in place: 3.1x
    kornia's ``box_blur`` with the formula written out on a 24 MP colour frame, equal to 6e-9."""
    win, pad = SSIM_WINDOW_PX, (SSIM_WINDOW_PX - 1) // 2
    H, W = a.shape[-2:]
    if min(H, W) < win:
        raise ValueError(f"an image of {W} x {H} px is smaller than SSIM's {win} x {win} px window")
    cov = win * win / (win * win - 1)
    if a.numel() <= SSIM_FLOAT64_MAX_VALUES:  # crops: float64 moments, the same digits on any CPU and thread count
        a, b = a.to(torch.float64), b.to(torch.float64)
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    total = torch.zeros(a.shape[1], dtype=torch.float64, device=a.device)
    for r0 in range(pad, H - pad, SSIM_BAND_ROWS):
        r1 = min(H - pad, r0 + SSIM_BAND_ROWS)  # the band's kept rows; the windows reach pad rows either side
        x, y = a[:, :, r0 - pad: r1 + pad], b[:, :, r0 - pad: r1 + pad]
        # moments about the band's mean: the variances E[x^2] - E[x]^2 cancel less in float32 (scipy's filter,
        # under scikit-image's, accumulates in float64; without the shift a float32 SSIM was 6e-6 off)
        c = x.mean(dim=(-2, -1), keepdim=True)
        x, y = x - c, y - c
        m = torch.cat([x, y, x * x, y * y, x * y], dim=1)
        del x, y
        m = _box_sum_valid(_box_sum_valid(m, win, -2), win, -1).mul_(1 / (win * win))
        ux, uy, uxx, uyy, uxy = m.chunk(5, dim=1)
        v_sum = (uxx + uyy).sub_(ux.square()).sub_(uy.square()).mul_(cov).add_(c2)  # vx + vy + C2
        v_xy = (uxy - ux * uy).mul_(2 * cov).add_(c2)  # 2 vxy + C2
        del m, uxx, uyy, uxy
        ux, uy = ux + c, uy + c
        num = (ux * uy).mul_(2).add_(c1).mul_(v_xy)  # (2 ux uy + C1)(2 vxy + C2)
        den = ux.square_().add_(uy.square_()).add_(c1).mul_(v_sum)  # (ux^2 + uy^2 + C1)(vx + vy + C2)
        total += num.div_(den).sum(dim=(0, -2, -1), dtype=torch.float64)
    return float((total / ((H - 2 * pad) * (W - 2 * pad) * a.shape[0])).mean())


def _mse_tiles_torch(a: torch.Tensor, b: torch.Tensor, tile: int) -> torch.Tensor:
    """The MSE of each ``tile`` x ``tile`` block, one row of tiles at a time (no frame-sized copy)."""
    B, C = a.shape[:2]
    H, W = a.shape[-2] // tile * tile, a.shape[-1] // tile * tile
    rows = []
    for r0 in range(0, H, tile):
        d = (a[..., r0:r0 + tile, :W] - b[..., r0:r0 + tile, :W]).square_()
        rows.append(d.reshape(B, C, tile, W // tile, tile).sum(dim=(0, 1, 2, 4), dtype=torch.float64))
    return (torch.stack(rows) / (B * C * tile * tile)).cpu()


SCORERS.register(Scorer("kornia", _encode_kornia, _psnr_kornia, _ssim_kornia, _mse_tiles_torch,
                        "kornia on the images' device (default)"))


# -- scikit-image: the reference, on the host -------------------------------------------------------------------


def _host(x: torch.Tensor) -> np.ndarray:
    return x[0].permute(1, 2, 0).to("cpu", torch.float32).numpy()


def _encode_colour(x: torch.Tensor) -> torch.Tensor:
    return linear_to_srgb(x.clamp(0, 1)).to(torch.float32)


def _psnr_skimage(a: torch.Tensor, b: torch.Tensor) -> float:
    from skimage.metrics import peak_signal_noise_ratio

    a, b = _host(a), _host(b)
    if (a == b).all():
        return float("inf")
    return float(peak_signal_noise_ratio(a, b, data_range=1.0))


def _ssim_skimage(a: torch.Tensor, b: torch.Tensor) -> float:
    from skimage.metrics import structural_similarity

    a, b = _host(a), _host(b)
    return float(structural_similarity(a, b, data_range=1.0, channel_axis=-1)) if a.shape[-1] > 1 else \
        float(structural_similarity(a[..., 0], b[..., 0], data_range=1.0))


SCORERS.register(Scorer("skimage", _encode_colour, _psnr_skimage, _ssim_skimage, _mse_tiles_torch,
                        "scikit-image on the host, colour-science's sRGB curve (the reference)"))


# -- the public functions ---------------------------------------------------------------------------------------


def encode_srgb(image: torch.Tensor, crop=None, *, scorer: str | None = None) -> torch.Tensor:
    """A linear ``(1, C, H, W)`` image clipped to [0, 1] and sRGB-encoded by the scorer: float32 ``(1, C, H, W)`` on
    the image's device (the scorer ``skimage`` encodes with colour-science on the host)."""
    check_image(image)
    if crop is not None:
        r0, r1, c0, c1 = crop
        image = image[..., r0:r1, c0:c1]
    return validate_scorer(scorer).encode(image)


def _prep(ref: torch.Tensor, test: torch.Tensor, crop, scorer):
    check_image(ref, "ref")
    check_image(test, "test")
    if ref.shape != test.shape or ref.shape[0] != 1:
        raise ValueError(f"shapes {tuple(ref.shape)} and {tuple(test.shape)}: expected two equal (1, C, H, W) tensors")
    return encode_srgb(ref, crop, scorer=scorer), encode_srgb(test, crop, scorer=scorer)


def _psnr_map(mse: torch.Tensor) -> torch.Tensor:
    with np.errstate(divide="ignore"):
        return torch.from_numpy(10 * np.log10(1.0 / mse.numpy()))


def _check_tile(shape, tile) -> None:
    if not (isinstance(tile, int) and not isinstance(tile, bool) and tile >= 1):
        raise ValueError(f"tile={tile!r} is not allowed: a positive number of pixels")
    if shape[-2] < tile or shape[-1] < tile:
        raise ValueError(f"image {shape[-2]}x{shape[-1]} is smaller than one {tile}-px tile")


def psnr_srgb(ref: torch.Tensor, test: torch.Tensor, crop=None, *, scorer: str | None = None) -> float:
    """PSNR (dB) of ``test`` against ``ref`` in sRGB, data range 1."""
    return validate_scorer(scorer).psnr(*_prep(ref, test, crop, scorer))


def ssim_srgb(ref: torch.Tensor, test: torch.Tensor, crop=None, *, scorer: str | None = None) -> float:
    """SSIM of ``test`` against ``ref`` in sRGB (scikit-image's definition: 7 x 7 uniform windows)."""
    return validate_scorer(scorer).ssim(*_prep(ref, test, crop, scorer))


def psnr_map_srgb(ref: torch.Tensor, test: torch.Tensor, tile: int = 256, *, scorer: str | None = None) -> torch.Tensor:
    """PSNR (dB) of ``test`` against ``ref`` in sRGB per ``tile`` x ``tile`` block, ``(rows, cols)`` float64.

    Blocks start at the top-left corner; a remainder narrower than ``tile`` at the right or bottom
    edge is left out. Each entry equals :func:`psnr_srgb` on that block (``inf`` where identical).
    """
    _check_tile(ref.shape, tile)
    a, b = _prep(ref, test, None, scorer)
    return _psnr_map(validate_scorer(scorer).mse_tiles(a, b, tile))


def scores_encoded(ref_srgb: torch.Tensor, test_srgb: torch.Tensor, *, tile: int | None = None, ssim: bool = True,
                   scorer: str | None = None) -> dict:
    """PSNR, SSIM (unless ``ssim=False``; the slow one) and, with ``tile``, the PSNR map of two :func:`encode_srgb`
    images ``(1, C, H, W)``.

    For whole frames: encode each image once and score several against the same reference, instead
    of re-encoding both images in every call of :func:`psnr_srgb` / :func:`ssim_srgb`.
    """
    if ref_srgb.shape != test_srgb.shape or ref_srgb.ndim != 4 or ref_srgb.shape[0] != 1:
        raise ValueError(f"shapes {tuple(ref_srgb.shape)} and {tuple(test_srgb.shape)}: expected two equal "
                         "(1, C, H, W) tensors")
    sc = validate_scorer(scorer)
    out = {"psnr_db": sc.psnr(ref_srgb, test_srgb)}
    if ssim:
        out["ssim"] = sc.ssim(ref_srgb, test_srgb)
    if tile is not None:
        _check_tile(ref_srgb.shape, tile)
        out["psnr_map_db"] = _psnr_map(sc.mse_tiles(ref_srgb, test_srgb, tile))
    return out
