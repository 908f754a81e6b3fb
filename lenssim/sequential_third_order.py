"""The paper's design criteria of any sequential lens through its third-order wavefront (``lenssim tradeoff
--wavefront third_order``): the paper's own route (Sections 2.1-2.3), generalised from the thin singlet.

:func:`evaluate_third_order` reads the Seidel coefficients of the prescription's surfaces at each field angle and
wavelength (:func:`lenssim.optics.seidel_wavefront.third_order_coefficients`) into the singlet's OTF criteria
(:func:`lenssim.metrics.otf_criteria_bank`: the anti-aliased pupil, the PSF point-sampled on the pixel grid, the
image model's frequency integrals), on the camera of :func:`lenssim.optics.seidel_wavefront.equivalent_thin_lens`
(the working F-number and the entrance pupil) with the lens's wavelengths at equal weights. For the paper's singlet
written as a prescription every criterion equals :func:`lenssim.metrics.evaluate`'s (tests). It is fast (no ray is
traced: a design in tens of milliseconds) and as accurate as third order: higher-order aberrations, vignetting and
the asphere's ``A6`` and beyond are absent (the exact route, :func:`lenssim.sequential_metrics.evaluate_sequential`,
has them).
"""

from __future__ import annotations

import torch

from .criteria import CRITERIA, otf_criteria, wavefront_rms_per_field
from .metrics import otf_criteria_bank
from .model.camera import Camera
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .model.sensor import Sensor
from .model.spectrum import Spectrum
from .optics.aberrations import TERMS
from .optics.cost import prescription_costs
from .optics.psf_bank import fft_size as choose_fft_size
from .optics.seidel_wavefront import SEIDEL_TERMS, equivalent_thin_lens, third_order_coefficients
from .optics.sequential import SequentialLens
from .torch_utils import HOST, tensor_of

__all__ = ["evaluate_third_order", "third_order_camera"]


def third_order_camera(seq: SequentialLens, pitch_um: float, angles_deg) -> Camera:
    """The camera the third-order criteria of ``seq`` are computed on: :func:`equivalent_thin_lens`, a sensor of
    ``pitch_um`` (um) pixels, the prescription's wavelengths (um) at equal weights."""
    lams = seq.prescription.wavelengths_um
    light = Spectrum(lams, (1.0,) * len(lams), name=f"the lens's {len(lams)} wavelength(s)")
    return Camera(equivalent_thin_lens(seq, angles_deg), Sensor(pixel_pitch_um=pitch_um, width_px=1, height_px=1),
                  light)


def evaluate_third_order(seq: SequentialLens, snr_db, *, pitch_um: float, rho0: float, angles_deg,
                         psd_model: str = "discrete", numerics: Numerics = DEFAULT_NUMERICS, criteria=None,
                         dtype=torch.float32) -> dict:
    """Every criterion of the lens ``seq`` (object at infinity) from its third-order wavefront at the field angles
    ``angles_deg`` (deg) on pixels of ``pitch_um`` (um, point samples, the paper's image model) at the SNRs ``snr_db``
    (dB), with the image model's correlation ``rho0``. Returns what
    :func:`lenssim.sequential_metrics.evaluate_sequential` returns: each OTF criterion's field mean (``(S,)`` per
    SNR) and ``NAME_alpha``, ``rms_w`` (waves of the first wavelength; the paper's: no piston removal, about the
    Gaussian image point), ``rms_w_alpha``, ``rms_w_piston_removed``, ``cost`` and ``cost_per_surface`` (the
    prescription's aspheres, as the exact route), ``fft_size`` ``(A,)``, ``alpha_deg``, ``snr_db``; the OTFs in
    ``dtype`` (float32: the paper's sweep)."""
    names = otf_criteria() if criteria is None else tuple(c for c in criteria if CRITERIA[c].from_otf is not None)
    angles = tuple(float(a) for a in angles_deg)
    camera = third_order_camera(seq, pitch_um, angles)
    coeffs = third_order_coefficients(seq, angles, camera.spectrum.wavelengths_um)  # (A, K, 5)
    terms = SEIDEL_TERMS
    if len(camera.spectrum) == 1:  # one wavelength: no lateral colour, the paper's four terms exactly
        coeffs, terms = coeffs[..., :len(TERMS)], TERMS
    sizes = choose_fft_size(camera, coeffs, numerics, terms=terms)
    snr = tensor_of(snr_db, torch.float64).reshape(-1)
    out: dict = {"alpha_deg": torch.tensor(angles, dtype=torch.float64, device=HOST), "snr_db": snr, "fft_size": sizes}
    if names:
        per = otf_criteria_bank(camera, coeffs.to(dtype), sizes, snr, rho0=rho0, psd_model=psd_model,
                                numerics=numerics, criteria=names, terms=terms)
        for name, v in per.items():
            out[name], out[f"{name}_alpha"] = v.mean(dim=0), v
    if criteria is None or "rms_w" in criteria:
        c = coeffs[None]
        out["rms_w_alpha"] = wavefront_rms_per_field(camera, c, terms=terms)[0]
        out["rms_w"] = torch.sqrt((out["rms_w_alpha"] ** 2).mean())
        out["rms_w_piston_removed"] = torch.sqrt(
            (wavefront_rms_per_field(camera, c, True, terms=terms)[0] ** 2).mean())
    if criteria is None or "cost" in criteria:
        per_surface = prescription_costs(seq.prescription, numerics.cost_points)
        out["cost"] = torch.tensor(sum(v["cost"] for v in per_surface.values()), dtype=torch.float64, device=HOST)
        out["cost_per_surface"] = per_surface
    return out
