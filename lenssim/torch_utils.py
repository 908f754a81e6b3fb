"""Small torch helpers shared by every layer: tensor conversion and device selection."""

from __future__ import annotations

import torch

__all__ = ["as_tensor", "tensor_of", "select_device", "DEVICE_CHOICES", "GPU_MEMORY_FRACTION", "chunk_budget_bytes", "HOST",
           "abs_square", "centred_variance", "broadcast_shape"]

HOST = torch.device("cpu")
"""Where the library makes a tensor that no input places: tables it caches or reads on the host (moved to the inputs'
device where they meet them), numbers given as Python numbers, and what the CPU-only real-ray tracer computes. Named so
that no tensor follows torch's default device (``torch.set_default_device``): every other tensor follows its inputs
(tests/test_device_follow.py runs the public API under another default device to check it)."""

DEVICE_CHOICES = "auto (CUDA if present, else CPU), cpu, cuda or cuda:N"


def as_tensor(x, *, like: torch.Tensor | None = None, dtype=None, device=None) -> torch.Tensor:
    """Convert ``x`` to a floating tensor, following ``like`` (dtype, device) when given; numbers (not a tensor) go to
    ``device`` or :data:`HOST`, never torch's default device."""
    if like is not None:
        dtype = dtype or like.dtype
        device = device or like.device
    if isinstance(x, torch.Tensor):
        if not x.is_floating_point():
            x = x.to(torch.get_default_dtype())
        return x.to(dtype=dtype or x.dtype, device=device or x.device)
    return torch.as_tensor(x, dtype=dtype or torch.get_default_dtype(), device=device or HOST)


def tensor_of(x, dtype=None) -> torch.Tensor:
    """``torch.as_tensor(x, dtype)`` where ``x`` stays on its device if it is a tensor and numbers and lists go to
    :data:`HOST`: never to torch's default device (which ``torch.as_tensor`` would move even a tensor to)."""
    return torch.as_tensor(x, dtype=dtype, device=x.device if isinstance(x, torch.Tensor) else HOST)


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


GPU_MEMORY_FRACTION = 0.25
"""Share of a GPU's free memory one batch of work may hold (its temporaries come on top)."""


def chunk_budget_bytes(device, cpu_bytes: int) -> int:
    """Working memory (bytes) of one batch of work on ``device``: ``cpu_bytes`` on a CPU (sized to its caches, so
    the batch's data stays warm), and on a GPU :data:`GPU_MEMORY_FRACTION` of its free memory (at least
    ``cpu_bytes``), so a batch fills the device. The one rule of the metrics' and the image windows' chunks."""
    device = torch.device(device)
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        return int(max(cpu_bytes, GPU_MEMORY_FRACTION * free))
    return int(cpu_bytes)


def abs_square(z: torch.Tensor) -> torch.Tensor:
    """``|z|^2`` of a complex tensor as ``z.real^2 + z.imag^2``, the same bits as that expression, built in one real
    buffer: the squared modulus of every field, OTF and spectrum (``abs()`` rounds through a square root; the
    expression's third temporary cost 1.1 ms against 0.6 ms for a batch of four 448 px windows' OTFs in three
    channels, measured on 2 cores). Differentiable (the sum is formed in place on the first square, which autograd
    does not keep)."""
    p = z.real.square()
    return p.add_(z.imag.square())


def centred_variance(x: torch.Tensor, mean: torch.Tensor, dim) -> torch.Tensor:
    """The population variance of ``x`` over ``dim`` about its ``mean`` (keepdim, as ``mean`` was taken): the mean
    square of ``x - mean``, two passes. Equal to ``x.var(dim, correction=0)`` to float rounding (1.1e-7 relative in
    float32 against float64, Welford's 4e-8) and 17x faster on the 128 px centres of a batch of windows on a CPU
    (0.03 against 0.56 ms for 4 windows in three channels, measured on 2 cores: ``var``'s Welford update does not
    vectorise there)."""
    return (x - mean).square_().mean(dim=dim, keepdim=True)


def broadcast_shape(*shapes) -> torch.Size:
    """The shape that ``shapes`` broadcast to, as ``torch.broadcast_shapes`` (a ``RuntimeError`` where they do not),
    computed by numpy: torch's own imports ``torch.fx``'s symbolic shapes and sympy on its first call, 0.3 s of every
    command's start-up (measured on 2 cores)."""
    import numpy as np

    try:
        return torch.Size(np.broadcast_shapes(*(tuple(int(n) for n in s) for s in shapes)))
    except ValueError as exc:
        raise RuntimeError(f"shapes {[tuple(s) for s in shapes]} do not broadcast together") from exc
