"""Checks of the images and settings the pipeline takes, at its public boundary (before any work)."""

from __future__ import annotations


from lenssim import PSFProvider, check_shape
from lenssim.validate import FULL_WELL_RANGE_E, check_finite, check_real

__all__ = ["check_image", "check_scene", "check_provider", "check_full_well", "check_boxes"]


def check_image(image, name: str = "image", *, nonnegative: bool = False) -> dict:
    """A floating ``(B, C, H, W)`` tensor of finite values (and >= 0 if asked); returns the sizes by name."""
    sizes = check_shape(image, "B C H W", name)
    if image.is_complex():
        raise ValueError(f"{name} is complex: expected a real linear image")
    if min(sizes["H"], sizes["W"], sizes["B"], sizes["C"]) < 1:
        raise ValueError(f"{name} has shape {tuple(image.shape)}: expected at least one pixel")
    check_finite(name, image, "pixel values")
    if nonnegative and bool((image < 0).any()):
        raise ValueError(f"{name} has negative values (min {float(image.min()):.3g}): a linear image of light must "
                         "be >= 0")
    return sizes


def check_scene(image, name: str = "ideal") -> dict:
    """A linear scene: ``(1, C, H, W)``, finite, >= 0 and not all black (its maximum sets the photon count)."""
    sizes = check_image(image, name, nonnegative=True)
    if sizes["B"] != 1:
        raise ValueError(f"{name} has shape {tuple(image.shape)}: expected one image (1, C, H, W)")
    if not float(image.amax()) > 0:
        raise ValueError(f"{name} is black (all pixels 0): there is no light to simulate")
    return sizes


def check_provider(psf, name: str = "psf"):
    """``psf`` if it is a PSF provider; ``ValueError`` otherwise."""
    if not isinstance(psf, PSFProvider):
        raise ValueError(f"{name} is a {type(psf).__name__}: expected a PSF provider (lenssim.LensPSF, lenssim.FunctionPSF)")
    return psf


def check_full_well(value, name: str = "full_well") -> float:
    """A full-well capacity in electrons within :data:`lenssim.validate.FULL_WELL_RANGE_E`."""
    lo, hi = FULL_WELL_RANGE_E
    return check_real(name, value, lo, hi, unit="electrons")


def check_boxes(boxes, shape) -> list[tuple[int, int, int, int]]:
    """Boxes ``(r0, r1, c0, c1)`` inside a frame of ``shape`` ``(..., H, W)``, each at least one pixel."""
    H, W = shape[-2:]
    out = []
    for b in boxes:
        try:
            r0, r1, c0, c1 = (int(v) for v in b)
        except (TypeError, ValueError):
            raise ValueError(f"box {b!r} is not allowed: (r0, r1, c0, c1) in pixels") from None
        if not (0 <= r0 < r1 <= H and 0 <= c0 < c1 <= W):
            raise ValueError(f"box {b!r} is not allowed: it must lie inside the {H} x {W} frame with r0 < r1, c0 < c1")
        out.append((r0, r1, c0, c1))
    if not out:
        raise ValueError("no boxes given: at least one (r0, r1, c0, c1)")
    return out
