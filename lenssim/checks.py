"""One helper for tensor contracts at the public boundary (as kornia's ``KORNIA_CHECK_SHAPE``).

``check_shape(x, "B C H W", "image")`` checks that ``x`` is a tensor with one axis per named
dimension, and returns the sizes by name. ``*`` stands for any number of leading axes; a number
fixes an axis's size (``"* 4"``); a name used twice must have equal sizes.
"""

from __future__ import annotations

import torch

__all__ = ["check_shape"]


def check_shape(x, dims: str, name: str = "tensor", *, floating: bool = True) -> dict[str, int]:
    """Check ``x`` against the named dimensions ``dims`` and return ``{name: size}``; raise ``ValueError``."""
    spec = dims.split()
    expected = f"a {'floating ' if floating else ''}tensor of shape ({', '.join(spec)})"
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} is a {type(x).__name__}: expected {expected}")
    shape = tuple(x.shape)
    star = spec[:1] == ["*"]
    fixed = spec[1:] if star else spec
    if (len(shape) < len(fixed)) if star else (len(shape) != len(fixed)):
        raise ValueError(f"{name} has shape {shape}: expected {expected}")
    if floating and not x.is_floating_point() and not x.is_complex():
        raise ValueError(f"{name} has dtype {x.dtype}: expected {expected}")
    sizes: dict[str, int] = {}
    for d, n in zip(fixed, shape[len(shape) - len(fixed):]):
        if d.isdigit():
            if n != int(d):
                raise ValueError(f"{name} has shape {shape}: expected {expected}")
        elif sizes.setdefault(d, n) != n:
            raise ValueError(f"{name} has shape {shape}: dimension {d} differs between axes; expected {expected}")
    return sizes
