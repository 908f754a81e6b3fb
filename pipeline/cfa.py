"""A Bayer colour filter array: sampling a linear RGB image to a one-plane mosaic, and demosaicing it back (issue 31,
the camera chain's ``mosaic`` and ``demosaic`` stages).

A pattern (:data:`CFA_PATTERNS`) names the filters of the 2 x 2 tile row by row, from the image's top-left pixel
(``RGGB``: red at (0, 0), green at (0, 1) and (1, 0), blue at (1, 1)), as DNG's ``CFAPattern`` and LibRaw do.
:func:`mosaic` keeps at each pixel the channel its filter passes (``(B, 3, H, W) -> (B, 1, H, W)``);
:func:`demosaic` estimates the other two at every pixel with a method of :data:`DEMOSAIC_METHODS`, a table from name
to the colour-demosaicing implementation (bilinear; Malvar, He and Cutler, ICASSP 2004; Menon, Andriani and
Calvagno, IEEE TIP 16(1), 2007), validated with a message listing the names. Both take and give linear ``(B, C, H,
W)`` tensors (the demosaic on the CPU in float64, as colour-demosaicing computes; the result in the input's dtype and
device).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from lenssim.registry import Registry

from .checks import check_image

__all__ = ["CFA_PATTERNS", "DEMOSAIC_METHODS", "DemosaicMethod", "validate_cfa", "cfa_masks", "mosaic", "demosaic"]

DEMOSAIC_BORDER_PX = 4
"""The mosaic is mirrored this far (px, even: the Bayer tile's phase kept) beyond its borders before demosaicing (the
methods' filters reach 2 px)."""
CFA_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
"""The Bayer patterns, their 2 x 2 tile read row by row from the top-left pixel."""
_CHANNEL = {"R": 0, "G": 1, "B": 2}


@dataclass(frozen=True)
class DemosaicMethod:
    """``fn(cfa (H, W) float64 numpy, pattern) -> (H, W, 3)``, its label and reference."""

    name: str
    fn: Callable
    label: str
    reference: str


def _colour_demosaicing(name: str) -> Callable:
    def run(cfa, pattern):
        import warnings

        with warnings.catch_warnings():  # colour-demosaicing 0.2.7 reaches convolve through a namespace SciPy deprecates
            warnings.filterwarnings("ignore", message=".*scipy.ndimage.filters.*", category=DeprecationWarning)
            import colour_demosaicing

            return getattr(colour_demosaicing, f"demosaicing_CFA_Bayer_{name}")(cfa, pattern)
    return run


DEMOSAIC_METHODS = Registry("demosaicing method")
"""Demosaicing methods by name (:class:`DemosaicMethod`)."""
for _name, _label, _ref in (
        ("bilinear", "bilinear interpolation", "each missing sample the mean of its nearest same-colour neighbours"),
        ("Malvar2004", "Malvar-He-Cutler", "H. S. Malvar, L.-W. He, R. Cutler, ICASSP 2004, vol. 3, pp. 485-488"),
        ("Menon2007", "Menon-Andriani-Calvagno (DDFAPD)",
         "D. Menon, S. Andriani, G. Calvagno, IEEE Trans. Image Process. 16(1), 132-141 (2007)")):
    DEMOSAIC_METHODS.register(DemosaicMethod(_name, _colour_demosaicing(_name), _label, _ref))


def validate_cfa(pattern: str) -> str:
    """``pattern`` if it is one of :data:`CFA_PATTERNS` (case-insensitive, returned upper-case); a one-line
    ``ValueError`` listing them otherwise."""
    p = str(pattern).upper()
    if p not in CFA_PATTERNS:
        raise ValueError(f"CFA pattern {pattern!r} is not allowed: one of {', '.join(CFA_PATTERNS)}")
    return p


def cfa_masks(pattern: str, height: int, width: int, *, device=None) -> torch.Tensor:
    """``(3, H, W)`` boolean: where each of R, G, B is sampled under ``pattern``; every pixel in exactly one."""
    p = validate_cfa(pattern)
    masks = torch.zeros(3, height, width, dtype=torch.bool, device=device)
    for k, f in enumerate(p):
        masks[_CHANNEL[f], k // 2::2, k % 2::2] = True
    return masks


def mosaic(image: torch.Tensor, pattern: str) -> torch.Tensor:
    """The raw mosaic ``(B, 1, H, W)`` of a linear RGB image ``(B, 3, H, W)`` under ``pattern``."""
    sizes = check_image(image, "image")
    if sizes["C"] != 3:
        raise ValueError(f"image has {sizes['C']} channels: a colour filter array samples an RGB image (3)")
    m = cfa_masks(pattern, sizes["H"], sizes["W"], device=image.device).to(image.dtype)
    return (image * m).sum(dim=1, keepdim=True)


def demosaic(raw: torch.Tensor, pattern: str, method: str = "Malvar2004") -> torch.Tensor:
    """A linear RGB image ``(B, 3, H, W)`` from the mosaic ``raw`` ``(B, 1, H, W)`` under ``pattern``, by ``method``
    (:data:`DEMOSAIC_METHODS`)."""
    p = validate_cfa(pattern)
    m = DEMOSAIC_METHODS.validate(method)
    sizes = check_image(raw, "raw mosaic")
    if sizes["C"] != 1:
        raise ValueError(f"raw mosaic has {sizes['C']} channels: expected one plane (B, 1, H, W)")
    if sizes["H"] <= DEMOSAIC_BORDER_PX or sizes["W"] <= DEMOSAIC_BORDER_PX:
        raise ValueError(f"raw mosaic of {sizes['H']} x {sizes['W']} px: demosaicing needs more than "
                         f"{DEMOSAIC_BORDER_PX} x {DEMOSAIC_BORDER_PX}")
    import numpy as np

    e = DEMOSAIC_BORDER_PX
    out = []
    for r in raw:
        # mirrored beyond the borders by an even width (the tile's phase kept): colour-demosaicing's filters read zeros
        # there, which darkens a grey scene's outer pixels (bilinear: by half)
        cfa = np.pad(r[0].detach().to("cpu", torch.float64).numpy(), e, mode="reflect")
        out.append(torch.from_numpy(np.ascontiguousarray(m.fn(cfa, p)[e:-e, e:-e])).permute(2, 0, 1))
    return torch.stack(out).to(dtype=raw.dtype, device=raw.device)
