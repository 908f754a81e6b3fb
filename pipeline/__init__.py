"""pipeline: the camera pipeline (photo -> linear -> spatially-variant blur -> noise -> restoration).

Modules: image I/O (:mod:`pipeline.io`), the ideal image of a run (:mod:`pipeline.photo`), sRGB <->
linear (:mod:`pipeline.colour_space`), optional gentle denoising of the input
(:mod:`pipeline.denoise`), the generated default scene (:mod:`pipeline.scene`), sensor noise
(:mod:`pipeline.noise`), the windowed spatially-variant blur with its exact per-pixel reference
(:mod:`pipeline.blur`), the restoration methods and their registry (:mod:`pipeline.restoration`),
PSNR/SSIM in sRGB (:mod:`pipeline.quality`), PSNR over the field (:mod:`pipeline.field_map`), the
simulation of crops and whole frames (:mod:`pipeline.simulate`). The optics come in as PSF providers (:class:`lenssim.LensPSF`).
Dependencies flow one way: ``pipeline`` uses :mod:`lenssim`, never the reverse, and never the
command line (:mod:`lenssim_cli`).
"""

from .blur import (PAPER_SCHEME, WindowScheme, apply_windowed, blur_exact, blur_windowed, core_irfft2, tent_weights,
                   window_centres, window_count)
from .colour_space import linear_to_srgb, srgb_to_linear
from .denoise import gentle_denoise
from .field_map import field_psnr, plot_field_psnr
from .io import ImageFileError, ImageInfo, read_image, write_image
from .noise import NoiseModel, add_poisson_noise, expose
from .photo import load_photo
from .quality import psnr_map_srgb, psnr_srgb, ssim_srgb
from .restoration import (RESTORATION_METHODS, Restoration, RestorationMethod, parse_restoration, restore,
                          richardson_lucy_windowed, validate_method, wiener_windowed)
from .restoration.tikhonov import tikhonov_windowed
from .scene import resolution_scene
from .simulate import (DEFAULT_METHODS, CropResult, FrameResult, crop_at_field_angle, crops_from_frame, simulate_crops,
                       simulate_frame)

__all__ = [
    "DEFAULT_METHODS",
    "PAPER_SCHEME",
    "RESTORATION_METHODS",
    "CropResult",
    "FrameResult",
    "ImageFileError",
    "ImageInfo",
    "Restoration",
    "RestorationMethod",
    "WindowScheme",
    "NoiseModel",
    "add_poisson_noise",
    "expose",
    "apply_windowed",
    "blur_exact",
    "blur_windowed",
    "core_irfft2",
    "crop_at_field_angle",
    "crops_from_frame",
    "field_psnr",
    "gentle_denoise",
    "linear_to_srgb",
    "load_photo",
    "plot_field_psnr",
    "psnr_map_srgb",
    "psnr_srgb",
    "read_image",
    "parse_restoration",
    "resolution_scene",
    "restore",
    "richardson_lucy_windowed",
    "simulate_crops",
    "simulate_frame",
    "srgb_to_linear",
    "ssim_srgb",
    "tent_weights",
    "tikhonov_windowed",
    "validate_method",
    "window_centres",
    "window_count",
    "wiener_windowed",
    "write_image",
]
