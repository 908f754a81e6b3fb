"""RAW in: a camera's RAW file (DNG, NEF, CR2/CR3, ARW, RAF, ...) read by LibRaw (rawpy) as a linear camera-RGB image.

:func:`raw_info` reads what a file's header says (:class:`RawInfo`: output size in px, Bayer pattern, black and white
levels in digital numbers (DN), the as-shot white balance, the camera <- XYZ matrix: LibRaw's, or for a DNG, whose
matrix LibRaw gives as zeros, the file's own ColorMatrix1 or ColorMatrix2 tag, and which one). :func:`read_raw` checks the
output pixel count from the header against a limit *before* anything is decoded, then has LibRaw demosaic the file and
returns a float32 tensor ``(1, 3, H, W)`` in [0, 1], linear in light, in the camera's own RGB (no colour matrix), white
balanced with the camera's as-shot multipliers (a grey card comes back grey).

LibRaw's settings (:data:`POSTPROCESS_SETTINGS`, LibRaw 0.22 through rawpy 0.28) and what they give (measured, tested):

- demosaicing: AHD (adaptive homogeneity-directed; LibRaw's default, named explicitly). X-Trans sensors get LibRaw's
  own X-Trans interpolation whatever is asked.
- scaling: each channel is ``(DN - black) / (white - black) * 65535 * m / min(m)`` with ``m`` the as-shot white-balance
  multipliers (the smallest normalised to 1), truncated to a whole 16-bit value and clipped at 65535 (highlights
  clipped, LibRaw's mode 0): a flat DNG at 1000 DN with black 64 and white 4095 DN reads 15217 / 65535 in every
  channel ((1000 - 64) / 4031 = 0.232204; 15217.26 truncated), the white level reads exactly 1, the black level 0.
  Dividing by 65535 thus gives ``(DN - black) / (white - black)`` in the channel(s) whose multiplier is the smallest
  (green, for a daylight white balance), within 1 / 65535 below.
- LibRaw's ``adjust_maximum_thr`` is set to 0: by default (0.75) LibRaw takes the brightest pixel as the white level
  whenever it lies above 75 % of the real one, which re-scales a photo without any clipped pixel (measured: a scene
  at 1000 DN with a patch at 3500 DN read 0.272 instead of 0.232, the patch 1.0).
- gamma (1, 1), no automatic brightening, 16 bits out: the values are linear in the raw DN.
- no rotation (``user_flip=0``): the image is returned as the sensor lies, whatever orientation the camera recorded
  (the tensor's rows are sensor rows), so that it lines up with a sensor model's pixel grid.

LibRaw writes some decoding errors to the process's standard error (e.g. ``file.dng: Unexpected end of file``): while it
runs, file descriptor 2 is redirected to a temporary file; the text becomes part of the one-line error when decoding
fails, and is passed on to standard error unchanged when it does not. Every refusal is one line, an
:class:`pipeline.io.ImageFileError` (a ``ValueError``) naming the file as the caller gave it.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from .dng import D65_ILLUMINANT
from .io import ImageFileError

__all__ = ["RAW_EXTENSIONS", "RawInfo", "is_raw_path", "raw_info", "read_raw", "RAW_FULL_SCALE", "POSTPROCESS_SETTINGS"]

RAW_EXTENSIONS = frozenset({
    ".dng",  # Adobe Digital Negative
    ".nef", ".nrw",  # Nikon
    ".cr2", ".cr3", ".crw",  # Canon
    ".arw", ".srf", ".sr2",  # Sony
    ".raf",  # Fujifilm
    ".orf",  # Olympus / OM System
    ".rw2", ".raw", ".rwl",  # Panasonic, Leica (RAW also older Panasonic and others)
    ".pef", ".ptx",  # Pentax
    ".srw",  # Samsung
    ".x3f",  # Sigma
    ".3fr", ".fff",  # Hasselblad
    ".iiq",  # Phase One
    ".erf",  # Epson
    ".kdc", ".dcr",  # Kodak
    ".mrw",  # Minolta
    ".mos",  # Leaf
    ".mef",  # Mamiya
})
"""File name extensions (lower case, with the dot) of RAW formats that LibRaw reads."""

RAW_MAX_PIXELS = 200_000_000
"""The most pixels a RAW photo may decode to (the largest medium-format backs have 150 MP): 2.4 GB of 16-bit RGB and
2.4 GB as float32 at the limit."""
RAW_FULL_SCALE = 65535
"""The 16-bit value LibRaw gives the white level (after black subtraction and scaling): read values are divided by
it."""

POSTPROCESS_SETTINGS = {
    "gamma": (1, 1),  # linear: no tone curve
    "no_auto_bright": True,  # no histogram-based brightening
    "adjust_maximum_thr": 0.0,  # the file's white level, not the brightest pixel, is full scale
    "output_bps": 16,
    "use_camera_wb": True,  # the as-shot white balance
    "user_flip": 0,  # no rotation: rows and columns as on the sensor
}
"""LibRaw postprocessing settings of :func:`read_raw` (rawpy keywords; the colour space (camera RGB) and demosaicing
(AHD) are added where rawpy is imported)."""

PIXEL_ASPECT_TOLERANCE = 1e-5
"""A pixel aspect ratio this close to 1 counts as square (LibRaw's own test)."""
_BAYER_LETTERS = "BGGR"
"""The letters of a 2 x 2 Bayer tile, sorted."""


def is_raw_path(path: str | os.PathLike) -> bool:
    """Whether ``path``'s extension (any case) is one of :data:`RAW_EXTENSIONS`."""
    return Path(path).suffix.lower() in RAW_EXTENSIONS


@dataclass(frozen=True)
class RawInfo:
    """What a RAW file's header says, as LibRaw reads it. Per-channel values (tuples) are in LibRaw's colour order
    (R, G, B, second G for Bayer sensors)."""

    path: str  # as given
    width_px: int  # of the image read_raw returns (unrotated)
    height_px: int
    raw_pattern: str | None  # the 2 x 2 Bayer tile row by row from the top-left pixel ("RGGB"); None if not Bayer
    black_level_dn: tuple[int, ...]  # per channel, DN
    white_level_dn: int  # DN
    camera_white_balance: tuple[float, ...]  # as-shot multipliers (4, or 3 when LibRaw gives no fourth)
    rgb_xyz_matrix: tuple[tuple[float, float, float], ...] | None  # 3 x 3, camera <- XYZ; None if the file has none
    rgb_xyz_matrix_source: str | None = None  # where it came from: LibRaw, or a DNG's own tag and its illuminant
    rgb_xyz_matrix_note: str | None = None  # why a DNG's colour-matrix tags were not used (one line), if they were not

    @property
    def pixels(self) -> int:
        return self.width_px * self.height_px

    def to_dict(self) -> dict:
        """A JSON-serialisable summary (for metrics.json): lists for tuples, a non-finite number as ``None``."""

        def num(v):
            return v if isinstance(v, int) else (float(v) if math.isfinite(v) else None)

        return {
            "path": self.path, "width_px": self.width_px, "height_px": self.height_px, "raw_pattern": self.raw_pattern,
            "black_level_dn": [num(v) for v in self.black_level_dn], "white_level_dn": num(self.white_level_dn),
            "camera_white_balance": [num(v) for v in self.camera_white_balance],
            "rgb_xyz_matrix": None if self.rgb_xyz_matrix is None else [[num(v) for v in row] for row in self.rgb_xyz_matrix],
            "rgb_xyz_matrix_source": self.rgb_xyz_matrix_source, "rgb_xyz_matrix_note": self.rgb_xyz_matrix_note,
        }


@contextmanager
def _stderr_to(box: list):
    """Redirect file descriptor 2 (where LibRaw prints) to a temporary file; its text is appended to ``box`` on exit."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no standard error to redirect
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            box.append(tmp.read().decode("utf-8", errors="replace"))


def _libraw(fn, path, what: str, *args, **kwargs):
    """``fn(*args, **kwargs)`` (a LibRaw call) with its errors as one-line :class:`ImageFileError` naming ``path``."""
    import rawpy

    box: list[str] = []
    try:
        with _stderr_to(box):
            out = fn(*args, **kwargs)
    except (rawpy.LibRawError, OSError, MemoryError, UnicodeError) as exc:
        reason = exc.args[0] if exc.args else type(exc).__name__
        reason = reason.decode("utf-8", errors="replace") if isinstance(reason, bytes) else str(reason)
        said = [line.split(": ", 1)[-1].strip() for line in "".join(box).splitlines() if line.strip()]
        detail = "; ".join(dict.fromkeys([reason] + said))  # LibRaw's lines name the file by its full path: cut it
        raise ImageFileError(f"cannot read {what} {str(path)!r}: {detail}") from None
    text = "".join(box)
    if text:
        sys.stderr.write(text)
    return out


def _output_size(sizes) -> tuple[int, int]:
    """``(width, height)`` px of LibRaw's output image, unrotated, from the header's sizes (non-square pixels are
    stretched to square, as LibRaw does)."""
    w, h, aspect = int(sizes.width), int(sizes.height), float(sizes.pixel_aspect)
    if aspect < 1 - PIXEL_ASPECT_TOLERANCE:
        h = int(h / aspect + 0.5)
    elif aspect > 1 + PIXEL_ASPECT_TOLERANCE:
        w = int(w * aspect + 0.5)
    return w, h


def _check_max_pixels(max_pixels) -> int:
    if isinstance(max_pixels, bool) or not isinstance(max_pixels, (int, np.integer)) or max_pixels < 1:
        raise ValueError(f"max_pixels={max_pixels!r} is not allowed: a whole number of pixels >= 1")
    return int(max_pixels)


def _open(path, what: str, max_pixels: int | None):
    """An unpacked ``rawpy.RawPy`` of ``path`` and its :class:`RawInfo`; the output size is checked against
    ``max_pixels`` from the header before the raw data are unpacked. The caller closes it."""
    import rawpy

    from lenssim.io.files import InputFileError, check_input_file

    if max_pixels is not None:
        max_pixels = _check_max_pixels(max_pixels)
    try:
        p = check_input_file(path, what)
        empty = os.stat(p).st_size == 0
    except InputFileError as exc:
        raise ImageFileError(str(exc)) from None
    except OSError as exc:
        raise ImageFileError(f"cannot read {what} {str(path)!r}: {exc.strerror or exc}") from None
    if empty:
        raise ImageFileError(f"{what} {str(path)!r} is empty (0 bytes)")
    raw = rawpy.RawPy()
    try:
        name = os.fsdecode(p)
        try:
            name.encode("utf-8")  # rawpy passes the name to LibRaw as UTF-8
        except UnicodeEncodeError:
            with open(p, "rb") as fh:  # a name that is not UTF-8: LibRaw reads the file's bytes instead
                _libraw(raw.open_buffer, path, what, fh)
        else:
            _libraw(raw.open_file, path, what, name)
        width, height = _output_size(raw.sizes)
        if width < 1 or height < 1:
            raise ImageFileError(f"{what} {str(path)!r} has no pixels ({width} x {height})")
        if max_pixels is not None and width * height > max_pixels:
            raise ImageFileError(f"{what} {str(path)!r} has {width} x {height} = {width * height:,} pixels: more than "
                                 f"the limit of {max_pixels:,}")
        _libraw(raw.unpack, path, what)
        matrix = _matrix(raw.rgb_xyz_matrix)
        source, note = ("LibRaw", None) if matrix is not None else (None, None)
        if matrix is None and Path(p).suffix.lower() == ".dng":  # LibRaw gives a DNG's matrix as zeros: its own tags
            matrix, source, note = _dng_color_matrix(p)
        info = RawInfo(str(path), width, height, _pattern(raw), tuple(int(v) for v in raw.black_level_per_channel),
                       int(raw.white_level), _white_balance(raw.camera_whitebalance), matrix, source, note)
    except BaseException:
        raw.close()
        raise
    return raw, info


def _pattern(raw) -> str | None:
    """The 2 x 2 Bayer tile as letters row by row, e.g. ``"RGGB"``; None for any other filter layout."""
    tile = raw.raw_pattern
    desc = raw.color_desc.decode("ascii", errors="replace")
    if tile is None or tile.shape != (2, 2) or int(tile.max()) >= len(desc):
        return None
    letters = "".join(desc[int(i)] for i in tile.reshape(-1))
    return letters if "".join(sorted(letters)) == _BAYER_LETTERS else None


def _white_balance(values) -> tuple[float, ...]:
    wb = [float(v) for v in values]
    return tuple(wb[:3] if len(wb) == 4 and wb[3] == 0 else wb)


def _matrix(values) -> tuple[tuple[float, float, float], ...] | None:
    m = np.asarray(values, dtype=np.float64)[:3, :3]
    if m.shape != (3, 3) or not np.isfinite(m).all() or not m.any():
        return None
    return tuple(tuple(float(v) for v in row) for row in m)


DNG_COLOR_MATRICES = ((50721, "ColorMatrix1", 50778, "CalibrationIlluminant1"),
                      (50722, "ColorMatrix2", 50779, "CalibrationIlluminant2"))
"""A DNG's colour matrices (XYZ -> camera, SRATIONAL, row by row) and the tags of the illuminants they were calibrated
under (EXIF LightSource codes), as numbered in Adobe's DNG Specification 1.4.0.0, IFD 0."""
EXIF_LIGHT_SOURCES = {0: "unknown", 1: "daylight", 2: "fluorescent", 3: "tungsten", 4: "flash", 9: "fine weather",
                      10: "cloudy", 11: "shade", 12: "daylight fluorescent", 13: "day white fluorescent",
                      14: "cool white fluorescent", 15: "white fluorescent", 16: "warm white fluorescent",
                      17: "standard light A", 18: "standard light B", 19: "standard light C", 20: "D55", 21: "D65",
                      22: "D75", 23: "D50", 24: "ISO studio tungsten", 255: "other"}
"""The EXIF 2.3 LightSource codes (the DNG's CalibrationIlluminant values), for the recorded matrix's source."""
_SRATIONAL, _RATIONAL = 10, 5
"""TIFF type codes of a signed and an unsigned rational (two 32-bit integers: numerator, denominator)."""
_NOTE_CHARS = 200
"""The longest note of unusable colour-matrix tags kept (a reader's message is cut there: one line)."""


def _dng_color_matrix(path) -> tuple[tuple[tuple[float, float, float], ...] | None, str | None, str | None]:
    """A DNG's own colour matrix (XYZ -> camera, 3 x 3) from its IFD 0 tags (read by tifffile), its source (which tag,
    under which illuminant) and a one-line note of the tags that could not be used (None if none): of two usable
    matrices the one calibrated under D65 (:data:`pipeline.dng.D65_ILLUMINANT`), else ColorMatrix1. A tag with the
    wrong type or count (not 3 x 3: a 4-colour camera), a zero denominator or all zeros is not used and is named in
    the note, as is a DNG without either tag; a file whose tags cannot be read at all gives ``(None, None, note)``.
    Nothing is printed: tifffile's log is caught while it reads."""
    import logging

    import tifffile

    said: list[str] = []

    class _Keep(logging.Handler):
        def emit(self, record):
            said.append(record.getMessage())

    log = logging.getLogger("tifffile")
    keep, propagate = _Keep(), log.propagate
    log.addHandler(keep)
    log.propagate = False
    try:
        with open(path, "rb") as fh, tifffile.TiffFile(fh) as tif:
            tags = tif.pages.first.tags
            found = [(name, tags.get(code), ill_name, tags.get(ill)) for code, name, ill, ill_name in DNG_COLOR_MATRICES]
            found = [(name, None if t is None else (int(t.dtype), t.count, t.value), ill_name,
                      None if i is None else i.value) for name, t, ill_name, i in found]
    except Exception as exc:  # noqa: BLE001 - any reader failure: the matrix is optional, the note says why
        return None, None, _one_line(f"the DNG's colour-matrix tags could not be read ({type(exc).__name__}: {exc})")
    finally:
        log.removeHandler(keep)
        log.propagate = propagate
    notes = [f"a colour-matrix tag could not be read (tifffile: {m})" for m in said
             if any(str(code) in m for code, *_ in DNG_COLOR_MATRICES)]
    if not notes and all(tag is None for _, tag, _, _ in found):
        return None, None, "the DNG has no ColorMatrix1 or ColorMatrix2 tag"
    usable = []
    for name, tag, ill_name, ill in found:
        if tag is None:
            continue
        matrix, why = _rational_matrix(*tag)
        if matrix is None:
            notes.append(f"{name} {why}: not used")
            continue
        ill = ill if isinstance(ill, int) and not isinstance(ill, bool) else None
        light = "absent" if ill is None else f"{ill}, {EXIF_LIGHT_SOURCES.get(ill, 'not an EXIF light source')}"
        usable.append((matrix, f"DNG {name} ({ill_name} {light})", ill))
    if not usable:
        return None, None, _one_line("; ".join(notes))
    matrix, source, _ = next((u for u in usable if u[2] == D65_ILLUMINANT), usable[0]) if len(usable) > 1 else usable[0]
    return matrix, source, _one_line("; ".join(notes)) if notes else None


def _rational_matrix(dtype: int, count: int, value) -> tuple[tuple[tuple[float, float, float], ...] | None, str]:
    """A 3 x 3 matrix from a rational tag's ``(type, count, value)`` as tifffile gives it (flat numerator, denominator
    pairs), or None and why not."""
    if dtype not in (_SRATIONAL, _RATIONAL):
        return None, f"is of TIFF type {dtype}, not a rational"
    if count != 9:
        return None, f"has {count} values, not 9 (3 x 3: a 3-colour camera)"
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        return None, "has values that are not numbers"
    if v.size != 18:
        return None, f"has {v.size // 2} rationals, not 9"
    num, den = v[0::2], v[1::2]
    if not den.all():
        return None, "has a zero denominator"
    m = (num / den).reshape(3, 3)
    if not m.any():
        return None, "is all zeros"
    return tuple(tuple(float(x) for x in row) for row in m), ""


def _one_line(text: str) -> str:
    """``text`` on one line, at most :data:`_NOTE_CHARS` characters."""
    text = " ".join(text.split())
    return text if len(text) <= _NOTE_CHARS else text[:_NOTE_CHARS - 3] + "..."


def raw_info(path: str | os.PathLike, what: str = "RAW photo", *, max_pixels: int | None = None) -> RawInfo:
    """The :class:`RawInfo` of the RAW file ``path``, without demosaicing. The output size comes from the header alone
    and is checked against ``max_pixels`` (if given) first; the levels, pattern and white balance need LibRaw to
    unpack the raw data (rawpy 0.28 gives them only then: 2 bytes per sensor pixel, held while this runs).
    ``what`` names the file in errors."""
    raw, info = _open(path, what, max_pixels)
    raw.close()
    return info


def read_raw(path: str | os.PathLike, *, max_pixels: int, what: str = "RAW photo") -> tuple[torch.Tensor, RawInfo]:
    """The linear camera-RGB image of the RAW file ``path``, float32 ``(1, 3, H, W)`` in [0, 1] (see the module's
    notes on LibRaw's scaling), and its :class:`RawInfo`.

    The output's pixel count is read from the header and checked against ``max_pixels`` before anything is unpacked or
    demosaiced. A missing, empty, unreadable, truncated or unsupported file, or one whose image is all zero, is refused
    with a one-line :class:`pipeline.io.ImageFileError` naming ``path`` as given (``what`` says what it is).
    """
    import rawpy

    max_pixels = _check_max_pixels(max_pixels)
    raw, info = _open(path, what, max_pixels)
    try:
        rgb = _libraw(raw.postprocess, path, what, output_color=rawpy.ColorSpace.raw,
                      demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD, **POSTPROCESS_SETTINGS)
    finally:
        raw.close()
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = rgb[..., None]
    if rgb.ndim != 3 or rgb.shape[2] not in (1, 3) or min(rgb.shape) < 1:
        raise ImageFileError(f"cannot read {what} {str(path)!r}: LibRaw gave an image of shape {rgb.shape}, "
                             "expected rows x columns x 3")
    height, width = rgb.shape[:2]
    if width * height > max_pixels:  # a layout the header does not show (e.g. Fujifilm's rotated SuperCCD)
        raise ImageFileError(f"{what} {str(path)!r} decodes to {width} x {height} = {width * height:,} pixels: more "
                             f"than the limit of {max_pixels:,}")
    if (width, height) != (info.width_px, info.height_px):
        info = replace(info, width_px=width, height_px=height)
    out = np.empty((3, height, width), dtype=np.float32)
    out[...] = rgb.transpose(2, 0, 1)  # one channel (monochrome sensor): repeated as grey
    out /= RAW_FULL_SCALE
    if not np.isfinite(out).all():
        raise ImageFileError(f"{what} {str(path)!r} decodes to NaN or infinite values")
    if not out.any():
        raise ImageFileError(f"{what} {str(path)!r} is black (all pixels 0 after the black level is subtracted): there "
                             "is no light to simulate")
    return torch.from_numpy(out)[None], info
