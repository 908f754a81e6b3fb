"""Spatially-variant blur by local convolutions in overlapping windows (paper Section 3.3).

Window positions lie on a grid of step ``stride`` (pixels), placed by the scheme's ``anchor``:
``"axis"`` (default) at ``optical axis + k stride``, the axis itself included, so that for a rotationally
symmetric lens (a provider whose ``mirror_symmetric`` is true) the windows at the mirror images of a
position (about the row or the column through the optical axis, or the diagonal) share one PSF
computation: the others are its exact flips and transpose, up to 8 windows per PSF (6x fewer PSFs over
a 24 MP frame). A position may fall between pixels (the axis of an even-sized frame does); the window's
patch and core then sit on the next pixel and its tent is centred on the position. ``"origin"`` puts
the windows on pixels ``0, stride, 2 stride, ...`` (the first version's grid). Around each position a
``window`` x ``window`` patch of the (reflect-padded) image is convolved, by FFT, with the PSF *at that
position*
(from a PSF provider, :mod:`lenssim.optics.psf_provider`: the lens model with exact pupil rotation, or
measured PSFs); only the central ``core`` x ``core`` of the
result is kept, weighted by a separable tent of half-width ``core / 2`` and blended with its
neighbours. With the paper's scheme (512, 32, 64) the tents form a partition of unity, so every
pixel is a linear interpolation of the 2 x 2 nearest local convolutions. Weights are normalised by
their sum in any case. The PSF must fit in the window: its extent plus the core must stay within
the window or the circular convolution would wrap into the core. Where a PSF outgrows ``window`` (e.g. a
colour PSF in a corner of the frame) that window alone grows to hold it: it takes :func:`grown_window` px, its PSF
computed on that grid (:func:`window_sizes`; at most :data:`MAX_WINDOW_PX`, else ``ValueError``).

Geometry: image rows/columns are ``y``/``x`` in the image plane (:class:`lenssim.FieldGeometry`);
``optical_center`` (row, col) in pixels of this array, default the array centre. Crops of a
larger frame pass the crop's offset so each window gets the PSF of its true field position. A
provider may give one PSF for all channels or one per channel (``(P, C, n, n)``, e.g. colour).

Tensor contract: ``(B, C, H, W)`` linear float in, same shape out.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import torch

from lenssim import PSFProvider, frame_center
from lenssim.optics.psf_bank import nice_fft_size
from lenssim.torch_utils import HOST, chunk_budget_bytes, tensor_of

from .checks import check_image, check_provider

__all__ = ["WindowScheme", "WINDOW_ANCHORS", "PAPER_SCHEME", "window_centres", "axis_positions", "scheme_positions",
           "window_count", "window_chunk", "WINDOW_COPIES", "tent_weights", "core_irfft2", "FIT_SIZES", "fitted_windows", "grown_window",
           "window_sizes", "largest_window", "fold_psf", "StrideZones", "choose_stride_zones",
           "interpolation_error_db", "BLUR_ZONE_TOL_DB",
           "apply_windowed", "blur_windowed", "WindowPlan", "window_plan", "window_batches",
           "run_windows", "weight_sum", "core_slices", "box_mean", "blur_exact"]


WINDOW_ANCHORS = ("axis", "origin")
"""Where the window grid is anchored: symmetric about the optical axis, or at pixel 0."""


MAX_WINDOW_PX = 4096
"""Largest local-convolution window (px): 8x the paper's 512, a PSF grid of 16.8 M samples per window."""


@dataclass(frozen=True)
class WindowScheme:
    """Local-convolution windows: ``window`` (px, even), centre ``stride`` (px), blended ``core`` (px), the
    grid's ``anchor`` (one of :data:`WINDOW_ANCHORS`) and ``fit``: the blur's and the Wiener restoration's transforms
    sized to the local PSF (see :func:`blur_windowed`; the other restorations work on ``window`` px)."""

    window: int = 512
    stride: int = 32
    core: int = 64
    anchor: str = "axis"
    fit: bool = True

    def __post_init__(self):
        for name in ("window", "stride", "core"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v > 0 and v % 2 == 0):
                raise ValueError(f"{name}={v!r} is not allowed: a positive even number of pixels")
        # stride == core would leave the pixels midway between two centres with zero weight in both tents
        if self.window > MAX_WINDOW_PX:
            raise ValueError(f"window={self.window} is not allowed: at most {MAX_WINDOW_PX} px (a window's patch and "
                             "its spectrum per channel must fit in memory many times over)")
        if not self.stride < self.core <= self.window:
            raise ValueError(f"stride={self.stride}, core={self.core}, window={self.window}: need stride < core <= window")
        if self.anchor not in WINDOW_ANCHORS:
            raise ValueError(f"anchor={self.anchor!r} is not allowed: one of {', '.join(WINDOW_ANCHORS)}")
        if not isinstance(self.fit, bool):
            raise ValueError(f"fit={self.fit!r} is not allowed: True or False")


PAPER_SCHEME = WindowScheme()


def window_centres(length: int, stride: int) -> torch.Tensor:
    """Centres ``0, stride, 2 stride, ...`` up to the first one at or beyond ``length - 1``."""
    return torch.arange(0, (length - 1) + stride, stride, device=HOST)[: int(math.ceil((length - 1) / stride)) + 1]


def axis_positions(length: int, stride: int, core: int, center: float) -> torch.Tensor:
    """Window positions (px, float64) along one axis of ``length`` px: ``center + k stride`` for every integer ``k``
    whose tent reaches into ``[0, length)`` (closer than ``core / 2`` px to it).

    The optical axis itself is a position, and the set is symmetric about it whatever ``center`` is (on a
    pixel, between two or anywhere): a position may fall between pixels, where the window's PSF is
    evaluated; its patch and core are laid on the pixel ``ceil(position)`` and its tent is centred on the
    position itself (:func:`tent_weights` with ``shift``), so the tents stay a partition of unity.
    """
    lo, hi = -core / 2, length - 1 + core / 2  # exclusive: a position this far out has zero weight inside
    c = float(center)
    k = torch.arange(math.floor((lo - c) / stride), math.ceil((hi - c) / stride) + 1, dtype=torch.float64, device=HOST)
    pos = c + stride * k
    return pos[(pos > lo) & (pos < hi)]


def scheme_positions(length: int, scheme: WindowScheme, center: float) -> torch.Tensor:
    """The scheme's window positions (px, float64) along one axis of ``length`` px with the optical axis at
    ``center``: :func:`axis_positions`, or the integer :func:`window_centres` for the ``"origin"`` anchor."""
    if scheme.anchor == "origin":
        return window_centres(length, scheme.stride).to(torch.float64)
    return axis_positions(length, scheme.stride, scheme.core, center)


def window_count(shape, scheme: WindowScheme | None = None, optical_center=None, zones=None, region=None) -> int:
    """Number of windows over an image of ``shape`` ``(..., H, W)`` (one pass of :func:`apply_windowed`; with
    ``zones``, a blur zoned by :class:`StrideZones`; with ``region`` ``(r0, r1, c0, c1)``, the windows whose cores
    touch it, as a pass over that region only)."""
    scheme = scheme or PAPER_SCHEME
    cy, cx = optical_center if optical_center is not None else frame_center(shape)
    if region is not None or (zones is not None and not zones.uniform):
        return int(_zoned_positions(shape, scheme, (cy, cx), region, zones)[0].numel())
    return len(scheme_positions(shape[-2], scheme, cy)) * len(scheme_positions(shape[-1], scheme, cx))


def tent_weights(core: int, dtype=torch.float64, shift: float = 0.0) -> torch.Tensor:
    """1-D tent over the core: ``1 - |d + shift| / (core/2)`` at pixel offsets ``d = -core/2 .. core/2 - 1`` from
    the core's anchor pixel, for a window position ``shift`` (``0 <= shift < 1``) px before that pixel."""
    d = torch.arange(-core // 2, core // 2, dtype=torch.float64, device=HOST) + shift
    return (1 - d.abs() / (core / 2)).clamp_min(0).to(dtype)


def pads_by_reflection(p: int, shape) -> bool:
    """Whether :func:`_pad` pads an image of ``shape`` ``(H, W)`` by ``p`` px by reflection (else by repeating the
    edge: the image is smaller than the pad)."""
    return p < min(shape)


def _pad(image: torch.Tensor, p: int) -> torch.Tensor:
    """Reflect padding (edge replication where the image is smaller than the pad)."""
    mode = "reflect" if pads_by_reflection(p, image.shape[-2:]) else "replicate"
    return torch.nn.functional.pad(image, (p, p, p, p), mode=mode)


def core_irfft2(spectrum: torch.Tensor, window: int, core: int) -> torch.Tensor:
    """The central ``core x core`` of ``irfft2(spectrum, s=(window, window))``, ``(*, core, core)``.

    Pruned inverse: the row transform runs on all columns but only the ``core`` rows that are kept go
    through the column transform (~3x faster than the full inverse for the paper's 512 / 64). The kept rows
    are made contiguous first: the row transform of the strided slice was 1.25x slower (same numbers).
    """
    lo = window // 2 - core // 2
    rows = torch.fft.ifft(spectrum, dim=-2)[..., lo:lo + core, :].contiguous()
    return torch.fft.irfft(rows, n=window, dim=-1)[..., lo:lo + core]


CPU_CACHE_BYTES = 32 * 2**20
"""Working set (bytes) of one chunk of windows on a CPU: about a last-level cache (measured on this
2-core CPU with 32 MiB of L3, paper scheme, three channels: chunks of 2-4 windows ran at 3.1 ms per
window, 8 at 3.9 ms, 16 at 7.1 ms)."""

PSF_BATCH = 64
"""Windows whose PSFs are computed together on an axis-symmetric grid (whole mirror groups: up to 8 windows share a
PSF, so about 8 PSFs per batch), where :data:`PSF_BATCH_BYTES` allows. Measured here: 2.4-2.6 ms per blur window with
16 against 2.9 ms with one group at a time; 64 against 16: the restoration of a 1536 px square around the axis of the
forest photo 6.35 -> 6.08 s, the same bits; 128 as 64."""

PSF_BATCH_OWN = 16
"""Windows whose PSFs are computed together where every window has its own PSF (no mirror symmetry: an as-built lens,
the origin grid): 16 PSFs at a time, as before the mirror groups' batch grew."""

PSF_BATCH_BYTES = 128 * 2**20
"""Most bytes of the OTFs of one batch (``C w (w/2 + 1)`` complex values per window): 64 windows of 512 px in one
channel (67 MB), fewer in colour or where windows grow (a 4096 px window's OTF alone is 67 MB), never fewer than the
transforms' own batch."""


def psf_batch(image: torch.Tensor, window: int, channels: int, k_chunk: int, symmetric: bool = True) -> int:
    """Windows whose PSFs are computed together for ``window`` px windows of ``image`` with ``channels`` PSFs per
    window: :data:`PSF_BATCH` on a mirror-symmetric grid (``symmetric``), else :data:`PSF_BATCH_OWN`, within
    :data:`PSF_BATCH_BYTES`, and at least ``k_chunk`` (the transforms' batch) and 1."""
    per_window = channels * window * (window // 2 + 1) * 2 * image.element_size()
    return max(k_chunk, 1, min(PSF_BATCH if symmetric else PSF_BATCH_OWN, PSF_BATCH_BYTES // per_window))


WINDOW_COPIES = 3
"""Values a window holds per pixel and channel of its patch in a windowed pass (its patch and the patch's spectrum):
what :func:`window_chunk` budgets by default."""


def window_chunk(image: torch.Tensor, window: int, copies: float = WINDOW_COPIES) -> int:
    """Windows per batch: enough to fill a GPU, few enough for a CPU's caches.

    A window holds about ``copies B C window^2`` values of ``image``'s dtype (:data:`WINDOW_COPIES`: its patch and the
    patch's spectrum); a batch gets :func:`lenssim.torch_utils.chunk_budget_bytes` (:data:`CPU_CACHE_BYTES` on a CPU:
    3 windows of 512 px in three float32 channels; a share of the free memory on a GPU, at most 256
    windows). The PSFs are computed for :func:`psf_batch` windows at a time (whole mirror groups).
    """
    per_window = copies * image.shape[0] * image.shape[1] * window * window * image.element_size()
    most = 256 if image.device.type == "cuda" else 64
    return int(min(most, max(1, chunk_budget_bytes(image.device, CPU_CACHE_BYTES) // int(per_window))))


FIT_SIZES = (256, 288, 320, 336, 384, 400, 432, 448)
"""Transform sizes (px) a fitted blur window may take below the scheme's window. The least is 256 px: the
diffraction tail beyond any support wraps inside the window, and near the axis (supports of 20-40 px) windows of
96-128 px gave 67.8 dB against one PSF per pixel on a photo, 256 px 77.1 dB (512 px: 79.5 dB). The others run at
about the speed per pixel of 512 px here (6-7 ns per pixel for the blur's transforms); 450 to 500 px gained
nothing over 512, and 480 px ran 3x slower."""

FIT_MARGIN_PX = 64
"""Room (px) a fitted blur window keeps beyond the PSF's support and the core, for the light the geometric support
leaves out (measured on a photo 9-12 deg off axis: no margin 73.3 dB against one PSF per pixel, 64 px 80.1 dB,
512 px windows 88.6 dB)."""


def fitted_windows(need: torch.Tensor, window: int, least: int | None = None) -> torch.Tensor:
    """Window size (px) for each need ``(P,)`` (PSF support + core, px; 0 where unknown): the smallest of
    :data:`FIT_SIZES` (below ``window``, at least ``least``, default the least of them) holding ``need +``
    :data:`FIT_MARGIN_PX`, else ``window``."""
    least = FIT_SIZES[0] if least is None else least
    table = torch.tensor([w for w in FIT_SIZES if least <= w < window] + [window], dtype=torch.int64, device=need.device)
    w = table[torch.searchsorted(table, (need + FIT_MARGIN_PX).clamp(max=window))]
    return torch.where(need > 0, w, window)


def grown_window(need: int) -> int:
    """The window (px) for a PSF whose support plus core, ``need`` px, is more than the scheme's window: the smallest
    size with no prime factor above 5 (a multiple of 16) holding ``need +`` :data:`FIT_MARGIN_PX`."""
    return nice_fft_size(int(need) + FIT_MARGIN_PX)


def window_sizes(extents: torch.Tensor, scheme: WindowScheme, fit: bool, least: int | None = None) -> torch.Tensor:
    """Each window's size (px, ``(P,)`` int64) for PSF supports ``extents`` (px, ``(P,)``; 0 where unknown).

    A window whose PSF support plus core fits ``scheme.window`` takes the scheme's window, or with ``fit`` its
    :func:`fitted_windows` size (at least ``least`` px); one whose PSF does not fit takes :func:`grown_window` px
    (its PSF then computed on that grid, not folded), so no PSF wraps into a core. ``ValueError`` where that is over
    :data:`MAX_WINDOW_PX`.
    """
    win, core = scheme.window, scheme.core
    need = torch.where(extents > 0, extents + core, 0).to(torch.int64)
    sizes = fitted_windows(need, win, least) if fit else torch.full_like(need, win)
    over = need > win
    if bool(over.any()):
        most = int(need.max())
        grown = grown_window(most)
        if grown > MAX_WINDOW_PX:
            raise ValueError(f"the PSF spans {most - core} px: with the {core}-px core a window of {grown} px would be "
                             f"needed, over the {MAX_WINDOW_PX} px allowed (use a smaller core, or a sharper design)")
        values, inv = torch.unique(need[over], return_inverse=True)
        sizes = sizes.clone()
        sizes[over] = torch.tensor([grown_window(int(v)) for v in values.tolist()], dtype=sizes.dtype,
                                   device=sizes.device)[inv]
    return sizes


def largest_window(psf: PSFProvider, shape, scheme: WindowScheme = PAPER_SCHEME, optical_center=None,
                   region=None) -> int:
    """The largest window (px) a windowed pass over an image of ``shape`` ``(..., H, W)`` takes: ``scheme.window``,
    or more where a PSF outgrows it (:func:`window_sizes`); with ``region = (r0, r1, c0, c1)`` only the windows whose
    cores touch it. For the margins a crop needs around it."""
    check_provider(psf)
    center = optical_center if optical_center is not None else frame_center(shape)
    Y, X = torch.meshgrid(*_region_positions(shape, scheme, center, region), indexing="ij")
    symmetric = scheme.anchor == "axis" and bool(psf.mirror_symmetric)
    sizes = window_sizes(_extents(psf, Y.flatten(), X.flatten(), center, symmetric), scheme, fit=False)
    return max([scheme.window] + sizes.tolist())


def _region_positions(shape, scheme: WindowScheme, center, region=None) -> tuple[torch.Tensor, torch.Tensor]:
    """The window positions (px, float64) along the rows and the columns of an image of ``shape`` ``(..., H, W)``
    whose cores touch ``region = (r0, r1, c0, c1)`` (default: the whole image)."""
    H, W = shape[-2], shape[-1]
    r0, r1, c0, c1 = region if region is not None else (0, H, 0, W)
    py, px = scheme_positions(H, scheme, center[0]), scheme_positions(W, scheme, center[1])
    half = scheme.core / 2
    return py[(py + half > r0) & (py - half < r1)], px[(px + half > c0) & (px - half < c1)]


def fold_psf(p: torch.Tensor, w: int) -> torch.Tensor:
    """A PSF ``(..., n, n)`` with its centre at ``[0, 0]`` (DFT order) folded onto a ``w x w`` grid: the value at
    offset ``d`` (``-n/2 < d < n/2``) is added to index ``d mod w``; the row (column) at ``n/2``, which the periodic
    grid puts at ``+n/2`` and at ``-n/2`` alike, goes half to each, so that folding commutes with the flips and the
    transpose of the mirror groups. A circular convolution over ``w`` px with the folded PSF is that over ``n`` px
    with ``p`` wherever the two wrap the same pixels: at every pixel of a core farther than the PSF's support from
    the window's edge. Unit sum is kept. ``w = n``: ``p`` itself."""
    n = p.shape[-1]
    if w == n:
        return p
    j = ((torch.arange(n, device=p.device) + n // 2) % n - n // 2) % w  # each index's signed offset, mod w
    lo, hi = (-(n // 2)) % w, (n // 2) % w  # where the two halves of the Nyquist row go
    for dim, shape in ((p.ndim - 2, p.shape[:-2] + (w, n)), (p.ndim - 1, p.shape[:-2] + (w, w))):
        q = p.new_zeros(shape).index_add_(dim, j, p)
        if lo != hi:
            nyq = p.select(dim, n // 2)
            q.select(dim, lo).sub_(nyq, alpha=0.5)
            q.select(dim, hi).add_(nyq, alpha=0.5)
        p = q
    return p


class _WindowOTFs:
    """The OTFs of the windows (``rfft2`` of the PSF at each centre, moved to ``[0, 0]``).

    A provider whose ``mirror_symmetric`` is true has the same PSF, flipped or transposed, at the mirror
    images of a position about the row and the column through the optical centre and about the diagonal.
    Then windows are visited grouped by their canonical position ``(u, v) = sorted(|dy|, |dx|)``; one PSF
    is computed per group and each window's OTF follows exactly: a flip of the PSF's rows is a reversal
    of the spectrum's rows (``H(-f_y, f_x)``), a flip of its columns the conjugate of that (``H(f_y, -f_x) =
    conj H(-f_y, f_x)`` for a real PSF), a transpose the transform of the transposed PSF.
    """

    def __init__(self, psf: PSFProvider, center, win: int, dtype, device, symmetric: bool, n: int | None = None,
                 pedestal: int | None = None):
        self.psf, self.center, self.win, self.dtype, self.device = psf, center, win, dtype, device
        self.n = win if n is None else n  # the PSFs' grid (px): folded onto the window where it is larger
        self.symmetric = symmetric
        # per channel, the uniform level taken out of each PSF: the pedestal on the caller's grid of ``pedestal`` px,
        # which the caller convolves apart. On a larger grid (a grown window) the PSF's own pedestal is smaller; the
        # rest of the level taken out is uniform over the whole grid, which a circular convolution over it sees at
        # the zero frequency only: the PSF keeps its exact OTF at every other frequency and a sum of one less the
        # caller's pedestal.
        self.level = (torch.tensor(psf.pedestal_fractions(pedestal), dtype=torch.float64, device=HOST) / self.n**2
                      if pedestal is not None else None)
        self.rev = (-torch.arange(win, device=device)) % win  # the row of -f_y for each row f_y

    def _canonical(self, ys, xs):
        """Offsets ``dy, dx`` from the axis, the canonical ``u <= v`` and whether the window is transposed."""
        dy, dx = ys.to(torch.float64) - self.center[0], xs.to(torch.float64) - self.center[1]
        ady, adx = dy.abs(), dx.abs()
        return dy, dx, torch.minimum(ady, adx), torch.maximum(ady, adx), ady > adx

    def chunks(self, Y, X, chunk: int):
        """Batches ``(ys, xs)`` of at least ``chunk`` windows (the last may have fewer); with symmetry the
        windows sharing a PSF come together and a group is never split."""
        if not self.symmetric:
            for k in range(0, Y.numel(), chunk):
                yield Y[k:k + chunk], X[k:k + chunk]
            return
        _, _, u, v, _ = self._canonical(Y, X)
        iu, iv = torch.round(2 * u).to(torch.int64), torch.round(2 * v).to(torch.int64)
        key = iu * (int(iv.max()) + 1) + iv
        key, order = torch.sort(key, stable=True)
        Y, X = Y[order], X[order]
        bounds = [0] + (torch.nonzero(key[1:] != key[:-1]).flatten() + 1).tolist() + [key.numel()]
        a = 0
        for g in range(1, len(bounds)):
            if bounds[g] - bounds[a] >= chunk or g == len(bounds) - 1:
                yield Y[bounds[a]:bounds[g]], X[bounds[a]:bounds[g]]
                a = g

    def _psfs(self, ys, xs):
        # the PSFs with their centre at [0, 0], computed in the image's precision
        p = self.psf.psf_at_pixels(ys, xs, self.center, self.n, centered=False, dtype=self.dtype,
                                   device=self.device).to(dtype=self.dtype, device=self.device)
        if self.level is not None and bool(self.level.any()):
            p = p - (self.level.to(p)[:, None, None] if p.ndim == 4 else self.level.to(p)[0])
        return fold_psf(p, self.win)

    def __call__(self, ys, xs) -> torch.Tensor:
        """``(k, 1, 1 or C, win, win/2+1)`` for the windows centred at ``(ys, xs)`` (px)."""
        if not self.symmetric:
            otf = torch.fft.rfft2(self._psfs(ys, xs))
        else:
            dy, dx, u, v, swap = self._canonical(ys, xs)  # swap: the PSF is the transpose of the one at (u, v)
            uniq, inv = torch.unique(torch.stack([u, v], 1), dim=0, return_inverse=True)
            p = self._psfs(uniq[:, 0] + self.center[0], uniq[:, 1] + self.center[1])  # PSFs at (u, v), u <= v
            H = torch.fft.rfft2(p)
            need_t = torch.unique(inv[swap]).tolist()
            HT = dict(zip(need_t, torch.fft.rfft2(p[need_t].transpose(-2, -1)))) if need_t else {}
            parts = []
            for m, j in enumerate(inv.tolist()):
                h = HT[j] if bool(swap[m]) else H[j]
                if bool(dy[m] < 0) != bool(dx[m] < 0):
                    h = h[..., self.rev, :]
                parts.append(h.conj() if bool(dx[m] < 0) else h)
            otf = torch.stack(parts).resolve_conj()
        return otf[:, None, None] if otf.ndim == 3 else otf[:, None]


BLUR_ZONE_TOL_DB = 55.0
"""The interpolation error a coarser blur stride may make (:func:`choose_stride_zones`): the RMS difference between
the bilinear blend of four windows' PSFs and the PSF at the centre of their cell, convolved with a unit-variance image
of the paper's image model (``rho0^|r|``), at most ``10^(-55/20)`` = 1.8e-3. The estimate is a worst case: a real
photo has a tenth of that variance and less high-frequency content. Measured on the 24 MP forest photo with the paper's
E2E design, a blur zoned at this bound (stride 64 beyond ~350 px from the axis) is 81-95 dB from one PSF per pixel and
80+ dB from the paper's stride-32 blur (docs/performance.md)."""
ZONE_MULTIPLES = (1, 2)
"""Stride multiples a zone may take (the scheme's stride and core times each)."""
ZONE_SAMPLES = 24
"""Radii (from the axis to the frame's corners) at which the interpolation error is estimated."""
ZONE_RADII_PER_BATCH = 4
"""Radii whose PSFs (five each, float64) are computed together when estimating the error (~42 MB at 512 px)."""


@dataclass(frozen=True)
class StrideZones:
    """Blur window strides by distance from the optical axis: the radii ``edges_px`` (increasing) split the frame into
    ``len(edges_px) + 1`` rings; ring ``k`` takes windows of stride ``multiples[k] * scheme.stride`` and core
    ``multiples[k] * scheme.core`` on the axis-anchored grid (a coarser grid's positions are the finer one's every
    ``m``-th). A window is used where its tent reaches into its ring; where two rings' windows meet, a pixel's value
    is the normalised blend of both (:func:`apply_windowed`)."""

    edges_px: tuple[float, ...]
    multiples: tuple[int, ...]

    def __post_init__(self):
        if len(self.multiples) != len(self.edges_px) + 1 or not all(isinstance(m, int) and m >= 1
                                                                     for m in self.multiples):
            raise ValueError(f"stride zones {self.multiples} / {self.edges_px}: one multiple (an integer >= 1) per "
                             "ring, one ring more than edges")
        if list(self.edges_px) != sorted(self.edges_px):
            raise ValueError(f"stride zone edges {self.edges_px} are not increasing")

    @property
    def uniform(self) -> bool:
        return set(self.multiples) == {1}

    def to_dict(self) -> dict:
        return {"edges_px": [round(float(e), 3) for e in self.edges_px], "multiples": list(self.multiples)}


def interpolation_error_db(psf: PSFProvider, scheme: WindowScheme, multiple: int, radii_px, optical_center, *,
                           n: int | None = None, rho0: float = 0.97, azimuth_deg: float = 45.0) -> torch.Tensor:
    """The estimated blur interpolation error (dB, :data:`BLUR_ZONE_TOL_DB`'s measure) of windows at ``multiple``
    times the scheme's stride, at the centre of a window cell whose centre lies ``radii_px`` from the axis at
    ``azimuth_deg`` (from the rows' direction; default the diagonal): ``-10 log10`` of the variance of ``(mean of the
    cell corners' PSFs - the centre's PSF) * x`` for a unit-variance ``x`` of the image model with ``rho0`` (summed
    over the spectrum with :func:`lenssim.image_psd`), the worst channel's."""
    from lenssim import image_psd

    n = scheme.window if n is None else n
    s = multiple * scheme.stride
    r = tensor_of(radii_px, torch.float64).reshape(-1)
    cy, cx = optical_center
    a = math.radians(azimuth_deg)
    py, px = cy + r * math.sin(a), cx + r * math.cos(a)
    off = torch.tensor([[-1, -1], [-1, 1], [1, -1], [1, 1], [0, 0]], dtype=torch.float64, device=r.device) * (s / 2)
    P = image_psd(n, rho0, dtype=torch.float64)
    P = P / P.mean()
    var = []
    for k in range(0, r.numel(), ZONE_RADII_PER_BATCH):  # 5 float64 PSFs per radius: a few at a time
        ys = (py[k:k + ZONE_RADII_PER_BATCH, None] + off[None, :, 0]).reshape(-1)
        xs = (px[k:k + ZONE_RADII_PER_BATCH, None] + off[None, :, 1]).reshape(-1)
        p = psf.psf_at_pixels(ys, xs, (cy, cx), n, centered=False, dtype=torch.float64)
        p = p.reshape(-1, 5, *(p.shape[1:-2] or (1,)), n, n)  # (R, 5, 1 or C, n, n)
        d = p[:, :4].mean(dim=1) - p[:, 4]
        var.append((torch.fft.fft2(d).abs().square() * P).mean(dim=(-2, -1)).amax(dim=-1))
    return -10 * torch.log10(torch.cat(var).clamp_min(1e-300))


def choose_stride_zones(psf: PSFProvider, shape, scheme: WindowScheme = None, optical_center=None, *,
                        tol_db: float = BLUR_ZONE_TOL_DB, region=None) -> StrideZones:
    """Rings of blur stride for a frame of ``shape`` ``(..., H, W)``: at :data:`ZONE_SAMPLES` radii from the axis to
    the frame's corners, the coarsest of :data:`ZONE_MULTIPLES` whose :func:`interpolation_error_db` is at least
    ``tol_db`` there and at both neighbouring samples (the ring's edges halfway between samples), along the diagonal
    for a rotationally symmetric lens (``mirror_symmetric``), else the worst of eight azimuths. The paper's single
    stride where none is coarse enough, or for the ``"origin"`` anchor.

    ``region = (r0, r1, c0, c1)`` (the frame's pixels a blur computes, e.g. a crop's): only the samples whose rings
    its windows can reach (two beyond on either side) are estimated; over the region the rings are the whole frame's,
    so its blur is the same, for a fraction of the PSFs."""
    scheme = scheme or PAPER_SCHEME
    if scheme.anchor != "axis" or max(ZONE_MULTIPLES) == 1:
        return StrideZones((), (1,))
    center = optical_center if optical_center is not None else frame_center(shape)
    H, W = shape[-2:]
    corner = max(math.hypot(a, b) for a in (center[0], H - 1 - center[0]) for b in (center[1], W - 1 - center[1]))
    radii = torch.linspace(0.0, corner, ZONE_SAMPLES, dtype=torch.float64, device=HOST)  # cells reach s/sqrt(2) px beyond
    if region is not None:
        reach = max(ZONE_MULTIPLES) * scheme.core  # a window touching the region: its tent this far beyond
        r0, r1, c0, c1 = (region[0] - reach, region[1] + reach, region[2] - reach, region[3] + reach)
        dy = (max(r0 - center[0], center[0] - r1, 0.0), max(abs(r0 - center[0]), abs(r1 - center[0])))
        dx = (max(c0 - center[1], center[1] - c1, 0.0), max(abs(c0 - center[1]), abs(c1 - center[1])))
        lo, hi = math.hypot(dy[0], dx[0]), math.hypot(dy[1], dx[1])
        step = corner / (ZONE_SAMPLES - 1)
        radii = radii[(radii >= lo - 2 * step) & (radii <= hi + 2 * step)]
        if radii.numel() == 0:
            return StrideZones((), (1,))
    best = torch.ones(radii.numel(), dtype=torch.int64, device=radii.device)
    for m in sorted(ZONE_MULTIPLES)[1:]:
        if m * scheme.core > scheme.window:
            break
        azimuths = (45.0,) if psf.mirror_symmetric else tuple(22.5 + 45.0 * k for k in range(8))
        err = torch.stack([_cached_errors(psf, scheme, m, radii, center, az) for az in azimuths])
        ok = err.amin(dim=0) >= tol_db
        ok = ok & torch.cat([ok[:1], ok[:-1]]) & torch.cat([ok[1:], ok[-1:]])  # and at both neighbours
        best = torch.where(ok, torch.full_like(best, m), best)
    edges, mults = [], [int(best[0])]
    for i in range(1, radii.numel()):
        if int(best[i]) != mults[-1]:
            edges.append(float(radii[i - 1] + radii[i]) / 2)
            mults.append(int(best[i]))
    return StrideZones(tuple(edges), tuple(mults))


ZONE_CACHE_ENTRIES = 4096
"""Interpolation-error estimates kept in this process (by provider fingerprint, scheme, multiple, azimuth and radius):
another crop, command or design asks only for the radii it has not seen."""
_ZONE_ERRORS: OrderedDict = OrderedDict()
_ZONE_LOCK = threading.Lock()


def _cached_errors(psf: PSFProvider, scheme: WindowScheme, m: int, radii: torch.Tensor, center, az: float):
    """:func:`interpolation_error_db` at ``radii``, each (radius, ...) estimated once per process for a provider with
    a fingerprint (the estimate depends on the offsets from the axis only, not on where the axis is)."""
    fp = getattr(psf, "fingerprint", None)
    fp = fp() if callable(fp) else None
    if fp is None:
        return interpolation_error_db(psf, scheme, m, radii, center, azimuth_deg=az)
    keys = [(fp, scheme.window, scheme.stride, m, az, round(float(r), 6)) for r in radii]
    with _ZONE_LOCK:
        missing = [i for i, k in enumerate(keys) if k not in _ZONE_ERRORS]
    if missing:
        values = interpolation_error_db(psf, scheme, m, radii[missing], center, azimuth_deg=az)
        with _ZONE_LOCK:
            for i, v in zip(missing, values.tolist()):
                _ZONE_ERRORS[keys[i]] = v
            while len(_ZONE_ERRORS) > ZONE_CACHE_ENTRIES:
                _ZONE_ERRORS.popitem(last=False)
    with _ZONE_LOCK:
        out = []
        for k in keys:
            if k in _ZONE_ERRORS:
                _ZONE_ERRORS.move_to_end(k)
                out.append(_ZONE_ERRORS[k])
            else:  # dropped meanwhile by another thread's entries: estimated again
                out.append(float(interpolation_error_db(psf, scheme, m, [k[-1]], center,
                                                        azimuth_deg=az)[0]))
    return torch.tensor(out, dtype=torch.float64, device=HOST)


def _zoned_positions(shape, scheme: WindowScheme, center, region, zones: StrideZones | None):
    """Window positions ``(Y, X)`` (px, float64) and each one's core (px, int64) over ``region``: one grid, or with
    ``zones`` each ring's grid, a window kept where its tent reaches into its ring."""
    if zones is None or zones.uniform or scheme.anchor != "axis":
        py, px = _region_positions(shape, scheme, center, region)
        Y, X = torch.meshgrid(py, px, indexing="ij")
        return Y.flatten(), X.flatten(), torch.full((Y.numel(),), scheme.core, dtype=torch.int64, device=Y.device)
    edges = (0.0,) + tuple(zones.edges_px) + (math.inf,)
    Ys, Xs, Cs = [], [], []
    for k, m in enumerate(zones.multiples):
        sub = WindowScheme(scheme.window, m * scheme.stride, m * scheme.core, scheme.anchor, scheme.fit)
        py, px = _region_positions(shape, sub, center, region)
        Y, X = torch.meshgrid(py, px, indexing="ij")
        Y, X = Y.flatten(), X.flatten()
        h = sub.core / 2
        ady, adx = (Y - center[0]).abs(), (X - center[1]).abs()
        rmin = torch.hypot((ady - h).clamp_min(0), (adx - h).clamp_min(0))
        rmax = torch.hypot(ady + h, adx + h)
        keep = (rmax > edges[k]) & (rmin < edges[k + 1])
        Ys.append(Y[keep])
        Xs.append(X[keep])
        Cs.append(torch.full((int(keep.sum()),), sub.core, dtype=torch.int64, device=keep.device))
    return torch.cat(Ys), torch.cat(Xs), torch.cat(Cs)


def apply_windowed(image: torch.Tensor, psf: PSFProvider, op, *, scheme: WindowScheme = PAPER_SCHEME,
                   optical_center=None, region=None, chunk: int | None = None, progress=None,
                   fit: bool = False, pedestal: bool = False, zones: StrideZones | None = None,
                   least_fit: int | None = None) -> torch.Tensor:
    """Run ``op(patches, otf, core)`` in every window and blend the cores (the machinery of :func:`blur_windowed`).

    ``patches`` is ``(k, B, C, w, w)`` (image rows ``y - w/2 .. y + w/2 - 1`` around each window's pixel ``y =
    ceil(position)``), ``otf`` is ``(k, 1, 1 or C, w, w/2 + 1)`` (``rfft2`` of the PSF at the window's position, moved
    to ``[0, 0]``; one for all channels or one per channel), broadcasting against the patches, and ``core`` the
    window's core (px: the scheme's, or a zone's); ``op`` returns either processed patches of the same shape (real),
    whose central ``core`` is kept, their cores ``(k, B, C, core, core)`` (real), or their spectra (complex, ``rfft2``
    layout), of which only the core is inverse transformed (:func:`core_irfft2`). ``w`` is the scheme's ``window``, or
    with ``fit`` (for an ``op`` that convolves with the PSF, whose core then does not depend on the window beyond the
    PSF's reach) the :func:`fitted_windows` size of the PSF's support at the window's position plus the core (at least
    ``least_fit`` px), the PSF computed on the ``window`` grid and folded onto ``w`` (:func:`fold_psf`). A window
    whose PSF outgrows ``window`` (support plus core) takes :func:`grown_window` px instead, its PSF computed on that
    grid (:func:`window_sizes`): ``op`` must take the size from its patches. Windows of one size are processed
    together. With ``pedestal`` the provider's uniform pedestal on the ``window`` grid
    (:meth:`lenssim.PSFProvider.pedestal_fractions`) is taken out of every PSF: the caller convolves it itself
    (:func:`blur_windowed` adds it as a :func:`box_mean` over ``window`` px). ``zones`` (:class:`StrideZones`):
    windows of a coarser stride and core in the rings it names (the scheme's elsewhere).
    """
    check_image(image)
    plan = window_plan(image.shape, psf, scheme, optical_center, region, fit=fit, zones=zones, least_fit=least_fit)
    batches = window_batches(plan, psf, image, chunk, pedestal)
    return run_windows(image, plan, batches, op, progress)


@dataclass(frozen=True)
class WindowPlan:
    """Where a windowed pass over an image of ``H x W`` px puts its windows (:func:`window_plan`): the optical
    ``center`` (row, col, px), the ``region`` ``(r0, r1, c0, c1)`` it computes, the window positions ``Y``, ``X``
    (px, float64) with each one's ``cores`` and ``sizes`` (px, int64), the largest ``core``, the fraction of a pixel
    ``shift_y``, ``shift_x`` each window lies before its anchor pixel, whether mirror groups share a PSF
    (``symmetric``), the reflect ``pad`` (px) and the scheme's ``window`` (the PSFs' least grid)."""

    shape: tuple
    center: tuple
    region: tuple
    Y: torch.Tensor
    X: torch.Tensor
    cores: torch.Tensor
    sizes: torch.Tensor
    core: int
    shift_y: float
    shift_x: float
    symmetric: bool
    pad: int
    window: int

    def tents(self, dtype, device) -> dict:
        """Each core's 2-D tent ``(c, c)`` (:func:`tent_weights` at the plan's shifts), by core."""
        return {c: (tent_weights(c, dtype, self.shift_y)[:, None] * tent_weights(c, dtype, self.shift_x)[None, :]
                    ).to(device) for c in torch.unique(self.cores).tolist()}


def window_plan(shape, psf: PSFProvider, scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, *,
                fit: bool = False, zones: StrideZones | None = None, least_fit: int | None = None) -> WindowPlan:
    """The windows of a pass over an image of ``shape`` ``(..., H, W)`` (see :func:`apply_windowed` for the
    arguments): positions, cores, sizes and padding, before any transform."""
    check_provider(psf)
    H, W = shape[-2], shape[-1]
    if len(shape) == 4 and psf.channels not in (1, shape[1]):
        raise ValueError(f"the PSF provider has {psf.channels} channels and the image {shape[1]}: expected 1 or "
                         f"{shape[1]}")
    center = optical_center if optical_center is not None else frame_center(shape)
    region = tuple(region) if region is not None else (0, H, 0, W)
    Y, X, cores = _zoned_positions(shape, scheme, center, region, zones)  # positions (px, float64), cores
    core = int(cores.max()) if cores.numel() else scheme.core  # the accumulators' margin: the largest core
    # each window's patch and core sit on the pixel ceil(position); along an axis the positions are evenly
    # spaced from the optical centre, so every window lies the same fraction of a pixel before its pixel
    shift_y = float(torch.ceil(Y[0]) - Y[0]) if Y.numel() else 0.0
    shift_x = float(torch.ceil(X[0]) - X[0]) if X.numel() else 0.0
    # the origin grid has (almost) no mirror pairs: it keeps the first version's order of work, bit for bit
    symmetric = scheme.anchor == "axis" and bool(psf.mirror_symmetric)
    # each window's support, asked once: its size (the scheme's, fitted, or grown where the PSF outgrows it)
    extents = _extents(psf, Y, X, center, symmetric)
    sizes = torch.zeros_like(extents)
    for c in torch.unique(cores).tolist():
        sel = cores == c
        sub = WindowScheme(scheme.window, scheme.stride if c == scheme.core else c // 2, c, scheme.anchor, scheme.fit)
        sizes[sel] = window_sizes(extents[sel], sub, fit, least_fit)
    pad = max([scheme.window] + sizes.tolist()) // 2 + core
    return WindowPlan((H, W), center, region, Y, X, cores, sizes, core, shift_y, shift_x, symmetric, pad,
                      scheme.window)


def window_batches(plan: WindowPlan, psf: PSFProvider, image: torch.Tensor, chunk: int | None = None,
                   pedestal: bool = False):
    """The plan's windows in batches ``(w, c, anchors, otf)``: the window size ``w`` and core ``c`` (px), the anchor
    pixels ``[(row, col), ...]`` and their OTFs ``(k, 1, 1 or C, w, w/2 + 1)`` in ``image``'s dtype and on its device
    (see :func:`apply_windowed`), in the order :func:`apply_windowed` visits them. ``chunk``: windows per batch, a
    function of the window size giving it, or None (:func:`window_chunk`)."""
    win = plan.window
    for w in torch.unique(plan.sizes).tolist():
        k_chunk = chunk(w) if callable(chunk) else chunk if chunk is not None else window_chunk(image, w)
        otfs = _WindowOTFs(psf, plan.center, w, image.dtype, image.device, symmetric=plan.symmetric, n=max(w, win),
                           pedestal=win if pedestal else None)
        for c in torch.unique(plan.cores[plan.sizes == w]).tolist():
            sel = (plan.sizes == w) & (plan.cores == c)
            for gy, gx in otfs.chunks(plan.Y[sel], plan.X[sel], psf_batch(image, w, psf.channels, k_chunk, plan.symmetric)):
                group_otf = otfs(gy, gx)  # (k, 1, 1 or C, w, w/2+1): the PSFs of a few mirror groups at once
                for k in range(0, gy.numel(), k_chunk):  # the transforms in cache-sized batches
                    ys, xs = gy[k:k + k_chunk], gx[k:k + k_chunk]
                    anchors = list(zip(torch.ceil(ys).to(torch.int64).tolist(),
                                       torch.ceil(xs).to(torch.int64).tolist()))
                    yield w, c, anchors, group_otf[k:k + k_chunk]


def core_slices(plan: WindowPlan, c: int, y: int, x: int) -> tuple[slice, slice]:
    """The rows and columns of a ``c`` px core anchored at pixel ``(y, x)`` in the accumulators of :func:`run_windows`
    (the image with ``plan.core`` px each side)."""
    m = plan.core
    return slice(y + m - c // 2, y + m + c // 2), slice(x + m - c // 2, x + m + c // 2)


def weight_sum(plan: WindowPlan, batches, dtype, device) -> torch.Tensor:
    """The sum of the windows' tents over the accumulators ``(H + 2 core, W + 2 core)`` (each pixel's normaliser)."""
    H, W = plan.shape
    tents = plan.tents(dtype, device)
    wsum = torch.zeros(H + 2 * plan.core, W + 2 * plan.core, dtype=dtype, device=device)
    for _, c, anchors, _ in batches:
        for y, x in anchors:
            sl = core_slices(plan, c, y, x)
            wsum[sl[0], sl[1]] += tents[c]
    return wsum


def run_windows(image: torch.Tensor, plan: WindowPlan, batches, op, progress=None) -> torch.Tensor:
    """Run ``op(patches, otf, core)`` in every window of ``batches`` (from :func:`window_batches`, or a list of them kept)
    and blend the cores over the plan's region (zeros elsewhere): :func:`apply_windowed`'s work."""
    B, C, H, W = image.shape
    r0, r1, c0, c1 = plan.region
    core, pad = plan.core, plan.pad
    padded = _pad(image, pad)
    out = torch.zeros(B, C, H + 2 * core, W + 2 * core, dtype=image.dtype, device=image.device)
    wsum = torch.zeros(H + 2 * core, W + 2 * core, dtype=image.dtype, device=image.device)
    tents = plan.tents(image.dtype, image.device)
    for w, c, anchors, otf in batches:
        hw = w // 2
        tent2 = tents[c]
        patches = torch.stack([padded[:, :, y + pad - hw: y + pad + hw, x + pad - hw: x + pad + hw]
                               for y, x in anchors])  # (k, B, C, w, w)
        res = op(patches, otf, c)
        if res.is_complex():
            cores_k = core_irfft2(res, w, c)
        elif res.shape[-1] == c:  # the core itself (a whole window where w == c: the same)
            cores_k = res
        else:
            cores_k = res[..., hw - c // 2: hw + c // 2, hw - c // 2: hw + c // 2]
        for j, (y, x) in enumerate(anchors):
            sl = core_slices(plan, c, y, x)
            out[:, :, sl[0], sl[1]] += cores_k[j] * tent2
            wsum[sl[0], sl[1]] += tent2
        if progress is not None:
            progress(len(anchors))
    out = out[:, :, core:core + H, core:core + W]
    wsum = wsum[core:core + H, core:core + W]
    result = torch.zeros_like(image)
    result[:, :, r0:r1, c0:c1] = out[:, :, r0:r1, c0:c1] / wsum[r0:r1, c0:c1]
    return result


def _extents(psf: PSFProvider, Y, X, center, symmetric: bool) -> torch.Tensor:
    """The PSF support (px, int64) of the windows at ``(Y, X)`` (px). With symmetry it is asked at each window's
    canonical position, so a mirror group shares one value (and one fitted size)."""
    if symmetric:
        dy, dx = (Y - center[0]).abs(), (X - center[1]).abs()
        Y, X = center[0] + torch.minimum(dy, dx), center[1] + torch.maximum(dy, dx)
    return psf.extents_px(Y, X, center).to(torch.int64)


def blur_windowed(image: torch.Tensor, psf: PSFProvider, *, scheme: WindowScheme = PAPER_SCHEME,
                  optical_center=None, region=None, chunk: int | None = None, progress=None,
                  zones: StrideZones | None = None) -> torch.Tensor:
    """Blur ``image`` ``(B, C, H, W)`` with the spatially-variant PSF of the provider ``psf``.

    ``region = (r0, r1, c0, c1)`` computes only those output pixels (others are zero), using only
    the windows whose cores touch it. ``progress(k)`` is called after each chunk of ``k`` windows
    (``chunk``: default from :func:`window_chunk`). Runs on ``image``'s device and in its dtype.
    With ``scheme.fit`` (default) each window's transform is sized to the local PSF's support plus the core (at
    most ``scheme.window``; see :func:`apply_windowed`), the PSF still computed on the ``window`` grid and folded
    onto it: a core then differs from the ``window``-sized one only where the PSF's far diffraction tail wraps
    (1e-4 of the signal and less; the same > 70 dB against one PSF per pixel), at a fraction of the cost near
    the axis. ``fit=False``: every window ``scheme.window`` px (the paper's transforms). ``zones``
    (:class:`StrideZones`, e.g. :func:`choose_stride_zones`'s): coarser windows where the PSF varies slowly.
    """
    def convolve(patches, otf, core):
        return torch.fft.rfft2(patches).mul_(otf)

    out = apply_windowed(image, psf, convolve, scheme=scheme, optical_center=optical_center, region=region,
                         chunk=chunk, progress=progress, fit=scheme.fit, pedestal=True, zones=zones)
    fractions = psf.pedestal_fractions(scheme.window)
    if any(fractions):
        out = _add_box_mean(out, image, scheme.window, fractions, region)
    return out


BOX_BAND_ROWS = 1024
"""Output rows per band of :func:`box_mean` (its working set is about ``3 (band + n) (W + n)`` values per channel)."""


def box_mean(image: torch.Tensor, n: int, region=None) -> torch.Tensor:
    """The mean of ``image`` ``(B, C, H, W)`` over the ``n x n`` px box of every pixel, as a convolution with an
    ``n x n`` PSF of uniform value centred at ``[n/2, n/2]`` sees it: rows ``r - n/2 + 1 .. r + n/2``, the image
    reflect-padded as :func:`blur_exact` pads it. Only ``region = (r0, r1, c0, c1)`` is computed (zeros elsewhere).
    Summed-area differences in ``image``'s dtype, in bands of :data:`BOX_BAND_ROWS` output rows (a band's sums start
    afresh: in float32 a box mean is then exact to ~1e-6 of itself, 3e-9 of the signal once weighted by a pedestal)."""
    B, C, H, W = image.shape
    r0, r1, c0, c1 = region if region is not None else (0, H, 0, W)
    padded = _pad(image, n // 2)  # image row r is padded row r + n/2
    out = torch.zeros_like(image)
    for a in range(r0, r1, BOX_BAND_ROWS):
        b = min(r1, a + BOX_BAND_ROWS)
        slab = padded[:, :, a + 1: b + n, c0 + 1: c1 + n]  # rows a+1 .. b-1+n of the padding
        cs = torch.nn.functional.pad(slab.cumsum(dim=-2), (0, 0, 1, 0))
        rows = cs[:, :, n:] - cs[:, :, : b - a]  # (B, C, b - a, c1 - c0 + n - 1): each output row's n rows
        cs = torch.nn.functional.pad(rows.cumsum(dim=-1), (1, 0))
        out[:, :, a:b, c0:c1] = (cs[..., n:] - cs[..., : c1 - c0]).div_(n * n)
    return out


def _add_box_mean(out: torch.Tensor, image: torch.Tensor, n: int, fractions, region) -> torch.Tensor:
    """``out + fraction_c * box_mean(image)`` per channel (one fraction for every channel, or one per channel)."""
    f = torch.tensor(fractions, dtype=image.dtype, device=image.device)
    f = f.reshape(1, -1, 1, 1)
    return out.add_(box_mean(image, n, region).mul_(f))


def blur_exact(image: torch.Tensor, psf: PSFProvider, rows, cols, *, n: int = 512, optical_center=None) -> torch.Tensor:
    """Reference: each listed output pixel with the PSF of its own position (``(B, C, P)``).

    ``out(p) = sum_d PSF_p(d) x(p - d)`` over the ``n x n`` PSF support, reflect padding at the edges.
    """
    check_image(image)
    check_provider(psf)
    B, C, H, W = image.shape
    center = optical_center if optical_center is not None else frame_center(image.shape)
    rows, cols = tensor_of(rows), tensor_of(cols)
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
