"""lenssim: cost-performance trade-off of end-to-end lens design (optics side).

Implements "Integrated analysis of industrial limitations and image quality: an end-to-end
design approach", Optics Express 31(10), 16897 (2023): a thin lens with a spherical front and a
conic back surface, third-order aberrations over the field, PSF/OTF banks by Fourier optics,
the asphere's RMS slope-departure cost and the expected-MSE design criteria.

The objects a designer names: :class:`Lens`, :class:`Sensor`, :class:`Spectrum` (together a
:class:`Camera`), a :class:`Design` (named free parameters, :data:`PARAMETERS`), the criteria
(:data:`CRITERIA`), the numerical settings (:class:`Numerics`) and PSF providers
(:class:`LensPSF`, :class:`FunctionPSF`) for the image pipeline. No value of the paper is a default
here: the paper is a scenario, :mod:`lenssim_studies.paper`, that the studies and the command line pass
in. See docs/architecture.md.
"""

__version__ = "0.2.0"

from .optics.aberrations import (
    COEFFICIENT_NAMES,
    TERMS,
    field_rms_wavefront,
    rms_wavefront,
    seidel_sums,
    wavefront,
    wavefront_coefficients,
    wavefront_gradient,
)
from .model.camera import Camera
from .checks import check_shape
from .optics.cost import best_fit_sphere_curvature, slope_departure_cost, slope_departure_cost_third_order
from .criteria import CRITERIA, Criterion, validate_criterion
from .model.design import PARAMETERS, Design, Parameter, load_designs, parameter_name
from .model.geometry import FieldGeometry, frame_center
from .model.glass import ConstantGlass
from .optics.image_model import image_psd, noise_variance, psd_continuous
from .model.lens import Lens, LensError
from .metrics import evaluate, otf_criteria_bank
from .model.numerics import DEFAULT_NUMERICS, FAST_NUMERICS, Numerics
from .optics.psf_bank import (fft_size, max_wavefront_slope, otf, otf_quarter, otf_quarter_spectrum, psf, psf_at,
                       pupil_amplitude, spectral_coefficients)
from .optics.bank import OTFBank, PSFBank
from .optics.psf_provider import AsBuiltPSF, FunctionPSF, LensPSF, PSFProvider
from .model.tolerances import GRADES, Perturbations, Tolerances
from .tolerancing import as_built_criteria
from .model.sensor import Sensor
from .model.spectrum import Spectrum
from .torch_utils import select_device

__all__ = [
    "__version__",
    "AsBuiltPSF",
    "CRITERIA",
    "COEFFICIENT_NAMES",
    "Camera",
    "ConstantGlass",
    "Criterion",
    "DEFAULT_NUMERICS",
    "Design",
    "FAST_NUMERICS",
    "FieldGeometry",
    "FunctionPSF",
    "GRADES",
    "Lens",
    "LensError",
    "LensPSF",
    "Numerics",
    "OTFBank",
    "PSFBank",
    "PARAMETERS",
    "PSFProvider",
    "Parameter",
    "Perturbations",
    "Sensor",
    "Spectrum",
    "TERMS",
    "Tolerances",
    "as_built_criteria",
    "best_fit_sphere_curvature",
    "check_shape",
    "evaluate",
    "fft_size",
    "field_rms_wavefront",
    "frame_center",
    "image_psd",
    "load_designs",
    "max_wavefront_slope",
    "noise_variance",
    "otf",
    "otf_criteria_bank",
    "otf_quarter",
    "otf_quarter_spectrum",
    "parameter_name",
    "psd_continuous",
    "psf",
    "psf_at",
    "pupil_amplitude",
    "rms_wavefront",
    "seidel_sums",
    "select_device",
    "slope_departure_cost",
    "slope_departure_cost_third_order",
    "spectral_coefficients",
    "validate_criterion",
    "wavefront",
    "wavefront_coefficients",
    "wavefront_gradient",
]
