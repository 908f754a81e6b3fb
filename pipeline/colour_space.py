"""Gamma-encoded sRGB <-> linear light with colour-science (IEC 61966-2-1 piecewise curves).

colour-science computes in float64 by default (11.6 s on a 24 MP image here); we scope its
default float dtype to float32 for the duration of a call (1.5 s) and restore it afterwards, so
the global setting of the caller is untouched. Tensors ``(B, C, H, W)`` in, same shape, dtype and
device out.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch

__all__ = ["srgb_to_linear", "linear_to_srgb"]


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


def srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    """Decode gamma-encoded sRGB values in [0, 1] to linear light (``colour.cctf_decoding``, sRGB)."""
    import colour

    return _apply(x, lambda a: colour.cctf_decoding(a, function="sRGB"))


def linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    """Encode linear light to gamma-encoded sRGB (``colour.cctf_encoding``, sRGB)."""
    import colour

    return _apply(x, lambda a: colour.cctf_encoding(a, function="sRGB"))
