"""lenssim: cost-performance trade-off of end-to-end lens design (optics side).

Implements "Integrated analysis of industrial limitations and image quality: an end-to-end
design approach", Optics Express 31(10), 16897 (2023): a thin lens with a spherical front and a
conic back surface, third-order aberrations over the field, PSF/OTF banks by Fourier optics,
the asphere's RMS slope-departure cost and the expected-MSE design criteria.
"""

__version__ = "0.1.0"

from .aberrations import (
    COEFFICIENT_NAMES,
    field_rms_wavefront,
    rms_wavefront,
    seidel_sums,
    wavefront,
    wavefront_coefficients,
    wavefront_gradient,
)
from .cost import best_fit_sphere_curvature, slope_departure_cost, slope_departure_cost_third_order
from .designs import Design, load_designs
from .image_model import PAPER_RHO0, PAPER_SNR_DB, image_psd, noise_variance, psd_continuous
from .lens import PAPER_LENS, LensError, ThinLens
from .metrics import evaluate, mse_bank, mse_from_otf_quarter
from .psf_bank import fft_size, max_wavefront_slope, otf, otf_quarter, psf, psf_at, pupil_amplitude

__all__ = [
    "__version__",
    "COEFFICIENT_NAMES",
    "Design",
    "LensError",
    "PAPER_LENS",
    "PAPER_RHO0",
    "PAPER_SNR_DB",
    "ThinLens",
    "best_fit_sphere_curvature",
    "evaluate",
    "fft_size",
    "field_rms_wavefront",
    "image_psd",
    "load_designs",
    "max_wavefront_slope",
    "mse_bank",
    "mse_from_otf_quarter",
    "noise_variance",
    "otf",
    "otf_quarter",
    "psd_continuous",
    "psf",
    "psf_at",
    "pupil_amplitude",
    "rms_wavefront",
    "seidel_sums",
    "slope_departure_cost",
    "slope_departure_cost_third_order",
    "wavefront",
    "wavefront_coefficients",
    "wavefront_gradient",
]
