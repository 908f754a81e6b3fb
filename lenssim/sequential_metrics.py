"""The paper's design criteria for any sequential lens on a sensor: real-ray wavefronts instead of third order.

:func:`evaluate_sequential` computes, for a :class:`lenssim.optics.psf_provider.SequentialPSF` (a lens from a
prescription, object at infinity, on a sensor's pixels, in one spectrum or colour channels), what
:func:`lenssim.metrics.evaluate` computes for the paper's singlet (Sections 2.2-2.3 of the paper):

* per field angle (:data:`EVALUATION_FIELDS` angles from the axis to the provider's largest, evenly, as the paper's
  0..14 deg), the pixel-sampled PSF by Fourier optics of the real-ray OPD (vignetted pupil, every wavelength of the
  spectrum), its OTF ``H`` on an ``n x n`` pixel grid (``n`` at least ``numerics.min_size`` and the PSF's support),
  and every registered OTF criterion of one lens (``mse_s``, ``mse_r`` per SNR, ``strehl``, ``mtf50``, ...) from the
  same :class:`lenssim.criteria.OTFContext` the singlet's evaluation builds: the image model ``P_x`` and the
  frequency integrals on an ``oversample`` x finer grid (the PSF zero-padded), averaged over the field angles;
* ``rms_w``: the root of the field-average of the mean square OPD over the unvignetted pupil (uniform weight per
  pupil area), in waves of the primary wavelength, weighted over the spectrum, referred to the chief ray (the OPD is
  0 at the pupil's centre: the paper's "no piston removal"); ``rms_w_piston_removed`` likewise about the mean;
* ``cost``: ``C_a``, the sum over the lens's aspheric surfaces of their RMS slope departure from the best-fitting
  sphere (:func:`lenssim.optics.cost.prescription_costs`; ``cost_per_surface`` by surface number).

Each PSF is taken about its chief ray's image point, not the paraxial point: distortion is the lens's geometric
mapping (a camera corrects it, or a simulated photo renders it, :mod:`lenssim.optics.psf_bank`), not blur, and
a pixel-wise MSE against the undistorted scene would score a shift of whole pixels as error. The Strehl ratio is
therefore at the chief ray's point, against the aberration-free PSF of the same (vignetted) pupil.

The PSFs along one radius of a rotationally symmetric lens are mirror-symmetric about it, so ``Re H`` and ``|H|^2``
are even in both frequency axes and the quarter plane carries the integrals, as for the singlet. A decentred or
tilted lens (a manufactured copy, :mod:`lenssim.sequential_tolerance`) is evaluated along its ``+y`` field (other
azimuths: :meth:`lenssim.optics.sequential.SequentialLens.rotated`), its PSFs about the chief ray's point
(``registered``) and not mirror-symmetric: each criterion is the mean of its values on the quarters ``fx >= 0`` and
``fx <= 0`` (``|H|^2`` and ``Re H`` are even under ``f -> -f``: exactly the full plane's mean for the integrals
``mse_s``, ``mse_r``, ``mse_r_nominal``; for ``mtf50``, the mean of the two halves' values).

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Sections 2.1-2.3, Eqs. (2)-(6).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch

from .criteria import CRITERIA, OTFContext, lens_criteria, otf_criteria, quarter_weights
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .optics.cost import prescription_costs
from .optics.exact_wavefront import pupil_quadrature
from .optics.image_model import image_psd_quarter, noise_variance
from .optics.psf_provider import SequentialPSF
from .torch_utils import HOST, tensor_of
from .validate import ResourceLimitError, check_memory

__all__ = ["evaluate_sequential", "evaluation_angles", "sequential_criteria", "EVALUATION_FIELDS", "RMS_PUPIL_GRID",
           "RMS_QUADRATURES"]

EVALUATION_FIELDS = 15
"""Field angles of the field averages, from the axis to the largest evenly (the paper's 15, 0..14 deg)."""
RMS_PUPIL_GRID = 64
"""Pupil samples across the diameter of the grid the RMS wavefront is averaged on (equal area per sample)."""
RMS_QUADRATURES = ("grid", "gauss")
"""How ``rms_w`` averages over the pupil: ``"grid"`` (the default), the samples of the :data:`RMS_PUPIL_GRID` square
grid inside the disc, equal weights (its staircase rim holds 0.3% more samples than the disc's area, where the
wavefront is largest: +0.4% in the paper's singlet's RMS_W); ``"gauss"``,
:func:`lenssim.optics.exact_wavefront.pupil_quadrature` (Gauss-Legendre in ``rho^2`` times the trapezoid rule in
azimuth, exact for polynomials of the degree the singlet's exact route fits: that route's quadrature)."""


def evaluation_angles(max_field_deg: float, count: int = EVALUATION_FIELDS) -> tuple[float, ...]:
    """``count`` field angles (deg) from 0 to ``max_field_deg``, evenly (the axis alone if ``max_field_deg`` is 0)."""
    if max_field_deg <= 0:
        return (0.0,)
    return tuple(float(v) for v in torch.linspace(0.0, float(max_field_deg), count, dtype=torch.float64, device=HOST))


@dataclasses.dataclass(frozen=True)
class _SensorView:
    """What an :class:`lenssim.criteria.OTFContext` reads of a camera besides the OTFs: the sensor (pixel pitch)."""

    sensor: object


def _grid_size(psf: SequentialPSF, support_px: int, numerics: Numerics) -> int:
    """The PSF grid ``n`` (even, px): the support, at least ``numerics.min_size``; refused beyond ``max_fft_size``."""
    n = max(int(support_px), numerics.min_size)
    n += n % 2
    if n > numerics.max_fft_size:
        raise ResourceLimitError(f"the PSF needs a {n} x {n} pixel grid at {psf.sensor.pixel_pitch_um:g} um per pixel, "
                                 f"more than the largest allowed ({numerics.max_fft_size}; raise max_fft_size or use "
                                 "larger pixels)", "max_fft_size")
    return n


def _otf_quarters(psf_centered: torch.Tensor, m: int, mirrored: bool):
    """Quarter-plane OTF ``(..., m/2+1, m/2+1)`` of PSFs ``(..., n, n)`` centred at ``[n//2, n//2]`` (unit sum),
    zero-padded to ``m x m`` about their centre (frequency sample ``k`` at ``k/m`` cycles/pixel), and with
    ``mirrored`` also the quarter ``fx <= 0`` (``H(fy, -fx)``, sample ``k`` at
    ``-k/m``): ``(Q, Q_mirrored or None)``. A PSF not mirror-symmetric about its meridian (a decentred or tilted lens)
    needs both: its ``|H|^2`` and ``Re H`` are even under ``f -> -f`` only, so the full plane is these two quarters
    and their point reflections."""
    n = psf_centered.shape[-1]
    o = m // 2 - n // 2
    pad = torch.zeros(*psf_centered.shape[:-2], m, m, dtype=psf_centered.dtype, device=psf_centered.device)
    pad[..., o:o + n, o:o + n] = psf_centered
    H = torch.fft.fft2(torch.fft.ifftshift(pad, dim=(-2, -1)))
    q = m // 2 + 1
    if not mirrored:
        return H[..., :q, :q], None
    neg = torch.remainder(-torch.arange(q, device=H.device), m)
    return H[..., :q, :q], H[..., :q, :].index_select(-1, neg)


def _rms_wavefront(psf: SequentialPSF, angles: torch.Tensor, registered: bool,
                   quadrature: str = "grid") -> tuple[torch.Tensor, torch.Tensor]:
    """Per field angle ``(A,)``: the RMS OPD (waves of the primary wavelength) over the unvignetted pupil, referred to
    the chief ray and about the mean, mean square weighted over the spectrum; against the sphere centred on the
    primary chief ray's image point (``registered``) or on the paraxial image point (the distortion's tilt kept);
    averaged by the pupil ``quadrature`` (:data:`RMS_QUADRATURES`)."""
    table = psf.table()
    lams, weights = psf.spectrum()
    if quadrature == "gauss":
        py, px, area = pupil_quadrature()  # rho_r (along the field, +y), rho_t, area weights
    else:
        g = (torch.arange(RMS_PUPIL_GRID, dtype=torch.float64, device=angles.device) + 0.5) / RMS_PUPIL_GRID * 2 - 1
        Y, X = torch.meshgrid(g, g, indexing="ij")
        disc = X**2 + Y**2 <= 1
        px, py = X[disc], Y[disc]
        area = torch.ones_like(px)
    A = angles.numel()
    ref = psf.lens.primary_wavelength_um
    ms = torch.zeros(A, dtype=torch.float64, device=angles.device)
    ms_p = torch.zeros(A, dtype=torch.float64, device=angles.device)
    wsum = sum(weights)
    dist_um = torch.zeros_like(angles) if registered else table.distortion_at(angles) * 1e3
    N_w = psf.working_f_number
    for k, (lam, w) in enumerate(zip(lams, weights)):
        if not w:
            continue
        W, V = table.sample(k, angles, px.expand(A, -1)[:, None, :], py.expand(A, -1)[:, None, :])
        W = W[:, 0] - (dist_um / (2 * lam * N_w))[:, None] * py  # the tilt that moves the image to the paraxial point
        W, ok = W * (lam / ref), (V[:, 0] <= 1).to(torch.float64) * area
        cnt = ok.sum(-1).clamp_min(torch.finfo(torch.float64).tiny)  # 0 / tiny = 0 where every ray is vignetted
        mean = (W * ok).sum(-1) / cnt
        ms += w / wsum * (W.square() * ok).sum(-1) / cnt
        ms_p += w / wsum * ((W - mean[:, None]).square() * ok).sum(-1) / cnt
    return ms.sqrt(), ms_p.sqrt()


def _check_reference(psf: SequentialPSF, reference: SequentialPSF, alpha: torch.Tensor) -> None:
    """A reference provider must sample the same pixels in the same light as ``psf``, out to the angles asked."""
    if not isinstance(reference, SequentialPSF):
        raise ValueError(f"reference={type(reference).__name__} is not allowed: a SequentialPSF")
    if reference.sensor.pixel_pitch_um != psf.sensor.pixel_pitch_um or reference.sampling != psf.sampling:
        raise ValueError("the reference lens's PSFs must be on the same pixels (pitch and sampling) as the lens's")
    if reference.quadrature() != psf.quadrature():
        raise ValueError("the reference lens's PSFs must be in the same wavelengths and channels as the lens's")
    if float(alpha.max()) > reference.max_field_deg * (1 + 1e-12):
        raise ValueError(f"field angle {float(alpha.max()):g} deg is beyond the reference's {reference.max_field_deg:g}")


def _reference_otf(reference: SequentialPSF, a: torch.Tensor, n: int, m: int, registered: bool) -> torch.Tensor:
    """The reference provider's quarter-plane OTFs ``(C, q, q)`` at field angle ``a`` ``(1,)`` on the ``n``-pixel,
    ``m``-frequency grid, and its mirrored quarter (:func:`_otf_quarters`; the same one for a centred lens), kept with
    the provider (a Monte Carlo asks for the same ones for every copy)."""
    store = reference._cache.setdefault("reference_otfs", {})
    key = (float(a[0]), n, m, registered)
    if key not in store:
        half_pi = torch.tensor([math.pi / 2], dtype=torch.float64, device=a.device)
        q, q_m = _otf_quarters(reference.psfs_at_angles(a, half_pi, n, n, distortion=not registered,
                                                        complex_dtype=torch.complex128)[0], m,
                               not reference.lens.is_centred)
        store[key] = (q, q if q_m is None else q_m)
    return store[key]


def evaluate_sequential(psf: SequentialPSF, snr_db, *, rho0: float, angles_deg=None, psd_model: str = "discrete",
                        numerics: Numerics = DEFAULT_NUMERICS, criteria=None, registered: bool = True,
                        progress: Callable[[int], None] | None = None, reference: SequentialPSF | None = None,
                        rms_quadrature: str = "grid", grid_px: int | None = None) -> dict:
    """Every criterion of one lens (:func:`lenssim.criteria.lens_criteria` computed from the OTF, and ``rms_w``) for
    ``psf`` (see the module docstring) at the SNRs ``snr_db`` (dB) with the image model's correlation ``rho0``.

    Returns ``{name: field average}`` (``(S,)`` per SNR or a scalar; with colour channels their mean and
    ``NAME_per_channel`` ``(C, ...)``), ``NAME_alpha`` per field angle ``(A, S)`` / ``(A,)`` (channel mean),
    ``rms_w`` and ``rms_w_piston_removed`` (waves), ``rms_w_alpha``, ``alpha_deg``, ``snr_db`` and ``psf_grid_px``
    (the pixel grid ``n`` of the OTFs). ``registered=False``: every PSF and wavefront about the paraxial image point
    (distortion scored as error, as the paper's singlet's Gaussian image point). ``progress(k)`` is called with the
    number of field angles done.

    ``reference``: another provider (e.g. the nominal lens's, on the same sensor and wavelengths) whose OTF at each
    field angle, on the same grid, fills :attr:`lenssim.criteria.OTFContext.reference` (``mse_r_nominal``: the Wiener
    filter designed for it applied to this lens); the grid ``n`` is then the larger of the two PSFs' supports. Without
    it every result is as before (``mse_r_nominal`` equals ``mse_r``). ``rms_quadrature``: how ``rms_w`` averages over
    the pupil (:data:`RMS_QUADRATURES`). ``grid_px``: the PSFs' pixel grid ``n`` (even; at least the PSF's support and
    ``numerics.min_size``) instead of the support's, e.g. the FFT size the singlet's exact route chooses."""
    if rms_quadrature not in RMS_QUADRATURES:
        raise ValueError(f"rms_quadrature={rms_quadrature!r} is not allowed: one of {', '.join(RMS_QUADRATURES)}")
    if grid_px is not None and (isinstance(grid_px, bool) or not isinstance(grid_px, int) or grid_px % 2
                                or grid_px < numerics.min_size):
        raise ValueError(f"grid_px={grid_px!r} is not allowed: an even number of pixels, at least "
                         f"{numerics.min_size} (numerics.min_size) and the PSF's support")
    names = otf_criteria() if criteria is None else tuple(c for c in criteria if CRITERIA[c].from_otf is not None)
    alpha = torch.tensor(evaluation_angles(psf.max_field_deg) if angles_deg is None else
                         [float(a) for a in angles_deg], dtype=torch.float64, device=HOST)  # as the wavefront table
    for a in alpha.tolist():
        if not (math.isfinite(a) and 0 <= a <= psf.max_field_deg * (1 + 1e-12)):
            raise ValueError(f"field angle {a:g} deg is not allowed: 0 to the {psf.max_field_deg:g} deg the PSFs were "
                             "set up for")
    sigma2 = noise_variance(snr_db).reshape(-1).to(torch.float64)
    S, A, C = sigma2.numel(), alpha.numel(), psf.channels
    geo = psf.geometry
    rows = torch.tensor([geo.radius_px(a) for a in alpha.tolist()], dtype=torch.float64, device=HOST)
    cols = torch.zeros_like(rows)
    # the grid and its FFT from a few rays, before the wavefront table (minutes for a lens far out of focus)
    psf.check_fft_size(_grid_size(psf, max(psf.estimated_extent_px(), grid_px or 0), numerics))
    support = int(psf.extents_px(rows, cols, (0.0, 0.0)).max())
    if reference is not None:
        _check_reference(psf, reference, alpha)
        ref_rows = torch.tensor([reference.geometry.radius_px(a) for a in alpha.tolist()], dtype=torch.float64,
                                device=HOST)
        support = max(support, int(reference.extents_px(ref_rows, cols, (0.0, 0.0)).max()))
    if grid_px is not None:
        if grid_px < support:
            raise ValueError(f"grid_px={grid_px} is not allowed: below the PSF's support ({support} px)")
        support = grid_px
    n = _grid_size(psf, support, numerics)
    m = n * numerics.oversample
    check_memory(C * 8 * m * m * 16, f"the OTFs of one field angle on {m} x {m} frequency samples",
                 setting="max_fft_size")
    psd_q = image_psd_quarter(m, rho0, model=psd_model, dtype=torch.float64, device=HOST)
    weights = quarter_weights(m, torch.float64, HOST)
    pw = psd_q * weights
    # the aberration-free PSF of the same (vignetted) pupil, centred on its image point: the Strehl ratio's reference
    perfect = dataclasses.replace(psf.table(), opd_waves=torch.zeros_like(psf.table().opd_waves),
                                  distortion_mm=torch.zeros_like(psf.table().distortion_mm))
    view = _SensorView(psf.sensor)
    per = {c: torch.empty((C, A, S) if CRITERIA[c].per_snr else (C, A), dtype=torch.float64, device=HOST) for c in names}
    half_pi = torch.tensor([math.pi / 2], dtype=torch.float64, device=HOST)  # the field along +y: the rows
    mirrored = not psf.lens.is_centred  # a decentred or tilted lens: both quarters (_otf_quarters)
    for i in range(A if names else 0):
        a = alpha[i:i + 1]
        k = n  # the PSF on the whole grid: the diffraction wings beyond its support matter to the MSEs at the 1% level
        H_all = _otf_quarters(psf.psfs_at_angles(a, half_pi, n, k, distortion=not registered,
                                                 complex_dtype=torch.complex128)[0], m, mirrored)  # (C, q, q) each
        H0_all = _otf_quarters(psf.psfs_at_angles(a, half_pi, n, k, table=perfect, distortion=False,
                                                  complex_dtype=torch.complex128)[0], m, mirrored)
        R_all = (None, None) if reference is None else _reference_otf(reference, a, n, m, registered)
        for c in range(C):
            vals = {name: [] for name in names}
            for j in range(2 if mirrored else 1):  # the quarter fx >= 0, then (mirrored) fx <= 0
                H = H_all[j][c:c + 1]
                ctx = OTFContext(H, H.real.square() + H.imag.square(), psd_q, weights, pw, sigma2, n, view, numerics,
                                 reference=None if R_all[j] is None else R_all[j][c:c + 1],
                                 _cache={"dl": H0_all[j][c:c + 1]})
                for name in names:
                    vals[name].append(CRITERIA[name].from_otf(ctx)[0])
            for name in names:  # the full plane's mean: the two quarters' average (exact for the MSE integrals)
                per[name][c, i] = vals[name][0] if len(vals[name]) == 1 else 0.5 * (vals[name][0] + vals[name][1])
        if progress is not None:
            progress(1)
    out: dict = {"alpha_deg": alpha, "snr_db": tensor_of(snr_db, torch.float64).reshape(-1),
                 "psf_grid_px": n}
    for name in names:
        v = per[name]
        out[f"{name}_alpha"] = v.mean(dim=0)
        field_mean = v.mean(dim=1)  # (C, S) or (C,)
        out[name] = field_mean.mean(dim=0)
        if C > 1:
            out[f"{name}_per_channel"] = field_mean
    if criteria is None or "cost" in criteria:  # C_a: the lens's aspheres, each over its clear aperture
        per = prescription_costs(psf.lens.prescription, numerics.cost_points)
        out["cost"] = torch.tensor(sum(v["cost"] for v in per.values()), dtype=torch.float64, device=HOST)
        out["cost_per_surface"] = per
    if criteria is None or "rms_w" in criteria:
        rms, rms_p = _rms_wavefront(psf, alpha, registered, rms_quadrature)
        out["rms_w_alpha"] = rms
        out["rms_w"] = torch.sqrt((rms**2).mean())
        out["rms_w_piston_removed"] = torch.sqrt((rms_p**2).mean())
    return out


def sequential_criteria() -> tuple[str, ...]:
    """The criteria :func:`evaluate_sequential` computes: every OTF criterion of one lens, ``rms_w`` and ``cost``."""
    return tuple(k for k in lens_criteria() if k in otf_criteria() or k in ("rms_w", "cost"))
