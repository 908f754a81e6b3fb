"""Loading the ideal (linear) image of a simulation: a file, a scikit-image sample, or the built-in scene."""

from __future__ import annotations

import numpy as np
import torch

from .colour_space import srgb_to_linear
from .io import read_image

__all__ = ["load_photo", "scene_name"]


def scene_name(camera) -> str:
    """The description of the generated default scene for ``camera``."""
    return f"generated resolution scene {camera.sensor.width_px}x{camera.sensor.height_px}"


def load_photo(spec: str | None, camera=None) -> tuple[torch.Tensor, str]:
    """Linear ``(1, C, H, W)`` float32 image and a description, from a file path, ``skimage:NAME`` (an 8-bit
    sample image that scikit-image ships) or ``None``: the generated default scene, of ``camera``'s sensor size
    with its targets at field angles of ``camera``'s geometry (a :class:`lenssim.Camera`, needed then)."""
    if spec is None:
        from .scene import resolution_scene

        if camera is None:
            raise ValueError("the generated default scene needs the camera (its sensor size and field geometry)")
        return (resolution_scene(camera.sensor.height_px, camera.sensor.width_px, geometry=camera.geometry),
                scene_name(camera))
    if spec.startswith("skimage:"):
        import skimage.data

        name = spec.split(":", 1)[1]
        fn = getattr(skimage.data, name, None)
        if fn is None or not callable(fn) or name.startswith("_"):
            raise ValueError(f"{spec!r}: scikit-image ships no image called {name!r}")
        arr = np.asarray(fn())
        if arr.dtype != np.uint8:
            raise ValueError(f"{spec!r}: only 8-bit scikit-image images are supported")
        t = torch.from_numpy(arr.astype(np.float32) / 255)
        t = t[None, None] if t.ndim == 2 else t.permute(2, 0, 1)[None, :3]
        return srgb_to_linear(t), spec
    img, info = read_image(spec)
    return (img if info.linear else srgb_to_linear(img)), spec
