"""The paper's design criteria of a lens on a sensor (Sections 2.2-2.3 of the paper): one evaluation, for the thin
singlet's batched designs and for any sequential lens.

Every route computes, per field angle, the pixel-sampled OTF ``H`` on an ``n x n`` pixel grid, and from it every
registered OTF criterion of :mod:`lenssim.criteria` (``mse_s``, ``mse_r`` per SNR, ``strehl``, ``mtf50``, ...) through
one :class:`lenssim.criteria.OTFContext` (:func:`_otf_criteria`: the image model ``P_x`` of
:mod:`lenssim.optics.image_model` and the frequency integrals on an ``oversample`` x finer grid), then averages over
the field angles (:func:`_field_means`); ``rms_w`` is the root of the field-average of the mean square wavefront
(waves, no piston removal: the paper's), ``rms_w_piston_removed`` likewise about the mean (:func:`_rms_results`), and
``cost`` is ``C_a``. The routes differ in where the OTFs come from:

* **wavefront coefficients** (the fast path, no ray traced): :func:`otf_criteria_bank` turns batches of pupil
  polynomials into pixel-sampled OTFs (:func:`lenssim.optics.psf_bank.otf_quarter_spectrum`: the anti-aliased pupil,
  weighted over the camera's spectrum), grouped by FFT size (:func:`lenssim.optics.psf_bank.fft_size`) in bounded-memory
  chunks. The paper's singlet (:func:`evaluate`: batches of :class:`lenssim.Design`, the third-order closed forms),
  the exact ray-traced wavefront of one singlet design fitted by polynomials (:func:`exact_criteria`), and the Seidel
  wavefront of any prescription (:func:`evaluate_third_order`, on :func:`third_order_camera`) take it;
* **real-ray PSFs** of any lens (:func:`evaluate_sequential`, a :class:`lenssim.optics.psf_provider.SequentialPSF`:
  a prescription, object at infinity, on a sensor's pixels, in one spectrum or colour channels): at
  :data:`EVALUATION_FIELDS` angles from the axis to the provider's largest, the PSF by Fourier optics of the real-ray
  OPD (vignetted pupil, every wavelength), zero-padded to the oversampled grid (:func:`_otf_quarters`); ``rms_w`` over
  the unvignetted pupil (:data:`RMS_QUADRATURES`) in waves of the primary wavelength, referred to the chief ray;
  ``cost`` the sum over the aspheres (:func:`lenssim.optics.cost.prescription_costs`, ``cost_per_surface``).

Each real-ray PSF is taken about its chief ray's image point, not the paraxial point: distortion is the lens's
geometric mapping (a camera corrects it, or a simulated photo renders it), not blur. The Strehl ratio is therefore at
the chief ray's point, against the aberration-free PSF of the same (vignetted) pupil. The PSFs along one radius of a
rotationally symmetric lens are mirror-symmetric about it, so ``Re H`` and ``|H|^2`` are even in both frequency axes
and the quarter plane carries the integrals, as for the singlet. A decentred or tilted lens (a manufactured copy,
:mod:`lenssim.tolerancing`) is evaluated along its ``+y`` field, its PSFs not mirror-symmetric: each criterion is the
mean of its values on the quarters ``fx >= 0`` and ``fx <= 0`` (exactly the full plane's mean for the integrals
``mse_s``, ``mse_r``, ``mse_r_nominal``; for ``mtf50``, the mean of the two halves' values).

The criteria of each wavefront model (:data:`lenssim.optics.wavefront_models.WAVEFRONT_MODELS`) live here, in the
evaluation layer: ``third_order`` is :func:`evaluate`, ``exact`` takes the OTF criteria from the ray-traced wavefront
(:func:`exact_criteria`); this module registers them with the optics' table when it is imported
(:func:`lenssim.optics.wavefront_models.register_evaluator`), so that the optics never imports the criteria.

References
----------
.. [1] Optics Express 31(10), 16897 (2023), Sections 2.1-2.3, Eqs. (2)-(6).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch

from .checks import check_shape
from .criteria import CRITERIA, OTFContext, lens_criteria, otf_criteria, quarter_weights, validate_criterion, wavefront_rms_per_field
from .model.camera import Camera
from .model.design import Design
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .model.sensor import Sensor
from .model.spectrum import Spectrum
from .optics.aberrations import N_TERMS, TERMS
from .optics.cost import prescription_costs
from .optics.exact_wavefront import EXACT_TERMS, exact_wavefront_coefficients, pupil_quadrature
from .optics.image_model import image_psd_quarter, noise_variance
from .optics.psf_bank import fft_size as choose_fft_size
from .optics.psf_bank import otf_quarter_spectrum, spectral_coefficients
from .optics.seidel_wavefront import SEIDEL_TERMS, equivalent_thin_lens, third_order_coefficients
from .optics.sequential import SequentialLens
from .optics.psf_provider import SequentialPSF
from .optics.wavefront_models import WAVEFRONT_MODELS, register_evaluator
from .torch_utils import HOST, abs_square, as_tensor, chunk_budget_bytes, tensor_of
from .validate import NumericalError, ResourceLimitError, check_memory

__all__ = ["otf_criteria_bank", "evaluate", "exact_criteria", "evaluate_third_order", "third_order_camera",
           "evaluate_sequential", "evaluation_angles", "EVALUATION_FIELDS", "RMS_PUPIL_GRID",
           "RMS_QUADRATURES"]

MIN_FFT_SIZE = 16
"""The smallest FFT size (px) a caller may fix for the coefficient routes' PSFs (``fft_size``)."""
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


# ---- what every route shares: the image model, the OTF context, the field means, RMS_W, C_a -----------------------
def _image_model(m: int, rho0: float, psd_model: str, dtype, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The image model on the ``m``-sample quarter plane: its PSD ``P_x``, the quarter's weights and their product."""
    psd_q = image_psd_quarter(m, rho0, model=psd_model, dtype=dtype, device=device)
    weights = quarter_weights(m, psd_q.dtype, psd_q.device)
    return psd_q, weights, psd_q * weights


def _otf_criteria(names, H: torch.Tensor, image, sigma2: torch.Tensor, n: int, camera, numerics: Numerics, cache: dict,
                  reference: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Each criterion of ``names`` ``{name: (B, S) or (B,)}`` of the quarter-plane OTFs ``H`` ``(B, q, q)`` of an
    ``n``-pixel grid, through one :class:`lenssim.criteria.OTFContext` (``image``: :func:`_image_model`)."""
    ctx = OTFContext(H, abs_square(H), *image, sigma2, n, camera, numerics, reference=reference,
                     _cache=cache)
    return {name: CRITERIA[name].from_otf(ctx) for name in names}


def _field_means(per: dict) -> dict:
    """``{NAME: field mean, NAME_alpha: per field}`` of per-field criteria ``(..., A, S)`` (``(..., A)`` for one that
    does not depend on the SNR)."""
    out = {}
    for name, v in per.items():
        out[name], out[f"{name}_alpha"] = v.mean(dim=-2 if CRITERIA[name].per_snr else -1), v
    return out


def _rms_results(rms_alpha: torch.Tensor, rms_p_alpha: torch.Tensor) -> dict:
    """``rms_w_alpha``, ``rms_w`` (the root of the field-mean square) and ``rms_w_piston_removed`` from the RMS
    wavefront per field angle ``(..., A)`` (waves) and about its mean."""
    return {"rms_w_alpha": rms_alpha, "rms_w": torch.sqrt((rms_alpha**2).mean(dim=-1)),
            "rms_w_piston_removed": torch.sqrt((rms_p_alpha**2).mean(dim=-1))}


def _prescription_cost(prescription, numerics: Numerics) -> dict:
    """``cost`` (``C_a``: the sum over the prescription's aspheres, each over its clear aperture) and
    ``cost_per_surface`` (:func:`lenssim.optics.cost.prescription_costs`)."""
    per = prescription_costs(prescription, numerics.cost_points)
    return {"cost": torch.tensor(sum(v["cost"] for v in per.values()), dtype=torch.float64, device=HOST),
            "cost_per_surface": per}


def _checked_grid(name: str, value, minimum: int, allowed: str) -> int:
    """A PSF grid (px) the caller fixes, refused unless an even integer of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int) or value % 2 or value < minimum:
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}")
    return value


# ---- wavefront coefficients: the singlet's batched designs, its exact fit, the third order of any lens -----------
def otf_criteria_bank(camera: Camera, coeffs: torch.Tensor, sizes: torch.Tensor, snr_db, *,
                      rho0: float, psd_model: str = "discrete", numerics: Numerics = DEFAULT_NUMERICS,
                      criteria=None, progress: Callable[[int], None] | None = None,
                      terms=None, channel_weights=None, wavelength_sizes=None) -> dict[str, torch.Tensor]:
    """OTF criteria ``{name: (P, S)}`` (``(P,)`` for a criterion that does not depend on the SNR; float64) for
    field-axis coefficient sets ``(P, K, T)`` (``terms``: their monomial table, default
    :data:`lenssim.optics.aberrations.TERMS`). Each criterion receives an :class:`lenssim.criteria.OTFContext`.

    PSFs are grouped by FFT size ``sizes`` ``(P,)`` and processed in chunks of at most
    ``numerics.chunk_bytes`` of working memory on a CPU (a share of the free memory on a GPU:
    :func:`lenssim.torch_utils.chunk_budget_bytes`), so memory stays bounded whatever ``P``. The
    frequency integrals use ``numerics.oversample`` x finer grids than the FFT (the Wiener-error
    integrand is not band-limited and needs them). ``progress`` is called with the number of PSFs
    finished after each chunk.

    ``channel_weights`` ``(C, K)`` (shared colour channels, :meth:`lenssim.Camera.node_camera`): each wavelength's PSF
    is computed once for every channel, and every criterion is ``(C, P, S)`` (``(C, P)``), one row per channel.
    ``wavelength_sizes`` ``(P, K)``: the FFT size each wavelength needs (:func:`lenssim.optics.psf_bank.fft_size` with
    ``per_wavelength``; at most ``sizes``): each chunk computes a wavelength on the largest its PSFs need.
    """
    check_shape(coeffs, f"P K {N_TERMS if terms is None else len(terms)}", "coeffs (waves per wavelength)")
    names = otf_criteria() if criteria is None else tuple(criteria)
    for c in names:
        if validate_criterion(c).from_otf is None:
            raise ValueError(f"criterion {c!r} is not computed from the OTF")
    sigma2 = noise_variance(snr_db, device=coeffs.device).reshape(-1)
    P, S = coeffs.shape[0], sigma2.numel()
    C = 1 if channel_weights is None else len(channel_weights)
    lead = () if channel_weights is None else (C,)
    out = {c: torch.empty(lead + ((P, S) if CRITERIA[c].per_snr else (P,)), dtype=torch.float64, device=coeffs.device)
           for c in names}
    if channel_weights is not None:  # each channel's criteria see a camera with its own weights on these wavelengths
        lam = camera.spectrum.wavelengths_um
        channel_cams = [Camera(camera.lens, camera.sensor, Spectrum(lam, w)) for w in channel_weights]
    sizes = sizes.reshape(-1).cpu()
    oversample = numerics.oversample

    def otf_bytes(n: int) -> int:  # one PSF's OTF and its working copies, every channel
        m = n * oversample
        return C * 6 * max(n, m) * (max(n, m) // 2 + 1) * (2 * coeffs.element_size())

    if sizes.numel():  # the largest size before any work (a raised --max-fft-size may ask for more than there is)
        n_max = int(sizes.max())
        check_memory(otf_bytes(n_max), f"one OTF of {n_max * oversample} x {n_max * oversample} samples",
                     setting="max_fft_size")
    for n in torch.unique(sizes).tolist():
        idx = torch.nonzero(sizes == n).flatten().to(coeffs.device)
        image = _image_model(n * oversample, rho0, psd_model, coeffs.dtype, coeffs.device)
        caches = [{} for _ in range(C)]  # what the contexts of this FFT size share (e.g. the diffraction-limited OTF)
        if channel_weights is not None:  # the channels' diffraction-limited OTFs from one pass over the wavelengths
            zero = torch.zeros(1, *coeffs.shape[1:], dtype=coeffs.dtype, device=coeffs.device)
            dl = otf_quarter_spectrum(camera, zero, n, oversample=oversample, numerics=numerics, terms=terms,
                                      channel_weights=channel_weights)
            for c in range(C):
                caches[c]["dl"] = dl[:, c]
        step = max(1, int(chunk_budget_bytes(coeffs.device, numerics.chunk_bytes) // otf_bytes(n)))
        for start in range(0, idx.numel(), step):
            sel = idx[start:start + step]
            nk = None if wavelength_sizes is None else wavelength_sizes[sel.cpu()].amax(dim=0).tolist()
            H_all = otf_quarter_spectrum(camera, coeffs[sel], n, oversample=oversample, numerics=numerics, terms=terms,
                                         channel_weights=channel_weights, wavelength_sizes=nk)
            for c in range(C):
                one = channel_weights is None
                vals = _otf_criteria(names, H_all if one else H_all[:, c], image, sigma2, n,
                                     camera if one else channel_cams[c], numerics, caches[c])
                for name, v in vals.items():
                    out[name][sel if one else (c, sel)] = v
            if progress is not None:
                progress(sel.numel())
    return out


def evaluate(camera: Camera, design: Design, snr_db, *, rho0: float,
             psd_model: str = "discrete", fft_size: int | None = None, numerics: Numerics = DEFAULT_NUMERICS,
             dtype=torch.float32, device=None, progress: Callable[[int], None] | None = None) -> dict:
    """Every registered criterion for the designs of ``design`` (parameters broadcast to ``(*)``).

    Returns a dict of tensors (float64 for the criteria) with ``A`` field angles and ``S`` SNRs:
    each criterion of :data:`lenssim.criteria.CRITERIA` by name, ``(*, S)`` if it depends on the
    SNR else ``(*)``; per field angle ``NAME_alpha`` ``(*, A, S)`` (``(*, A)``) for the OTF criteria and
    ``rms_w_alpha`` ``(*, A)``; ``rms_w_piston_removed`` ``(*)``; ``fft_size`` ``(*, A)`` (the FFT size
    used for each PSF); ``snr_db`` ``(S,)``; ``alpha_deg`` ``(A,)``. ``fft_size`` overrides the
    automatic choice (:func:`lenssim.optics.psf_bank.fft_size`). The OTFs are computed in ``dtype``.

    A camera with colour ``channels`` is evaluated channel by channel: each result is then the mean
    over the channels, and ``NAME_per_channel`` holds the channels' values on a leading axis
    (``fft_size`` is the largest over the channels).

    References
    ----------
    .. [1] Optics Express 31(10), 16897 (2023), Section 2.3, Eqs. (4)-(6) (the expected MSEs) and Section 2.2,
       Eq. (3) (``C_a``).

    Examples
    --------
    >>> import torch
    >>> from lenssim import FAST_NUMERICS, Camera, ConstantGlass, Design, Lens, Sensor, Spectrum
    >>> lens = Lens(focal_length_mm=25.0, pupil_radius_mm=2.0, glass=ConstantGlass(1.5), field_angles_deg=(0.0, 7.0))
    >>> camera = Camera(lens, Sensor(pixel_pitch_um=1.5625, width_px=6000, height_px=4000), Spectrum.monochromatic(0.5))
    >>> designs = Design(s=torch.tensor([-0.775, -0.725]), Q_back=torch.tensor([-2.4, -10.0]))
    >>> r = evaluate(camera, designs, [21.6, 27.6], rho0=0.97, numerics=FAST_NUMERICS)
    >>> tuple(r["mse_r"].shape), tuple(r["mse_r_alpha"].shape), tuple(r["cost"].shape)
    ((2, 2), (2, 2, 2), (2,))
    """
    if camera.channels:
        camera = camera.with_quadrature(numerics.spectral_tol)
        if camera.shared_channels:
            parts = _evaluate_shared(camera, design, snr_db, rho0=rho0, psd_model=psd_model, fft_size=fft_size,
                                     numerics=numerics, dtype=dtype, device=device, progress=progress)
        else:
            parts = [evaluate(c, design, snr_db, rho0=rho0, psd_model=psd_model, fft_size=fft_size, numerics=numerics,
                              dtype=dtype, device=device, progress=progress) for c in camera.channel_cameras()]
        out = {}
        for k, v in parts[0].items():
            if k in ("snr_db", "alpha_deg"):
                out[k] = v
            elif k == "fft_size":
                out[k] = torch.stack([p[k] for p in parts]).amax(dim=0)
            else:
                out[f"{k}_per_channel"] = torch.stack([p[k] for p in parts])
                out[k] = out[f"{k}_per_channel"].mean(dim=0)
        return out
    d64, coeffs64, flat, sizes, snr = _prepare(camera, design, snr_db, fft_size, numerics, device)
    per_field = otf_criteria_bank(camera, flat.to(dtype), sizes, snr, rho0=rho0, psd_model=psd_model,
                                  numerics=numerics, progress=progress)
    return _assemble(camera, d64, coeffs64, per_field, sizes, snr, numerics)


def _evaluate_shared(camera: Camera, design: Design, snr_db, *, rho0, psd_model, fft_size, numerics, dtype, device,
                     progress) -> list[dict]:
    """:func:`evaluate` per colour channel of channels on shared wavelengths: each wavelength's PSF computed once."""
    nodes, weights = camera.node_camera()
    d64, coeffs64, flat, sizes, snr = _prepare(nodes, design, snr_db, fft_size, numerics, device)
    # each wavelength on the FFT size it needs (the largest sets the OTF's grid)
    per_k = None if fft_size is not None else choose_fft_size(nodes, flat, numerics, per_wavelength=True)
    per_field = otf_criteria_bank(nodes, flat.to(dtype), sizes, snr, rho0=rho0, psd_model=psd_model, numerics=numerics,
                                  progress=progress, channel_weights=weights, wavelength_sizes=per_k)
    return [_assemble(cam, d64, coeffs64, {k: v[c] for k, v in per_field.items()}, sizes, snr, numerics)
            for c, cam in enumerate(camera.channel_cameras())]


def _prepare(camera: Camera, design: Design, snr_db, fft_size, numerics: Numerics, device):
    """The designs (float64, broadcast), their coefficients ``(*, A, K, T)`` and flattened ``(P, K, T)``, the FFT
    sizes ``(P,)`` and the SNRs (dB) of :func:`evaluate`."""
    d64 = design.to(torch.float64, device).broadcast()
    camera.lens.check_design(d64)
    coeffs64 = spectral_coefficients(camera, d64)  # (*, A, K, T)
    A, K = coeffs64.shape[-3], coeffs64.shape[-2]
    flat = coeffs64.reshape(-1, K, N_TERMS)
    try:
        sizes = _fft_sizes(camera, flat, numerics, _checked_fft_size(fft_size))
    except ResourceLimitError as exc:
        i = getattr(exc, "index", 0)
        at = ", ".join(f"{k} = {float(v.reshape(-1)[i // A]):g}" for k, v in d64.values.items())
        alpha = camera.lens.field_angles_deg[i % A]
        raise ResourceLimitError(f"design {at} at {alpha:g} deg: {exc}", exc.setting) from None
    snr = torch.as_tensor(snr_db, dtype=torch.float64, device=HOST).reshape(-1)
    return d64, coeffs64, flat, sizes, snr


def _checked_fft_size(fft_size) -> int | None:
    """A fixed FFT size (every PSF on it), refused unless an even integer of at least :data:`MIN_FFT_SIZE`."""
    return None if fft_size is None else _checked_grid("fft_size", fft_size, MIN_FFT_SIZE,
                                                       f"an even integer >= {MIN_FFT_SIZE}")


def _fft_sizes(camera: Camera, coeffs: torch.Tensor, numerics: Numerics, fft_size: int | None, terms=None):
    """The FFT size ``(P,)`` of each PSF of coefficients ``(P, K, T)``: each one's own
    (:func:`lenssim.optics.psf_bank.fft_size`), or every one on ``fft_size`` (:func:`_checked_fft_size`)."""
    if fft_size is None:
        return choose_fft_size(camera, coeffs, numerics, terms=terms)
    return torch.full((coeffs.shape[0],), fft_size, dtype=torch.int64, device=HOST)


def _assemble(camera: Camera, d64: Design, coeffs64: torch.Tensor, per_field: dict, sizes, snr, numerics) -> dict:
    """:func:`evaluate`'s result for one camera (channel) from its per-field OTF criteria."""
    shape = d64.shape
    A, S = coeffs64.shape[-3], snr.numel()
    out = {}
    for name, crit in lens_criteria().items():
        if crit.from_otf is not None:
            out |= _field_means({name: per_field[name].reshape(shape + ((A, S) if crit.per_snr else (A,)))})
        else:
            out[name] = as_tensor(crit.from_design(camera, d64, coeffs64, numerics), dtype=torch.float64)
    rms = _rms_results(wavefront_rms_per_field(camera, coeffs64), wavefront_rms_per_field(camera, coeffs64, True))
    out["rms_w_alpha"], out["rms_w_piston_removed"] = rms["rms_w_alpha"], rms["rms_w_piston_removed"]
    out["fft_size"] = sizes.reshape(shape + (A,))
    out["snr_db"] = snr
    out["alpha_deg"] = camera.lens.field_angles(dtype=torch.float64)
    for name in lens_criteria():
        if not bool(torch.isfinite(out[name]).all()):
            i = int(torch.nonzero(~torch.isfinite(out[name].reshape(shape + (-1,)).amax(-1).reshape(-1)) |
                                  ~torch.isfinite(out[name].reshape(shape + (-1,)).amin(-1).reshape(-1)))[0])
            at = ", ".join(f"{k} = {float(v.reshape(-1)[i]):g}" for k, v in d64.values.items())
            raise NumericalError(f"criterion {name} of the design {at} is not finite (numerical breakdown); "
                                 "no result is reported")
    return out


def _coefficient_criteria(camera: Camera, coeffs: torch.Tensor, snr_db, *, rho0: float, numerics: Numerics, terms,
                          fft_size: int | None = None, criteria=None, psd_model: str = "discrete",
                          dtype=torch.float32) -> dict:
    """The criteria of one lens from its wavefront coefficients ``(A, K, T)`` (waves; ``terms`` their monomials) at the
    camera's ``A`` field angles: each OTF criterion of ``criteria`` (default all) by :func:`otf_criteria_bank` (OTFs in
    ``dtype``), its field mean and ``NAME_alpha``; ``fft_size`` ``(A,)`` (:func:`_fft_sizes`); with ``criteria``
    ``None`` or naming ``rms_w``, :func:`_rms_results` of the coefficients' wavefront."""
    names = otf_criteria() if criteria is None else tuple(c for c in criteria if CRITERIA[c].from_otf is not None)
    sizes = _fft_sizes(camera, coeffs, numerics, _checked_fft_size(fft_size), terms)
    out: dict = {"fft_size": sizes}
    if names:
        out |= _field_means(otf_criteria_bank(camera, coeffs.to(dtype), sizes, snr_db, rho0=rho0, psd_model=psd_model,
                                              numerics=numerics, criteria=names, terms=terms))
    if criteria is None or "rms_w" in criteria:
        out |= _rms_results(wavefront_rms_per_field(camera, coeffs, terms=terms),
                            wavefront_rms_per_field(camera, coeffs, True, terms))
    return out


def exact_criteria(camera: Camera, design: Design, snr_db, *, rho0: float,
                   numerics: Numerics = DEFAULT_NUMERICS, fft_size: int | None = None) -> dict:
    """Every registered OTF criterion (field averages, ``(S,)`` float64, ``()`` for one that does not depend on the
    SNR) of one design with the exact (ray-traced, fitted) wavefront at each field angle
    (:func:`lenssim.optics.exact_wavefront.exact_wavefront_coefficients`), one wavelength (the spectrum's first);
    also ``NAME_alpha`` ``(A, S)`` (``(A,)``), ``fft_size`` ``(A,)``, and the RMS of the fitted wavefront over the
    pupil (waves, no piston removal: the paper's ``RMS_W`` of the exact wavefront) ``rms_w``, ``rms_w_alpha`` ``(A,)``
    and ``rms_w_piston_removed``. ``fft_size``: every PSF on this FFT grid (an even integer >= 16) instead of each
    one's own (:func:`lenssim.optics.psf_bank.fft_size`), e.g. the pixel grid of a prescription's PSFs
    (:func:`evaluate_sequential`'s ``psf_grid_px``) for the same frequency samples."""
    if len(camera.spectrum) != 1 or camera.channels:
        raise ValueError("exact_criteria takes a one-wavelength camera")
    _checked_fft_size(fft_size)  # refused before the rays are traced
    lam = camera.spectrum.wavelengths_um[0]
    c = torch.stack([exact_wavefront_coefficients(camera, design, a, lam) for a in camera.lens.field_angles_deg])
    return _coefficient_criteria(camera, c[:, None], snr_db, rho0=rho0, numerics=numerics, terms=EXACT_TERMS,
                                 fft_size=fft_size)


def third_order_camera(seq: SequentialLens, pitch_um: float, angles_deg) -> Camera:
    """The camera the third-order criteria of ``seq`` are computed on:
    :func:`lenssim.optics.seidel_wavefront.equivalent_thin_lens` (the working F-number and the entrance pupil), a
    sensor of ``pitch_um`` (um) pixels, the prescription's wavelengths (um) at equal weights."""
    lams = seq.prescription.wavelengths_um
    light = Spectrum(lams, (1.0,) * len(lams), name=f"the lens's {len(lams)} wavelength(s)")
    return Camera(equivalent_thin_lens(seq, angles_deg), Sensor(pixel_pitch_um=pitch_um, width_px=1, height_px=1),
                  light)


def evaluate_third_order(seq: SequentialLens, snr_db, *, pitch_um: float, rho0: float, angles_deg,
                         psd_model: str = "discrete", numerics: Numerics = DEFAULT_NUMERICS, criteria=None,
                         dtype=torch.float32) -> dict:
    """Every criterion of the lens ``seq`` (object at infinity) from its third-order wavefront (``lenssim tradeoff
    --wavefront third_order``: the paper's own route, generalised from the thin singlet) at the field angles
    ``angles_deg`` (deg) on pixels of ``pitch_um`` (um, point samples, the paper's image model) at the SNRs ``snr_db``
    (dB), with the image model's correlation ``rho0``: the Seidel coefficients of the surfaces at each field angle and
    wavelength (:func:`lenssim.optics.seidel_wavefront.third_order_coefficients`) on :func:`third_order_camera`.

    Returns what :func:`evaluate_sequential` returns: each OTF criterion's field mean (``(S,)`` per SNR) and
    ``NAME_alpha``, ``rms_w`` (waves of the first wavelength; the paper's: no piston removal, about the Gaussian image
    point), ``rms_w_alpha``, ``rms_w_piston_removed``, ``cost`` and ``cost_per_surface`` (the prescription's aspheres,
    as the real-ray route), ``fft_size`` ``(A,)``, ``alpha_deg``, ``snr_db``; the OTFs in ``dtype`` (float32: the
    paper's sweep). For the paper's singlet written as a prescription every criterion equals :func:`evaluate`'s
    (tests). No ray is traced (a design in tens of milliseconds); higher-order aberrations, vignetting and the
    asphere's ``A6`` and beyond are absent (the real-ray route has them)."""
    angles = tuple(float(a) for a in angles_deg)
    camera = third_order_camera(seq, pitch_um, angles)
    coeffs = third_order_coefficients(seq, angles, camera.spectrum.wavelengths_um)  # (A, K, 5)
    terms = SEIDEL_TERMS
    if len(camera.spectrum) == 1:  # one wavelength: no lateral colour, the paper's four terms exactly
        coeffs, terms = coeffs[..., :len(TERMS)], TERMS
    snr = tensor_of(snr_db, torch.float64).reshape(-1)
    out = {"alpha_deg": torch.tensor(angles, dtype=torch.float64, device=HOST), "snr_db": snr}
    out |= _coefficient_criteria(camera, coeffs, snr, rho0=rho0, numerics=numerics, terms=terms, criteria=criteria,
                                 psd_model=psd_model, dtype=dtype)
    if criteria is None or "cost" in criteria:
        out |= _prescription_cost(seq.prescription, numerics)
    return out


# ---- real-ray PSFs of any lens -------------------------------------------------------------------------------------
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
    # columns 0, m - 1, ..., m - q + 1 (sample k at -k/m): two slices, the second reversed (a copy, not a gather)
    return H[..., :q, :q], torch.cat([H[..., :q, :1], H[..., :q, m - q + 1:].flip(-1)], dim=-1)


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
    """Every criterion of one lens (:func:`lenssim.criteria.lens_criteria` computed from the OTF, ``rms_w`` and
    ``cost``) for ``psf`` (see the module docstring) at the SNRs ``snr_db`` (dB) with the image model's correlation
    ``rho0``.

    Returns ``{name: field average}`` (``(S,)`` per SNR or a scalar; with colour channels their mean and
    ``NAME_per_channel`` ``(C, ...)``), ``NAME_alpha`` per field angle ``(A, S)`` / ``(A,)`` (channel mean),
    ``rms_w`` and ``rms_w_piston_removed`` (waves), ``rms_w_alpha``, ``cost``, ``cost_per_surface``, ``alpha_deg``,
    ``snr_db`` and ``psf_grid_px`` (the pixel grid ``n`` of the OTFs). ``registered=False``: every PSF and wavefront
    about the paraxial image point (distortion scored as error, as the paper's singlet's Gaussian image point).
    ``progress(k)`` is called with the number of field angles done.

    ``reference``: another provider (e.g. the nominal lens's, on the same sensor and wavelengths) whose OTF at each
    field angle, on the same grid, fills :attr:`lenssim.criteria.OTFContext.reference` (``mse_r_nominal``: the Wiener
    filter designed for it applied to this lens); the grid ``n`` is then the larger of the two PSFs' supports. Without
    it every result is as before (``mse_r_nominal`` equals ``mse_r``). ``rms_quadrature``: how ``rms_w`` averages over
    the pupil (:data:`RMS_QUADRATURES`). ``grid_px``: the PSFs' pixel grid ``n`` (even; at least the PSF's support and
    ``numerics.min_size``) instead of the support's, e.g. the FFT size the singlet's exact route chooses."""
    if rms_quadrature not in RMS_QUADRATURES:
        raise ValueError(f"rms_quadrature={rms_quadrature!r} is not allowed: one of {', '.join(RMS_QUADRATURES)}")
    if grid_px is not None:
        _checked_grid("grid_px", grid_px, numerics.min_size, f"an even number of pixels, at least {numerics.min_size} "
                      "(numerics.min_size) and the PSF's support")
    names = otf_criteria() if criteria is None else tuple(c for c in criteria if CRITERIA[c].from_otf is not None)
    alpha = torch.tensor(evaluation_angles(psf.max_field_deg) if angles_deg is None else
                         [float(a) for a in angles_deg], dtype=torch.float64, device=HOST)  # as the wavefront table
    for a in alpha.tolist():
        if not (math.isfinite(a) and 0 <= a <= psf.max_field_deg * (1 + 1e-12)):
            raise ValueError(f"field angle {a:g} deg is not allowed: 0 to the {psf.max_field_deg:g} deg the PSFs were "
                             "set up for")
    sigma2 = noise_variance(snr_db).reshape(-1).to(torch.float64)
    S, A, C = sigma2.numel(), alpha.numel(), psf.channels

    def support_px(p: SequentialPSF) -> int:  # the largest PSF's support over the field angles along +y (px)
        rows = torch.tensor([p.geometry.radius_px(a) for a in alpha.tolist()], dtype=torch.float64, device=HOST)
        return int(p.extents_px(rows, torch.zeros_like(rows), (0.0, 0.0)).max())

    # the grid and its FFT from a few rays, before the wavefront table (minutes for a lens far out of focus)
    psf.check_fft_size(_grid_size(psf, max(psf.estimated_extent_px(), grid_px or 0), numerics))
    support = support_px(psf)
    if reference is not None:
        _check_reference(psf, reference, alpha)
        support = max(support, support_px(reference))
    if grid_px is not None:
        if grid_px < support:
            raise ValueError(f"grid_px={grid_px} is not allowed: below the PSF's support ({support} px)")
        support = grid_px
    n = _grid_size(psf, support, numerics)
    m = n * numerics.oversample
    check_memory(C * 8 * m * m * 16, f"the OTFs of one field angle on {m} x {m} frequency samples",
                 setting="max_fft_size")
    image = _image_model(m, rho0, psd_model, torch.float64, HOST)
    # the aberration-free PSF of the same (vignetted) pupil, centred on its image point: the Strehl ratio's reference
    perfect = dataclasses.replace(psf.table(), opd_waves=torch.zeros_like(psf.table().opd_waves),
                                  distortion_mm=torch.zeros_like(psf.table().distortion_mm))
    view = _SensorView(psf.sensor)
    per = {c: torch.empty((C, A, S) if CRITERIA[c].per_snr else (C, A), dtype=torch.float64, device=HOST) for c in names}
    half_pi = torch.tensor([math.pi / 2], dtype=torch.float64, device=HOST)  # the field along +y: the rows
    mirrored = not psf.lens.is_centred  # a decentred or tilted lens: both quarters (_otf_quarters)
    for i in range(A if names else 0):
        a = alpha[i:i + 1]
        # each PSF on the whole grid: the diffraction wings beyond its support matter to the MSEs at the 1% level
        H_all = _otf_quarters(psf.psfs_at_angles(a, half_pi, n, n, distortion=not registered,
                                                 complex_dtype=torch.complex128)[0], m, mirrored)  # (C, q, q) each
        H0_all = _otf_quarters(psf.psfs_at_angles(a, half_pi, n, n, table=perfect, distortion=False,
                                                  complex_dtype=torch.complex128)[0], m, mirrored)
        R_all = (None, None) if reference is None else _reference_otf(reference, a, n, m, registered)
        for c in range(C):
            vals = [_otf_criteria(names, H_all[j][c:c + 1], image, sigma2, n, view, numerics,
                                  {"dl": H0_all[j][c:c + 1]}, None if R_all[j] is None else R_all[j][c:c + 1])
                    for j in range(2 if mirrored else 1)]  # the quarter fx >= 0, then (mirrored) fx <= 0
            for name in names:  # the full plane's mean: the two quarters' average (exact for the MSE integrals)
                per[name][c, i] = vals[0][name][0] if len(vals) == 1 else 0.5 * (vals[0][name][0] + vals[1][name][0])
        if progress is not None:
            progress(1)
    out: dict = {"alpha_deg": alpha, "snr_db": tensor_of(snr_db, torch.float64).reshape(-1), "psf_grid_px": n}
    for name, v in _field_means(per).items():  # (C, ...): the channels' mean, and each channel's field mean
        out[name] = v.mean(dim=0)
        if C > 1 and name in per:
            out[f"{name}_per_channel"] = v
    if criteria is None or "cost" in criteria:
        out |= _prescription_cost(psf.lens.prescription, numerics)
    if criteria is None or "rms_w" in criteria:
        out |= _rms_results(*_rms_wavefront(psf, alpha, registered, rms_quadrature))
    return out


# ---- the wavefront models' criteria (WavefrontModel.evaluate), registered with the optics' table --------------
def _exact_evaluate(camera, design, snr_db, *, rho0, numerics, device=None):
    """Every criterion: the OTF criteria and RMS_W (with its per-angle and piston-removed forms) from the exact
    wavefront at each field angle (none is left at its third-order value); C_a, a property of the surfaces."""
    WAVEFRONT_MODELS["exact"].check(camera)
    out = evaluate(camera, design, snr_db, rho0=rho0, numerics=numerics, device=device)
    ex = exact_criteria(camera, design, snr_db, rho0=rho0, numerics=numerics)
    for name, c in lens_criteria().items():
        if c.from_otf is not None:
            out[name], out[f"{name}_alpha"] = ex[name], ex[f"{name}_alpha"]
    for name in ("rms_w", "rms_w_alpha", "rms_w_piston_removed"):  # the exact wavefront's, not third order's
        out[name] = ex[name].to(out[name].dtype)
    out["fft_size"] = ex["fft_size"]
    return out


register_evaluator("third_order", evaluate)
register_evaluator("exact", _exact_evaluate)
