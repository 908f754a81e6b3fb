"""Sensor files: a :class:`lenssim.Sensor` from a TOML file's ``[sensor]`` table, or a shipped preset by name.

The presets are ``configs/sensors/NAME.toml`` (``paper``: the paper's photon-noise-only sensor, the default; real
sensors with each value's source in the file and in ``configs/sensors/SOURCES.md``). The keys are the fields of
:class:`lenssim.Sensor`, units in their names (``read_noise_e``, ``dark_current_e_per_s``, ``black_level_dn``, ...);
an unknown key, a wrong type or a value out of range is refused in one line naming the file and the key.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..model.sensor import Sensor
from ..validate import listed
from .resources import _root

__all__ = ["sensor_names", "sensor_path", "load_sensor", "DEFAULT_SENSOR"]

DEFAULT_SENSOR = "paper"
"""The preset a camera command uses when no ``--sensor`` is given."""
_KEYS = tuple(f.name for f in dataclasses.fields(Sensor))


def sensors_dir() -> Path:
    return _root() / "sensors"


def sensor_names() -> list[str]:
    """The shipped sensor presets' names."""
    return sorted(p.stem for p in sensors_dir().glob("*.toml"))


def sensor_path(spec: str) -> Path:
    """The file of ``spec``: a path ending in ``.toml``, else a shipped preset's name."""
    from .files import check_input_file

    s = str(spec)
    if s.endswith(".toml") or "/" in s or "\\" in s:
        return check_input_file(Path(s), "sensor file")
    if s not in sensor_names():
        raise ValueError(f"sensor {s!r} is not a shipped preset; presets: {', '.join(sensor_names())} (or give a "
                         "FILE.toml with a [sensor] table)")
    return sensors_dir() / f"{s}.toml"


def load_sensor(spec: str) -> Sensor:
    """The sensor of ``spec`` (a preset name or a TOML file), checked; ``ValueError`` in one line naming the file and
    the key otherwise."""
    from .files import read_toml

    path = sensor_path(spec)
    data = read_toml(spec if path == Path(str(spec)) else path, "sensor file")
    table = data.get("sensor")
    if not isinstance(table, dict) or set(data) - {"sensor"}:
        raise ValueError(f"sensor file {str(spec)!r} must hold one [sensor] table (found: "
                         f"{listed(sorted(data)) if data else 'nothing'})")
    bad = sorted(set(table) - set(_KEYS))
    if bad:
        raise ValueError(f"sensor file {str(spec)!r}: unknown key(s) {listed(bad)}; allowed: {listed(_KEYS, near=bad)}")
    for k in ("pixel_pitch_um", "width_px", "height_px"):
        if k not in table:
            raise ValueError(f"sensor file {str(spec)!r}: {k} is missing")
    kw = dict(table)
    if "full_well_e" in kw:
        fw = kw["full_well_e"]
        if not isinstance(fw, list) or not all(isinstance(p, list) and len(p) == 2 for p in fw):
            raise ValueError(f"sensor file {str(spec)!r}: full_well_e={fw!r} is not allowed: [[ISO, electrons], ...]")
        kw["full_well_e"] = tuple(tuple(p) for p in fw)
    for k in ("quantum_efficiency",):
        if k in kw:
            kw[k] = tuple(kw[k]) if isinstance(kw[k], list) else kw[k]
    if "colour_matrix" in kw and isinstance(kw["colour_matrix"], list):
        kw["colour_matrix"] = tuple(tuple(r) if isinstance(r, list) else r for r in kw["colour_matrix"])
    try:
        return Sensor(**kw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"sensor file {str(spec)!r}: {exc}") from None
