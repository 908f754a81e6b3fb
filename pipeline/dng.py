"""A simulated sensor mosaic written as a DNG that raw converters read (issue 31, RAW out).

:func:`write_dng` writes a 16-bit Bayer mosaic as a single-page, uncompressed DNG 1.4 with tifffile: the CFA
photometric interpretation (32803), the pattern (``CFARepeatPatternDim`` 2 x 2, ``CFAPattern`` row by row with
0 = R, 1 = G, 2 = B), the black and white levels, the as-shot neutral (white balance) and a colour matrix
(``ColorMatrix1``, XYZ -> camera, D65 by default). The tags and their numbers are those of Adobe's DNG
Specification 1.4.0.0 (2012); LibRaw (rawpy) reads such a file back with the same digital numbers, pattern, levels
and white balance (tested). The file is written atomically; an existing file is never overwritten.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np
import torch

from lenssim.torch_utils import tensor_of

from .cfa import validate_cfa

__all__ = ["write_dng", "DNG_VERSION", "D65_ILLUMINANT"]

DNG_VERSION = (1, 4, 0, 0)
"""DNGVersion and DNGBackwardVersion written."""
D65_ILLUMINANT = 21
"""CalibrationIlluminant1 of D65 (EXIF LightSource code)."""
_CFA_CODE = {"R": 0, "G": 1, "B": 2}


def _rationals(values, signed: bool) -> list[int]:
    out = []
    for v in values:
        f = Fraction(float(v)).limit_denominator(1_000_000)
        if not signed and f < 0:
            raise ValueError(f"{float(v)!r} is negative: an unsigned rational is needed")
        out += [f.numerator, f.denominator]
    return out


def write_dng(path: str | os.PathLike, raw: torch.Tensor, pattern: str, *, black_level: int, white_level: int,
              as_shot_neutral=(1.0, 1.0, 1.0), color_matrix=((1, 0, 0), (0, 1, 0), (0, 0, 1)),
              camera_model: str = "lenssim simulated sensor") -> Path:
    """Write the mosaic ``raw`` (``(H, W)`` or ``(1, 1, H, W)``, whole digital numbers 0..65535 after the black
    level is added, DN) under ``pattern`` to ``path`` (``.dng``): ``black_level`` and ``white_level`` (DN),
    ``as_shot_neutral`` (the camera's response to white, per R, G, B: its reciprocal is the white balance),
    ``color_matrix`` (3 x 3, XYZ (D65) -> camera). Returns the path."""
    import tifffile

    from lenssim.io.files import atomic_write, check_output_file

    p = validate_cfa(pattern)
    path = Path(path)
    if path.suffix.lower() != ".dng":
        raise ValueError(f"DNG file {str(path)!r} is not allowed: a name ending .dng")
    check_output_file(path, "DNG file")
    if path.exists():
        raise FileExistsError(f"{str(path)!r} exists; choose another DNG file or remove it")
    a = tensor_of(raw)
    if a.ndim == 4 and a.shape[:2] == (1, 1):
        a = a[0, 0]
    if a.ndim != 2:
        raise ValueError(f"raw mosaic of shape {tuple(raw.shape)}: expected (H, W) or (1, 1, H, W)")
    v = a.detach().cpu().to(torch.float64).numpy()
    if not (np.isfinite(v).all() and (v == np.round(v)).all() and v.min() >= 0 and v.max() <= 65535):
        raise ValueError("raw mosaic: expected whole digital numbers from 0 to 65535")
    if not (0 <= black_level < white_level <= 65535):
        raise ValueError(f"black level {black_level} and white level {white_level} are not allowed: "
                         "0 <= black < white <= 65535 DN")
    neutral = [float(x) for x in as_shot_neutral]
    matrix = np.asarray(color_matrix, dtype=np.float64)
    if len(neutral) != 3 or not all(x > 0 and np.isfinite(x) for x in neutral) or matrix.shape != (3, 3) \
            or not np.isfinite(matrix).all():
        raise ValueError("as_shot_neutral: three finite values > 0; color_matrix: a finite 3 x 3 matrix")
    tags = [
        (50706, "B", 4, DNG_VERSION, True),  # DNGVersion
        (50707, "B", 4, DNG_VERSION, True),  # DNGBackwardVersion
        (50708, "s", 0, camera_model, True),  # UniqueCameraModel
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, tuple(_CFA_CODE[c] for c in p), True),  # CFAPattern
        (50714, "I", 1, (int(black_level),), True),  # BlackLevel
        (50717, "I", 1, (int(white_level),), True),  # WhiteLevel
        (50721, "2i", 9, _rationals(matrix.reshape(-1), True), True),  # ColorMatrix1 (SRATIONAL)
        (50778, "H", 1, (D65_ILLUMINANT,), True),  # CalibrationIlluminant1
        (50728, "2I", 3, _rationals(neutral, False), True),  # AsShotNeutral (RATIONAL)
    ]
    data = v.astype(np.uint16)

    def write(tmp):
        tifffile.imwrite(tmp, data, photometric=32803, compression=None, extratags=tags, metadata=None,
                         subfiletype=0)
    atomic_write(path, write)
    return path
