"""Named lens designs (``configs/designs.toml`` and the paper's built-ins)."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Design", "load_designs", "BUILTIN_DESIGNS"]


@dataclass(frozen=True)
class Design:
    """A design ``(s, Q)``: shape factor and conic constant of the posterior surface."""

    name: str
    s: float
    Q: float
    description: str = ""


BUILTIN_DESIGNS = {
    "rms_w_paper": Design("rms_w_paper", -0.725, -10.0, "paper's RMS_W optimum (Fig. 8, conventional design)"),
    "end_to_end_paper": Design("end_to_end_paper", -0.775, -2.4, "paper's end-to-end MSE_R design at 27.6 dB (Fig. 8)"),
}


def load_designs(path: str | Path | None = None) -> dict[str, Design]:
    """Built-in designs, updated from a TOML file of ``[name] s = .. Q = .. description = ..`` tables."""
    designs = dict(BUILTIN_DESIGNS)
    if path is None:
        return designs
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"designs file {str(path)!r} does not exist") from None
    for name, t in raw.items():
        if not isinstance(t, dict) or "s" not in t or "Q" not in t:
            raise ValueError(f"designs file {str(path)!r}: [{name}] needs numeric keys s and Q")
        designs[name] = Design(name, float(t["s"]), float(t["Q"]), str(t.get("description", "")))
    return designs


