"""The design criteria for batches of designs: OTF banks by FFT size, in bounded-memory chunks.

For each field angle of the lens and each noise level the OTF criteria of :mod:`lenssim.criteria`
(``mse_s``, ``mse_r``) are computed from the pixel-sampled OTF (:func:`lenssim.optics.psf_bank.otf_quarter`,
weighted over the camera's spectrum) and the image model of :mod:`lenssim.optics.image_model`, then
averaged over the field; the design criteria (``rms_w``, ``cost``) come from the wavefront
coefficients and the surfaces.

The criteria of each wavefront model (:data:`lenssim.optics.wavefront_models.WAVEFRONT_MODELS`) live here, in the
evaluation layer: ``third_order`` is :func:`evaluate`, ``exact`` takes the OTF criteria from the ray-traced wavefront
(:func:`exact_criteria`); this module registers them with the optics' table when it is imported
(:func:`lenssim.optics.wavefront_models.register_evaluator`), so that the optics never imports the criteria.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from .optics.aberrations import N_TERMS
from .optics.exact_wavefront import EXACT_TERMS, exact_wavefront_coefficients
from .model.camera import Camera
from .checks import check_shape
from .criteria import CRITERIA, OTFContext, lens_criteria, otf_criteria, quarter_weights, validate_criterion, wavefront_rms_per_field
from .model.design import Design
from .optics.image_model import image_psd_quarter, noise_variance
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .optics.psf_bank import fft_size as choose_fft_size
from .optics.psf_bank import otf_quarter_spectrum, spectral_coefficients
from .optics.wavefront_models import WAVEFRONT_MODELS, register_evaluator
from .torch_utils import HOST, as_tensor, chunk_budget_bytes
from .validate import NumericalError, ResourceLimitError, check_memory

__all__ = ["otf_criteria_bank", "evaluate", "exact_criteria"]


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
        from .model.spectrum import Spectrum

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
        m = n * oversample
        psd_q = image_psd_quarter(m, rho0, model=psd_model, dtype=coeffs.dtype, device=coeffs.device)
        weights = quarter_weights(m, psd_q.dtype, psd_q.device)
        pw = psd_q * weights
        caches = [{} for _ in range(C)]  # what the contexts of this FFT size share (e.g. the diffraction-limited OTF)
        if channel_weights is not None:  # the channels' diffraction-limited OTFs from one pass over the wavelengths
            zero = torch.zeros(1, *coeffs.shape[1:], dtype=coeffs.dtype, device=coeffs.device)
            dl = otf_quarter_spectrum(camera, zero, n, oversample=oversample, numerics=numerics, terms=terms,
                                      channel_weights=channel_weights)
            for c in range(C):
                caches[c]["dl"] = dl[:, c]
        per_psf = otf_bytes(n)
        step = max(1, int(chunk_budget_bytes(coeffs.device, numerics.chunk_bytes) // per_psf))
        for start in range(0, idx.numel(), step):
            sel = idx[start:start + step]
            nk = None if wavelength_sizes is None else wavelength_sizes[sel.cpu()].amax(dim=0).tolist()
            H_all = otf_quarter_spectrum(camera, coeffs[sel], n, oversample=oversample, numerics=numerics, terms=terms,
                                         channel_weights=channel_weights, wavelength_sizes=nk)
            for c in range(C):
                H = H_all if channel_weights is None else H_all[:, c]
                H2 = H.real.square() + H.imag.square()
                ctx = OTFContext(H, H2, psd_q, weights, pw, sigma2, n,
                                 camera if channel_weights is None else channel_cams[c], numerics, _cache=caches[c])
                for name in names:
                    if channel_weights is None:
                        out[name][sel] = CRITERIA[name].from_otf(ctx)
                    else:
                        out[name][c, sel] = CRITERIA[name].from_otf(ctx)
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
    if fft_size is None:
        try:
            sizes = choose_fft_size(camera, flat, numerics)
        except ResourceLimitError as exc:
            i = getattr(exc, "index", 0)
            at = ", ".join(f"{k} = {float(v.reshape(-1)[i // A]):g}" for k, v in d64.values.items())
            alpha = camera.lens.field_angles_deg[i % A]
            raise ResourceLimitError(f"design {at} at {alpha:g} deg: {exc}", exc.setting) from None
    else:
        sizes = torch.full((flat.shape[0],), _checked_fft_size(fft_size), dtype=torch.int64, device=HOST)
    snr = torch.as_tensor(snr_db, dtype=torch.float64, device=HOST).reshape(-1)
    return d64, coeffs64, flat, sizes, snr


def _checked_fft_size(fft_size) -> int:
    """A given FFT size (every PSF on it), refused unless an even integer >= 16."""
    if isinstance(fft_size, bool) or not (isinstance(fft_size, int) and fft_size >= 16 and fft_size % 2 == 0):
        raise ValueError(f"fft_size={fft_size!r} is not allowed: an even integer >= 16")
    return fft_size


def _assemble(camera: Camera, d64: Design, coeffs64: torch.Tensor, per_field: dict, sizes, snr, numerics) -> dict:
    """:func:`evaluate`'s result for one camera (channel) from its per-field OTF criteria."""
    shape = d64.shape
    A, S = coeffs64.shape[-3], snr.numel()
    out = {}
    for name, crit in lens_criteria().items():
        if crit.from_otf is not None:
            v = per_field[name].reshape(shape + ((A, S) if crit.per_snr else (A,)))
            out[name], out[f"{name}_alpha"] = v.mean(dim=-2 if crit.per_snr else -1), v
        else:
            out[name] = as_tensor(crit.from_design(camera, d64, coeffs64, numerics), dtype=torch.float64)
    out["rms_w_alpha"] = wavefront_rms_per_field(camera, coeffs64)
    out["rms_w_piston_removed"] = torch.sqrt((wavefront_rms_per_field(camera, coeffs64, True) ** 2).mean(dim=-1))
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


def exact_criteria(camera: Camera, design: Design, snr_db, *, rho0: float,
                   numerics: Numerics = DEFAULT_NUMERICS, fft_size: int | None = None) -> dict:
    """Every registered OTF criterion (field averages, ``(S,)`` float64, ``()`` for one that does not depend on the
    SNR) of one design with the exact (ray-traced, fitted) wavefront at each field angle
    (:func:`lenssim.optics.exact_wavefront.exact_wavefront_coefficients`), one wavelength (the spectrum's first);
    also ``NAME_alpha`` ``(A, S)`` (``(A,)``), ``fft_size`` ``(A,)``, and the RMS of the fitted wavefront over the
    pupil (waves, no piston removal: the paper's ``RMS_W`` of the exact wavefront) ``rms_w``, ``rms_w_alpha`` ``(A,)``
    and ``rms_w_piston_removed``. ``fft_size``: every PSF on this FFT grid (an even integer >= 16) instead of each
    one's own (:func:`lenssim.optics.psf_bank.fft_size`), e.g. the pixel grid of a prescription's PSFs
    (:func:`lenssim.sequential_metrics.evaluate_sequential`'s ``psf_grid_px``) for the same frequency samples."""
    if len(camera.spectrum) != 1 or camera.channels:
        raise ValueError("exact_criteria takes a one-wavelength camera")
    n = None if fft_size is None else _checked_fft_size(fft_size)
    lam = camera.spectrum.wavelengths_um[0]
    c = torch.stack([exact_wavefront_coefficients(camera, design, a, lam) for a in camera.lens.field_angles_deg])
    sizes = (choose_fft_size(camera, c[:, None], numerics, terms=EXACT_TERMS) if n is None
             else torch.full((c.shape[0],), n, dtype=torch.int64, device=c.device))
    per = otf_criteria_bank(camera, c[:, None].to(torch.float32), sizes, snr_db, rho0=rho0, numerics=numerics,
                            terms=EXACT_TERMS)
    out = {}
    for k, v in per.items():
        out[k], out[f"{k}_alpha"] = v.mean(dim=0), v
    out["fft_size"] = sizes
    out["rms_w_alpha"] = wavefront_rms_per_field(camera, c[:, None], terms=EXACT_TERMS)
    out["rms_w"] = torch.sqrt((out["rms_w_alpha"] ** 2).mean())
    rms_p = wavefront_rms_per_field(camera, c[:, None], True, EXACT_TERMS)
    out["rms_w_piston_removed"] = torch.sqrt((rms_p**2).mean())
    return out


# ---- the wavefront models' criteria (WavefrontModel.evaluate), registered with the optics' table --------------
def _third_order_evaluate(camera, design, snr_db, *, rho0, numerics, device=None):
    return evaluate(camera, design, snr_db, rho0=rho0, numerics=numerics, device=device)


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


register_evaluator("third_order", _third_order_evaluate)
register_evaluator("exact", _exact_evaluate)
