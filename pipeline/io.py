"""Image files through OpenImageIO: ``(1, C, H, W)`` float32 tensors, atomic writes, clear errors.

Reading: JPEG, PNG, 8/16-bit TIFF, float/half EXR and whatever else OpenImageIO reads; grey (C = 1)
and RGB (C = 3) are kept, an alpha channel (grey+alpha, RGBA) is dropped with a warning. Integer
files are scaled to [0, 1]; float files (EXR, float TIFF) are returned as stored and flagged
``linear=True`` (scene-linear, not gamma-encoded). Reading is bounded: :func:`image_info` reads the
header alone, :func:`read_image` with a ``region`` decodes only the rows (scanline files) or tiles
(tiled files) it needs, and :func:`scan_image` checks every pixel of a file of any size in bands of
at most :data:`READ_BAND_BYTES`.

Writing: 8- or 16-bit integer (clipped to [0, 1]) or float (EXR); the file is written under a
temporary name in the destination folder and renamed, so a crash never leaves a half-written
file, and a path that is one of the inputs is refused.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lenssim.io.files import atomic_write
from lenssim.torch_utils import HOST

from .colour_space import EIGHT_BIT_CODES

__all__ = ["exit_without_teardown", "ImageFileError", "ImageInfo", "ImageStats", "image_info", "read_image", "scan_image",
           "write_image", "READ_BAND_BYTES", "MAX_LINEAR_VALUE"]


class ImageFileError(ValueError):
    """An image file that cannot be read or written as asked."""


READ_BAND_BYTES = 64 * 2**20
"""Working buffer (bytes, float32) of one band of rows while a file is read or scanned: reading never holds more
than this beyond what it returns."""

MAX_LINEAR_VALUE = 65504.0
"""Largest pixel value a linear (float) image may hold: the largest half float, the range of half-float EXRs, where
HDR photographs are stored with 1 as diffuse white. The pipeline's scores encode [0, 1] in sRGB, so a file in
absolute units (cd/m^2) would score as white everywhere: such a file is refused, to be scaled first."""


@dataclass(frozen=True)
class ImageInfo:
    """What a file's header says: its path (as given), size (px), channels (after dropping alpha), pixel format
    and whether its values are scene-linear (float data) or gamma-encoded (integer data)."""

    path: str
    width: int
    height: int
    channels: int  # after dropping alpha
    file_format: str  # OpenImageIO's pixel format, e.g. uint8, uint16, half, float
    linear: bool  # float data: scene-linear; integer data: gamma-encoded (sRGB)
    file_channels: int = 0  # channels in the file (alpha included)
    tile_height: int = 0  # rows per tile (0: a scanline file)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """``(1, C, H, W)`` of the tensor :func:`read_image` returns."""
        return (1, self.channels, self.height, self.width)

    @property
    def pixels(self) -> int:
        return self.width * self.height

    def row_bytes(self) -> int:
        """Bytes (float32) of one full row as the reader decodes it (alpha included)."""
        return self.width * max(self.file_channels, self.channels) * 4


@dataclass(frozen=True)
class ImageStats:
    """Range of a file's pixel values (as read: integer files scaled to [0, 1]) over every channel kept."""

    minimum: float
    maximum: float


def _open(path, what: str):
    """``(ImageInput, spec)`` of ``path`` (checked as a readable regular file first); the caller closes it."""
    import OpenImageIO as oiio

    from lenssim.io.files import InputFileError, check_input_file

    try:
        check_input_file(path, what)
    except InputFileError as exc:
        raise ImageFileError(str(exc)) from None
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageFileError(f"cannot read {what} {str(path)!r}: {oiio.geterror() or 'unsupported or corrupt file'}")
    return inp, inp.spec()


def _info(path, spec, what: str) -> ImageInfo:
    c = int(spec.nchannels)
    if c not in (1, 2, 3, 4):
        raise ImageFileError(f"{what} {str(path)!r} has {c} channels: only grey, grey+alpha, RGB and RGBA are "
                             "supported")
    if spec.width < 1 or spec.height < 1:
        raise ImageFileError(f"{what} {str(path)!r} has no pixels ({spec.width} x {spec.height})")
    fmt = str(spec.format)
    return ImageInfo(str(path), int(spec.width), int(spec.height), c - 1 if c in (2, 4) else c, fmt,
                     fmt in ("half", "float", "double"), c, int(spec.tile_height) if spec.tile_width else 0)


_INFO_CACHE: dict = {}
"""Headers read in this process, by path, device and inode, size and modification time (:func:`image_info`)."""
INFO_CACHE_FILES = 64
"""Most headers :func:`image_info` keeps (a command reads its inputs' headers a few times each)."""


def image_info(path: str | os.PathLike, what: str = "image") -> ImageInfo:
    """The :class:`ImageInfo` of ``path`` from its header alone (no pixel is decoded): size, channels, format.
    ``what`` names the file in errors (e.g. ``"photo"``). A camera RAW file: :func:`pipeline.photo.photo_info`.

    Kept for the process while the file's device and inode, size and modification time stay the same: OpenImageIO's JPEG reader
    takes 0.2-0.4 s to open a 24 MP file, and a command asks for its photo's header three times (measured on 2 cores).
    """
    try:
        st = os.stat(path)
        key = (str(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        key = None  # _open names what is wrong
    if key in _INFO_CACHE:
        return _INFO_CACHE[key]
    inp, spec = _open(path, what)
    try:
        info = _info(path, spec, what)
    finally:
        inp.close()
    if key is not None:
        if len(_INFO_CACHE) >= INFO_CACHE_FILES:
            _INFO_CACHE.pop(next(iter(_INFO_CACHE)))
        _INFO_CACHE[key] = info
    return info


def _read_rows(inp, spec, info: ImageInfo, r0: int, r1: int, c0: int, c1: int, what: str,
               fmt: str = "float") -> np.ndarray:
    """Rows ``r0:r1``, columns ``c0:c1`` (data-window coordinates) as ``(h, w, C)`` (alpha dropped): float32 values, or
    with ``fmt="uint8"`` an 8-bit file's codes; scanline files decode whole rows, tiled files the tiles that cover the
    region."""
    ch = info.channels
    if info.tile_height:
        tw, th = int(spec.tile_width), int(spec.tile_height)
        y0, x0 = (r0 // th) * th, (c0 // tw) * tw
        y1, x1 = min(-(-r1 // th) * th, info.height), min(-(-c1 // tw) * tw, info.width)
        data = inp.read_tiles(0, 0, spec.x + x0, spec.x + x1, spec.y + y0, spec.y + y1, spec.z, spec.z + 1, 0, ch,
                              format=fmt)
        cut = (slice(r0 - y0, r1 - y0), slice(c0 - x0, c1 - x0))
    else:
        data = inp.read_scanlines(0, 0, spec.y + r0, spec.y + r1, spec.z, 0, ch, format=fmt)
        cut = (slice(None), slice(c0, c1))
    err = inp.geterror()
    if data is None or err:
        raise ImageFileError(f"cannot read {what} {info.path!r}: {err or 'truncated or corrupt pixel data'}")
    arr = np.asarray(data, dtype=np.uint8 if fmt == "uint8" else np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    return arr[cut[0], cut[1]]


def _band_rows(info: ImageInfo) -> int:
    """Rows per band so that a band's buffer stays within :data:`READ_BAND_BYTES` (whole tiles for tiled files)."""
    rows = max(1, READ_BAND_BYTES // info.row_bytes())
    if info.tile_height:
        rows = max(info.tile_height, rows // info.tile_height * info.tile_height)
    return rows


def _check_values(arr: np.ndarray, info: ImageInfo, r0: int, c0: int, what: str) -> None:
    """Every value finite and (float files) within :data:`MAX_LINEAR_VALUE`; the first bad pixel named by its
    row and column in the file."""
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c, _ = np.argwhere(bad)[0]
        raise ImageFileError(f"{what} {info.path!r} holds a NaN or infinite value at row {r0 + r}, column {c0 + c}: "
                             "pixel values must be finite numbers")
    if info.linear and arr.size:
        top = float(np.abs(arr).max())
        if top > MAX_LINEAR_VALUE:
            r, c, _ = np.argwhere(np.abs(arr) == top)[0]
            raise ImageFileError(f"{what} {info.path!r} holds the value {float(arr[r, c].max()):.4g} at row {r0 + r}, "
                                 f"column {c0 + c}: linear values up to {MAX_LINEAR_VALUE:g} are allowed (1 = white); "
                                 "scale the image")


def code_values() -> np.ndarray:
    """The float32 value ``(256,)`` OpenImageIO reads each 8-bit code ``0..255`` as (its own conversion, which is not
    ``k / 255`` to the last bit for every code)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(oiio.ImageSpec(EIGHT_BIT_CODES + 1, 1, 1, "uint8"))
    buf.set_pixels(oiio.ROI(0, EIGHT_BIT_CODES + 1, 0, 1, 0, 1, 0, 1),
                   np.arange(EIGHT_BIT_CODES + 1, dtype=np.uint8).reshape(1, -1, 1))
    return np.asarray(buf.get_pixels("float"), dtype=np.float32).reshape(-1)


def read_image(path: str | os.PathLike, region=None, *, what: str = "image",
               table=None) -> tuple[torch.Tensor, ImageInfo]:
    """Read ``path`` into a float32 tensor ``(1, C, H, W)`` (C = 1 or 3) and its :class:`ImageInfo`.

    ``region`` ``(r0, r1, c0, c1)`` (px, inside the frame) reads only those rows and columns: a scanline file
    (PNG, JPEG) decodes the rows up to ``r1``, a band of at most :data:`READ_BAND_BYTES` at a time, a tiled one
    (TIFF, EXR) only the tiles over the region; without it the whole frame is read. Every value read is checked:
    finite, and for float files at most :data:`MAX_LINEAR_VALUE`. ``what`` names the file in errors.

    ``table``: a function of float32 values (numpy, elementwise) that a file of 8-bit samples (``info.file_format ==
    "uint8"``) is read through: applied once to the 256 values its codes read as (:func:`code_values`) and looked up
    per pixel as the codes are decoded, band by band. The same values as the function of the float image, with no
    float frame of the file's own values (the forest's 24 MP JPEG decoded to linear light in 0.5 s against 2.2 s
    through the float image, measured on 2 cores). Other formats are returned as read (the caller applies it).
    """
    inp, spec = _open(path, what)
    try:
        info = _info(path, spec, what)
        H, W = info.height, info.width
        r0, r1, c0, c1 = (0, H, 0, W) if region is None else (int(v) for v in region)
        if not (0 <= r0 < r1 <= H and 0 <= c0 < c1 <= W):
            raise ImageFileError(f"region {tuple(region)!r} is not inside {what} {info.path!r} ({W} x {H} px)")
        out = np.empty((info.channels, r1 - r0, c1 - c0), dtype=np.float32)
        step = _band_rows(info)
        lookup = None
        if table is not None and info.file_format == "uint8":
            lookup = np.asarray(table(code_values()), dtype=np.float32)
            if lookup.shape != (EIGHT_BIT_CODES + 1,):
                raise ValueError(f"table gave {lookup.shape} values for the 256 codes: expected one per code")
        for y in range(r0, r1, step):
            y1 = min(y + step, r1)
            if lookup is not None:  # codes are finite: only the lookup
                band = _read_rows(inp, spec, info, y, y1, c0, c1, what, fmt="uint8")
                np.take(lookup, band.transpose(2, 0, 1), out=out[:, y - r0:y1 - r0], mode="clip")
                continue
            band = _read_rows(inp, spec, info, y, y1, c0, c1, what)
            _check_values(band, info, y, c0, what)
            out[:, y - r0:y1 - r0] = band.transpose(2, 0, 1)
    finally:
        inp.close()
    if info.file_channels in (2, 4):
        warnings.warn(f"{Path(path).name}: alpha channel dropped ({info.file_channels} channels -> {info.channels})",
                      stacklevel=2)
    return torch.from_numpy(out)[None], info


def scan_image(path: str | os.PathLike, *, what: str = "image", progress=None) -> tuple[ImageInfo, ImageStats]:
    """Check every pixel of ``path`` (as :func:`read_image` does) in bands of at most :data:`READ_BAND_BYTES`, and
    return its :class:`ImageInfo` and value range: bounded memory for a file of any size, so that every input of a
    run is checked before its first computation. ``progress(rows)`` is called after each band."""
    inp, spec = _open(path, what)
    lo, hi = math.inf, -math.inf
    try:
        info = _info(path, spec, what)
        step = _band_rows(info)
        for y in range(0, info.height, step):
            y1 = min(y + step, info.height)
            band = _read_rows(inp, spec, info, y, y1, 0, info.width, what)
            _check_values(band, info, y, 0, what)
            lo, hi = min(lo, float(band.min())), max(hi, float(band.max()))
            if progress is not None:
                progress(y1 - y)
    finally:
        inp.close()
    if info.file_channels in (2, 4):
        warnings.warn(f"{Path(path).name}: alpha channel dropped ({info.file_channels} channels -> {info.channels})",
                      stacklevel=2)
    return info, ImageStats(lo, hi)


PNG_COMPRESSION_LEVEL = 3
"""zlib level of the PNGs written (0-9; OpenImageIO's default is 6). Measured on a 24 MP 8-bit frame here:
level 6 took 3.8 s for 17.8 MB, level 3 1.8 s for 19.4 MB, level 1 1.4 s for 20.8 MB."""


WRITE_BAND_ROWS = 256
"""Rows per band that :func:`write_image` converts and hands to OpenImageIO (its host copy stays a band's size)."""


def write_image(path: str | os.PathLike, image: torch.Tensor, *, bits: int | str = 8, inputs=(),
                exr_compression: str | None = None) -> Path:
    """Write a ``(1, C, H, W)`` or ``(C, H, W)`` tensor. ``bits`` is 8, 16 or ``"float"`` (use .exr).
    ``exr_compression``: an EXR's compression by OpenImageIO's name (``"none"``, ``"zip"``, ...; default OpenImageIO's,
    zip); other formats ignore it."""
    import OpenImageIO as oiio

    p = Path(path)
    for q in inputs:
        if Path(q).exists() and p.exists() and p.resolve() == Path(q).resolve():
            raise ImageFileError(f"refusing to write {str(p)!r}: it is one of the inputs")
    if image.ndim == 4:
        if image.shape[0] != 1:
            raise ImageFileError(f"image batch of {image.shape[0]}: write one image (B = 1) at a time")
        image = image[0]
    if image.ndim != 3 or image.shape[0] not in (1, 3):
        raise ImageFileError(f"image tensor of shape {tuple(image.shape)}: expected (1, C, H, W) or (C, H, W), C = 1 or 3")
    fmts = {8: "uint8", 16: "uint16", "float": "float"}
    if bits not in fmts:
        raise ImageFileError(f"bits={bits!r} is not allowed: 8, 16 or 'float'")
    image = image.detach()
    C, H, W = image.shape

    def writer(tmp: str) -> None:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise ImageFileError(f"cannot write {str(p)!r}: {oiio.geterror() or 'unknown file extension'}")
        spec = oiio.ImageSpec(W, H, C, fmts[bits])
        spec.attribute("png:compressionLevel", PNG_COMPRESSION_LEVEL)  # other formats ignore it
        if exr_compression is not None and p.suffix.lower() == ".exr":  # TIFF reads the same attribute
            spec.attribute("compression", exr_compression)
        ok = out.open(tmp, spec)
        # in bands of rows: a band's (rows, W, C) float32 host copy at a time, not the frame's
        for r0 in range(0, H, WRITE_BAND_ROWS):
            if not ok:
                break
            r1 = min(H, r0 + WRITE_BAND_ROWS)
            band = torch.empty((r1 - r0, W, C), dtype=torch.float32, device=HOST)
            band.copy_(image[:, r0:r1].permute(1, 2, 0))
            if bits != "float":
                band.clamp_(0.0, 1.0)
            ok = out.write_scanlines(r0, r1, 0, band.numpy())
        msg = out.geterror()
        out.close()
        if not ok:
            raise ImageFileError(f"cannot write {str(p)!r}: {msg}")

    return atomic_write(p, writer)


def exit_without_teardown(rc: int = 0) -> None:
    """End a script or console command: flush the standard streams and leave without the interpreter's teardown.

    colour-science imports OpenImageIO, and with torch also loaded the teardown runs in an order where
    OpenImageIO's nanobind bindings report their module-level objects as "leaked" (a page of messages after
    every run that touched images, exit status unchanged). Call it only when every output is complete and
    closed (the project's writes are atomic), as the last statement of a script.
    """
    import os
    import sys

    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(int(rc or 0))
