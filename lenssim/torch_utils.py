"""Small torch helpers shared by every layer: tensor conversion and device selection."""

from __future__ import annotations

import torch

__all__ = ["as_tensor", "select_device", "DEVICE_CHOICES"]

DEVICE_CHOICES = "auto (CUDA if present, else CPU), cpu, cuda or cuda:N"


def as_tensor(x, *, like: torch.Tensor | None = None, dtype=None, device=None) -> torch.Tensor:
    """Convert ``x`` to a floating tensor, following ``like`` (dtype, device) when given."""
    if like is not None:
        dtype = dtype or like.dtype
        device = device or like.device
    if isinstance(x, torch.Tensor):
        if not x.is_floating_point():
            x = x.to(torch.get_default_dtype())
        return x.to(dtype=dtype or x.dtype, device=device or x.device)
    return torch.as_tensor(x, dtype=dtype or torch.get_default_dtype(), device=device)


def select_device(name: str = "auto") -> torch.device:
    """``auto`` picks CUDA when available, else CPU; ``cpu``/``cuda``/``cuda:N`` are taken as given."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError):
        raise ValueError(f"device={name!r} is not allowed: {DEVICE_CHOICES}") from None
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device={name!r} is not allowed: {DEVICE_CHOICES}")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device={name!r} is not available: no CUDA device; use 'cpu' or 'auto'")
    return dev
