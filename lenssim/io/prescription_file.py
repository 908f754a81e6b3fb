"""Lens prescriptions in a TOML file a person can read and write, and one entry point for every lens source.

The file is :meth:`lenssim.model.prescription.Prescription.to_dict` written as TOML; surfaces numbered from 1 in
file order (the object is surface 0, the image plane lies ``thickness_mm`` of the last surface behind it)::

    name = "Cooke triplet"
    source = "W. J. Smith, Modern Optical Engineering, 4th ed. (2008), ch. 6"
    notes = "free text"
    stop_surface = 5                       # the aperture stop's surface number

    [aperture]
    entrance_pupil_diameter_mm = 29.2
    stop_size = "paraxial"                 # optional: or "real" (lenssim.model.prescription.STOP_SIZES)

    [object]
    distance_mm = "inf"                    # or a distance > 0 (mm) before surface 1

    [fields]
    angles_deg = [0.0, 8.45, 11.86]        # object at infinity; heights_mm = [...] for a finite object

    [wavelengths]
    um = [0.4861327, 0.5875618, 0.6562725]
    primary_um = 0.5875618                 # may be left out when there is one wavelength

    [published]                            # optional: the figures printed in the source (efl_mm, bfl_mm, ...)
    efl_mm = 101.181

    [[surfaces]]                           # surface 1; one table per surface, in order
    radius_mm = 37.4                       # "inf" for a flat surface; or curvature_per_mm = ...
    thickness_mm = 5.9                     # to the next surface (the last surface's: the image distance)
    material = [1.61272, 58.63]            # "air", a catalogue glass name ("N-BK7") or a model glass [n_d, V_d]
    conic = 0.0                            # optional
    aspheric_coefficients = []             # optional: [A4, A6, ... A16] of r^4, r^6, ... (mm^-3, mm^-5, ...)
    semi_diameter_mm = 14.7                # optional: the clear semi-aperture
    comment = "L1 front"                   # optional
    kind = "standard"                      # optional: a surface kind (lenssim.model.surface_kinds); its own keys
                                           # beside these, e.g. kind = "qbfs" with normalization_radius_mm = 14.7
                                           # and aspheric_coefficients = [a0, a1, ...] (mm)

``f_number_given`` (top level) is the F-number a Zemax file gave its aperture as (kept in ``extra``). A key that is
not one of these is refused in one line naming it and the allowed ones. :func:`write_prescription_toml` writes a file
that reads back equal (to the last bit: a radius whose reciprocal does not give back the curvature exactly is written
as ``curvature_per_mm``). :func:`read_lens` reads a ``.zmx`` or ``.toml`` file, or a shipped lens by name.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..model.prescription import AIR, STOP_SIZES, Prescription, PrescriptionError, PrescriptionSurface
from ..model.surface_kinds import SURFACE_KINDS
from ..validate import listed, quoted
from .files import InputFileError, atomic_write_text, read_toml

__all__ = ["read_prescription_toml", "write_prescription_toml", "prescription_from_dict", "prescription_toml",
           "read_lens"]

_WHAT = "lens prescription file"

_TOP = ("name", "source", "notes", "stop_surface", "f_number_given", "aperture", "object", "fields", "wavelengths",
        "published", "surfaces")
_APERTURE = ("entrance_pupil_diameter_mm", "stop_size")
_OBJECT = ("distance_mm",)
_FIELDS = ("angles_deg", "heights_mm")
_WAVELENGTHS = ("um", "primary_um")
_SURFACE = ("radius_mm", "curvature_per_mm", "thickness_mm", "material", "conic", "aspheric_coefficients",
            "semi_diameter_mm", "comment", "kind")
_EXTRA = ("published", "f_number_given")
"""The keys of ``Prescription.extra`` this format holds."""


class _Bad(Exception):
    """A file error before the file name is added."""


def _keys(table, allowed: tuple[str, ...], where: str) -> dict:
    if not isinstance(table, dict):
        raise _Bad(f"{where or 'the file'} must be a table, not {_kind(table)}")
    for k in table:
        if k not in allowed:
            raise _Bad(f"{where + ': ' if where else ''}unknown key {quoted(k)}{'' if where else ' at the top level'}; "
                       f"allowed: {listed(allowed, near=[k])}")
    return table


def _kind(v) -> str:
    return {bool: "a boolean", str: "a string", list: "an array", dict: "a table"}.get(type(v), type(v).__name__)


def _number(v, where: str, *, allow_inf: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _Bad(f"{where} = {quoted(v)} is not a number")
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise _Bad(f"{where} = {quoted(v)} is not a finite number")
    return v


def _infinite(v) -> bool:
    return (isinstance(v, str) and v.strip().lower() in ("inf", "infinity", "+inf")) or (
        isinstance(v, float) and math.isinf(v) and v > 0)


def _numbers(v, where: str) -> list:
    if not isinstance(v, list):
        raise _Bad(f"{where} must be an array of numbers, not {_kind(v)}")
    return [_number(x, f"{where}[{i}]") for i, x in enumerate(v)]


def _string(v, where: str) -> str:
    if not isinstance(v, str):
        raise _Bad(f"{where} = {quoted(v)} is not a string")
    return v


def _surface(t, number: int) -> PrescriptionSurface:
    where = f"surface {number}"
    if not isinstance(t, dict):
        _keys(t, _SURFACE, where)  # not a table: refused
    kind = _string(t.get("kind", "standard"), f"{where}: kind")
    if kind not in SURFACE_KINDS:
        raise _Bad(f"{where}: kind {quoted(kind)} is not known; valid: {listed(SURFACE_KINDS, near=[kind])}")
    own = SURFACE_KINDS[kind].shape_parameters
    _keys(t, _SURFACE + own, where)
    if "radius_mm" in t and "curvature_per_mm" in t:
        raise _Bad(f"{where}: give radius_mm or curvature_per_mm, not both")
    if "radius_mm" in t:
        r = t["radius_mm"]
        if _infinite(r) or (isinstance(r, float) and math.isinf(r)):
            c = 0.0
        else:
            if isinstance(r, str):
                raise _Bad(f"{where}: radius_mm = {quoted(r)} is not allowed: a number or \"inf\" (flat)")
            r = _number(r, f"{where}: radius_mm")
            if r == 0:
                raise _Bad(f"{where}: radius_mm = 0 is not allowed: \"inf\" for a flat surface")
            c = 1.0 / r
    elif "curvature_per_mm" in t:
        c = float(_number(t["curvature_per_mm"], f"{where}: curvature_per_mm"))
    else:
        raise _Bad(f"{where}: radius_mm (\"inf\" for flat) or curvature_per_mm is missing")
    if "thickness_mm" not in t:
        raise _Bad(f"{where}: thickness_mm is missing")
    thickness = _number(t["thickness_mm"], f"{where}: thickness_mm")
    mat = t.get("material", AIR)
    if isinstance(mat, str):
        if not mat.strip():
            raise _Bad(f"{where}: material \"\" is not allowed: \"air\", a glass name or [n_d, V_d]")
        material = AIR if mat.strip().lower() == AIR else mat.strip()
    elif isinstance(mat, list) and len(mat) == 2:
        material = tuple(_numbers(mat, f"{where}: material"))
    else:
        raise _Bad(f"{where}: material = {quoted(mat)} is not allowed: \"air\", a glass name or a model glass [n_d, V_d]")
    sd = t.get("semi_diameter_mm")
    return PrescriptionSurface(
        curvature_per_mm=c, thickness_mm=thickness, material=material,
        conic=_number(t.get("conic", 0.0), f"{where}: conic"),
        aspheric_coefficients=tuple(_numbers(t.get("aspheric_coefficients", []), f"{where}: aspheric_coefficients")),
        semi_diameter_mm=None if sd is None else _number(sd, f"{where}: semi_diameter_mm"),
        comment=_string(t.get("comment", ""), f"{where}: comment"), kind=kind,
        shape_parameters={k: _number(t[k], f"{where}: {k}") for k in own if k in t})


def _published(t) -> dict:
    if not isinstance(t, dict):
        raise _Bad(f"published must be a table, not {_kind(t)}")
    for k, v in t.items():
        ok = (isinstance(v, (str, bool)) or (isinstance(v, (int, float)) and math.isfinite(v))
              or (isinstance(v, list) and all(not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x)
                                              for x in v)))
        if not ok:
            raise _Bad(f"published: {quoted(k)} = {quoted(v)} is not allowed: a number, a string or an array of numbers")
    return dict(t)


def prescription_from_dict(d: dict) -> Prescription:
    """The lens of the file's dict ``d`` (the inverse of :meth:`Prescription.to_dict`); :class:`PrescriptionError` in
    one line naming the key or the surface."""
    try:
        return _from_dict(d)
    except _Bad as exc:
        raise PrescriptionError(str(exc)) from None


def _from_dict(d: dict) -> Prescription:
    _keys(d, _TOP, "")
    for k in ("surfaces", "stop_surface", "aperture"):
        if k not in d:
            raise _Bad(f"{k} is missing" + (" ([aperture] entrance_pupil_diameter_mm = ...)" if k == "aperture" else ""))
    surfaces = d["surfaces"]
    if not isinstance(surfaces, list) or not surfaces:
        raise _Bad("surfaces must be one or more [[surfaces]] tables")
    surfs = tuple(_surface(t, i + 1) for i, t in enumerate(surfaces))
    aperture = _keys(d["aperture"], _APERTURE, "[aperture]")
    if "entrance_pupil_diameter_mm" not in aperture:
        raise _Bad("[aperture]: entrance_pupil_diameter_mm is missing")
    epd = _number(aperture["entrance_pupil_diameter_mm"], "[aperture] entrance_pupil_diameter_mm")
    stop_size = aperture.get("stop_size", STOP_SIZES[0])
    if stop_size not in STOP_SIZES:
        raise _Bad(f"[aperture] stop_size = {quoted(stop_size)} is not allowed: one of {', '.join(STOP_SIZES)}")
    obj = _keys(d.get("object", {}), _OBJECT, "[object]")
    dist = obj.get("distance_mm", "inf")
    if _infinite(dist):
        distance = math.inf
    else:
        if isinstance(dist, str):
            raise _Bad(f"[object] distance_mm = {quoted(dist)} is not allowed: \"inf\" or a distance > 0 (mm)")
        distance = _number(dist, "[object] distance_mm")
    fields_t = _keys(d.get("fields", {"angles_deg": [0.0]} if math.isinf(distance) else {}), _FIELDS, "[fields]")
    if len(fields_t) != 1:
        raise _Bad("[fields]: give angles_deg (object at infinity) or heights_mm (finite object), one of them")
    (fkey, fvalues), = fields_t.items()
    if fkey == "angles_deg" and not math.isinf(distance):
        raise _Bad("[fields] angles_deg with an object at a finite distance: give heights_mm (mm), or distance_mm = \"inf\"")
    if fkey == "heights_mm" and math.isinf(distance):
        raise _Bad("[fields] heights_mm with an object at infinity: give angles_deg, or a finite [object] distance_mm")
    fields = tuple(_numbers(fvalues, f"[fields] {fkey}"))
    waves = _keys(d.get("wavelengths", {"um": [0.5875618]}), _WAVELENGTHS, "[wavelengths]")
    if "um" not in waves:
        raise _Bad("[wavelengths]: um is missing")
    lams = tuple(_numbers(waves["um"], "[wavelengths] um"))
    if "primary_um" in waves:
        primary = _number(waves["primary_um"], "[wavelengths] primary_um")
    elif len(lams) == 1:
        primary = lams[0]
    else:
        raise _Bad("[wavelengths]: primary_um is missing (one of um)")
    stop = d["stop_surface"]
    if isinstance(stop, bool) or not isinstance(stop, int):
        raise _Bad(f"stop_surface = {quoted(stop)} is not a surface number")
    extra = {}
    if "published" in d:
        extra["published"] = _published(d["published"])
    if "f_number_given" in d:
        extra["f_number_given"] = _number(d["f_number_given"], "f_number_given")
    return Prescription(surfaces=surfs, stop_surface=stop, entrance_pupil_diameter_mm=epd, fields=fields,
                        wavelengths_um=lams, primary_wavelength_um=primary, object_distance_mm=distance,
                        name=_string(d.get("name", ""), "name"), source=_string(d.get("source", ""), "source"),
                        notes=_string(d.get("notes", ""), "notes"), stop_size=stop_size, extra=extra)


def read_prescription_toml(path) -> Prescription:
    """The lens of our TOML file ``path`` (format: the module docstring). Errors in one line naming the file:
    :class:`lenssim.io.files.InputFileError` (cannot be read), ``ValueError`` (not TOML),
    :class:`PrescriptionError` (a key, a value or a surface not allowed)."""
    d = read_toml(path, _WHAT)
    try:
        return _from_dict(d)
    except (_Bad, PrescriptionError) as exc:
        raise PrescriptionError(f"{_WHAT} {str(path)!r}: {exc}") from None


# -- writing --------------------------------------------------------------------------------------------------------
def _toml_str(s: str) -> str:
    out = ['"']
    for ch in s:
        o = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04x}")
        elif 0xD800 <= o <= 0xDFFF:
            raise PrescriptionError(f"text {s!r} holds a lone surrogate character (U+{o:04X}): it cannot be written")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            raise PrescriptionError("NaN cannot be written to a lens file")
        return "inf" if v == math.inf else "-inf" if v == -math.inf else repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise PrescriptionError(f"{v!r} ({type(v).__name__}) cannot be written to a lens file")


def _key(k: str) -> str:
    return k if k and all(ch.isascii() and (ch.isalnum() or ch in "_-") for ch in k) else _toml_str(k)


def prescription_toml(prescription: Prescription) -> str:
    """The TOML text of ``prescription`` (what :func:`write_prescription_toml` writes)."""
    d = prescription.to_dict()
    unknown = [k for k in prescription.extra if k not in _EXTRA]
    if unknown:
        raise PrescriptionError(f"extra[{unknown[0]!r}] cannot be written to a lens file; the file holds "
                                f"{', '.join(_EXTRA)}")
    title = "".join(ch if ch.isprintable() else " " for ch in prescription.name) or "unnamed"
    lines = [f"# Lens prescription: {title} (lenssim TOML lens file; lengths in mm, surfaces in order from the object)"]
    for k in ("name", "source", "notes", "stop_surface", "f_number_given"):
        if k in d:
            lines.append(f"{k} = {_toml_value(d[k])}")
    for table in ("aperture", "object", "fields", "wavelengths", "published"):
        if table in d:
            lines += ["", f"[{table}]"]
            lines += [f"{_key(k)} = {_toml_value(v)}" for k, v in d[table].items()]
    for i, (s, sd) in enumerate(zip(prescription.surfaces, d["surfaces"]), start=1):
        note = " (aperture stop)" if i == prescription.stop_surface else ""
        note += " (its thickness: the image distance)" if i == len(prescription.surfaces) else ""
        lines += ["", f"[[surfaces]]  # surface {i}{note}"]
        c = s.curvature_per_mm
        if c != 0 and 1.0 / (1.0 / c) != c:  # the radius would not give the curvature back exactly
            sd = {"curvature_per_mm": c, **{k: v for k, v in sd.items() if k != "radius_mm"}}
        lines += [f"{k} = {_toml_value(v)}" for k, v in sd.items()]
    return "\n".join(lines) + "\n"


def write_prescription_toml(prescription: Prescription, path) -> Path:
    """Write ``prescription`` to the TOML file ``path`` atomically (read back equal by
    :func:`read_prescription_toml`); returns the path."""
    return atomic_write_text(path, prescription_toml(prescription))


# -- any lens -------------------------------------------------------------------------------------------------------
def read_lens(spec) -> Prescription:
    """The lens ``spec``: a Zemax file (``.zmx``), our TOML file (``.toml``), or the name of a shipped lens
    (``configs/lenses/NAME.toml``: ``cooke_triplet``, ``double_gauss``, ...). An unknown name is refused in one line
    listing the shipped ones."""
    from .resources import lens_path
    from .zemax import read_zmx

    p = Path(spec)
    suffix = p.suffix.lower()
    if suffix == ".zmx":
        return read_zmx(spec)
    bare = p.parent == Path(".") and not str(spec).startswith(".")
    if suffix == ".toml" and (p.exists() or not bare):
        return read_prescription_toml(spec)
    if bare and suffix in ("", ".toml"):
        try:
            return read_prescription_toml(lens_path(p.name))
        except FileNotFoundError as exc:
            raise InputFileError(str(exc)) from None
    raise InputFileError(f"lens {str(spec)!r}: the file type {p.suffix!r} is not a lens file: give a .zmx (Zemax) or "
                         ".toml file, or the name of a shipped lens")
