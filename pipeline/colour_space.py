"""Gamma-encoded sRGB <-> linear light with colour-science (IEC 61966-2-1 piecewise curves).

colour-science computes in float64 by default (11.6 s on a 24 MP image here); we scope its
default float dtype to float32 for the duration of a call (1.5 s) and restore it afterwards, so
the global setting of the caller is untouched. Tensors ``(B, C, H, W)`` in, same shape, dtype and
device out.

An 8-bit photo holds at most 256 values, one per code (about ``k / 255``: the reader's own float32 conversion):
:func:`srgb_to_linear` decodes those through a table of them decoded by colour-science (the same function on the same
float32 values: the same bits, tested), and an image holding more values through colour-science itself. The
process's first decoding of the 24 MP forest JPEG took 3.9 s through colour-science (its float32 arithmetic on 72
million values in frame-sized temporaries, each mapped afresh) against 1.6 s through the table (warm, 0.4-0.5 s either
way).
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch

__all__ = ["srgb_to_linear", "linear_to_srgb", "EIGHT_BIT_CODES"]

EIGHT_BIT_CODES = 255
"""The largest code of an 8-bit image: its values in [0, 1] are ``k / EIGHT_BIT_CODES``."""

_TABLE_LEAST_VALUES = 1 << 16
"""Images of fewer values are decoded by colour-science directly (looking for the codes costs more than it saves)."""

_TABLE_BAND_VALUES = 1 << 22
"""Values looked up at a time (the table path's working memory: a few tens of MB beyond its output)."""


@contextlib.contextmanager
def _float32_colour():
    import colour.constants as cc
    import colour.utilities as cu

    old = cc.DTYPE_FLOAT_DEFAULT
    cu.set_default_float_dtype(np.float32)
    try:
        yield
    finally:
        cu.set_default_float_dtype(old)


def _apply(x: torch.Tensor, fn) -> torch.Tensor:
    if not isinstance(x, torch.Tensor) or not x.is_floating_point():
        raise TypeError(f"expected a floating tensor, got {type(x).__name__}")
    arr = x.detach().to("cpu", torch.float32).numpy()
    with _float32_colour():
        out = np.asarray(fn(arr), dtype=np.float32)
    return torch.from_numpy(out).to(device=x.device, dtype=x.dtype)


def _decode(a: np.ndarray) -> np.ndarray:
    import colour

    return colour.cctf_decoding(a, function="sRGB")


def _decoded_by_table(x: torch.Tensor) -> torch.Tensor | None:
    """``x`` (float32) decoded through a table of its 256 values if it holds at most one value per 8-bit code (each
    value's nearest ``k / 255``), as an 8-bit image converted to float does, else None. Band by band: the first pass
    finds each code's value, the second checks every value against its code's and looks it up."""
    flat = x.reshape(-1)
    values = torch.zeros(EIGHT_BIT_CODES + 1, dtype=flat.dtype, device=flat.device)

    def codes(band):  # each value's nearest code (NaN: 0, where the check below fails)
        return torch.nan_to_num(band * EIGHT_BIT_CODES, nan=0.0).round_().clamp_(0, EIGHT_BIT_CODES).to(torch.int64)

    for i in range(0, flat.numel(), _TABLE_BAND_VALUES):
        band = flat[i:i + _TABLE_BAND_VALUES]
        values[codes(band)] = band  # one of each code's values (all of them equal, checked below)
    table = _apply(values, _decode)
    out = torch.empty_like(flat)
    for i in range(0, flat.numel(), _TABLE_BAND_VALUES):
        band = flat[i:i + _TABLE_BAND_VALUES]
        k = codes(band)
        if not torch.equal(values[k], band):
            return None
        torch.index_select(table, 0, k, out=out[i:i + _TABLE_BAND_VALUES])
    return out.view_as(x)


def srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    """Decode gamma-encoded sRGB values in [0, 1] to linear light (``colour.cctf_decoding``, sRGB); the values of an
    8-bit image (at most one per code ``k / 255``) through a table of them decoded by the same function."""
    if isinstance(x, torch.Tensor) and x.dtype == torch.float32 and x.numel() >= _TABLE_LEAST_VALUES:
        out = _decoded_by_table(x)
        if out is not None:
            return out
    return _apply(x, _decode)


def linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    """Encode linear light to gamma-encoded sRGB (``colour.cctf_encoding``, sRGB)."""
    import colour

    return _apply(x, lambda a: colour.cctf_encoding(a, function="sRGB"))
