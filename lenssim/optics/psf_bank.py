"""PSFs and OTFs by Fraunhofer (FFT) diffraction of an OPD on a pupil, for every lens kind.

One pipeline, two sources of the OPD: the singlet's wavefront coefficients (third order or the exact fit, batched
closed forms: the fast path, :func:`psf`, :func:`otf_quarter_spectrum` and the sweeps' banks) or the real rays of any
sequential lens (:class:`WavefrontTable`, :func:`psfs_from_table`). Both share the pupil's box of samples
(:func:`_box_coords`), the pupil -> PSF transform and its normalisation by the pupil's area (:func:`_intensity`)
and the spectrum and colour-channel weighting (:func:`_channel_rows`, :func:`_add_weighted`).

Sampling. The image pixel pitch is the sensor's ``Delta`` (1.5625 um for the paper). With an
``N x N`` FFT the pupil-plane sample spacing is ``lambda f / (N Delta)``, so the pupil radius spans
``R = N Delta / (2 lambda f#)`` samples (``N / 4`` at the Nyquist pitch: the pupil fills half the
grid and the OTF support, ``|f| < Delta / (lambda f#)`` cycles/pixel, just fits in ``[-1/2, 1/2)``).
A pitch coarser than ``lambda f# / 2`` would alias the OTF and is refused
(:meth:`lenssim.model.camera.Camera.check_sampling`).

Spectrum. Coefficient banks carry a wavelength axis ``K`` (the camera's spectrum): ``(*, K, T)``
in waves at each wavelength. The PSF of a spectrum is the weighted sum of the unit-sum PSFs of
each wavelength on the same pixel grid (each with its own pupil scale ``R``); its OTF is the
weighted sum of the OTFs.

FFT size. A wavefront slope of ``G`` waves per unit normalised pupil radius is ``G / R`` waves per
pupil sample and moves light by ``G lambda f / (y Delta)`` pixels (``4 G`` at the Nyquist pitch).
:func:`fft_size` picks the smallest FFT-friendly ``N`` for which the largest slope over the pupil
uses at most ``fill`` of the Nyquist limit (0.5 wave per sample) and the geometric PSF plus
``margin_px`` pixels of diffraction fits in the grid, so neither the pupil phase nor the PSF
aliases (settings: :class:`lenssim.model.numerics.Numerics`).

Orientation. PSF arrays are indexed ``[..., row, col] = [y, x]`` in image-plane pixel units
with the paraxial image point at ``[N // 2, N // 2]`` (or ``[0, 0]`` for the unshifted banks).
The pupil field is ``A exp(-2 pi i W)`` with ``W`` in Welford's sign, so that the light lands at
the transverse ray aberration ``eps = -(f / y) grad W`` (see :mod:`lenssim.optics.aberrations`).

Real rays (any sequential lens, object at infinity; the provider is :class:`lenssim.optics.psf_provider.SequentialPSF`):

1. **The wavefront table** (:func:`wavefront_table`). The lens is rotationally symmetric, so the wavefront of a field
   depends on the field angle only, up to a rotation of the pupil. For each wavelength and each field angle of a set
   of nodes from the axis to the largest angle asked, the OPD (:meth:`SequentialLens.wavefront`, real rays aimed at
   the stop, vignetted by every semi-diameter) is traced on a ``grid x grid`` square of the entrance pupil in the
   meridional frame (field along ``+y``), against the reference sphere centred on the primary wavelength's chief-ray
   point; the distortion that moves that point from the pixel's paraxial one ``m tan(alpha)`` (``m`` the paraxial
   image scale on the image plane, :func:`image_scale_mm`) is kept apart and added as a tilt. The OPD therefore
   holds, as tilt, the distortion and the lateral colour, and as defocus the axial colour and the focus. Beyond the
   vignetting's edge the OPD is traced through the surfaces extended past their semi-diameters (its smooth
   continuation, what the interpolation at the edge reads). Field-angle nodes are added (bisection) until the table,
   interpolated in angle, matches traced OPDs at the mid-nodes to :data:`TABLE_TOLERANCE_WAVES`; the error reached
   is :attr:`WavefrontTable.interpolation_error_waves`.
2. **The pupil of one PSF**: the FFT grid's pupil samples (radius ``R = N delta / (2 lambda N_w)`` samples for an
   ``N``-point FFT of pitch ``delta``, ``N_w`` the paraxial working F-number) are rotated into the meridional frame
   of the PSF's azimuth and the table's OPD and aperture ratio (each ray's largest height over a semi-diameter) are
   interpolated there (bilinear in the pupil, cubic in angle). The amplitude is 1 inside the unit disc where the rays
   pass (interpolated aperture ratio <= 1), so an off-axis pupil takes the vignetted shape the semi-diameters give.
3. **The PSF** ``|FFT(A exp(-2 pi i W))|^2`` (the sign puts the PSF's centroid where the rays land: checked against
   the rays' centroid in the tests), summed over the wavelengths with their weights, on a grid ``s`` times finer
   than the pixels; ``sampling="area"`` sums each pixel's ``s x s`` samples (a pixel of full fill factor integrates
   the light falling on it; ``s`` odd), ``sampling="point"`` takes the samples at the pixel centres (the paper's
   model, ``s = 1``). Each PSF has unit sum on its ``n x n`` pixels.

Neglected, as in :mod:`lenssim.optics.lens_report`: the entrance pupil's grid is mapped linearly onto the exit
pupil (pupil aberrations and the oblique beam's foreshortening, ``1/cos`` factors of the off-axis PSF's scale).
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache

import torch

from .aberrations import (N_TERMS, _check_coeffs, monomial_gradients, pupil_monomials, wavefront_coefficients,
                          wavefront_gradient, wavefront_rotated)
from ..model.camera import Camera
from ..checks import check_shape
from ..model.design import Design
from ..model.numerics import DEFAULT_NUMERICS, Numerics
from .sequential import Fields, SequentialLens
from ..torch_utils import HOST, abs_square, as_tensor, broadcast_shape
from ..validate import OTF_BYTES_PER_SAMPLE, NumericalError, ResourceLimitError, check_finite, check_int

__all__ = [
    "nice_fft_size",
    "max_wavefront_slope",
    "spectral_coefficients",
    "fft_size",
    "pupil_amplitude",
    "psf",
    "pedestal_fraction",
    "psf_at",
    "otf",
    "otf_quarter",
    "otf_quarter_spectrum",
    "otf_quarter_pair",
    "WavefrontTable",
    "wavefront_table",
    "cached_wavefront_table",
    "psfs_from_table",
    "image_scale_mm",
    "chief_point_mm",
    "SAMPLINGS",
    "TABLE_GRID",
    "TABLE_INITIAL_NODES",
    "TABLE_MAX_NODES",
    "TABLE_TOLERANCE_WAVES",
]


def _smooth_part(k: int) -> int:
    """``k`` with its factors 2, 3 and 5 divided out."""
    for p in (2, 3, 5):
        while k % p == 0:
            k //= p
    return k


def nice_fft_size(n: int, multiple: int = 16) -> int:
    """Smallest ``m >= n`` that is a multiple of ``multiple`` and has no prime factor above 5.

    Found among the numbers ``2^a 3^b 5^c`` (a few hundred candidates for any size), not by counting up, so a
    size of any magnitude is answered at once (an absurd design asks for absurd sizes, refused by its caller).
    """
    if isinstance(multiple, bool) or not isinstance(multiple, int) or multiple < 1 or _smooth_part(multiple) != 1:
        raise ValueError(f"multiple={multiple!r} is not allowed: a whole number >= 1 with no prime factor above 5")
    j = max(1, -(-int(math.ceil(n)) // multiple))  # m = multiple * k, k the smallest 5-smooth number >= j
    best, p5 = None, 1
    while p5 < 2 * j:
        p35 = p5
        while p35 < 2 * j:
            k = p35
            while k < j:
                k *= 2
            best = k if best is None else min(best, k)
            p35 *= 3
        p5 *= 5
    return multiple * best


@lru_cache(maxsize=8)
def _polar_probe(n_r: int = 33, n_t: int = 72):
    r = torch.linspace(0, 1, n_r, dtype=torch.float64, device=HOST)
    t = torch.linspace(0, 2 * math.pi, n_t + 1, dtype=torch.float64, device=HOST)[:-1]
    R, T = torch.meshgrid(r, t, indexing="ij")
    return (R * torch.cos(T)).flatten(), (R * torch.sin(T)).flatten()


def max_wavefront_slope(coeffs: torch.Tensor, terms=None) -> torch.Tensor:
    """Largest ``|grad_rho W|`` over the unit pupil (waves per unit radius), shape ``(*)``.

    Evaluated on a 33 x 72 polar probe of the disc (the maximum of these polynomials lies on the
    rim or at an interior critical point; the probe's step is 1/32 in radius). ``terms``: the
    coefficients' monomial table (default :data:`lenssim.optics.aberrations.TERMS`).
    """
    n_terms = N_TERMS if terms is None else len(terms)
    if terms is None:
        _check_coeffs(coeffs)
    else:
        check_shape(coeffs, f"* {n_terms}", "coeffs (waves)")
        check_finite("coeffs", coeffs.detach())
    rr, rt = _polar_probe()
    rr, rt = rr.to(coeffs.device), rt.to(coeffs.device)
    flat = coeffs.reshape(-1, n_terms).to(torch.float64)
    grads = None if terms is None else monomial_gradients(rr, rt, terms)
    out = torch.empty(flat.shape[0], dtype=torch.float64, device=coeffs.device)
    for i in range(0, flat.shape[0], 4096):  # bounded memory for any batch
        if grads is None:
            g_r, g_t = wavefront_gradient(flat[i:i + 4096], rr, rt)
        else:
            g_r, g_t = flat[i:i + 4096] @ grads[0], flat[i:i + 4096] @ grads[1]
        out[i:i + 4096] = torch.sqrt(g_r**2 + g_t**2).amax(dim=-1)
    return out.reshape(coeffs.shape[:-1])


def spectral_coefficients(camera: Camera, design: Design, alpha_deg=None, *, elementwise: bool = False) -> torch.Tensor:
    """Wavefront coefficients at every wavelength of the camera's spectrum: ``(*, A, K, T)`` in waves
    (``(*, K, T)`` if elementwise; see :func:`lenssim.optics.aberrations.wavefront_coefficients`)."""
    return torch.stack([wavefront_coefficients(camera.lens, design, alpha_deg, wavelength_um=lam, elementwise=elementwise)
                        for lam in camera.spectrum.wavelengths_um], dim=-2)


def _check_spectral(camera: Camera, coeffs: torch.Tensor, n_terms: int = N_TERMS) -> None:
    K = check_shape(coeffs, f"* K {n_terms}", "coeffs (waves per wavelength)")["K"]
    check_finite("coeffs", coeffs.detach())
    if K != len(camera.spectrum):
        raise ValueError(f"coeffs has {K} wavelengths, the camera's spectrum {len(camera.spectrum)}: expected "
                         "(*, K, T) with one row per wavelength (see spectral_coefficients)")


def fft_size(camera: Camera, coeffs: torch.Tensor, numerics: Numerics = DEFAULT_NUMERICS, *,
             terms=None, per_wavelength: bool = False) -> torch.Tensor:
    """FFT size ``N`` for each coefficient set ``(*, K, T)`` (waves at each wavelength); int64 ``(*)``.

    ``N`` is the smallest :func:`nice_fft_size` with, at every wavelength, (i) at most
    ``numerics.fill`` x 0.5 wave of pupil phase per sample and (ii) the geometric PSF diameter
    ``2 G lambda f / (y Delta)`` plus ``numerics.margin_px`` pixels inside the grid (``G`` =
    :func:`max_wavefront_slope`), and ``N >= numerics.min_size``. ``terms``: the coefficients'
    monomial table (default :data:`lenssim.optics.aberrations.TERMS`). ``per_wavelength``: the size each wavelength
    needs by these rules on its own, ``(*, K)`` (the metrics compute each wavelength's PSF on it and zero-pad it to
    the largest, :func:`otf_quarter_spectrum`).
    """
    _check_spectral(camera, coeffs, N_TERMS if terms is None else len(terms))
    camera.check_sampling()
    fill = numerics.fill
    need = None
    needs = []
    for k, lam in enumerate(camera.spectrum.wavelengths_um):
        G = max_wavefront_slope(coeffs[..., k, :], terms).cpu()
        r_per_n = camera.pupil_radius_px(1, lam)  # pupil radius (samples) per unit N
        n_phase = G / (0.5 * fill) / r_per_n
        n_psf = 2 * camera.geometric_radius_px(G, lam) / fill + numerics.margin_px
        nk = torch.maximum(torch.maximum(n_phase, n_psf), torch.tensor(float(numerics.min_size), dtype=G.dtype, device=G.device))
        need = nk if need is None else torch.maximum(need, nk)
        needs.append(nk)
    if not bool(torch.isfinite(need).all()):
        raise NumericalError("a wavefront slope is not finite: the coefficients hold NaN or infinite values")
    worst = int(torch.argmax(need.reshape(-1)))
    if float(need.reshape(-1)[worst]) > numerics.max_fft_size:
        n_req = nice_fft_size(int(math.ceil(float(need.reshape(-1)[worst]))))
        gib = OTF_BYTES_PER_SAMPLE * (n_req * numerics.oversample) ** 2 / 2**30
        err = ResourceLimitError(f"a PSF needs an FFT of {n_req} samples (about {gib:.3g} GiB for its OTF); the "
                                 f"limit is max_fft_size = {numerics.max_fft_size}", "max_fft_size")
        err.index = worst
        raise err
    if per_wavelength:
        need = torch.stack(needs, dim=-1)
    sizes = sorted({nice_fft_size(int(math.ceil(v))) for v in need.flatten().tolist()})
    table = torch.tensor(sizes, dtype=torch.float64, device=need.device)
    idx = torch.searchsorted(table, need.to(torch.float64).flatten().contiguous())
    return table[idx].to(torch.int64).reshape(need.shape)


RIM_REACH = 0.7072
"""Farthest a sample centre (samples) may lie outside the pupil's radius and still overlap the disc: half a unit
sample's diagonal, rounded up (sqrt(2)/2 = 0.70711)."""


def _coverage(yv: torch.Tensor, xv: torch.Tensor, radius: float, supersample: int) -> torch.Tensor:
    """Area fraction of each unit sample centred at ``(yv[i], xv[j])`` inside the disc ``|r| <= radius``.

    Samples farther than ``sqrt(2)/2`` from the rim are 0 or 1; only rim samples are supersampled
    (``supersample^2`` points), so memory stays ``O(len(yv) len(xv))`` for any size.
    """
    r = torch.hypot(yv[:, None], xv[None, :])
    amp = (r <= radius).to(torch.float64)
    rim = (r - radius).abs() < RIM_REACH
    if rim.any():
        iy, ix = torch.nonzero(rim, as_tuple=True)
        sub = (torch.arange(supersample, dtype=torch.float64, device=yv.device) + 0.5) / supersample - 0.5
        py = yv[iy][:, None, None] + sub[None, :, None]
        px = xv[ix][:, None, None] + sub[None, None, :]
        amp[iy, ix] = ((py**2 + px**2) <= radius**2).to(torch.float64).mean(dim=(1, 2))
    return amp


def _max_radius(n: int) -> float:
    """Largest pupil radius (samples) whose anti-aliased box still fits an ``n``-point grid."""
    return n / 2 - 2


def _radius(camera: Camera, n: int, wavelength_um: float) -> float:
    """:meth:`Camera.pupil_radius_px`, refused where the pupil would not fit the ``n``-point grid."""
    R = camera.pupil_radius_px(n, wavelength_um)
    if R > _max_radius(n):
        raise ValueError(f"pupil radius {R:.3f} samples does not fit an FFT of n = {n} (at most n/2 - 2)")
    return R


@lru_cache(maxsize=4)
def _pupil_cached(n: int, radius: float, supersample: int):
    """Anti-aliased pupil amplitude on the DFT grid (origin at index 0), float64 CPU ``(n, n)``."""
    k = torch.arange(n, dtype=torch.float64, device=HOST)
    x = torch.where(k < n / 2, k, k - n)
    return _coverage(x, x, radius, supersample), x


def pupil_amplitude(camera: Camera, n: int, wavelength_um: float | None = None, *,
                    numerics: Numerics = DEFAULT_NUMERICS, dtype=torch.float32, device=None):
    """Pupil transmission (area fraction of each sample inside the disc) and sample coordinates.

    Returns ``(amp, rho)``: ``amp`` ``(n, n)`` with the pupil centre at index ``[0, 0]`` (DFT
    order) and ``rho`` ``(n,)``, the normalised pupil coordinate of each index, at ``wavelength_um``
    (default: the spectrum's first).
    """
    lam = camera.spectrum.wavelengths_um[0] if wavelength_um is None else wavelength_um
    R = _radius(camera, n, lam)
    amp, x = _pupil_cached(int(n), float(R), int(numerics.supersample))
    return amp.to(dtype=dtype, device=device), (x / R).to(dtype=dtype, device=device)


@lru_cache(maxsize=128)
def _pupil_box_cached(radius: float, supersample: int):
    """Anti-aliased pupil on its bounding box only: coordinates ``-m..m`` samples, ``m = ceil(R + 0.71)``."""
    x = _box_coords(radius)
    return _coverage(x, x, radius, supersample), x / radius


def _box_coords(radius: float) -> torch.Tensor:
    """The samples ``-m..m`` (float64, :data:`HOST`) of the box about a pupil of ``radius`` samples, ``m = ceil(R +``
    :data:`RIM_REACH` ``)``: every sample that overlaps the disc, for every lens kind."""
    m = int(math.ceil(radius + RIM_REACH))
    return torch.arange(-m, m + 1, dtype=torch.float64, device=HOST)


def _field(coeffs, radius, azimuth_rad, supersample, dtype, device, terms=None):
    """Complex pupil field ``(B, 2m+1, 2m+1)`` on the pupil's bounding box, coefficients ``(B, T)``.

    Only the box is evaluated (the rest of the ``n x n`` grid is zero); :func:`_intensity`
    zero-pads it. Placing the box at index 0 instead of centring it on the DFT origin multiplies
    the image-plane amplitude by a linear phase, which ``|.|^2`` removes. ``azimuth_rad`` ``(B,)``
    rotates each pupil to its image point's azimuth (exactly, no resampling); None puts the field
    along +y (rows).
    """
    amp, rho = _pupil_box_cached(float(radius), int(supersample))
    amp, rho = amp.to(dtype=dtype, device=device), rho.to(dtype=dtype, device=device)
    coeffs = coeffs.to(dtype)
    ry, rx = rho[:, None], rho[None, :]  # rows = y, cols = x
    if azimuth_rad is None:
        rho_r, rho_t = ry.expand_as(amp)[None], rx.expand_as(amp)[None]
    else:
        azimuth_rad = azimuth_rad.to(dtype)
        c, s = torch.cos(azimuth_rad)[:, None, None], torch.sin(azimuth_rad)[:, None, None]
        rho_r, rho_t = rx * c + ry * s, -rx * s + ry * c
    W = wavefront_rotated(coeffs, rho_r, rho_t, *(() if terms is None else (terms,)))  # (B, rows, cols)
    return torch.polar(amp.expand_as(W), -2 * math.pi * W)


def _kept(a: torch.Tensor, dim: int, keep: torch.Tensor) -> torch.Tensor:
    """``a.index_select(dim, keep)``; where ``keep`` is a run of consecutive indices that may wrap past the end (a
    window about the DFT origin), as one or two slices (the same values: a copy, not a gather, several times
    faster on complex tensors)."""
    n, w, k0 = a.shape[dim], keep.numel(), int(keep[0])
    if not torch.equal(keep, (torch.arange(w, device=keep.device) + k0) % n):
        return a.index_select(dim, keep)
    if k0 + w <= n:
        return a.narrow(dim, k0, w)
    return torch.cat([a.narrow(dim, k0, n - k0), a.narrow(dim, 0, w - (n - k0))], dim)


def _intensity(field: torch.Tensor, n: int, *, area=None, keep: torch.Tensor | None = None) -> torch.Tensor:
    """``|DFT_n(field)|^2`` ``(B, n, n)`` of a pupil field on its box ``(B, rows, cols)`` zero-padded to ``n x n``: the
    pupil -> PSF step of every lens kind. ``keep`` ``(w,)``: the indices (DFT order) of the rows and columns to keep
    (a ``w x w`` window of the PSF; the transform then runs one axis at a time, keeping only those after each).
    ``area``: the pupil's area (samples; a number or ``(B, 1, 1)``), the PSF then divided by ``n^2 area``, so that the
    whole grid holds ``sum(amp^2) / sum(amp)`` of the light (Parseval: all of it for a pupil of 0/1 amplitude)."""
    if keep is None:
        a = torch.fft.fft2(field, s=(n, n))
    else:
        a = _kept(torch.fft.fft(field, n=n, dim=-1), -1, keep)
        a = _kept(torch.fft.fft(a, n=n, dim=-2), -2, keep)
    p = abs_square(a)
    return p if area is None else p.div_((n * n) * area)


def _add_weighted(outs: list, p: torch.Tensor, rows, k: int) -> None:
    """``outs[c] += rows[c][k] p`` for every channel ``c`` that weighs wavelength ``k`` (``outs[c]`` None until its
    first): the spectrum weighting of every lens kind's PSFs (``p`` itself where it is one spectrum's only one)."""
    for c, r in enumerate(rows):
        if r[k] > 0:
            if outs[c] is None:
                outs[c] = p if len(rows) == 1 and r[k] == 1 else p * r[k]
            else:
                outs[c].add_(p, alpha=r[k])


def _azimuth(azimuth_deg, flat: torch.Tensor):
    if azimuth_deg is None:
        return None
    return torch.deg2rad(as_tensor(azimuth_deg, like=flat)).reshape(-1).expand(flat.shape[0])


def _wavelength_fields(camera: Camera, coeffs: torch.Tensor, n: int, azimuth_deg, dtype, numerics: Numerics,
                       terms=None, skip=None):
    """For each wavelength of the spectrum (but those ``skip`` marks): ``(lambda, weight, pupil field (B, box, box),
    coeffs (B, K, T), lead shape)``."""
    n_terms = N_TERMS if terms is None else len(terms)
    _check_spectral(camera, coeffs, n_terms)
    lead = coeffs.shape[:-2]
    flat = coeffs.reshape(-1, coeffs.shape[-2], n_terms)
    az = _azimuth(azimuth_deg, flat)
    for k, (lam, w) in enumerate(zip(camera.spectrum.wavelengths_um, camera.spectrum.weights)):
        if skip is not None and skip[k]:
            continue
        field = _field(flat[:, k], _radius(camera, int(n), lam), az, numerics.supersample, dtype or flat.dtype,
                       flat.device, terms)
        yield k, lam, w, field, flat, lead


def psf(camera: Camera, coeffs: torch.Tensor, n: int, *, azimuth_deg=None, centered: bool = True,
        dtype: torch.dtype | None = None, numerics: Numerics = DEFAULT_NUMERICS, terms=None,
        channel_weights=None) -> torch.Tensor:
    """Intensity PSFs ``(*, n, n)`` of unit sum, from coefficients ``(*, K, T)`` (waves per wavelength).

    Each wavelength's ``|DFT(pupil field)|^2`` is divided by the pupil area (samples) times ``n^2`` and the light
    the anti-aliased rim leaves out is spread evenly over the grid (:func:`pedestal_fraction`), so the PSF's DFT is the metrics' OTF
    (:func:`otf`) at every frequency.

    ``azimuth_deg`` ``(*)`` gives, per PSF, the direction (deg, from +x towards +y) of the image
    point seen from the optical axis; the pupil coordinates are rotated exactly (no resampling).
    ``None`` puts the field along +y (rows). With ``centered`` the paraxial image point is at
    ``[n // 2, n // 2]``, else at ``[0, 0]``. The computation runs in ``dtype`` (default: that of
    ``coeffs``; ``torch.float32`` is ~3x faster and accurate to ~1e-6 of the peak). ``terms``: the
    coefficients' monomial table (default :data:`lenssim.optics.aberrations.TERMS`). ``channel_weights``
    ``(C, K)``: one PSF per colour channel from the same wavelengths, ``(*, C, n, n)`` (each wavelength's field
    transformed once; see :func:`otf_quarter_spectrum`).
    """
    K = len(camera.spectrum)
    rows = (camera.spectrum.weights,) if channel_weights is None else _channel_rows(channel_weights, K)
    outs = [None] * len(rows)
    lead = None
    skip = [not any(r[k] > 0 for r in rows) for k in range(K)]
    for k, lam, _, field, flat, lead in _wavelength_fields(camera, coeffs, n, azimuth_deg, dtype, numerics, terms,
                                                           skip=skip):
        R = float(_radius(camera, int(n), lam))
        area = float(_pupil_box_cached(R, int(numerics.supersample))[0].sum())
        p = _intensity(field, int(n), area=area).add_(_rim_loss(R, int(numerics.supersample)) / (n * n))
        del field
        _add_weighted(outs, p, rows, k)
    out = outs[0] if channel_weights is None else torch.stack(outs, dim=-3)
    if centered:
        out = torch.fft.fftshift(out, dim=(-2, -1))
    return out.reshape(lead + out.shape[1:])


@lru_cache(maxsize=128)
def _rim_loss(radius: float, supersample: int) -> float:
    """``1 - c``, ``c = sum(amp^2) / sum(amp)`` of the anti-aliased pupil of ``radius`` samples."""
    a, _ = _pupil_box_cached(radius, supersample)
    return float(1 - a.square().sum() / a.sum())


def pedestal_fraction(camera: Camera, n: int, numerics: Numerics = DEFAULT_NUMERICS) -> float:
    """The fraction of a :func:`psf`'s light (on an ``n x n`` grid) spread evenly over the grid: the spectrum's
    weighted rim loss ``1 - c``, ``c = sum(amp^2) / sum(amp)`` of each wavelength's anti-aliased pupil.

    ``|DFT(field)|^2 / (area n^2)`` has the metrics' area-normalised OTF (:func:`_area_normalise`) at every
    non-zero frequency but sums to ``c < 1``: a rim sample of area fraction ``a`` transmits ``a^2`` of the light
    where the disc it stands for passes ``a``. The rest is the light the pupil's sharp rim diffracts to wide angles
    (0.53% at R = 64 samples, 0.26% at R = 128, the pipeline's 512 px grid at the Nyquist pitch; the Airy tail
    beyond 256 px holds 0.16% there). Spread evenly over the grid it changes only the zero frequency, so the PSF's
    DFT equals the metrics' OTF exactly; normalising to unit sum instead raises the MTF at every frequency by
    ``1 / c`` (measured: images 57-66 dB apart at n = 256).
    """
    return sum(w * _rim_loss(float(_radius(camera, int(n), lam)), int(numerics.supersample))
               for lam, w in zip(camera.spectrum.wavelengths_um, camera.spectrum.weights))


def psf_at(camera: Camera, design: Design, x_mm, y_mm, n: int | None = None, *, centered: bool = True,
           dtype: torch.dtype | None = None, numerics: Numerics = DEFAULT_NUMERICS, channel_weights=None):
    """PSFs at image points ``(x_mm, y_mm)`` (mm from the optical axis, image-plane axes).

    The field angle is ``atan(r / f)``, ``r = hypot(x, y)``, and the pupil is rotated to the point's
    azimuth, so the coma flare lies along the radial direction of ``(x, y)``. The design's
    parameters, ``x_mm`` and ``y_mm`` broadcast to ``(*)``; returns ``(psfs (*, n, n), n)``. ``n``
    defaults to :func:`fft_size` under ``numerics``. ``dtype``: as in :func:`psf`; Python numbers
    follow the tensors' precision (float64 if no tensor is given). ``channel_weights`` ``(C, K)``: one PSF per colour
    channel, ``(*, C, n, n)`` (see :func:`psf`).
    """
    given = [v for v in (x_mm, y_mm) if isinstance(v, torch.Tensor) and v.is_floating_point()]
    given += [v for v in design.values.values()]
    common = given[0].dtype if given else torch.float64
    for v in given[1:]:
        common = torch.promote_types(common, v.dtype)
    x, y = (as_tensor(v, dtype=common, device=given[0].device if given else None) for v in (x_mm, y_mm))
    design = design.to(common)
    shape = broadcast_shape(x.shape, y.shape, design.shape)
    x, y = x.expand(shape), y.expand(shape)
    design = design.map(lambda t: t.expand(shape))
    camera.lens.check_design(design)
    alpha = camera.geometry.field_angle_deg(x, y)
    if (alpha >= 90).any():
        raise ValueError("image point at or beyond 90 degrees of field")
    coeffs = spectral_coefficients(camera, design, alpha, elementwise=True).reshape(-1, len(camera.spectrum), N_TERMS)
    azimuth = torch.rad2deg(torch.atan2(y, x)).flatten()
    if n is None:
        n = int(fft_size(camera, coeffs, numerics).max())
    else:
        n = check_int("n", n, 16, numerics.max_fft_size)
    out = psf(camera, coeffs, n, azimuth_deg=azimuth, centered=centered, dtype=dtype, numerics=numerics,
              channel_weights=channel_weights)
    return out.reshape(shape + out.shape[1:]), n


def otf(camera: Camera, coeffs: torch.Tensor, n: int, *, azimuth_deg=None,
        numerics: Numerics = DEFAULT_NUMERICS) -> torch.Tensor:
    """OTFs ``(*, n, n)`` (complex, DFT order, ``OTF[0, 0] = 1``) from coefficients ``(*, K, T)``.

    ``fft2`` of ``|fft2(pupil)|^2`` per wavelength, normalised by the pupil area (see
    :func:`_area_normalise`), weighted over the spectrum. Frequencies are ``k / n`` cycles/pixel.
    This is the general (reference) path.
    """
    out = None
    for _, lam, w, field, flat, lead in _wavelength_fields(camera, coeffs, n, azimuth_deg, None, numerics):
        H = torch.fft.fft2(_intensity(field, int(n)))
        amp, _ = pupil_amplitude(camera, n, lam, numerics=numerics, dtype=flat.dtype, device=flat.device)
        H = _area_normalise(H, amp)
        out = H if len(camera.spectrum) == 1 else (w * H if out is None else out + w * H)
    return out.reshape(lead + (n, n))


def _quarter_basis_compute(n: int, radius: float, supersample: int, terms=None):
    """Half-pupil amplitude and monomial basis for :func:`otf_quarter` (float64, CPU).

    Rows are the pupil rows ``y = -ry..ry`` in natural order, columns ``x = 0..cx`` with ``cx`` the last
    column the anti-aliased rim reaches (at most ``n/2``; the transforms zero-pad the rest of the half-row).
    Basis ``(T, rows, cx+1)``: the monomials of :data:`lenssim.optics.aberrations.TERMS` with ``rho_r = y / R``.
    """
    h = n // 2
    ry = int(math.floor(radius + 0.5))
    cx = min(h, int(math.ceil(radius + RIM_REACH)))
    yv = torch.arange(-ry, ry + 1, dtype=torch.float64, device=HOST)
    xv = torch.arange(0, cx + 1, dtype=torch.float64, device=HOST)
    a = _coverage(yv, xv, radius, supersample)
    area = 2 * a.sum() - a[:, 0].sum()  # the x < 0 half mirrors x > 0
    basis = pupil_monomials((yv / radius)[:, None], (xv / radius)[None, :], *(() if terms is None else (terms,)))
    return a, basis, float(area)


_BASIS_CACHE: OrderedDict = OrderedDict()
_BASIS_CACHE_BYTES = 1 << 30
_basis_cache_used = 0


def _quarter_basis_cached(n: int, radius: float, supersample: int, terms=None, dtype=torch.float64, device=None):
    """:func:`_quarter_basis_compute` in ``dtype`` on ``device``, cached (LRU) up to 1 GiB in total: sweeps
    cycle through ~30 FFT sizes per chunk (times the wavelengths of a spectrum), while 4x-size checks make
    single entries of hundreds of MB. The copies are the float64 values converted, so every dtype sees the
    same numbers as converting at use."""
    global _basis_cache_used
    key = (n, radius, supersample, terms, dtype, str(device) if device is not None else "cpu")
    if key in _BASIS_CACHE:
        _BASIS_CACHE.move_to_end(key)
        return _BASIS_CACHE[key]
    a, basis, area = _quarter_basis_compute(n, radius, supersample, terms)
    val = (a.to(dtype=dtype, device=device), basis.to(dtype=dtype, device=device), area)
    _BASIS_CACHE[key] = val
    _basis_cache_used += val[0].nbytes + val[1].nbytes
    while len(_BASIS_CACHE) > 1 and _basis_cache_used > _BASIS_CACHE_BYTES:
        _, old = _BASIS_CACHE.popitem(last=False)
        _basis_cache_used -= old[0].nbytes + old[1].nbytes
    return val


def otf_quarter(coeffs: torch.Tensor, n: int, *, pupil_radius_px: float, oversample: int = 1,
                supersample: int = DEFAULT_NUMERICS.supersample, terms=None) -> torch.Tensor:
    """Fast OTF bank for field-axis PSFs at one wavelength: ``H[fy, fx]`` for ``fy, fx = 0..m/2``, ``m = oversample n``.

    Frequencies are ``k / m`` cycles/pixel. ``terms``: the pupil monomials of the coefficients (default
    :data:`lenssim.optics.aberrations.TERMS`; e.g. a higher-order table for fitted exact wavefronts). Input
    ``(B, T)`` coefficients (waves) with the field
    along +y and the pupil radius in samples of the ``n``-point FFT (:meth:`Camera.pupil_radius_px`,
    at most ``n / 4``); output ``(B, m/2+1, m/2+1)`` complex with ``H[0, 0] = 1``. With
    ``oversample=1`` it equals the quarter of :func:`otf` to rounding (above ``R = n / 4`` both are the
    aliased OTF of the point-sampled PSF); ``oversample > 1`` zero-pads
    the ``n x n`` PSF (which :func:`fft_size` keeps inside the grid) to sample the same OTF on a
    finer frequency grid, for integrals whose integrand is not band-limited (the Wiener error).
    It exploits:

    * the mirror symmetry ``W(x, y) = W(-x, y)``: only the ``x >= 0`` half of the pupil is
      evaluated and its ``x``-DFT (even sequence) is two real inverse FFTs of half length,
    * the zero rows of the pupil: the ``y``-FFT runs on the ``~n/2`` pupil rows, zero-padded by
      the FFT itself (the row offset this implies is a phase factor that ``|.|^2`` removes),
    * real transforms for PSF -> OTF: the even ``x``-DFT of the ``n`` PSF rows (one ``irfft`` each), then
      ``rfft`` along ``y`` on ``m/2+1`` columns (the output is a transposed view),
    * Hermitian symmetry ``H(-f) = conj H(f)`` with evenness in ``fx``: ``|H|^2`` and ``Re H`` are
      even in both axes, so the quarter plane carries everything the MSE integrals need.
    """
    p_half, area = _psf_half(coeffs, n, pupil_radius_px, supersample, terms)
    H = _otf_from_psf_half(p_half, n, oversample, area)
    H[..., 0, 0] = 1
    return H


def _psf_half(coeffs: torch.Tensor, n: int, pupil_radius_px: float, supersample: int, terms=None):
    """Stage 1 of :func:`otf_quarter`: the un-normalised PSF on ``u >= 0``, ``(B, n, n/2+1)`` (rows in DFT
    order; it carries ``1/n^2``), and the pupil area (samples)."""
    n_terms = N_TERMS if terms is None else len(terms)
    check_shape(coeffs, f"B {n_terms}", "coeffs (waves)")
    check_finite("coeffs", coeffs.detach())
    if n % 2:
        raise ValueError(f"n={n} is not allowed: must be even")
    R = float(pupil_radius_px)
    if not 0 < R <= _max_radius(n):
        raise ValueError(f"pupil radius {R:.3f} samples is not allowed: in (0, n/2 - 2 = {_max_radius(n)}] (the "
                         "pupil must fit the grid; above n/4 the sampled PSF aliases)")
    dtype, device = coeffs.dtype, coeffs.device
    a, basis, area = _quarter_basis_cached(int(n), R, int(supersample), None if terms is None else tuple(terms),
                                           dtype, device)
    h = n // 2
    B = coeffs.shape[0]
    W = (coeffs @ basis.reshape(n_terms, -1)).reshape(B, *a.shape)
    phase = (-2 * math.pi) * W
    re_im = torch.stack([a * torch.cos(phase), a * torch.sin(phase)], dim=1)  # (B, 2, rows, cx+1)
    row_dft = torch.fft.irfft(re_im, n=n, dim=-1)[..., : h + 1]  # even x-DFT / n, real and imag parts
    field_x = torch.complex(row_dft[:, 0], row_dft[:, 1])
    amp_img = torch.fft.fft(field_x, n=n, dim=-2)  # (B, n, h+1)
    return abs_square(amp_img), area  # PSF for u >= 0 (up to n^2 scaling)


def _otf_from_psf_half(p_half: torch.Tensor, n: int, oversample: int, area: float) -> torch.Tensor:
    """Stage 2 of :func:`otf_quarter`: the quarter-plane OTF of half-PSFs ``(B, n, n/2+1)`` (linear in
    them), on an ``m = oversample n`` grid, divided by ``area`` (one wavelength's pupil area in samples;
    1 for a sum of half-PSFs already divided by theirs). ``H[0, 0]`` is left as computed."""
    h = n // 2
    B = p_half.shape[0]
    m = n * int(oversample)
    hm = m // 2
    if m != n:  # zero-pad the PSF from n to m; the Nyquist row/column splits between +h and -h
        p_half = p_half.clone()
        p_half[:, h] *= 0.5
        p_half[..., h] *= 0.5
    # x first: each of the n PSF rows is real and even in x, so its DFT is one real inverse transform, zero-padded
    # from h+1 to m by the transform itself; then y, on the hm+1 columns, as real transforms along contiguous rows
    gx = torch.fft.irfft(p_half, n=m, dim=-1)[..., : hm + 1]  # (B, n, hm+1): x-frequencies 0..hm, y in image space
    del p_half
    if m == n:
        g = gx.transpose(-2, -1).contiguous()  # (B, hm+1, n)
    else:  # transposed into the rows of the zero-padded (B, hm+1, m): y = 0..h, then -h..-1
        g = gx.new_empty(B, hm + 1, m)
        g[..., h + 1: m - h].zero_()
        g[..., : h + 1].copy_(gx[:, : h + 1].transpose(-2, -1))
        g[..., m - h:].copy_(gx[:, h:].transpose(-2, -1))
    del gx
    # the irfft divides by m and p_half carries 1/n^2: G = (fft2 |fft2 field|^2) / (n^2 m), and the
    # area-normalised OTF is that over (area n^2) (see _area_normalise)
    H = torch.fft.rfft(g, dim=-1).transpose(-2, -1)  # (B, hm+1, hm+1): H[fy, fx]
    del g
    return H.mul_(float(m / area))


def otf_quarter_spectrum(camera: Camera, coeffs: torch.Tensor, n: int, *, oversample: int = 1,
                         numerics: Numerics = DEFAULT_NUMERICS, terms=None, channel_weights=None,
                         wavelength_sizes=None) -> torch.Tensor:
    """:func:`otf_quarter` for coefficients ``(B, K, T)`` at the camera's wavelengths, weighted over the spectrum.

    The PSF -> OTF transform is linear, so a spectrum's PSFs (each normalised by its own pupil area) are
    summed first and transformed once: the cost per wavelength is the pupil -> PSF stage only.

    ``channel_weights`` ``(C, K)`` (e.g. :meth:`lenssim.Camera.node_camera`'s): one OTF per colour channel from the
    same wavelengths, ``(B, C, m/2+1, m/2+1)``, each wavelength's PSF computed once for every channel (a channel's
    row is normalised to sum 1; the spectrum's own weights are then not used).

    ``wavelength_sizes`` ``(K,)``: an FFT size per wavelength (even, <= ``n``; e.g. :func:`fft_size` with
    ``per_wavelength``): each wavelength's PSF is computed on its own grid and zero-padded to ``n`` (its Nyquist row
    and column split between the two sides), which equals computing it on ``n`` where the PSF fits its own grid.
    """
    _check_spectral(camera, coeffs, N_TERMS if terms is None else len(terms))
    if channel_weights is None:  # one spectrum: its PSFs summed as they come
        if len(camera.spectrum) == 1:
            return otf_quarter(coeffs[:, 0], n, pupil_radius_px=_radius(camera, n, camera.spectrum.wavelengths_um[0]),
                               oversample=oversample, supersample=numerics.supersample, terms=terms)
        acc = None
        for k, (lam, w) in enumerate(zip(camera.spectrum.wavelengths_um, camera.spectrum.weights)):
            p, area = _wavelength_psf_half(camera, coeffs, k, lam, n, wavelength_sizes, numerics, terms)
            acc = p.mul_(w / area) if acc is None else acc.add_(p, alpha=w / area)
        H = _otf_from_psf_half(acc, n, oversample, 1.0)
        H[..., 0, 0] = 1
        return H
    # colour channels: the wavelengths' PSFs (each over its pupil area) stacked, mixed by one product with the
    # channels' weights, and transformed in one batch
    rows = _channel_rows(channel_weights, len(camera.spectrum))
    active = [k for k in range(len(camera.spectrum)) if any(r[k] > 0 for r in rows)]
    B, h = coeffs.shape[0], n // 2
    buf = None
    for i, k in enumerate(active):
        p, area = _wavelength_psf_half(camera, coeffs, k, camera.spectrum.wavelengths_um[k], n, wavelength_sizes,
                                       numerics, terms)
        if buf is None:
            buf = p.new_empty(len(active), B, n, h + 1)
        torch.mul(p, 1.0 / area, out=buf[i])
        del p
    mix = torch.tensor([[r[k] for k in active] for r in rows], dtype=buf.dtype, device=buf.device)
    acc = (mix @ buf.reshape(len(active), -1)).reshape(len(rows) * B, n, h + 1)
    del buf
    H = _otf_from_psf_half(acc, n, oversample, 1.0)
    H[..., 0, 0] = 1
    return H.reshape(len(rows), B, *H.shape[-2:]).transpose(0, 1)


def _wavelength_psf_half(camera: Camera, coeffs: torch.Tensor, k: int, lam: float, n: int, wavelength_sizes,
                         numerics: Numerics, terms):
    """:func:`_psf_half` of wavelength ``k`` on its own FFT size (``wavelength_sizes[k]``, default ``n``), zero-padded to
    ``n``: rows periodically, the columns ``u >= 0`` with the last one halved (it stood for both signs)."""
    nk = n if wavelength_sizes is None else int(wavelength_sizes[k])
    if not (nk <= n and nk % 2 == 0):
        raise ValueError(f"wavelength_sizes[{k}] = {nk} is not allowed: an even size <= n = {n}")
    p, area = _psf_half(coeffs[:, k], nk, _radius(camera, nk, lam), numerics.supersample, terms)
    if nk != n:
        p = _pad_periodic(p, n, -2)
        col = p.new_zeros(p.shape[:-1] + (n // 2 + 1,))
        col[..., : nk // 2].copy_(p[..., : nk // 2])
        col[..., nk // 2].copy_(0.5 * p[..., nk // 2])
        p = col
    return p, area


def _channel_rows(channel_weights, K: int) -> tuple[tuple[float, ...], ...]:
    """``channel_weights`` ``(C, K)`` checked (finite, >= 0, each row a positive sum) and each row normalised to 1."""
    rows = tuple(tuple(float(v) for v in r) for r in channel_weights)
    if not rows or any(len(r) != K for r in rows):
        raise ValueError(f"channel_weights: expected (C, K) with K = {K} wavelengths")
    if any(not all(math.isfinite(v) and v >= 0 for v in r) or not sum(r) > 0 for r in rows):
        raise ValueError("channel_weights: finite values >= 0 with a positive sum per channel")
    return tuple(tuple(v / sum(r) for v in r) for r in rows)


def _pad_periodic(p: torch.Tensor, m: int, dim: int) -> torch.Tensor:
    """Zero-pad a periodic sequence (DFT order) of even length ``n`` to ``m`` along ``dim``, the Nyquist sample split
    between ``+n/2`` and ``-n/2`` (as :func:`_otf_from_psf_half` does)."""
    n = p.shape[dim]
    if m == n:
        return p
    h = n // 2
    shape = list(p.shape)
    shape[dim] = m
    out = p.new_zeros(shape)
    out.narrow(dim, 0, h).copy_(p.narrow(dim, 0, h))
    out.narrow(dim, m - h + 1, h - 1).copy_(p.narrow(dim, h + 1, h - 1))
    half = 0.5 * p.narrow(dim, h, 1)
    out.narrow(dim, h, 1).copy_(half)
    out.narrow(dim, m - h, 1).copy_(half)
    return out


def otf_quarter_pair(camera: Camera, coeffs: torch.Tensor, n: int, *, oversample: int = 1,
                     numerics: Numerics = DEFAULT_NUMERICS, terms=None) -> torch.Tensor:
    """OTFs of PSFs with no mirror symmetry (e.g. an as-built lens's), as two quarter planes: ``(B, 2, m/2+1, m/2+1)``
    complex, ``m = oversample n``, ``H[:, 0] = H(fy, fx)`` and ``H[:, 1] = H(fy, -fx)`` for ``fy, fx = 0..m/2``, each
    ``H(0) = 1``; coefficients ``(B, K, T)`` of ``terms`` with the field along +y, weighted over the spectrum.

    ``H(-f) = conj H(f)``, so the two quarters hold the whole plane: the mean over the full grid of any function of
    ``H`` and a reference OTF at the same frequency, even under ``f -> -f``, is the mean of its quarter-plane means
    over the two (what :func:`lenssim.tolerancing.as_built_criteria` uses). For a mirror-symmetric wavefront both
    quarters equal :func:`otf_quarter_spectrum` (tested). The general path: full 2-D transforms of the pupil's
    bounding box and of the zero-padded PSF.
    """
    m = n * int(oversample)
    hm = m // 2
    acc = None
    for _, lam, w, field, _, _ in _wavelength_fields(camera, coeffs, n, None, None, numerics, terms):
        amp, _ = _pupil_box_cached(float(_radius(camera, int(n), lam)), int(numerics.supersample))
        p = _intensity(field, int(n), area=float(amp.sum())).mul_(w)
        acc = p if acc is None else acc.add_(p)
    acc = _pad_periodic(_pad_periodic(acc, m, -2), m, -1)
    H = torch.fft.rfft2(acc)  # (B, m, m/2+1): every fy, fx >= 0 (the PSF is real)
    del acc
    neg = (-torch.arange(hm + 1, device=H.device)) % m
    out = torch.stack([H[:, : hm + 1, : hm + 1], H[:, neg, : hm + 1].conj()], dim=1)  # H(fy, -fx) = conj H(-fy, fx)
    out[:, :, 0, 0] = 1
    return out


def _area_normalise(H: torch.Tensor, amp: torch.Tensor) -> torch.Tensor:
    """Normalise an un-normalised OTF (autocorrelation of the sampled pupil) by the pupil area.

    The anti-aliased pupil's autocorrelation at shift ``k != 0`` approximates the overlap area of
    the two shifted discs, but at ``k = 0`` it sums ``amp^2`` instead of ``amp`` (a partial sample
    overlaps itself fully). Dividing by the area ``sum(amp)`` and setting ``H(0) = 1`` removes an
    ``O(1 / (3 R))`` low-frequency error (R = pupil radius in samples) that the usual ``H / H(0)``
    leaves; the MTF then converges to the analytic one as ``O(1/R^2)`` at low frequencies.
    """
    n = amp.shape[-1]
    H = H / (amp.sum() * n * n)
    H[..., 0, 0] = 1
    return H


# -- the OPD on a pupil from real rays (any sequential lens) ---------------------------------------------------------

SAMPLINGS = ("area", "point")
"""How a PSF is sampled on the pixels: integrated over each pixel's area, or at the pixel centres."""
TABLE_GRID = 64
"""Pupil samples across the entrance pupil's diameter in the wavefront table (each wavelength and field node)."""
TABLE_INITIAL_NODES = 9
"""Field-angle nodes of the table before bisection (from the axis to the largest angle, evenly)."""
TABLE_MAX_NODES = 257
"""Most field-angle nodes of the table (the bisection stops there and the error reached is reported)."""
TABLE_TRACE_FIELDS = 32
"""Most field nodes of a wavefront table traced in one bundle (about 3,300 rays each at :data:`TABLE_GRID`)."""
TABLE_TOLERANCE_WAVES = 0.01
"""Largest error (waves) of the table's angle interpolation at the mid-nodes, over the unvignetted pupil."""
PHASE_SIGN = -1.0
"""The pupil function is ``A exp(PHASE_SIGN 2 pi i W)`` with ``W`` Welford's OPD (reference minus ray) and the image
axes along the pupil's: with -1 the PSF's centroid is the rays' centroid (tests/lenssim/test_sequential_psf.py)."""
TABLE_CACHE_SIZE = 8
"""Wavefront tables kept in the process (each a few MB)."""
_TABLES: dict = {}
CHUNK_BYTES = 2**28
"""PSFs are computed in batches whose complex FFT grids take at most this many bytes."""
APERTURE_UNTRACED = 2.0
"""The aperture ratio given to a pupil sample whose ray cannot be traced at all (well beyond the pass level 1)."""



def _meridional_grid(grid: int):
    """The table's pupil grid: ``grid`` samples from ``-e`` to ``e`` per axis, ``e`` a little beyond the unit disc so
    that interpolation at the rim has samples on both sides. Returns ``(coords (grid,), e)``."""
    e = 1.0 + 2.0 / (grid - 1) * 2
    return torch.linspace(-e, e, grid, dtype=torch.float64, device=HOST), e


def _inpaint(W: torch.Tensor, valid: torch.Tensor, sweeps: int = 3) -> torch.Tensor:
    """``W`` (…, G, G) with the samples where ``valid`` is False filled from their valid neighbours (``sweeps`` rings),
    0 beyond: the values a bilinear interpolation reads at the vignetting's edge."""
    W = torch.where(valid, W, torch.zeros_like(W))
    have = valid.to(W.dtype)
    for _ in range(sweeps):
        num = torch.zeros_like(W)
        den = torch.zeros_like(W)
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
            num += torch.roll(W * have, (dy, dx), dims=(-2, -1))
            den += torch.roll(have, (dy, dx), dims=(-2, -1))
        fill = (have == 0) & (den > 0)
        W = torch.where(fill, num / den.clamp(min=1), W)
        have = torch.where(fill, torch.ones_like(have), have)
    return W


def _stencil(nodes: torch.Tensor, alpha: torch.Tensor, width: int = 4):
    """Cubic Lagrange interpolation in angle: for each ``alpha`` ``(P,)`` the ``width`` nodes around it (fewer if the
    table has fewer) and their weights, ``(P, w)`` each (the weights sum to 1)."""
    A = nodes.numel()
    w = min(width, A)
    j = torch.clamp(torch.searchsorted(nodes, alpha.contiguous(), right=True) - 1, 0, A - 1)
    first = torch.clamp(j - (w // 2 - 1), 0, A - w)
    idx = first[:, None] + torch.arange(w, device=nodes.device)[None, :]
    x = nodes[idx]  # (P, w)
    wts = torch.ones_like(x)
    for i in range(w):
        for k in range(w):
            if i != k:
                wts[:, i] = wts[:, i] * (alpha - x[:, k]) / (x[:, i] - x[:, k])
    return idx, wts


@dataclass(frozen=True)
class WavefrontTable:
    """OPD maps (waves) of a lens per wavelength and field-angle node, in the meridional frame (see the module
    docstring): ``opd_waves`` and ``aperture_ratio`` ``(K, A, G, G)`` (the ray's largest height over a semi-diameter,
    :attr:`lenssim.optics.sequential.RayBundle.aperture_ratio`: the ray passes where it is <= 1, a smooth function
    whose interpolation places the vignetting's edge between samples; ``opd_waves`` continued smoothly across that
    edge), on the pupil coordinates
    ``grid_coords`` ``(G,)`` (``[row, col] = [py, px]``), ``angles_deg`` ``(A,)`` increasing from 0;
    ``spot_radius_mm`` ``(K, A)``: the largest distance of a ray's image point from the paraxial image point. The OPD
    is against the sphere centred on the primary wavelength's chief-ray point; the distortion that moves that point
    from the paraxial one is :attr:`distortion_mm` (a smooth function of the angle, interpolated by a cubic spline and
    added to the PSF as the tilt that moves it there: a tilt's linear interpolation in angle would need many more
    nodes)."""

    wavelengths_um: tuple[float, ...]
    angles_deg: torch.Tensor
    grid_coords: torch.Tensor
    extent: float
    opd_waves: torch.Tensor
    aperture_ratio: torch.Tensor
    spot_radius_mm: torch.Tensor
    distortion_mm: torch.Tensor
    """``(A,)``: the primary wavelength's chief-ray point minus the paraxial point ``m tan(alpha)`` (mm, radial)."""
    interpolation_error_waves: float

    def _bracket(self, alpha_deg: torch.Tensor):
        a = self.angles_deg
        if bool((alpha_deg > a[-1] * (1 + 1e-9) + 1e-12).any()):
            raise ValueError(f"field angle {float(alpha_deg.max()):.4g} deg is beyond the wavefront table's "
                             f"{float(a[-1]):.4g} deg")
        j = torch.clamp(torch.searchsorted(a, alpha_deg.contiguous(), right=True) - 1, 0, max(len(a) - 2, 0))
        if len(a) == 1:
            return j, j, torch.zeros_like(alpha_deg)
        t = ((alpha_deg - a[j]) / (a[j + 1] - a[j])).clamp(0, 1)
        return j, j + 1, t

    def spot_radius_at(self, alpha_deg: torch.Tensor) -> torch.Tensor:
        """The largest spot radius (mm) over the wavelengths at ``alpha_deg`` ``(P,)``: the larger of the two nodes'."""
        j0, j1, _ = self._bracket(alpha_deg)
        r = self.spot_radius_mm.amax(dim=0)
        return torch.maximum(r[j0], r[j1])

    def distortion_at(self, alpha_deg: torch.Tensor) -> torch.Tensor:
        """The distortion (mm, radial) at ``alpha_deg`` ``(P,)``: cubic spline through the nodes (not-a-knot)."""
        a = self.angles_deg.numpy()
        if len(a) < 4:
            return torch.from_numpy(__import__("numpy").interp(alpha_deg.numpy(), a, self.distortion_mm.numpy()))
        from scipy.interpolate import CubicSpline

        return torch.from_numpy(CubicSpline(a, self.distortion_mm.numpy())(alpha_deg.to(torch.float64).numpy()))

    def sample(self, k: int, alpha_deg: torch.Tensor, px: torch.Tensor, py: torch.Tensor):
        """OPD (waves) and aperture ratio (the ray passes where <= 1) of wavelength ``k`` at field angles ``alpha_deg``
        ``(P,)`` and meridional pupil points ``px, py`` ``(P, M, M)``: bilinear in the pupil, cubic in angle (Lagrange
        through the four nearest nodes). Returns two ``(P, M, M)``."""
        import torch.nn.functional as F

        self._bracket(alpha_deg)  # refuses angles beyond the table
        grid = torch.stack([px / self.extent, py / self.extent], dim=-1).to(self.opd_waves.dtype)  # x = col, y = row
        idx, wts = _stencil(self.angles_deg, alpha_deg.to(torch.float64))
        # the angle interpolation on the table's grid first (linear operations commute): one bilinear lookup per map
        wts = wts.to(self.opd_waves.dtype)[:, :, None, None]
        maps = torch.stack([(self.opd_waves[k][idx] * wts).sum(1), (self.aperture_ratio[k][idx] * wts).sum(1)], dim=1)
        out = F.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out[:, 0], out[:, 1]


def chief_point_mm(seq: SequentialLens, alpha: float, lam: float) -> tuple[float, float]:
    """Where the chief ray of field ``alpha`` (deg) at ``lam`` meets the image plane: its ``(x, y)`` (mm; ``x`` is 0
    for a centred lens, and taken as exactly 0 there)."""
    return _chief_points_mm(seq, Fields([alpha]), lam)[0]


def _chief_points_mm(seq: SequentialLens, fields: Fields, lam: float) -> list[tuple[float, float]]:
    """:func:`chief_point_mm` of every field of ``fields``, traced at once."""
    zero = torch.zeros(1, dtype=torch.float64, device=HOST)
    chief = seq.wavefront(fields, zero, zero, lam).chief_mm  # (F, 3)
    return [(0.0 if seq.is_centred else float(c[0]), float(c[1])) for c in chief]


def _trace_nodes(seq: SequentialLens, alphas, lams, scale_mm: float, grid: int) -> list:
    """Field nodes ``alphas`` (deg), traced at once (each as it would be alone): per node and wavelength, the OPD map
    against the sphere centred on the primary wavelength's chief-ray point, the vignetting, the disc's unvignetted
    samples, and the largest distance (mm) of a ray's image point from the paraxial point ``scale tan(alpha)``; and
    the distortion (mm) of the primary chief ray: ``[(maps per wavelength, distortion) per node]``."""
    coords, e = _meridional_grid(grid)
    Y, X = torch.meshgrid(coords, coords, indexing="ij")
    inside = X**2 + Y**2 <= (1 + 2 * (coords[1] - coords[0])) ** 2
    fields = Fields(alphas)
    chiefs = _chief_points_mm(seq, fields, seq.primary_wavelength_um)
    ref = ([c[0] for c in chiefs], [c[1] for c in chiefs])
    maps = [seq.wavefront(fields, X[inside], Y[inside], lam, reference_mm=ref, vignette=False) for lam in lams]
    nodes = []
    for f, alpha in enumerate(fields.values):
        paraxial = scale_mm * math.tan(math.radians(alpha))
        chief_x, chief = chiefs[f]
        out = []
        for lam, w in zip(lams, maps):
            opd, valid, ratio_in, image = w.opd_waves[f], w.valid[f], w.aperture_ratio[f], w.image_mm[f]
            W = torch.zeros(grid, grid, dtype=torch.float64, device=HOST)
            V = torch.zeros(grid, grid, dtype=torch.bool, device=HOST)
            T = torch.zeros(grid, grid, dtype=torch.bool, device=HOST)
            W[inside] = torch.nan_to_num(opd, nan=0.0)
            V[inside] = valid
            T[inside] = ~torch.isnan(opd)  # traced through the surfaces extended beyond their semi-diameters
            ratio = torch.full((grid, grid), APERTURE_UNTRACED, dtype=torch.float64, device=HOST)
            ratio[inside] = torch.where(T[inside], ratio_in, torch.full_like(ratio_in, APERTURE_UNTRACED))
            disc = V & (X**2 + Y**2 <= 1)
            if not bool(disc.any()):
                raise ValueError(f"field {alpha:.4g} deg at {lam:g} um: every ray is vignetted")
            pts = image[valid][:, :2]
            spot = float(torch.hypot(pts[:, 0] - chief_x, pts[:, 1] - paraxial).max())
            out.append((_inpaint(W, T), ratio, spot, disc))
        nodes.append((out, chief - paraxial))
    return nodes


def wavefront_table(seq: SequentialLens, wavelengths_um, max_angle_deg: float, image_scale_mm: float, *,
                    grid: int = TABLE_GRID, tolerance_waves: float = TABLE_TOLERANCE_WAVES,
                    max_nodes: int = TABLE_MAX_NODES, progress=None) -> WavefrontTable:
    """The :class:`WavefrontTable` of ``seq`` at ``wavelengths_um`` from the axis to ``max_angle_deg`` (see the module
    docstring); ``progress(k)`` is called with the number of traced maps as they are traced. The initial nodes are
    traced together, and each bisection round's mid-nodes together (at most :data:`TABLE_TRACE_FIELDS` a trace):
    every node's map is what it would be traced alone, and the bisection's choices are made in the same order."""
    lams = tuple(float(v) for v in wavelengths_um)
    amax = float(max_angle_deg)
    nodes = torch.linspace(0, amax, TABLE_INITIAL_NODES if amax > 0 else 1, dtype=torch.float64, device=HOST).tolist()
    maps: dict[float, tuple] = {}

    def trace(angles):
        new = [a for a in dict.fromkeys(angles) if a not in maps]
        for i in range(0, len(new), TABLE_TRACE_FIELDS):
            part = new[i:i + TABLE_TRACE_FIELDS]
            for a, m in zip(part, _trace_nodes(seq, part, lams, image_scale_mm, grid)):
                maps[a] = m
                if progress is not None:
                    progress(len(lams))

    trace(nodes)
    known_nodes = set(nodes)  # the nodes a stencil may use: those traced before, in the bisection's order
    err = 0.0
    todo = list(zip(nodes, nodes[1:]))  # intervals whose mid-node is checked
    left = 0.0
    while todo and len(known_nodes) < max_nodes:
        refine, left = [], 0.0
        trace([(a0 + a1) / 2 for a0, a1 in todo])  # the round's mid-nodes at once
        for a0, a1 in todo:
            known = torch.tensor(sorted(known_nodes), dtype=torch.float64, device=HOST)
            mid = (a0 + a1) / 2
            idx, wts = _stencil(known, torch.tensor([mid], dtype=torch.float64, device=HOST))
            stencil = [float(known[i]) for i in idx[0]]
            known_nodes.add(mid)
            m = maps[mid][0]
            e = 0.0
            for k, (Wm, _, _, dm) in enumerate(m):
                both = dm.clone()
                guess = torch.zeros_like(Wm)
                for a, wt in zip(stencil, wts[0]):
                    Wa, _, _, da = maps[a][0][k]
                    both &= da
                    guess = guess + float(wt) * Wa
                if bool(both.any()):
                    e = max(e, float((Wm - guess)[both].abs().max()))
            if e > tolerance_waves:
                refine += [(a0, mid), (mid, a1)]
                left = max(left, e)
            else:
                err = max(err, e)  # an interval accepted: its mid-node's error
        todo = refine
    if todo:  # stopped at max_nodes: the intervals not refined keep their error
        err = max(err, left)
    nodes = sorted(maps)
    K = len(lams)
    W = torch.stack([torch.stack([maps[a][0][k][0] for a in nodes]) for k in range(K)])
    V = torch.stack([torch.stack([maps[a][0][k][1] for a in nodes]) for k in range(K)])
    spot = torch.tensor([[maps[a][0][k][2] for a in nodes] for k in range(K)], dtype=torch.float64, device=HOST)
    dist = torch.tensor([maps[a][1] for a in nodes], dtype=torch.float64, device=HOST)
    coords, e = _meridional_grid(grid)
    return WavefrontTable(lams, torch.tensor(nodes, dtype=torch.float64, device=HOST), coords, e, W, V, spot, dist, err)


def cached_wavefront_table(seq: SequentialLens, wavelengths_um, max_angle_deg: float, image_scale_mm: float, *,
                           max_nodes: int = TABLE_MAX_NODES, progress=None) -> WavefrontTable:
    """:func:`wavefront_table`, traced once in the process for the same lens (everything that changes its optics: its
    ``cache_key``, so prescription, image plane, index offsets, misalignments), wavelengths, largest angle and node
    limit; the :data:`TABLE_CACHE_SIZE` most recently used are kept."""
    key = json.dumps([seq.cache_key(), tuple(wavelengths_um), max_angle_deg]
                     + ([max_nodes] if max_nodes != TABLE_MAX_NODES else []), sort_keys=True, default=str)
    hit = _TABLES.pop(key, None)
    if hit is None:
        hit = wavefront_table(seq, wavelengths_um, max_angle_deg, image_scale_mm, progress=progress,
                              max_nodes=max_nodes)
    _TABLES[key] = hit  # most recently used last
    while len(_TABLES) > TABLE_CACHE_SIZE:
        _TABLES.pop(next(iter(_TABLES)))
    return hit


def _paraxial_image_heights(seq: SequentialLens, lam: float, z_img: float, tan_field: float):
    """The paraxial marginal ray's and the chief ray's (at ``tan_field``) heights (mm) on the plane ``z_img`` at
    ``lam``."""
    par = seq.paraxial(lam)
    z_last = float(seq.prescription.vertex_z_mm[-1])
    r_ep = par.epd_mm / 2
    mh, mu = seq._ynu(r_ep, 0.0, lam)
    ch, cu = seq._ynu(-par.entrance_pupil_z_mm * tan_field, tan_field, lam)
    d = z_img - z_last
    return mh[-1] + mu[-1] * d, ch[-1] + cu[-1] * d


def image_scale_mm(seq: SequentialLens) -> float:
    """Paraxial chief-ray height on the image plane per unit tangent of the field angle (primary wavelength)."""
    lam = seq.primary_wavelength_um
    return _paraxial_image_heights(seq, lam, seq.image_z_mm, 1.0)[1]


def psfs_from_table(table: WavefrontTable, channel_weights, alpha_deg, phi_rad, n: int, s: int, N: int,
                    pitch_um: float, working_f_number: float, sampling: str,
                    complex_dtype=torch.complex64, distortion: bool = True) -> torch.Tensor:
    """PSFs ``(P, C, n, n)`` (unit sum) at field angles ``alpha_deg`` and image-plane azimuths ``phi_rad`` ``(P,)``
    from ``table``, with each channel's weights ``(C, K)`` at the table's wavelengths; ``s`` samples per pixel, an
    ``N``-point FFT (see the module docstring). Returns them and the fraction of each one's light the ``n x n``
    window holds, ``(P, C)``. ``distortion=False``: each PSF about the primary wavelength's chief-ray point instead of
    the paraxial point (the image registered, as for a criterion that scores blur, not the geometric mapping)."""
    P = alpha_deg.numel()
    rows_w = _channel_rows(channel_weights, len(table.wavelengths_um))
    C = len(rows_w)
    real = torch.float64 if complex_dtype == torch.complex128 else torch.float32
    dev = table.opd_waves.device
    out = torch.zeros(P, C, n, n, dtype=torch.float64, device=dev)
    held = torch.zeros(P, C, dtype=torch.float64, device=dev)
    fine = pitch_um / s
    half = N // 2
    per = max(1, CHUNK_BYTES // (N * N * (16 if complex_dtype == torch.complex128 else 8) * 3))
    lo = half - (n // 2) * s - s // 2
    if lo < 0:
        raise ValueError(f"FFT size {N} is smaller than the {n} px PSF at {s} samples per pixel")
    keep = (torch.arange(n * s, device=dev) + (lo - half)) % N  # the window's samples, frequency 0 at index 0
    for i0 in range(0, P, per):
        a = alpha_deg[i0:i0 + per].to(torch.float64)
        ph = phi_rad[i0:i0 + per].to(torch.float64)
        m = a.numel()
        dist_um = table.distortion_at(a) * 1e3 if distortion else torch.zeros_like(a)
        outs = [None] * C
        for k, lam in enumerate(table.wavelengths_um):
            if not any(r[k] > 0 for r in rows_w):
                continue
            R = N * fine / (2 * lam * working_f_number)
            j = _box_coords(R).to(dev) / R
            gy, gx = torch.meshgrid(j, j, indexing="ij")  # pupil [row, col] = [py, px], image-plane frame
            sp, cp = torch.sin(ph)[:, None, None], torch.cos(ph)[:, None, None]
            mx = gx * sp - gy * cp  # the meridional frame of each PSF's azimuth (field along +y)
            my = gx * cp + gy * sp
            W, V = table.sample(k, a, mx, my)
            # the distortion as a tilt: with PHASE_SIGN -1, W = -delta rho_y / (2 lambda N_w) moves the PSF by +delta
            W = W - (dist_um / (2 * lam * working_f_number))[:, None, None] * my
            amp = ((gx**2 + gy**2 <= 1)[None] & (V <= 1)).to(real)
            field_ = torch.polar(amp, (PHASE_SIGN * 2 * math.pi) * W.to(real)).to(complex_dtype)
            win = _intensity(field_, N, area=amp.sum(dim=(-2, -1), keepdim=True), keep=keep)  # the window's samples
            if sampling == "area":
                pix = win.reshape(m, n, s, n, s).sum(dim=(2, 4))
            else:
                pix = win[:, s // 2::s, s // 2::s]
            _add_weighted(outs, pix.to(torch.float64), rows_w, k)
        acc = torch.stack(outs, dim=1)
        inside = acc.sum(dim=(-2, -1))
        held[i0:i0 + m] = inside
        out[i0:i0 + m] = acc / inside[..., None, None]
    return out, held
