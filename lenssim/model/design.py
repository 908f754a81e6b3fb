"""The design: the lens's free parameters, by name, as tensors; and the named designs.

A :class:`Design` maps parameter names to tensors that broadcast together (one design, or a
batch or grid of designs). Every optics function takes a design, so a new free parameter is a new
entry in :data:`PARAMETERS` plus the code that uses it (see docs/architecture.md); sweeps, optima,
the trade-off, the autograd optimiser and the command line take their dimension names from here.

The paper's two parameters are ``s`` (shape factor) and ``Q_back`` (conic constant of the back
surface; alias ``Q``); beyond the paper, ``Q_front`` (conic of the front surface) and
``focus_shift_um`` (image-plane position). A parameter not given takes its default (a spherical
surface, the paraxial focus), so the paper's designs are unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from ..torch_utils import HOST, broadcast_shape
from ..validate import listed, quoted

__all__ = ["Parameter", "PARAMETERS", "parameter_name", "Design", "load_designs"]


@dataclass(frozen=True)
class Parameter:
    """A free design parameter: name, meaning, unit, default, aliases and a typical step (its grid step)."""

    name: str
    description: str
    unit: str = "1"
    default: float = 0.0
    aliases: tuple[str, ...] = ()
    step: float = 1.0
    lens_name: str = ""
    """The same number as a free parameter of the singlet's prescription (:meth:`lenssim.model.lens.Lens.prescription`,
    :mod:`lenssim.model.lens_parameters`): one lens, two names; accepted as an alias."""


PARAMETERS: dict[str, Parameter] = {p.name: p for p in (
    Parameter("s", "shape factor (c1 + c2) / (c1 - c2)", step=0.025, lens_name="E1.bending"),
    Parameter("Q_back", "conic constant of the back surface", aliases=("Q",), step=0.1, lens_name="S2.conic"),
    Parameter("Q_front", "conic constant of the front surface (an asphere only when given)", step=0.1,
              lens_name="S1.conic"),
    Parameter("focus_shift_um", "image plane behind the paraxial focus at the lens's reference wavelength",
              unit="um", step=5.0, lens_name="focus_um"),
)}
"""The registry of design parameters, in their canonical order."""


def parameter_name(name: str) -> str:
    """The canonical name of a parameter or alias; ``ValueError`` listing the valid names otherwise."""
    if name in PARAMETERS:
        return name
    for p in PARAMETERS.values():
        if name in p.aliases or name == p.lens_name:
            return p.name
    valid = ", ".join(f"{p.name}" + (f" (alias {', '.join(p.aliases + (p.lens_name,))})" if p.aliases or p.lens_name
                                     else "") for p in PARAMETERS.values())
    raise ValueError(f"design parameter {quoted(name)} is not known; valid: {valid}")


def _to_tensor(name: str, v, device) -> torch.Tensor:
    if isinstance(v, torch.Tensor):
        if v.is_complex():
            raise ValueError(f"design parameter {name} is complex: expected real values")
        return v if v.is_floating_point() else v.to(torch.float64)
    if isinstance(v, bool):
        raise ValueError(f"design parameter {name}={v!r} is not allowed: a number")
    try:
        return torch.as_tensor(v, dtype=torch.float64, device=device)  # numbers keep their full (double) precision
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"design parameter {name}={v!r} is not allowed: a number or a tensor of numbers") from None


class Design:
    """Named design parameters (tensors that broadcast together), with an optional name and description.

    ``Design(s=-0.775, Q_back=-2.4)``, ``Design({"s": s_grid, "Q": q_grid})`` (aliases accepted).
    ``design["Q"]`` and ``design["Q_back"]`` are the same tensor; a parameter that was not given
    reads as its default (a 0-d float64 tensor). Python numbers become float64 tensors, on the device of the tensors
    given beside them (the host if none is).
    """

    __slots__ = ("values", "name", "description")

    def __init__(self, values: Mapping | None = None, *, name: str = "", description: str = "", **kw):
        merged: dict[str, torch.Tensor] = {}
        given = list((values or {}).items()) + list(kw.items())
        device = next((v.device for _, v in given if isinstance(v, torch.Tensor)), HOST)
        for key, v in given:
            canon = parameter_name(key)
            if canon in merged:
                raise ValueError(f"design parameter {canon} is given twice (as {key!r} and another name)")
            merged[canon] = _to_tensor(canon, v, device)
        try:
            broadcast_shape(*(t.shape for t in merged.values()))
        except RuntimeError:
            shapes = {k: tuple(t.shape) for k, t in merged.items()}
            raise ValueError(f"design parameters do not broadcast together: {shapes}") from None
        self.values = {k: merged[k] for k in PARAMETERS if k in merged}
        self.name = name
        self.description = description

    # ---- access ---------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        """The parameters given (canonical names, registry order)."""
        return tuple(self.values)

    def __getitem__(self, name: str) -> torch.Tensor:
        canon = parameter_name(name)
        if canon in self.values:
            return self.values[canon]
        ref = next(iter(self.values.values()), None)
        return torch.tensor(PARAMETERS[canon].default, dtype=ref.dtype if ref is not None else torch.float64,
                            device=ref.device if ref is not None else HOST)

    def __contains__(self, name: str) -> bool:
        return parameter_name(name) in self.values

    @property
    def shape(self) -> torch.Size:
        return broadcast_shape(*(t.shape for t in self.values.values())) if self.values else torch.Size()

    # ---- transformations (each returns a new Design) ---------------------------------------
    def map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> "Design":
        return Design({k: fn(v) for k, v in self.values.items()}, name=self.name, description=self.description)

    def broadcast(self) -> "Design":
        """Every parameter expanded to the common :attr:`shape`."""
        shape = self.shape
        return self.map(lambda t: t.expand(shape))

    def to(self, dtype=None, device=None) -> "Design":
        return self.map(lambda t: t.to(dtype=dtype or t.dtype, device=device))

    def unsqueeze(self, dim: int) -> "Design":
        return self.map(lambda t: t.unsqueeze(dim))

    def flatten(self) -> "Design":
        return self.broadcast().map(lambda t: t.reshape(-1))

    def complete(self) -> "Design":
        """Every registered parameter, those not given at their defaults."""
        return Design({k: self[k] for k in PARAMETERS}, name=self.name, description=self.description)

    def replace(self, **kw) -> "Design":
        vals = dict(self.values)
        for k, v in kw.items():
            vals[parameter_name(k)] = v
        return Design(vals, name=self.name, description=self.description)

    # ---- scalars --------------------------------------------------------------------------
    def floats(self) -> dict[str, float]:
        """``{name: value}`` of a single design (every parameter a one-element tensor)."""
        out = {}
        for k, v in self.values.items():
            if v.numel() != 1:
                raise ValueError(f"design parameter {k} holds {v.numel()} values: expected a single design")
            out[k] = float(v.reshape(()))
        return out

    def label(self) -> str:
        """``"s = -0.775, Q_back = -2.4"`` for a single design."""
        return ", ".join(f"{k} = {v:g}" for k, v in self.floats().items())

    def __repr__(self) -> str:
        try:
            body = ", ".join(f"{k}={v:g}" for k, v in self.floats().items())
        except ValueError:
            body = ", ".join(f"{k}: shape {tuple(v.shape)}" for k, v in self.values.items())
        return f"Design({body}{', name=' + repr(self.name) if self.name else ''})"


def load_designs(path: str | Path | None = None, builtins: Mapping[str, Design] | None = None) -> dict[str, Design]:
    """Named designs: ``builtins`` (default: those of the built-in ``configs/designs.toml``; the paper's scenario
    adds its two, :func:`lenssim_studies.paper.paper_designs`),
    updated from a TOML file of tables ``[name]`` with parameter values (``s = -0.775``,
    ``Q_back = -2.4``; aliases accepted) and an optional ``description``."""
    if builtins is None:
        from ..io.resources import designs_file

        builtins = load_designs(designs_file(), {})
    designs = dict(builtins)
    if path is None:
        return designs
    from ..io.files import read_toml

    path = Path(path)
    raw = read_toml(path, "designs file")
    for name, t in raw.items():
        if not isinstance(t, dict):
            raise ValueError(f"designs file {str(path)!r}: [{quoted(name)}] must be a table of parameter values")
        t = dict(t)
        desc = str(t.pop("description", ""))
        bad = [k for k, v in t.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)]
        if bad or not t:
            raise ValueError(f"designs file {str(path)!r}: [{quoted(name)}] needs finite numeric parameter values "
                             f"(e.g. s and Q_back){'; bad: ' + listed(bad) if bad else ''}")
        try:
            designs[name] = Design(t, name=name, description=desc)
        except ValueError as exc:
            raise ValueError(f"designs file {str(path)!r}: [{quoted(name)}]: {exc}") from None
    return designs
