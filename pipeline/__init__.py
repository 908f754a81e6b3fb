"""pipeline: the camera pipeline (photo -> linear -> spatially-variant blur -> noise -> restoration).

Implemented so far: image I/O (:mod:`pipeline.io`), sRGB <-> linear (:mod:`pipeline.colour_space`),
Poisson noise at the paper's full-well capacities (:mod:`pipeline.noise`), the windowed
spatially-variant blur with its exact per-pixel reference (:mod:`pipeline.blur`), adaptive local
Wiener restoration (:mod:`pipeline.restoration`) and PSNR/SSIM in sRGB (:mod:`pipeline.quality`).
Still to come: the generated default scene, the ``simulate`` / ``psnr-table`` commands, a
non-linear comparison restorer and the 24 MP benchmark.
Dependencies flow one way: ``pipeline`` uses :mod:`lenssim`, never the reverse.
"""

from .blur import PAPER_SCHEME, apply_windowed, WindowScheme, blur_exact, blur_windowed, tent_weights, window_centres
from .colour_space import linear_to_srgb, srgb_to_linear
from .io import ImageFileError, ImageInfo, read_image, write_image
from .noise import ISO_FULL_WELL, add_poisson_noise, full_well_for_iso
from .quality import psnr_srgb, ssim_srgb
from .restoration import wiener_windowed

__all__ = [
    "ISO_FULL_WELL",
    "PAPER_SCHEME",
    "ImageFileError",
    "ImageInfo",
    "WindowScheme",
    "add_poisson_noise",
    "apply_windowed",
    "blur_exact",
    "blur_windowed",
    "full_well_for_iso",
    "linear_to_srgb",
    "psnr_srgb",
    "read_image",
    "srgb_to_linear",
    "ssim_srgb",
    "tent_weights",
    "window_centres",
    "wiener_windowed",
    "write_image",
]
