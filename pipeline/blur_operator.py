"""The windowed, spatially varying blur as a linear operator with its adjoint (for iterative restorations).

``A = BlurOperator(psf, shape, scheme=..., optical_center=..., region=...)`` is the map
:func:`pipeline.blur.blur_windowed` computes, ``A.forward(x) == blur_windowed(x, psf, ...)`` (the same windows, OTFs
and order of work), kept: the windows are placed once and their OTFs computed once per dtype and device (while they
fit :data:`OPERATOR_OTF_BYTES`; else again on every pass), so an iteration pays for the transforms alone.

Written out, with ``P_w`` the window ``w``'s patch of the reflect-padded image, ``h_w`` its PSF (pedestal taken out,
folded onto the window), ``K_w`` the central core of a circular convolution over the window, ``T_w`` its tent,
``S`` the sum of the tents and ``f`` the pedestal fraction (:func:`pipeline.blur.box_mean` over the scheme's
window ``n``)::

    A x = (1 / S) sum_w T_w K_w (h_w (*) P_w pad(x)) + f box_n(x)        (over the region; 0 elsewhere)

and its adjoint, the exact transpose (``<A x, y> = <x, A^T y>``)::

    A^T y = pad^T sum_w P_w^T (h~_w (*) K_w^T (T_w y / S)) + f box_n^T(y)

``h~`` the mirrored PSF (the conjugate OTF), ``K_w^T`` the core placed in a window of zeros, ``P_w^T`` the patch added
back where it was read, ``pad^T`` the reflect padding folded back onto the pixels it copied and ``box_n^T`` the mean
over the reversed box (zeros beyond the region), in the box's own padding, folded back the same way (in one fold with
the windows' where both pad alike: by reflection, or by repeating the edge). All written out (no autograd graph:
memory stays that of one pass; tested against autograd's vector-Jacobian products).

Tensors are ``(B, C, H, W)`` (checked by :func:`pipeline.checks.check_image`), batched over ``B``, on any device and in
any floating dtype: each pass follows its input's (kornia style).
"""

from __future__ import annotations

import torch

from lenssim import PSFProvider, frame_center

from .blur import (PAPER_SCHEME, WindowScheme, box_mean, core_slices, pads_by_reflection, run_windows, weight_sum,
                   window_batches, window_plan)
from .checks import check_image, check_provider

__all__ = ["BlurOperator", "RegionProblem", "OPERATOR_OTF_BYTES"]

OPERATOR_OTF_BYTES = 1 << 30
"""Most bytes of window OTFs (and their conjugates, for the adjoint) an operator keeps per dtype and device (1 GiB: a
256 px crop with its context takes 40-120 MB in one channel; a 24 MP frame's ~24,000 windows would take 6 GB, so a frame's OTFs are computed again on
every pass instead of kept)."""


def _fold(g: torch.Tensor, p: int, n: int, dim: int, reflect: bool) -> torch.Tensor:
    """The transpose of padding ``p`` px each side of a length-``n`` axis ``dim`` (reflected, or the edge repeated):
    ``g`` (``n + 2 p`` long there) summed onto the ``n`` pixels its values were copied from."""
    out = g.narrow(dim, p, n).clone()
    if p == 0:
        return out
    if reflect:  # padded p - 1 - i holds pixel 1 + i, padded n + p + i pixel n - 2 - i (i = 0 .. p - 1)
        out.narrow(dim, 1, p).add_(g.narrow(dim, 0, p).flip(dim))
        out.narrow(dim, n - 1 - p, p).add_(g.narrow(dim, n + p, p).flip(dim))
    else:
        out.narrow(dim, 0, 1).add_(g.narrow(dim, 0, p).sum(dim, keepdim=True))
        out.narrow(dim, n - 1, 1).add_(g.narrow(dim, n + p, p).sum(dim, keepdim=True))
    return out


def _pad_transpose(g: torch.Tensor, p: int, shape) -> torch.Tensor:
    """The transpose of :func:`pipeline.blur._pad` ``(., p)`` on images of ``shape`` ``(H, W)``: ``g``
    ``(..., H + 2 p, W + 2 p)`` folded back onto the pixels the padding copied (columns, then rows)."""
    H, W = shape
    reflect = pads_by_reflection(p, shape)
    return _fold(_fold(g, p, W, -1, reflect), p, H, -2, reflect)


def _conjugate(otf: torch.Tensor) -> torch.Tensor:
    """The conjugate of the OTFs ``otf`` ``(..., w, w/2 + 1)``, column-major (as :meth:`BlurOperator.adjoint`'s
    spectra are laid out)."""
    return otf.conj().resolve_conj().transpose(-1, -2).contiguous().transpose(-1, -2)


def _box_sums_transpose(t: torch.Tensor, n: int, dim: int) -> torch.Tensor:
    """The transpose of the sums over ``n`` consecutive entries along ``dim`` (:func:`pipeline.blur.box_mean`'s, one
    axis): ``t`` (``h`` long there) zero-extended, summed over the ``n`` entries ending at each of ``h + n - 1``
    positions (``out[k] = t[k - n + 1] + ... + t[k]``), as differences of one running sum over ``t``."""
    h = t.shape[dim]
    cs = t.cumsum(dim)
    shape = list(t.shape)
    shape[dim] = h + n - 1
    out = t.new_empty(shape)
    out.narrow(dim, 0, h).copy_(cs)  # k < h: the sum up to k ...
    out.narrow(dim, h, n - 1).copy_(cs.narrow(dim, h - 1, 1).expand_as(out.narrow(dim, h, n - 1)))  # ... or all of t
    out.narrow(dim, n, h - 1).sub_(cs.narrow(dim, 0, h - 1))  # less the sum up to k - n
    return out


class BlurOperator:
    """The windowed blur of ``psf`` over images of ``shape`` ``(..., H, W)`` as a linear operator (module docstring):
    :meth:`forward` is :func:`pipeline.blur.blur_windowed` with the same ``scheme``, ``optical_center`` (row, col,
    px; default the image's centre) and ``region`` ``(r0, r1, c0, c1)`` (the output pixels computed; zeros
    elsewhere), :meth:`adjoint` its transpose."""

    def __init__(self, psf: PSFProvider, shape, *, scheme: WindowScheme = PAPER_SCHEME, optical_center=None,
                 region=None, otf_bytes: int = OPERATOR_OTF_BYTES):
        check_provider(psf)
        self.psf, self.scheme, self.otf_bytes = psf, scheme, int(otf_bytes)
        H, W = int(shape[-2]), int(shape[-1])
        if region is not None:
            r0, r1, c0, c1 = (int(v) for v in region)
            if not (0 <= r0 < r1 <= H and 0 <= c0 < c1 <= W):
                raise ValueError(f"region {tuple(region)} is not allowed: (r0, r1, c0, c1) inside the {H} x {W} image "
                                 "with r0 < r1 and c0 < c1")
            region = (r0, r1, c0, c1)
        self.plan = window_plan(tuple(shape), psf, scheme, optical_center, region, fit=scheme.fit)
        self.fractions = psf.pedestal_fractions(scheme.window)
        self._kept = {}  # (dtype, device, B, C) -> (the window batches, the weight sum)

    @property
    def shape(self) -> tuple[int, int]:
        """The image size ``(H, W)`` (px) the operator maps from and to."""
        return self.plan.shape

    @property
    def region(self) -> tuple[int, int, int, int]:
        return self.plan.region

    @property
    def windows(self) -> int:
        """The number of windows a pass visits."""
        return int(self.plan.Y.numel())

    def _check(self, x: torch.Tensor, name: str):
        sizes = check_image(x, name)
        if (sizes["H"], sizes["W"]) != self.shape:
            raise ValueError(f"{name} is {sizes['H']} x {sizes['W']} px: this operator maps images of "
                             f"{self.shape[0]} x {self.shape[1]} px")
        if self.psf.channels not in (1, sizes["C"]):
            raise ValueError(f"the PSF provider has {self.psf.channels} channels and {name} {sizes['C']}: expected "
                             f"1 or {self.psf.channels}")

    def _windows(self, x: torch.Tensor):
        """The window batches for images like ``x`` and the tents' sum: kept after the first pass where they fit."""
        key = (x.dtype, x.device, x.shape[0], x.shape[1])  # the batches' sizes follow B and C (a cache's worth)
        if key in self._kept:
            return self._kept[key]
        itemsize = x.element_size() * 2  # complex
        need = sum(int(w) * (int(w) // 2 + 1) for w in self.plan.sizes.tolist()) * itemsize * self.psf.channels
        batches = lambda: window_batches(self.plan, self.psf, x, None, pedestal=True)  # noqa: E731
        if 2 * need <= self.otf_bytes:  # the OTFs and their conjugates (a conjugate view multiplies ~2x slower)
            kept = list(batches())
            found = (kept, weight_sum(self.plan, kept, x.dtype, x.device), [_conjugate(otf) for _, _, _, otf in kept])
        else:  # too many to keep: the OTFs again on every pass (the same ones, in the same order)
            found = (_Replay(batches), weight_sum(self.plan, batches(), x.dtype, x.device), None)
        self._kept[key] = found
        return found

    def forward(self, x: torch.Tensor, progress=None) -> torch.Tensor:
        """``A x`` for ``x`` ``(B, C, H, W)``: :func:`pipeline.blur.blur_windowed` of ``x``."""
        self._check(x, "x")
        batches, _, _ = self._windows(x)

        def convolve(patches, otf, core):
            return torch.fft.rfft2(patches).mul_(otf)

        out = run_windows(x, self.plan, batches, convolve, progress)
        if any(self.fractions):
            out = out.add_(box_mean(x, self.scheme.window, self.plan.region).mul_(self._fractions(x)))
        return out

    __call__ = forward

    def _fractions(self, x):
        return torch.tensor(self.fractions, dtype=x.dtype, device=x.device).reshape(1, -1, 1, 1)

    def adjoint(self, y: torch.Tensor, progress=None) -> torch.Tensor:
        """``A^T y`` for ``y`` ``(B, C, H, W)`` (only its region is read): the transpose of :meth:`forward`."""
        self._check(y, "y")
        plan = self.plan
        batches, wsum, conjugates = self._windows(y)
        B, C, H, W = y.shape
        r0, r1, c0, c1 = plan.region
        m, pad = plan.core, plan.pad
        z = torch.zeros(B, C, H + 2 * m, W + 2 * m, dtype=y.dtype, device=y.device)
        z[..., m + r0:m + r1, m + c0:m + c1] = y[..., r0:r1, c0:c1] / wsum[m + r0:m + r1, m + c0:m + c1]
        grad = torch.zeros(B, C, H + 2 * pad, W + 2 * pad, dtype=y.dtype, device=y.device)
        tents = plan.tents(y.dtype, y.device)
        for i, (w, c, anchors, otf) in enumerate(batches):
            hw, lo = w // 2, w // 2 - c // 2
            cores = torch.stack([z[:, :, s0, s1] for s0, s1 in (core_slices(plan, c, a, b) for a, b in anchors)])
            cores.mul_(tents[c])  # (k, B, C, c, c)
            # rfft2 of the core placed at [lo, lo + c) in a w x w window of zeros: the row transforms of its c rows,
            # then the column transforms of the w rows (K_w^T, the transpose of core_irfft2's pruned inverse), the
            # columns laid out as rows (the spectrum column-major: its transforms and product run on contiguous
            # memory, ~20% faster than along the rows' stride; on the CPU the same numbers, bit for bit)
            rows = torch.fft.rfft(torch.nn.functional.pad(cores, (lo, w - lo - c)), dim=-1)
            spec = torch.fft.fft(torch.nn.functional.pad(rows.transpose(-1, -2), (lo, w - lo - c)), dim=-1)
            otf_conj = conjugates[i] if conjugates is not None else _conjugate(otf)
            spec = spec.transpose(-1, -2).mul_(otf_conj)  # h~ (*): the conjugate OTF (laid out alike)
            patches = torch.fft.irfft2(spec, s=(w, w))
            for j, (a, b) in enumerate(anchors):
                grad[:, :, a + pad - hw: a + pad + hw, b + pad - hw: b + pad + hw] += patches[j]
            if progress is not None:
                progress(len(anchors))
        if not any(self.fractions):
            return _pad_transpose(grad, pad, (H, W))
        # the box mean's transpose: the mean over the reversed box (zeros beyond the region) in the n/2 px padding's
        # frame, folded back as that padding is; the same fold as the windows' where both pad alike (the n/2 px
        # padding is then the middle of the windows' pad px one)
        n = self.scheme.window
        g = y[..., r0:r1, c0:c1] * self._fractions(y)
        box = _box_sums_transpose(_box_sums_transpose(g, n, -2), n, -1).div_(n * n)  # the padding's r0+1 .. r1+n-1
        if pads_by_reflection(pad, (H, W)) == pads_by_reflection(n // 2, (H, W)):
            o = pad - n // 2  # the n/2 px padding's row 0 in grad
            grad[..., o + r0 + 1: o + r1 + n, o + c0 + 1: o + c1 + n] += box
            return _pad_transpose(grad, pad, (H, W))
        padded = torch.zeros(B, C, H + n, W + n, dtype=y.dtype, device=y.device)
        padded[..., r0 + 1: r1 + n, c0 + 1: c1 + n] = box
        return _pad_transpose(grad, pad, (H, W)).add_(_pad_transpose(padded, n // 2, (H, W)))

    def ones_adjoint(self, like: torch.Tensor) -> torch.Tensor:
        """``A^T 1`` over the region, in ``like``'s dtype and on its device (``(B, C, H, W)`` of ``like``): how much
        of each pixel's light lands in the region (Richardson-Lucy's normaliser)."""
        ones = torch.zeros_like(like)
        r0, r1, c0, c1 = self.plan.region
        ones[..., r0:r1, c0:c1] = 1
        return self.adjoint(ones)


class _Replay:
    """Window batches made afresh on every iteration (OTFs too large to keep)."""

    def __init__(self, make):
        self.make = make

    def __iter__(self):
        return iter(self.make())


class RegionProblem:
    """An iterative restoration's problem around a region of a frame: the observed pixels the estimate spans (``y``),
    the blur's operator over them (``A``, whose ``region`` is the data: the region and ``context`` px around it) and
    where they sit in the frame (``origin``: the frame's row and column of ``y[..., 0, 0]``).

    The estimate reaches beyond the data as far as the data's windows read (half the largest window, half a core and
    the pixel a window may lie before its anchor; for the ``"origin"`` anchor from a multiple of the stride, so the
    windows stay in place): the light that falls into the data from outside it is estimated too, the boundary
    unknown, as [Bertero-Boccacci 2005] do for Richardson-Lucy."""

    def __init__(self, observed: torch.Tensor, psf: PSFProvider, *, scheme: WindowScheme = PAPER_SCHEME,
                 optical_center=None, region=None, context: int = 0):
        check_image(observed, "observed")
        if isinstance(context, bool) or not (isinstance(context, int) and context >= 0):
            raise ValueError(f"context={context!r} is not allowed: an integer >= 0 (px)")
        self.frame_shape, self.scheme = tuple(observed.shape), scheme
        H, W = observed.shape[-2:]
        self.center = optical_center if optical_center is not None else frame_center(observed.shape)
        self.region = tuple(int(v) for v in region) if region is not None else (0, H, 0, W)
        r0, r1, c0, c1 = self.region
        self.data = (max(r0 - context, 0), min(r1 + context, H), max(c0 - context, 0), min(c1 + context, W))
        plan = window_plan(observed.shape, psf, scheme, self.center, self.data, fit=scheme.fit)
        reach = int(plan.sizes.max()) // 2 + scheme.core // 2 + 1 if plan.sizes.numel() else 0
        R0, C0 = self.data[0] - reach, self.data[2] - reach
        if scheme.anchor == "origin":
            R0, C0 = -(-R0 // scheme.stride) * scheme.stride, -(-C0 // scheme.stride) * scheme.stride
        R0, C0 = max(R0, 0), max(C0, 0)
        R1, C1 = min(self.data[1] + reach, H), min(self.data[3] + reach, W)
        self.origin = (R0, C0)
        self.y = observed[..., R0:R1, C0:C1]
        d = self.data
        self.A = BlurOperator(psf, self.y.shape, scheme=scheme, optical_center=(self.center[0] - R0, self.center[1] - C0),
                              region=(d[0] - R0, d[1] - R0, d[2] - C0, d[3] - C0))

    @property
    def local_data(self) -> tuple[int, int, int, int]:
        """The data's box in ``y``'s pixels."""
        return self.A.region

    def mask(self) -> torch.Tensor:
        """1 over the data, 0 elsewhere, shaped as ``y``."""
        d = self.local_data
        m = torch.zeros_like(self.y)
        m[..., d[0]:d[1], d[2]:d[3]] = 1
        return m

    def ticks(self, iterations: int, progress):
        """``tick(k)``: reports to ``progress`` after iteration ``k`` its share of the region's windows (so a progress
        bar over every method's windows ends where it should); a no-op without ``progress``."""
        from .blur import window_count

        n = window_count(self.frame_shape, self.scheme, self.center, region=self.region)
        share = [len(range(i, n, iterations)) for i in range(iterations)]

        def tick(k):
            if progress is not None and share[k]:
                progress(share[k])

        return tick

    def place(self, u: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        """The estimate ``u`` (shaped as ``y``) over the region, in a frame of zeros shaped as ``like``."""
        r0, r1, c0, c1 = self.region
        R0, C0 = self.origin
        out = torch.zeros_like(like)
        out[..., r0:r1, c0:c1] = u[..., r0 - R0:r1 - R0, c0 - C0:c1 - C0]
        return out
