"""Adaptive local Wiener restoration in the windows of the blur (paper Section 3.3).

In every window (same scheme as :mod:`pipeline.blur`: local PSF at the window centre, cores
blended linearly) and for every channel:

* ``mu`` and ``var_y``: mean and variance of the observed image over the central ``stats`` x ``stats``
  pixels of the window (the local statistics);
* noise variance at that mean, ``sigma_n^2 = noise.variance(mu)``: the camera chain's noise description
  (:class:`pipeline.camera_chain.NoiseModel`), for the paper's sensor the Poisson ``mu / e`` with ``e`` the number of
  electrons per unit of the linear image (``full_well / peak`` in the simulation), plus each further term of the
  sensor (read noise, dark current, DSNU, ADC rounding, PRNU) where it is on;
* signal variance of the *unblurred* image: ``sigma_x^2 = max(var_y - sigma_n^2, floor) / <|H|^2 P>``
  (blur scales the variance of a signal with spectrum ``P`` by the mean of ``|H|^2 P``);
* Wiener filter with the paper's image model ``P`` (``rho0^|r|``, unit variance, the same spectrum
  as :func:`lenssim.image_psd`) scaled by ``sigma_x^2``:
  ``G = conj(H) sigma_x^2 P / (|H|^2 sigma_x^2 P + sigma_n^2)`` applied to ``y - mu``, then ``+ mu``.

With no blur (``H = 1``) and no noise (``NoiseModel(math.inf)``) this is the identity.

The window's deviation from its local mean, ``y - mu``, is tapered to zero towards the window's edges before the
transform (a raised cosine over the outer :data:`WIENER_TAPER_PX` px along each edge, never reaching the core; option
``taper``, in px, 0: the paper's plain window). The transform treats the window as periodic: without the taper
the jump between a bright structure at one edge of the window and a dark region at the opposite edge is restored as
if it were an edge of the scene, and the filter, close to the inverse filter where the signal is strong, rings from it
into the core (see :data:`WIENER_TAPER_PX` for the measurements).

Option ``local="pixel"`` (``wiener:local=pixel``): a per-pixel adaptive signal variance. Local variance maps over
``pixel_stats`` x ``pixel_stats`` px boxes (kornia ``box_blur`` over each window's core and its halo) give each pixel's
signal variance relative to the window's, ``r = max(var_y(p) - sigma_n^2(p), floor) / max(mean over the core, floor)``
(``sigma_n^2(p)``: the noise description at the box's mean);
the window is restored with a bank of filters at ``sigma_x^2 * WIENER_PIXEL_LEVELS`` and each pixel takes the two
nearest in ``log r`` (linearly; clamped to the bank's ends). ``local="window"`` (the default): the paper's filter.

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Section 3.3 (the adaptive local Wiener filter) and Eq. (4).
.. [2] J.-S. Lee, "Digital image enhancement and noise filtering by use of local statistics", IEEE Trans.
   Pattern Anal. Mach. Intell. PAMI-2(2), 165-168 (1980): local mean and variance estimates.
"""

from __future__ import annotations

import math

import torch

from lenssim import PSFProvider, frame_center, image_psd

from lenssim.torch_utils import HOST, abs_square, centred_variance

from ..blur import PAPER_SCHEME, StrideZones, WindowScheme, apply_windowed, core_irfft2, window_chunk, window_count
from ..blur_operator import RegionProblem
from ..camera_chain import NoiseModel
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, register, windowed_margin

__all__ = ["wiener_windowed", "wiener_start", "WindowModel", "check_wiener_options", "WIENER_STATS_PX",
           "WIENER_FIT_LEAST_PX", "WIENER_LOCAL", "WIENER_PIXEL_LEVELS", "WIENER_PIXEL_STATS_PX", "WIENER_TAPER_PX",
           "window_taper", "WIENER_BANK_LEVELS", "WIENER_BANK_MOST_LEVELS", "WIENER_BANK_MULTIPLE",
           "WIENER_BANK_STATS_DIVISOR", "WIENER_BANK_WORKING_COPIES", "bank_scheme", "bank_points", "check_bank", "chebyshev_gauss",
           "lagrange_weights"]

WIENER_STATS_PX = 128
"""Side (px) of the central square of a window over which the local mean and variance are taken."""

WIENER_LOCAL = ("window", "pixel")
"""Where the signal variance adapts: once per window (the paper), or per pixel (see the module docstring)."""

WIENER_PIXEL_LEVELS = (0.25, 1.0, 4.0)
"""Signal-variance levels (relative to the window's) of the per-pixel filter bank: each pixel interpolates between
the two nearest in log variance (a pixel at the window's own level gets the paper's filter). The bank's ends clamp:
flat regions get the 1/4 level's smoothing at most."""

WIENER_PIXEL_STATS_PX = 9
"""Side (px) of the box over which the per-pixel local variance is taken."""

WIENER_FIT_LEAST_PX = 384
"""Least transform (px) of a Wiener window fitted to the local PSF (the blur's least is 256). The filter's impulse
response reaches beyond the PSF's support, and what the window's edges wrap into the core comes back ringing: on a
sharp photo near the axis (scikit-image's astronaut at ISO 100, supports of 20-40 px) 256 px windows moved the
restored SSIM by -0.0043 and PSNR by -0.025 dB from 512 px windows, 320 px by -0.0012 / -0.011 dB, 384 px by -0.0002
/ -0.004 dB, 448 px by -0.0003 / -0.001 dB (issue 33's bounds: 0.001 and 0.02 dB)."""

WIENER_TAPER_PX = 96
"""Width (px) of the band along each edge of a window over which the window's deviation from its local mean is tapered
to zero (raised cosine) before the filter's transform, so that the periodic window the transform assumes has no jump
at its edges; at most a quarter of a smaller window's side, and ``(window - core) / 2``, so the core is never tapered.

Root cause of issue 45's "restored below the sensor image": on the pier sunset photo (RMS_W design, 10 deg, crop rows
3259-3515, cols 4954-5210) a bright band (linear ~0.07) at the top of the crop's 384 px windows faced their dark
bottom (~0.004) across the periodic wrap, and the restored crop rang with a period of ~37 px: ISO 100 27.84 dB against
the sensor image's 30.60, ISO 400 29.33 against 29.19; fixed 512 / 1024 px windows without a taper gave 29.87 / 31.32
(ISO 100); smaller statistics boxes only hid it by regularising more (32 px: 30.68, at -1.25 dB on the centre crop).
Tapering 48 / 56 / 64 / 96 px: 30.90 / 31.54 / 31.88 / 32.26 dB (ISO 400 with 96 px: 32.25). On a synthetic band over
a dark region (tests/pipeline/test_restoration_edges.py) 48 and 56 px still left a crop below the sensor image
(39.58 / 40.90 dB against 43.60); 96 px none. On the frame's corner crops (pier, portrait; both designs; ISO 100 and
400) 15 / 25 / 35 % of a 384 px window's side were within 0.45 dB of each other, 25 % (96 px) at most 0.22 dB below
the best; the centre crops of the three photos moved by 0.02 dB or less. The cost: tapered data near the window's edges
no longer reach the core. On the astronaut frame of ``tests/pins.json`` (sharp, 280-1000 px off axis, ISO 100) 56 / 96
px moved the restored PSNR by -0.016 / -0.026 dB and SSIM by -0.0028 / -0.0045, and the 384 px windows fitted to the
PSF fell 0.0011 / 0.0020 in SSIM below 512 px windows with the same band (48 px: 0.0009; issue 33 bounds the plain
filter's to 0.001). Blending the edges with the circularly blurred window instead (MATLAB's ``edgetaper``) scored
within 0.35 dB of the plain taper at two more transforms per window; the periodic-plus-smooth decomposition (Moisan
2011, the smooth part left unfiltered) 31.20 dB on the pier crop and -0.74 dB on the astronaut frame."""

WIENER_RHO0 = 0.97
"""The filter's image prior: correlation per pixel of the ``rho0^|r|`` model (the value of the paper's image
model, Section 2.3; a method option, ``wiener:rho0=...``)."""

WIENER_BANK_LEVELS = 3
"""Filters per window of the bank evaluation that the whole frame runs (option ``bank``; see :func:`wiener_windowed`):
noise-to-signal ratios ``K`` at Chebyshev-Gauss nodes in ``log K`` over the span of the window's points, each pixel
taking the filters' outputs by Lagrange interpolation (0: the paper's one filter per window). Measured against the
filter at a stride of 16 px on 12 crops of the forest and pier photos (0-11 deg, ISO 100 and 400, E2E design;
docs/performance.md): with 3 filters every crop nearer the filter's image than the paper's stride (58.5-84.2 dB
against 52.8-78.4 dB) and its restored PSNR within 0.017 dB of the filter's (mean 0.0074 dB; the paper's stride 0.063
/ 0.025 dB): on the PSNR as near as 4 filters (0.017 / 0.0070 dB; their images 58.7-87.0 dB from the filter's), for
three quarters of their inverse transforms. At Chebyshev-Lobatto nodes (both ends of the span) 3 filters were 0.071
dB from the filter's PSNR on one crop (the forest at 11.4 deg, ISO 400; the paper's stride 0.060 there) and up to 3.2
dB further from its image than at Gauss nodes (0.2-3.2 dB on 11 crops, equal on the 12th), whose nodal polynomial is
1.5x smaller. Fewer filters where a batch's points agree (one more per 2.0 of their span of ``log K``) jumped the
result by up to 2e-3 where a rounding moved a span across a step (float32 against float64 on a test scene: 2.3e-3
against 2.3e-7 with a fixed count): not kept."""

WIENER_BANK_MOST_LEVELS = 8
"""Most filters per window of the bank (each one an inverse transform of the window's spectrum)."""

WIENER_BANK_MULTIPLE = 2
"""The bank's windows lie at this multiple of the scheme's stride, with this multiple of its core."""

WIENER_BANK_WORKING_COPIES = 6
"""Values a bank window holds per pixel and channel of its patch (its patch, spectrum, filtered spectrum and a
level's filter), for its batches' size (:func:`pipeline.blur.window_chunk`): half the paper's windows per batch. On
the forest photo's squares, batches of the default size (3 to 6 windows of 384-512 px) ran 12-22% slower.
"""

WIENER_BANK_STATS_DIVISOR = 2
"""The bank's statistics lie at the scheme's stride divided by this (16 px for the paper's 32), each over the central
``stats`` px of the window a finer scheme would put there."""


def window_taper(window: int, core: int, width: int, dtype=torch.float64, device=HOST) -> torch.Tensor:
    """The ``(window, window)`` separable raised-cosine taper: 1 over the centre, ``0.5 - 0.5 cos(pi (i + 1/2) / n)``
    at the ``i``-th pixel from each edge, over the outer ``n = min(width, window / 4, (window - core) / 2)`` px of each
    side (so the central half of a small window and the ``core`` px stay 1); all ones for ``width = 0``."""
    n = min(int(width), window // 4, (window - core) // 2)
    t = torch.ones(window, dtype=torch.float64, device=HOST)
    if n > 0:
        ramp = 0.5 - 0.5 * torch.cos(math.pi * (torch.arange(n, dtype=torch.float64, device=HOST) + 0.5) / n)
        t[:n], t[window - n:] = ramp, ramp.flip(0)
    return (t[:, None] * t[None, :]).to(dtype=dtype, device=device)



def chebyshev_gauss(n: int) -> tuple[float, ...]:
    """``n >= 1`` Chebyshev-Gauss nodes on ``[0, 1]`` (the roots of the degree-``n`` Chebyshev polynomial, increasing,
    the ends excluded): ``(1 - cos(pi (j + 1/2) / n)) / 2``. Of all ``n`` nodes on an interval they make the least
    largest nodal polynomial ``prod (t - t_j)``, the factor of a polynomial interpolant's error."""
    return tuple(0.5 - 0.5 * math.cos(math.pi * (j + 0.5) / n) for j in range(n))


def lagrange_weights(t: torch.Tensor, nodes) -> list[torch.Tensor]:
    """The Lagrange basis polynomials of ``nodes`` at ``t``: the weights that interpolate values at the nodes to ``t``
    (a polynomial of degree ``len(nodes) - 1``; they sum to 1)."""
    out = []
    for j, xj in enumerate(nodes):
        w = torch.ones_like(t)
        for i, xi in enumerate(nodes):
            if i != j:
                w = w * ((t - xi) / (xj - xi))
        out.append(w)
    return out


def bank_points(scheme: WindowScheme) -> tuple[int, int, float]:
    """The bank's grid of statistics (option ``bank``) inside one of its windows: its step (px), the number ``J`` of
    points each side of the window's centre whose tents reach its core (``2 J + 1`` along each axis) and the half-width
    (px) of their tents (the scheme's core over :data:`WIENER_BANK_STATS_DIVISOR`, halved)."""
    step = scheme.stride // WIENER_BANK_STATS_DIVISOR
    half = scheme.core / (2 * WIENER_BANK_STATS_DIVISOR)
    # a point j step px from the centre reaches the core's last pixel (< core / 2 from it) while j step < core / 2 + half
    return step, math.ceil((WIENER_BANK_MULTIPLE * scheme.core / 2 + half) / step) - 1, half


def bank_scheme(scheme: WindowScheme) -> WindowScheme:
    """The bank's windows: :data:`WIENER_BANK_MULTIPLE` times the scheme's stride and core."""
    m = WIENER_BANK_MULTIPLE
    return WindowScheme(scheme.window, m * scheme.stride, m * scheme.core, scheme.anchor, scheme.fit)


def check_bank(bank, scheme: WindowScheme | None, stats: int, fit: bool, what: str = "bank") -> None:
    """``ValueError`` where the bank evaluation cannot run: ``bank`` not 0 or 3 to :data:`WIENER_BANK_MOST_LEVELS`,
    the scheme's stride not a multiple of :data:`WIENER_BANK_STATS_DIVISOR`, twice its core over its window, or the
    statistics of the points nearest a window's edge reaching beyond its smallest window (``scheme`` None: the
    level count alone)."""
    if isinstance(bank, bool) or not isinstance(bank, int) or not (bank == 0 or 3 <= bank <= WIENER_BANK_MOST_LEVELS):
        raise ValueError(f"{what}={bank!r} is not allowed: 0 (the paper's evaluation, one filter per window) or a "
                         f"number of filters from 3 to {WIENER_BANK_MOST_LEVELS}")
    if not bank or scheme is None:
        return
    if scheme.stride % WIENER_BANK_STATS_DIVISOR:
        raise ValueError(f"{what}={bank}: the bank's statistics lie at the stride over {WIENER_BANK_STATS_DIVISOR}; "
                         f"the stride {scheme.stride} px is not a multiple of it")
    if WIENER_BANK_MULTIPLE * scheme.core > scheme.window:
        raise ValueError(f"{what}={bank}: the bank's windows take {WIENER_BANK_MULTIPLE}x the core "
                         f"({WIENER_BANK_MULTIPLE * scheme.core} px), over the window ({scheme.window} px)")
    step, J, _ = bank_points(scheme)
    least = min(WIENER_FIT_LEAST_PX, scheme.window) if fit and stats <= WIENER_FIT_LEAST_PX else scheme.window
    reach = J * step + stats // 2
    if 2 * reach > least:
        raise ValueError(f"{what}={bank}: the statistics of its points reach {reach} px from a window's centre (stats "
                         f"{stats} px), beyond the smallest window's half ({least // 2} px); use a smaller stats box")


class WindowModel:
    """The adaptive Wiener's model of one window (the module docstring): the image PSD ``P`` and the taper on each
    window size, and per window and channel the local mean, the noise variance at it and the signal variance of the
    unblurred image. Shared by the methods that start from this filter's windows."""

    def __init__(self, noise: NoiseModel, *, rho0: float, stats: int, taper: int, core: int, floor: float,
                 dtype, device):
        self.noise, self.rho0, self.stats, self.taper, self.core, self.floor = noise, rho0, stats, taper, core, floor
        self.dtype, self.device = dtype, device
        self._grids = {}

    def grid(self, win: int):
        """The image PSD ``P`` on a ``win`` px window (half-plane, mean 1), the half-plane's column weights
        (the scheme's window, or a larger one where the PSF outgrows it: see :func:`pipeline.blur.window_sizes`) and
        the window's taper."""
        if win not in self._grids:
            half = win // 2
            P = image_psd(win, self.rho0, dtype=self.dtype, device=self.device)[:, : half + 1]
            w = torch.full((half + 1,), 2.0, dtype=P.dtype, device=P.device)
            w[0] = w[-1] = 1
            self._grids[win] = (P / P.mean(), w, window_taper(win, self.core, self.taper, self.dtype, self.device))
        return self._grids[win]

    def deviation_spectrum(self, patches: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
        """``rfft2`` of the window's deviation from its local mean, tapered towards the window's edges."""
        return torch.fft.rfft2((patches - mu).mul_(self.grid(patches.shape[-1])[2]))

    def spectral_terms(self, H: torch.Tensor, win: int):
        """``|H|^2 P``, the blur's gain on the signal's variance ``<|H|^2 P>`` (``(k, 1, 1 or C, 1, 1)``) and ``P``
        for OTFs ``H`` ``(k, 1, 1 or C, win, win/2+1)``."""
        P, w, _ = self.grid(win)
        HP = abs_square(H).mul_(P)
        # <|H|^2 P> over the full grid from the half-plane (rfft layout: inner columns count twice)
        gain = (HP * w).sum(dim=(-2, -1), keepdim=True) / (win * win)
        return HP, gain, P

    def terms(self, patches: torch.Tensor, H: torch.Tensor):
        """The window's local mean, noise variance, ``|H|^2 P`` and signal variance (H: ``(k, 1, 1 or C, win,
        win/2+1)``), and ``P``."""
        win = patches.shape[-1]
        half, stats = win // 2, self.stats
        centre = patches[..., half - stats // 2: half + stats // 2, half - stats // 2: half + stats // 2]
        mu = centre.mean(dim=(-2, -1), keepdim=True)
        var_y = centred_variance(centre, mu, (-2, -1))
        var_n = self.noise.variance(mu)
        HP, gain, P = self.spectral_terms(H, win)
        return mu, var_n, HP, (var_y - var_n).clamp_min(self.floor) / gain, P


def wiener_windowed(observed: torch.Tensor, psf: PSFProvider, *, noise: NoiseModel,
                    rho0: float = WIENER_RHO0, stats: int = WIENER_STATS_PX,
                    scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int | None = None,
                    progress=None, floor: float = 1e-10, local: str = "window",
                    pixel_stats: int = WIENER_PIXEL_STATS_PX, fit: bool | None = None,
                    taper: int = WIENER_TAPER_PX, zones: StrideZones | None = None, bank: int = 0) -> torch.Tensor:
    """Restore a linear sensor image ``(B, C, H, W)`` blurred by the provider's PSFs, with the noise ``noise``
    describes (:class:`pipeline.camera_chain.NoiseModel`: a camera chain's ``noise_model()``, or
    ``NoiseModel(electrons_per_unit)`` for photon noise alone, ``math.inf``: none).

    ``fit`` (default ``scheme.fit``): each window's transform sized to the local PSF's support plus the core as the
    blur's are (:func:`pipeline.blur.fitted_windows`), but at least :data:`WIENER_FIT_LEAST_PX`, its statistics still
    over the central ``stats`` px (docs/performance.md); off where ``stats`` is over that size. ``taper``: the
    width (px) of the band along each edge of a window over which ``y - mu`` is tapered (:data:`WIENER_TAPER_PX`; 0:
    none). ``zones``: coarser windows where the PSF varies slowly (:class:`pipeline.blur.StrideZones`, as the blur's;
    None: the scheme's stride everywhere, the paper's restoration).

    ``bank`` (0: off, the paper's evaluation; else 3 to :data:`WIENER_BANK_MOST_LEVELS` filters): the same filter
    evaluated with :data:`WIENER_BANK_MULTIPLE` times fewer windows along each axis and its statistics on a finer grid.
    The windows lie at twice the scheme's stride with twice its core. Inside each, the local mean and variance are
    taken as the paper's windows take them, over the central ``stats`` px, around every point of a grid at half the
    scheme's stride (:data:`WIENER_BANK_STATS_DIVISOR`): each point has its noise-to-signal ratio ``K``. The window's
    deviation is filtered at ``bank`` values of ``K`` spanning its points' (Chebyshev-Gauss nodes in ``log K``), and
    each pixel takes the outputs with the weights the points' tents and Lagrange interpolation in ``log K`` give it.
    The paper's windows interpolate the whole filter linearly over 32 px; the bank interpolates the PSF over 64 px
    but the statistics, which carry most of the stride's error, over 16 px (docs/performance.md).
    Returns the same shape.
    """
    check_image(observed, "observed")
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: expected a pipeline.camera_chain.NoiseModel")
    if not (isinstance(stats, int) and 2 <= stats <= scheme.window):
        raise ValueError(f"stats={stats!r} is not allowed: an integer in [2, window={scheme.window}]")
    if local not in WIENER_LOCAL:
        raise ValueError(f"local={local!r} is not allowed: one of {', '.join(WIENER_LOCAL)}")
    if not (isinstance(pixel_stats, int) and not isinstance(pixel_stats, bool) and pixel_stats >= 3
            and pixel_stats % 2 == 1 and pixel_stats <= scheme.window - scheme.core):
        raise ValueError(f"pixel_stats={pixel_stats!r} is not allowed: an odd number of px, >= 3 and at most the "
                         f"window less the core ({scheme.window - scheme.core})")
    if isinstance(taper, bool) or not (isinstance(taper, int) and taper >= 0):
        raise ValueError(f"taper={taper!r} is not allowed: a width in px, an integer >= 0 (0: no taper)")
    if zones is not None and not zones.uniform and local == "pixel":
        raise ValueError("zones are not allowed with local='pixel' (its per-pixel bank is sized to the scheme's core)")
    fit = scheme.fit if fit is None else fit
    check_bank(bank, scheme, stats, fit)
    if bank and (local != "window" or (zones is not None and not zones.uniform)):
        raise ValueError(f"bank={bank} evaluates the paper's filter (local='window') on its own windows: not with "
                         f"local={local!r} or stride zones")
    if fit and stats > WIENER_FIT_LEAST_PX:  # the statistics need windows of at least ``stats`` px
        fit = False
    tiny = torch.finfo(observed.dtype).eps ** 2  # guards the noise-free inverse filter (|H| = 0) against 0 / 0
    windows = bank_scheme(scheme) if bank else scheme
    model = WindowModel(noise, rho0=rho0, stats=stats, taper=taper, core=windows.core, floor=floor,
                        dtype=observed.dtype, device=observed.device)
    window_terms, deviation_spectrum = model.terms, model.deviation_spectrum

    def restore(patches, otf, core):
        H = otf
        win = patches.shape[-1]
        mu, var_n, HP, sx, P = window_terms(patches, H)
        # G = conj(H) sx P / (|H|^2 sx P + var_n) = conj(H) P / (|H|^2 P + var_n / sx), built in place
        G = HP + var_n / sx
        torch.div(P, G.clamp_min_(tiny), out=G)
        out = deviation_spectrum(patches, mu)  # filter y - mu, then add mu back (its DC term)
        dc = mu[..., 0, 0] * (win * win)
        out.mul_(H.conj().resolve_conj())  # a conj view broadcast over the channels is ~2x slower (measured)
        out.mul_(G)  # complex by real: 4x faster than scaling a real view by G[..., None] (measured), the same values
        out[..., 0, 0] += dc
        return out  # spectrum: apply_windowed inverse transforms only the core

    levels = torch.tensor(WIENER_PIXEL_LEVELS, dtype=torch.float64, device=HOST).log()  # scalars read one at a time

    def restore_per_pixel(patches, otf, core):
        from kornia.filters import box_blur

        H = otf
        win = patches.shape[-1]
        half = win // 2
        mu, var_n, HP, sx, P = window_terms(patches, H)
        # the per-pixel signal variance relative to the window's, over the core (box filter over core + halo)
        h = pixel_stats // 2
        lo, hi = half - core // 2 - h, half + core // 2 + h
        k, B, C = patches.shape[:3]
        region = patches[..., lo:hi, lo:hi].reshape(k * B, C, hi - lo, hi - lo)
        m = box_blur(torch.cat([region, region * region], dim=1), pixel_stats, border_type="reflect")
        m = m[..., h:-h, h:-h].reshape(k, B, 2 * C, core, core)
        m1, m2 = m[:, :, :C], m[:, :, C:]
        local_sx = (m2 - m1.square() - noise.variance(m1)).clamp_min(floor)
        ratio = local_sx / local_sx.mean(dim=(-2, -1), keepdim=True)
        t = ratio.to(torch.float64).log().clamp(float(levels[0]), float(levels[-1]))
        spec = deviation_spectrum(patches, mu)
        spec.mul_(H.conj().resolve_conj())
        out = torch.zeros(patches.shape[:-2] + (core, core), dtype=patches.dtype, device=patches.device)
        for j, level in enumerate(WIENER_PIXEL_LEVELS):
            G = torch.div(P, (HP + var_n / (sx * level)).clamp_min_(tiny))
            r_j = core_irfft2(spec * G, win, core)
            # tent in log variance around level j: 1 at it, 0 at its neighbours (the ends extend flat)
            wj = torch.ones_like(t)
            if j > 0:
                wj = torch.where(t < levels[j], ((t - levels[j - 1]) / (levels[j] - levels[j - 1])).clamp(0, 1), wj)
            if j < len(WIENER_PIXEL_LEVELS) - 1:
                wj = torch.where(t > levels[j], ((levels[j + 1] - t) / (levels[j + 1] - levels[j])).clamp(0, 1), wj)
            out += r_j * wj.to(out.dtype)
        return out.add_(mu)  # the core itself: run_windows blends it as it is

    if bank:
        center = optical_center if optical_center is not None else frame_center(observed.shape)
        op = _bank_restore(model, noise, scheme, bank, center, tiny)
        if chunk is None:  # smaller batches: the bank holds more per window
            chunk = lambda w: window_chunk(observed, w, WIENER_BANK_WORKING_COPIES)  # noqa: E731
        if progress is not None:  # counted in the scheme's windows, as the paper's evaluation counts them
            progress = _scaled_progress(progress, window_count(observed.shape, scheme, center, region=region),
                                        window_count(observed.shape, windows, center, region=region))
    else:
        op = restore_per_pixel if local == "pixel" else restore
    return apply_windowed(observed, psf, op, scheme=windows, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress, fit=fit, least_fit=WIENER_FIT_LEAST_PX, zones=zones)


def _scaled_progress(progress, total: int, windows: int):
    """``progress`` called with whole numbers adding up to ``total`` over ``windows`` windows done."""
    done = [0, 0]

    def step(k: int):
        done[0] += k
        emit = done[0] * total // max(windows, 1) - done[1]
        if emit:
            done[1] += emit
            progress(emit)

    return step


def _bank_restore(model: WindowModel, noise: NoiseModel, scheme: WindowScheme, bank: int, center, tiny: float):
    """The bank evaluation's ``op(patches, otf, core)`` (:func:`wiener_windowed`, option ``bank``): the cores of the
    bank's windows, ``(k, B, C, core, core)``."""
    step, J, half_width = bank_points(scheme)
    offsets = torch.arange(-J, J + 1, dtype=torch.float64, device=HOST) * step  # the points, from the window's centre
    # every window lies the same fraction of a pixel before its anchor pixel (blur.axis_positions)
    shifts = [math.ceil(c) - c if scheme.anchor == "axis" else 0.0 for c in center]
    nodes = chebyshev_gauss(bank)
    stats, floor = model.stats, model.floor
    box = 2 * (stats // 2)  # as the paper's windows take their central square
    reach = J * step + box // 2  # the points' squares reach this far from the window's centre
    g = math.gcd(step, box)  # the squares are sums of g x g blocks, the points g-block multiples apart
    starts = torch.arange(2 * J + 1, device=model.device) * (step // g)
    tents = {}

    def point_tents(core: int):
        """Per axis, each point's tent over the core's pixels, normalised to sum 1 at every pixel: ``(2J+1, core)``."""
        if core not in tents:
            d = torch.arange(-core // 2, core // 2, dtype=torch.float64, device=HOST)
            axes = []
            for shift in shifts:
                t = (1 - (d[None, :] + shift - offsets[:, None]).abs() / half_width).clamp_min(0)
                axes.append((t / t.sum(dim=0, keepdim=True)).to(dtype=model.dtype, device=model.device))
            tents[core] = axes
        return tents[core]

    def box_sums(x: torch.Tensor) -> torch.Tensor:
        """Sums of ``x`` ``(..., 2 reach, 2 reach)`` (float64) over the ``box`` px squares at the points, ``(..., 2J+1,
        2J+1)``: its ``g x g`` blocks summed, then the blocks' running sums differenced."""
        nb = x.shape[-1] // g
        S = x.reshape(x.shape[:-2] + (nb, g, nb, g)).sum(dim=(-3, -1))
        S = torch.nn.functional.pad(S.cumsum(dim=-2).cumsum(dim=-1), (1, 0, 1, 0))
        a = box // g
        S = S.index_select(-2, starts + a) - S.index_select(-2, starts)
        return S.index_select(-1, starts + a) - S.index_select(-1, starts)

    def restore_bank(patches, otf, core):
        H = otf
        win = patches.shape[-1]
        half = win // 2
        HP, gain, P = model.spectral_terms(H, win)
        sub = patches[..., half - reach: half + reach, half - reach: half + reach].to(torch.float64)
        m1 = box_sums(sub).div_(box * box)  # each point's local mean and variance, as its own window takes them
        var_y = box_sums(sub.square()).div_(box * box).sub_(m1.square())  # sub may be the patches themselves
        var_n = noise.variance(m1)
        K = var_n * gain.to(torch.float64) / (var_y - var_n).clamp_min(floor)  # each point's noise-to-signal ratio
        mu = m1[..., J:J + 1, J:J + 1].to(patches.dtype)  # the window's own: the reference of its deviation
        kappa = K.clamp_min(tiny).log()
        lo = kappa.amin(dim=(-2, -1), keepdim=True)
        span = kappa.amax(dim=(-2, -1), keepdim=True) - lo
        t = (kappa - lo) / span.clamp_min(1e-12)  # where the points agree every level is their K: one filter
        ty, tx = point_tents(core)
        spec = model.deviation_spectrum(patches, mu).mul_(H.conj().resolve_conj())
        out = torch.zeros(patches.shape[:-2] + (core, core), dtype=patches.dtype, device=patches.device)
        filtered = torch.empty_like(spec)
        G = torch.empty(spec.shape, dtype=HP.dtype, device=HP.device)  # each level's filter, per channel
        for x, lam in zip(nodes, lagrange_weights(t, nodes)):
            level = (lo + x * span).exp().to(HP.dtype)  # (k, B, C, 1, 1), >= tiny > 0: no 0 / 0
            torch.div(P, torch.add(HP, level, out=G), out=G)
            r = core_irfft2(torch.mul(spec, G, out=filtered), win, core)
            out.addcmul_(torch.einsum("...ij,iy,jx->...yx", lam.to(out.dtype), ty, tx), r)
        return out.add_(mu)

    return restore_bank


def _wiener(observed, psf, *, noise, scheme, optical_center=None, region=None,
            progress=None, stats=WIENER_STATS_PX, rho0=WIENER_RHO0, local="window", taper=WIENER_TAPER_PX, bank=0):
    return wiener_windowed(observed, psf, noise=noise, stats=stats, rho0=rho0, scheme=scheme,
                           optical_center=optical_center, region=region, progress=progress, local=local, taper=taper,
                           bank=bank)


def check_wiener_options(options, scheme, method: str = "wiener"):
    """Raise ``ValueError`` for Wiener options (``stats``, ``rho0``, ``taper``, ``local``) ``method`` refuses (``scheme``
    None: those it refuses in any window)."""
    stats, top = options["stats"], (scheme.window if scheme is not None else None)
    if isinstance(stats, bool) or not (isinstance(stats, int) and 2 <= stats <= (top or stats)):
        raise ValueError(f"{method} option stats={stats!r} is not allowed: an integer >= 2 (px) and at most the window"
                         + (f" ({top} px)" if top else ""))
    if not 0 < options["rho0"] < 1:
        raise ValueError(f"{method} option rho0={options['rho0']!r} is not allowed: a correlation in (0, 1)")
    if options["taper"] < 0:
        raise ValueError(f"{method} option taper={options['taper']!r} is not allowed: a width in px, >= 0 (0: no taper, "
                         "the paper's filter)")
    if options["local"] not in WIENER_LOCAL:
        raise ValueError(f"{method} option local={options['local']!r} is not allowed: one of {', '.join(WIENER_LOCAL)}")
    if scheme is not None and WIENER_PIXEL_STATS_PX > scheme.window - scheme.core:  # wiener_windowed's own rule
        raise ValueError(f"the {method} restoration needs a window at least {WIENER_PIXEL_STATS_PX} px larger than "
                         f"the core; window={scheme.window}, core={scheme.core}")


def _check_wiener(options, scheme):
    check_wiener_options(options, scheme)
    bank = options["bank"]
    check_bank(bank, scheme, options["stats"], scheme is None or scheme.fit, "wiener option bank")
    if bank and options["local"] != "window":
        raise ValueError(f"wiener option bank={bank} evaluates the paper's filter: not with local={options['local']!r}")


def _wiener_margin(scheme, options=None) -> int:
    """What the Wiener reads beyond its region: half a window and a core, the bank's core where ``bank`` is on."""
    return windowed_margin(bank_scheme(scheme) if (options or {}).get("bank") else scheme)


register(RestorationMethod("wiener", "adaptive Wiener", "adaptive local Wiener filter in the blur's windows (paper)",
                           _wiener, (("stats", WIENER_STATS_PX), ("rho0", WIENER_RHO0), ("local", "window"),
                                     ("taper", WIENER_TAPER_PX), ("bank", 0)), margin=_wiener_margin,
                           check=_check_wiener, memory=WorkingMemory()))  # none beyond itself: the frame plan's measure


def wiener_start(problem: RegionProblem, observed: torch.Tensor, psf: PSFProvider, *, noise: NoiseModel,
                 scheme: WindowScheme) -> torch.Tensor:
    """The iterative restorations' start (``tv``, ``pnp``), shaped as ``problem.y``
    (:class:`pipeline.blur_operator.RegionProblem`): this filter over the data (its statistics over at most the
    window), the observed image beyond them (where the estimate only feeds light into the data: a Wiener there would
    cost up to ten times the data's area for a 256 px crop)."""
    u = problem.y.clone()
    data, d = problem.data, problem.local_data
    start = wiener_windowed(observed, psf, noise=noise, scheme=scheme, optical_center=problem.center, region=data,
                            stats=min(WIENER_STATS_PX, scheme.window))
    u[..., d[0]:d[1], d[2]:d[3]] = start[..., data[0]:data[1], data[2]:data[3]]
    return u
