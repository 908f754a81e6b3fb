"""The ideal (linear) image of a simulation: a file, a scikit-image sample, or the built-in scene.

:func:`open_photo` checks a file whole (every pixel, in bounded bands) before any work and gives a
:class:`Photo`: its shape and peak from that check, its pixels kept in memory when they fit
:data:`PHOTO_KEEP_BYTES`, else read region by region (a crop of a gigapixel panorama decodes only the
rows or tiles it needs). :func:`load_photo` gives the whole linear tensor, as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lenssim.torch_utils import HOST

from .colour_space import srgb_to_linear
from .io import ImageFileError, ImageInfo, read_image, scan_image

__all__ = ["Photo", "open_photo", "load_photo", "photo_info", "scene_name", "PHOTO_KEEP_BYTES"]

PHOTO_KEEP_BYTES = 2**30
"""A photo whose linear float32 pixels take at most this many bytes is decoded once and kept in memory (a 24 MP RGB
photo takes 0.29 GB); a larger one is read region by region as the crops need it."""


def scene_name(camera) -> str:
    """The description of the generated default scene for ``camera``."""
    return f"generated resolution scene {camera.sensor.width_px}x{camera.sensor.height_px}"


@dataclass
class Photo:
    """A linear photo ``(1, C, H, W)`` (float32), its pixels in memory (``tensor``) or read on demand from ``path``.

    ``peak`` is its largest linear value (it sets the photon count of the noise). :meth:`region` returns the rows
    ``r0:r1`` and columns ``c0:c1``; :meth:`load` the whole frame.
    """

    source: str
    shape: tuple[int, int, int, int]
    peak: float
    tensor: torch.Tensor | None = None
    path: str | None = None
    linear: bool = True
    device: torch.device | str = "cpu"
    metadata: dict | None = None
    """What the file says beyond its pixels (a RAW photo's pattern, levels, white balance: ``{"raw": ...}``)."""

    @classmethod
    def of(cls, image: torch.Tensor, source: str) -> "Photo":
        """A photo held in memory (a linear ``(1, C, H, W)`` tensor, checked as a scene)."""
        from .checks import check_scene

        check_scene(image, f"image {source!r}")
        return cls(source, tuple(image.shape), float(image.amax()), image, device=image.device)

    @property
    def dtype(self) -> torch.dtype:
        return torch.float32 if self.tensor is None else self.tensor.dtype

    @property
    def in_memory(self) -> bool:
        return self.tensor is not None

    def to(self, device) -> "Photo":
        """This photo on ``device`` (its pixels moved now if in memory, else when read)."""
        t = None if self.tensor is None else self.tensor.to(device)
        return Photo(self.source, self.shape, self.peak, t, self.path, self.linear, torch.device(device), self.metadata)

    def region(self, r0: int, r1: int, c0: int, c1: int) -> torch.Tensor:
        """Linear pixels of rows ``r0:r1`` and columns ``c0:c1`` (px), ``(1, C, r1 - r0, c1 - c0)``."""
        if self.tensor is not None:
            return self.tensor[..., r0:r1, c0:c1]
        return _read_linear(self.path, (r0, r1, c0, c1))[0].to(self.device)

    def load(self) -> torch.Tensor:
        """The whole linear frame (read now if it is not in memory)."""
        return self.tensor if self.tensor is not None else self.region(0, self.shape[2], 0, self.shape[3])

    def nbytes(self) -> int:
        """Bytes of the whole frame as float32."""
        return int(np.prod(self.shape)) * 4


def _sample(spec: str) -> torch.Tensor:
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
    return srgb_to_linear(t)


def _srgb_decoded(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values (float32, numpy) decoded to linear light by :func:`pipeline.colour_space.srgb_to_linear`."""
    return srgb_to_linear(torch.from_numpy(values)).numpy()


def _read_linear(path: str, region=None) -> tuple[torch.Tensor, ImageInfo]:
    """A photo file's pixels (``region`` as :func:`pipeline.io.read_image`'s) as linear light: a linear file's as read,
    an 8-bit one's codes decoded through their 256 decoded values as they are read, any other's decoded after."""
    img, info = read_image(path, region, what="photo", table=_srgb_decoded)
    return (img if info.linear or info.file_format == "uint8" else srgb_to_linear(img)), info


def photo_info(spec: str, what: str = "photo") -> ImageInfo:
    """The header of a photo file: :func:`pipeline.io.image_info`, or for a camera RAW file
    (:func:`pipeline.raw.is_raw_path`) LibRaw's: its demosaicked size, three linear channels (format ``"raw"``),
    the size checked against :data:`pipeline.raw.RAW_MAX_PIXELS`."""
    from .io import image_info
    from .raw import RAW_MAX_PIXELS, is_raw_path, raw_info

    if is_raw_path(spec):
        ri = raw_info(spec, what, max_pixels=RAW_MAX_PIXELS)
        return ImageInfo(str(spec), ri.width_px, ri.height_px, 3, "raw", True, 3)
    return image_info(spec, what)


def open_photo(spec: str | None, camera=None, *, keep_bytes: int = PHOTO_KEEP_BYTES, progress=None) -> Photo:
    """The :class:`Photo` of a file path (an image, or a camera RAW file read by LibRaw: :mod:`pipeline.raw`),
    ``skimage:NAME`` (an 8-bit sample image that scikit-image ships) or
    ``None``: the generated default scene, of ``camera``'s sensor size with its targets at field angles of
    ``camera``'s geometry (a :class:`lenssim.Camera`, needed then).

    A file is checked whole before this returns (its header, then every pixel in bounded bands: finite, within
    :data:`pipeline.io.MAX_LINEAR_VALUE`, >= 0 for linear files, not all black); it is kept in memory if its frame
    takes at most ``keep_bytes``, else read region by region later (``progress(rows)`` follows that check).
    """
    if spec is None:
        from .scene import resolution_scene

        if camera is None:
            raise ValueError("the generated default scene needs the camera (its sensor size and field geometry)")
        return Photo.of(resolution_scene(camera.sensor.height_px, camera.sensor.width_px, geometry=camera.geometry),
                        scene_name(camera))
    if spec.startswith("skimage:"):
        return Photo.of(_sample(spec), spec)
    from .raw import RAW_MAX_PIXELS, is_raw_path, read_raw

    if is_raw_path(spec):  # LibRaw: the linear camera RGB, as-shot white balance, demosaicked (AHD), in memory
        img, ri = read_raw(spec, max_pixels=RAW_MAX_PIXELS, what="photo")
        photo = Photo.of(img, spec)
        photo.metadata = {"raw": {**ri.to_dict(), "decoded_as": "linear camera RGB, as-shot white balance, LibRaw AHD "
                                  "demosaicing, (DN - black) / (white - black) in the lowest-gain channel"}}
        return photo
    info = None
    if keep_bytes > 0:
        from .io import image_info

        info = image_info(spec, "photo")
    if info is not None and int(np.prod(info.shape)) * 4 <= keep_bytes:
        img, info = _read_linear(spec)
        lo, hi = float(img.min()), float(img.max())
    else:
        img = None
        info, stats = scan_image(spec, what="photo", progress=progress)
        lo, hi = stats.minimum, stats.maximum
    if info.linear and lo < 0:
        raise ImageFileError(f"photo {spec!r} holds negative values (down to {lo:.3g}): a linear image of light "
                             "must be >= 0")
    if not hi > 0:
        raise ImageFileError(f"photo {spec!r} is black (all pixels 0): there is no light to simulate")
    if img is not None:
        return Photo.of(img, spec)
    peak = hi if info.linear else float(srgb_to_linear(torch.tensor([[[[hi]]]], dtype=torch.float32, device=HOST)))
    return Photo(spec, info.shape, peak, None, spec, info.linear)


def load_photo(spec: str | None, camera=None) -> tuple[torch.Tensor, str]:
    """Linear ``(1, C, H, W)`` float32 image and a description, from a file path, ``skimage:NAME`` or ``None`` (the
    generated default scene), as :func:`open_photo` opens them; the whole frame in memory."""
    photo = open_photo(spec, camera)
    return photo.load(), photo.source
