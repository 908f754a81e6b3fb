"""Sequential Zemax OpticStudio lens files (``.zmx``) read into a :class:`~lenssim.model.prescription.Prescription`.

The file is read whole and checked line by line; anything that would make the traced lens differ from the file's
is refused in one line naming the file, the surface (numbered as in the file) and the keyword, never skipped.

Encoding: UTF-16 with a byte-order mark (OpticStudio saves UTF-16 LE with a BOM and CRLF line ends; BE is read too),
UTF-16 without a BOM (recognised by its zero bytes), UTF-8 with or without a BOM, plain ASCII, and, failing UTF-8,
Windows-1252 text (older files with an accented comment). A binary file (an image renamed ``.zmx``) is refused.

Read:

* ``UNIT`` (the lens unit: ``MM``; ``CM``, ``IN``/``INCH`` and ``METER``/``M`` are converted to millimetres:
  lengths, curvatures, even-asphere coefficients, object heights and the pupil diameter);
* the aperture: ``ENPD`` (entrance-pupil diameter) or ``FNUM`` (image-space F-number, kept as
  ``extra["f_number_given"]``; the entrance-pupil diameter is then the paraxial focal length at the primary
  wavelength over the F-number, found by a paraxial y-nu trace: catalogue glasses through
  :func:`lenssim.model.glass.as_glass`, model glasses at their ``n_d``). Other aperture types (object-space NA,
  float by stop size) are refused;
* the fields: ``FTYP`` (type 0 field angles in degrees for an object at infinity, 1 object heights for a finite
  object; the number of fields and wavelengths), ``YFLN`` (the field values used), ``XFLN`` (must be 0: fields off
  the y axis are refused);
* the wavelengths (micrometres): ``WAVM n value weight`` or ``WAVL v1 v2 ...``, ``PWAV`` (primary, 1-based);
* ``NAME`` (the lens name);
* ``SURF n`` blocks numbered 0, 1, 2, ...: ``TYPE`` (a surface kind's ``zemax_type``,
  :mod:`lenssim.model.surface_kinds`: ``STANDARD`` or ``EVENASPH``), ``CURV`` (1/lens unit, the first number),
  ``CONI``, ``PARM k v`` (read by the kind: for ``EVENASPH`` ``PARM 1``, the ``r^2`` term, must be 0 and ``PARM 2 ..
  8`` are ``A4 .. A16``), ``DISZ`` (thickness; ``INFINITY``, or 1e10 lens units and more, for the object distance of surface
  0), ``GLAS NAME ...`` (the glass name kept as written; ``___BLANK`` is a model glass ``(n_d, V_d)`` from the 3rd and
  4th numbers after the name; no ``GLAS`` is air), ``DIAM`` (semi-diameter; 0: none), ``CLAP`` (a circular aperture:
  its radius replaces ``DIAM``), ``STOP``, ``COMM`` (comment).

Surface 0 is the object (its ``DISZ`` the object distance), the last ``SURF`` is the image plane, the ones between
are the prescription's surfaces 1..N (the image distance is the ``DISZ`` of surface N).

:func:`write_zmx` writes a prescription as such a file (lens unit mm, the aperture as ``ENPD``), read back equal;
a surface kind without a ``.zmx`` type (``qbfs``) is refused in one line.

Refused (one line each): a non-sequential file (``MODE NSC``, non-sequential objects), surface types other than the
kinds' (coordinate breaks, gratings, odd aspheres, ...), mirrors, tilted or decentred surfaces and apertures, annular,
rectangular or elliptical apertures and obscurations, a curved image surface, an object in glass, negative or
non-finite values, telecentric object space, afocal image space. Keywords that do not change the traced lens (``VERS``,
``MODE SEQ``, ``NOTE``, ``PFIL``, ``GCAT``, tolerances, pickups, drawing and coating settings, ...) and keywords this
reader does not know are ignored.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..model.prescription import AIR, STOP_SIZES, Prescription, PrescriptionError, PrescriptionSurface
from ..model.surface_kinds import SURFACE_KINDS, ZemaxParmError
from ..validate import looks_numeric
from .files import InputFileError, atomic_write_text, check_input_file, describe_os_error

__all__ = ["read_zmx", "write_zmx", "prescription_zmx", "MAX_ZMX_BYTES"]

MAX_ZMX_BYTES = 16 * 2**20
"""Largest ``.zmx`` file read (16 MiB; a lens file is a few tens of kilobytes)."""

_UNITS = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "INCH": 25.4, "METER": 1000.0, "M": 1000.0}
"""Millimetres per lens unit."""

_INFINITE_DISTANCE = 1e10
"""An object distance of this many lens units or more is at infinity (as OpticStudio takes it)."""

_KEYWORD = re.compile(r"[A-Z][A-Z0-9_]{1,7}")

_DECENTRE = {"DECX", "DECY", "DECZ", "TILX", "TILY", "TILZ", "TILT", "SCBD", "SCAD", "OBDC"}
"""Tilt and decentre data on a surface or its aperture: refused when any of their numbers is not 0."""

_NON_CIRCULAR = {"SQAP", "ELAP", "OBSC", "SQOB", "ELOB", "UDAD", "USAP"}
"""Rectangular, elliptical, user-defined apertures and obscurations."""

_NON_SEQUENTIAL = {"NSOA", "NSOD", "NSOH", "NSOO", "NSOP", "NSOQ", "NSOS", "NSOU", "NSOV", "NSOW", "NSCS"}

_APERTURE_REFUSED = {"OBNA": "object-space numerical aperture (OBNA)", "FLOA": "float by stop size (FLOA)"}

_FIELD_TYPES = {0: "angle", 1: "object height", 2: "paraxial image height", 3: "real image height",
                4: "theodolite angle"}


class _Fail(Exception):
    """A reading error before the file prefix is added."""


@dataclass
class _Surf:
    number: int
    line: int
    kind: str = "STANDARD"
    curvature: float = 0.0
    conic: float = 0.0
    parms: dict = field(default_factory=dict)
    thickness: float | None = None
    material: str | tuple[float, float] = AIR
    semi_diameter: float | None = None
    clear_aperture: float | None = None
    stop: bool = False
    comment: str = ""
    lines: dict = field(default_factory=dict)
    """The line of each keyword (``"PARM 2"`` for a parameter) in the file."""

    def at(self, kw: str) -> str:
        return f"surface {self.number} (line {self.lines.get(kw, self.line)})"


def _shown(path) -> str:
    return repr(str(path))


def _decode(raw: bytes) -> str:
    """The text of ``raw``; :class:`_Fail` for bytes that are not text."""
    utf16 = None
    if raw.startswith(b"\xff\xfe"):
        utf16, body = "utf-16-le", raw[2:]
    elif raw.startswith(b"\xfe\xff"):
        utf16, body = "utf-16-be", raw[2:]
    elif len(raw) >= 4 and raw[0] != 0 and raw[1] == 0 and raw[3] == 0:
        utf16, body = "utf-16-le", raw
    elif len(raw) >= 4 and raw[0] == 0 and raw[1] != 0 and raw[2] == 0:
        utf16, body = "utf-16-be", raw
    if utf16:
        if len(body) % 2:
            raise _Fail(f"is cut short: an odd number of bytes in a {utf16.upper()} text file (a truncated file)")
        try:
            text = body.decode(utf16)
        except UnicodeDecodeError as exc:
            raise _Fail(f"is not a text file: byte {exc.start} is not {utf16.upper()} text") from None
    else:
        body = raw[3:] if raw.startswith(b"\xef\xbb\xbf") else raw
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError as exc:
            if any(b < 32 and b not in (9, 10, 12, 13) for b in body):  # control bytes: binary, not ANSI text
                raise _Fail(f"is not a text file (binary data at byte {exc.start}); a Zemax lens file is text") from None
            text = body.decode("cp1252", errors="replace")
    bad = next((i for i, ch in enumerate(text) if ord(ch) < 32 and ch not in "\t\n\r\f"), None)
    if bad is not None:
        raise _Fail(f"is not a text file (control character {ord(text[bad]):#04x} at character {bad}); a Zemax lens "
                    "file is text")
    return text


def _number(tok: str, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise _Fail(f"{what} {tok!r} is not a number") from None
    if not math.isfinite(v):
        raise _Fail(f"{what} {tok!r} is not a finite number")
    return v


def _int(tok: str, what: str) -> int:
    v = _number(tok, what)
    if v != int(v):
        raise _Fail(f"{what} {tok!r} is not a whole number")
    return int(v)


def _arg(tokens: list[str], i: int, what: str) -> str:
    if len(tokens) <= i:
        raise _Fail(f"{what}: a value is missing")
    return tokens[i]


def _rest(line: str) -> str:
    parts = line.strip().split(None, 1)
    text = parts[1].strip() if len(parts) > 1 else ""
    if len(text) >= 2 and text[0] == text[-1] == '"':
        text = text[1:-1]
    return text


class _Reader:
    def __init__(self):
        self.scale = 1.0
        self.unit = "MM"
        self.name = ""
        self.epd: float | None = None
        self.fnum: tuple[float, int] | None = None
        self.ftyp: list[str] | None = None
        self.xfln: list[float] = []
        self.yfln: list[float] = []
        self.wavm: dict[int, float] = {}
        self.wavl: list[float] = []
        self.pwav = 1
        self.surfs: list[_Surf] = []
        self.seen_keyword = False

    # -- one line --------------------------------------------------------------------------------------------------
    def line(self, ln: int, raw: str) -> None:
        tokens = raw.split()
        if not tokens:
            return
        kw = tokens[0]
        if not _KEYWORD.fullmatch(kw):
            shown = raw.strip()
            shown = shown if len(shown) <= 40 else shown[:37] + "..."
            raise _Fail(f"line {ln}: {shown!r} is not a Zemax keyword line; not a Zemax lens file")
        self.seen_keyword = True
        cur = self.surfs[-1] if self.surfs else None
        where = f"surface {cur.number} (line {ln}): {kw}" if cur else f"line {ln}: {kw}"
        try:
            self._keyword(kw, tokens, raw, cur, ln)
        except _Fail as exc:
            raise _Fail(f"{where}: {exc}") from None

    def _keyword(self, kw, tokens, raw, cur, ln) -> None:
        if kw == "SURF":
            n = _int(_arg(tokens, 1, "SURF"), "surface number")
            if n != len(self.surfs):
                raise _Fail(f"surface number {n} out of order: surface {len(self.surfs)} expected next "
                            "(SURF blocks are numbered 0, 1, 2, ...)")
            self.surfs.append(_Surf(number=n, line=ln))
            return
        if kw == "MODE":
            mode = _arg(tokens, 1, "MODE").upper()
            if mode != "SEQ":
                raise _Fail(f"{mode}: a non-sequential file is not supported (sequential lenses only)")
            return
        if kw in _NON_SEQUENTIAL:
            raise _Fail("non-sequential objects are not supported (sequential lenses only)")
        if kw == "UNIT":
            unit = _arg(tokens, 1, "UNIT").upper()
            if unit not in _UNITS:
                raise _Fail(f"lens unit {tokens[1]!r} is not supported: MM, CM, IN or METER")
            if self.surfs:
                raise _Fail("the lens unit must be given before the surfaces")
            self.unit, self.scale = unit, _UNITS[unit]
            return
        if kw == "NAME":
            self.name = _rest(raw)
            return
        if kw == "ENPD":
            epd = _number(_arg(tokens, 1, "ENPD"), "entrance-pupil diameter")
            if not epd > 0:
                raise _Fail(f"entrance-pupil diameter {epd:g} is not allowed: > 0")
            self.epd = epd
            return
        if kw == "FNUM":
            f = _number(_arg(tokens, 1, "FNUM"), "F-number")
            flag = _int(tokens[2], "F-number type") if len(tokens) > 2 else 0
            if not f > 0:
                raise _Fail(f"F-number {f:g} is not allowed: > 0")
            if flag not in (0, 1):
                raise _Fail(f"F-number type {flag} is not supported: 0 (image-space F/#) or 1 (paraxial working F/#)")
            self.fnum = (f, flag)
            return
        if kw in _APERTURE_REFUSED:
            raise _Fail(f"the aperture as {_APERTURE_REFUSED[kw]} is not supported: give the entrance-pupil diameter "
                        "(ENPD) or the image-space F-number (FNUM)")
        if kw == "FTYP":
            self.ftyp = tokens[1:]
            return
        if kw in ("XFLN", "YFLN"):
            values = [_number(t, "field value") for t in tokens[1:]]
            if kw == "XFLN":
                self.xfln = values
            else:
                self.yfln = values
            return
        if kw == "WAVM":
            n = _int(_arg(tokens, 1, "WAVM"), "wavelength number")
            self.wavm.setdefault(n, _number(_arg(tokens, 2, "WAVM"), "wavelength (um)"))
            return
        if kw == "WAVL":
            self.wavl = [_number(t, "wavelength (um)") for t in tokens[1:]]
            return
        if kw == "PWAV":
            self.pwav = _int(_arg(tokens, 1, "PWAV"), "primary wavelength number")
            return
        if cur is None:
            if kw in ("TYPE", "CURV", "CONI", "PARM", "DISZ", "GLAS", "DIAM", "STOP", "CLAP"):
                raise _Fail("surface data before the first SURF")
            return
        cur.lines[kw if kw != "PARM" or len(tokens) < 2 else f"PARM {tokens[1]}"] = ln
        self._surface_keyword(kw, tokens, raw, cur)

    def _surface_keyword(self, kw, tokens, raw, cur: _Surf) -> None:
        if kw == "TYPE":
            kind = _arg(tokens, 1, "TYPE").upper()
            if kind == "COORDBRK":
                raise _Fail("COORDBRK: coordinate breaks (tilts, decentres, folds) are not supported; a centred lens only")
            if kind in ("DGRATING", "GRATING", "EGRATING", "VARGRATE"):
                raise _Fail(f"{kind}: diffraction gratings are not supported")
            if kind in ("NONSEQCO",):
                raise _Fail(f"{kind}: non-sequential components are not supported (sequential lenses only)")
            types = [k.zemax_type for k in SURFACE_KINDS.values() if k.zemax_type]
            if kind not in types:
                raise _Fail(f"surface type {tokens[1]!r} is not supported: {' or '.join(types)}")
            cur.kind = kind
        elif kw == "CURV":
            cur.curvature = _number(_arg(tokens, 1, "CURV"), "curvature") / self.scale
        elif kw == "CONI":
            cur.conic = _number(_arg(tokens, 1, "CONI"), "conic")
        elif kw == "PARM":
            k = _int(_arg(tokens, 1, "PARM"), "parameter number")
            cur.parms[k] = _number(_arg(tokens, 2, "PARM"), f"PARM {k}")
        elif kw == "XDAT":
            if any(_number(t, "extra data") != 0 for t in tokens[2:3]):
                raise _Fail("extra surface data is not supported (STANDARD or EVENASPH surfaces only)")
        elif kw == "DISZ":
            tok = _arg(tokens, 1, "DISZ")
            if tok.upper() in ("INFINITY", "INF") or tok.lower() in ("inf", "+inf"):
                t = math.inf
            else:
                t = _number(tok, "thickness")
            if cur.number > 0 and math.isinf(t):
                raise _Fail("INFINITY is allowed only for the object distance (surface 0)")
            cur.thickness = t * self.scale if math.isfinite(t) else t
        elif kw == "GLAS":
            name = _arg(tokens, 1, "GLAS")
            if name.upper() == "MIRROR":
                raise _Fail("MIRROR: mirrors are not supported (a refracting lens only)")
            if name == "___BLANK":
                nd = _number(_arg(tokens, 4, "GLAS ___BLANK (model glass n_d)"), "model glass n_d")
                vd = _number(_arg(tokens, 5, "GLAS ___BLANK (model glass V_d)"), "model glass V_d")
                cur.material = (nd, vd)
            elif name.upper() == "AIR":
                cur.material = AIR
            else:
                cur.material = name
        elif kw == "DIAM":
            sd = _number(_arg(tokens, 1, "DIAM"), "semi-diameter")
            if sd < 0:
                raise _Fail(f"semi-diameter {sd:g} is not allowed: >= 0 (0: none)")
            cur.semi_diameter = sd * self.scale if sd > 0 else None
        elif kw == "CLAP":
            r_min = _number(_arg(tokens, 1, "CLAP"), "aperture inner radius")
            r_max = _number(_arg(tokens, 2, "CLAP"), "aperture radius")
            if r_min != 0:
                raise _Fail(f"an annular aperture (inner radius {r_min:g}) is not supported")
            if not r_max > 0:
                raise _Fail(f"aperture radius {r_max:g} is not allowed: > 0")
            cur.clear_aperture = r_max * self.scale
        elif kw == "STOP":
            cur.stop = True
        elif kw == "COMM":
            cur.comment = _rest(raw)
        elif kw in _DECENTRE:
            if any(_number(t, kw) != 0 for t in tokens[1:] if looks_numeric(t)):
                raise _Fail("tilted or decentred surfaces are not supported; a centred, rotationally symmetric lens only")
        elif kw in _NON_CIRCULAR:
            raise _Fail("rectangular, elliptical or user-defined apertures and obscurations are not supported "
                        "(circular apertures only)")

    # -- the whole file --------------------------------------------------------------------------------------------
    def prescription(self, source: str) -> Prescription:
        surfs = self.surfs
        if not surfs:
            raise _Fail("has no SURF block; not a Zemax lens file" if self.seen_keyword else
                        "is empty; not a Zemax lens file")
        if len(surfs) < 3:
            raise _Fail(f"has {len(surfs)} SURF block{'s' if len(surfs) > 1 else ''}: an object surface, at least one "
                        "lens surface and an image surface are needed (a truncated file?)")
        obj, image, lens = surfs[0], surfs[-1], surfs[1:-1]
        kinds = {k.zemax_type: k for k in SURFACE_KINDS.values() if k.zemax_type}
        shapes = []
        for s in surfs:
            try:
                shapes.append(kinds[s.kind].from_zmx(s.parms, self.scale))
            except ZemaxParmError as exc:
                raise _Fail(f"{s.at(f'PARM {exc.parm}')}: {exc}") from None
        if image.material != AIR:
            raise _Fail(f"{image.at('GLAS')}: GLAS: the last SURF (the image plane) has a glass after it: the file is cut short "
                        "or its image surface is missing")
        if image.curvature != 0:
            raise _Fail(f"{image.at('CURV')}: CURV: a curved image surface is not supported (a flat image plane only; "
                        "or the file is cut short: its last SURF is taken as the image plane)")
        if obj.curvature != 0:
            raise _Fail(f"{obj.at('CURV')}: CURV: a curved object surface is not supported (a flat object plane only)")
        if obj.material != AIR:
            raise _Fail(f"{obj.at('GLAS')}: GLAS: an object in {obj.material!r} is not supported (object space is air)")
        stops = [s for s in surfs if s.stop]
        if not stops:
            raise _Fail("no surface is the STOP (a truncated file?)")
        stop = stops[0]
        if stop is obj or stop is image:
            raise _Fail(f"{stop.at('STOP')}: STOP: the stop must be a lens surface, not the "
                        f"{'object' if stop is obj else 'image'}")
        # object distance
        od = obj.thickness if obj.thickness is not None else 0.0
        if math.isfinite(od) and od >= _INFINITE_DISTANCE * self.scale:
            od = math.inf
        if not od > 0:
            raise _Fail(f"{obj.at('DISZ')}: DISZ: the object distance {od:g} mm is not allowed: > 0 or "
                        "INFINITY")
        for s in lens:
            where = f"{s.at('DISZ')}: DISZ"
            t = s.thickness if s.thickness is not None else 0.0
            if s is lens[-1] and not t > 0:
                raise _Fail(f"{where}: the image distance (the thickness after the last lens surface) {t:g} mm is not "
                            "allowed: > 0")
            if t < 0:
                raise _Fail(f"{where}: thickness {t:g} mm is not allowed: >= 0 (a sequential lens's surfaces follow "
                            "each other)")
        fields = self._fields(math.isinf(od))
        lams, primary = self._wavelengths()
        surfaces = tuple(PrescriptionSurface(
            curvature_per_mm=s.curvature, thickness_mm=s.thickness or 0.0, material=s.material, conic=s.conic,
            semi_diameter_mm=s.clear_aperture if s.clear_aperture is not None else s.semi_diameter,
            comment=s.comment, **shape) for s, shape in zip(lens, shapes[1:-1]))
        extra = {}
        if self.epd is not None:
            epd = self.epd * self.scale
        elif self.fnum is not None:
            f, flag = self.fnum
            if flag == 1 and not math.isinf(od):
                raise _Fail("FNUM: the paraxial working F-number with a finite object is not supported: give the "
                            "entrance-pupil diameter (ENPD) or the image-space F-number")
            epd = _paraxial_focal_length(surfaces, primary) / f
            extra["f_number_given"] = f
        else:
            raise _Fail("no aperture: give the entrance-pupil diameter (ENPD) or the image-space F-number (FNUM)")
        try:
            return Prescription(surfaces=surfaces, stop_surface=stop.number, entrance_pupil_diameter_mm=epd,
                                fields=fields, wavelengths_um=lams, primary_wavelength_um=primary,
                                object_distance_mm=od, name=self.name, source=source, extra=extra)
        except PrescriptionError as exc:
            raise _Fail(str(exc)) from None

    def _fields(self, infinite: bool) -> tuple[float, ...]:
        ftype, n = 0, None
        if self.ftyp is not None:
            try:
                ftype = _int(_arg(self.ftyp, 0, "FTYP"), "field type")
                tele = _int(self.ftyp[1], "telecentric flag") if len(self.ftyp) > 1 else 0
                n = _int(self.ftyp[2], "number of fields") if len(self.ftyp) > 2 else None
                afocal = _int(self.ftyp[6], "afocal flag") if len(self.ftyp) > 6 else 0
            except _Fail as exc:
                raise _Fail(f"FTYP: {exc}") from None
            if ftype not in (0, 1):
                raise _Fail(f"FTYP: fields as {_FIELD_TYPES.get(ftype, f'type {ftype}')} are not supported: field "
                            "angles (0) or object heights (1)")
            if tele:
                raise _Fail("FTYP: telecentric object space is not supported")
            if afocal:
                raise _Fail("FTYP: afocal image space is not supported")
            if n is not None and not 1 <= n <= max(len(self.yfln), 1):
                raise _Fail(f"FTYP: {n} fields, but YFLN gives {len(self.yfln)} values")
        if not self.yfln:
            ys = [0.0]
        elif n is not None:
            ys = self.yfln[:n]
        else:
            ys = list(self.yfln)
            while len(ys) > 1 and ys[-1] == 0:
                ys.pop()
        xs = self.xfln[:len(ys)]
        if any(x != 0 for x in xs):
            raise _Fail(f"XFLN: fields off the y axis (x = {next(x for x in xs if x != 0):g}) are not supported: the lens "
                        "is rotationally symmetric, give the fields on the y axis")
        if any(y < 0 for y in ys):
            raise _Fail(f"YFLN: field {min(ys):g} is negative; the lens is rotationally symmetric: give fields >= 0")
        if ftype == 0 and not infinite:
            raise _Fail("FTYP: field angles with an object at a finite distance are not supported: give object heights "
                        "(field type 1) or put the object at INFINITY")
        if ftype == 1:
            if infinite:
                raise _Fail("FTYP: object heights with an object at infinity are not possible: give field angles (field "
                            "type 0)")
            ys = [y * self.scale for y in ys]
        return tuple(ys)

    def _wavelengths(self) -> tuple[tuple[float, ...], float]:
        n = None
        if self.ftyp is not None and len(self.ftyp) > 3:
            try:
                n = _int(self.ftyp[3], "number of wavelengths")
            except _Fail as exc:
                raise _Fail(f"FTYP: {exc}") from None
        if self.wavm:
            count = n if n is not None else max(self.wavm)
            missing = [i for i in range(1, count + 1) if i not in self.wavm]
            if count < 1 or missing:
                raise _Fail(f"WAVM: wavelength {missing[0] if missing else 1} of {max(count, 1)} is missing")
            lams = [self.wavm[i] for i in range(1, count + 1)]
        elif self.wavl:
            lams = self.wavl[:n] if n is not None else list(self.wavl)
            if n is not None and len(lams) < n:
                raise _Fail(f"WAVL: {len(lams)} wavelengths given, FTYP says {n}")
        else:
            raise _Fail("no wavelengths (WAVM or WAVL)")
        if not 1 <= self.pwav <= len(lams):
            raise _Fail(f"PWAV: primary wavelength {self.pwav} is not one of the {len(lams)} wavelengths")
        return tuple(lams), lams[self.pwav - 1]


def _paraxial_focal_length(surfaces, wavelength_um: float) -> float:
    """The paraxial effective focal length (mm) by a y-nu trace of a ray parallel to the axis at ``wavelength_um``."""
    from ..model.glass import as_glass

    def index(i, mat):
        if isinstance(mat, tuple):
            return mat[0]
        if mat.lower() == AIR:
            return 1.0
        try:
            return float(as_glass(mat).index(wavelength_um))
        except (ValueError, KeyError) as exc:
            raise _Fail(f"FNUM: the entrance-pupil diameter needs the focal length, which needs the index of glass "
                        f"{mat!r} (surface {i}): {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}; give "
                        "the entrance-pupil diameter (ENPD) instead") from None

    n, y, nu = 1.0, 1.0, 0.0
    for i, s in enumerate(surfaces, start=1):
        n2 = index(i, s.material)
        nu -= y * s.paraxial_curvature_per_mm * (n2 - n)
        n = n2
        if i < len(surfaces):
            y += s.thickness_mm * nu / n
    if nu == 0 or not math.isfinite(nu):
        raise _Fail("FNUM: the lens is afocal (no paraxial focal length): give the entrance-pupil diameter (ENPD)")
    efl = -n / nu
    if not efl > 0:
        raise _Fail(f"FNUM: the paraxial focal length {efl:g} mm is not positive: give the entrance-pupil diameter (ENPD)")
    return efl


def _one_line(text: str) -> str:
    return "".join(ch if ch.isprintable() else " " for ch in text)


def prescription_zmx(prescription: Prescription) -> str:
    """The ``.zmx`` text of ``prescription`` (what :func:`write_zmx` writes): lens unit mm, the entrance-pupil diameter,
    fields on the ``y`` axis, every wavelength at weight 1. Names and comments are written on one line (control
    characters as spaces). :class:`PrescriptionError` for what a ``.zmx`` file cannot hold: a surface kind without a
    Zemax type, a glass name with a space, a stop sized by real rays (the reader knows no ray-aiming keyword)."""
    p = prescription
    if p.stop_size != STOP_SIZES[0]:
        raise PrescriptionError(f"stop_size {p.stop_size!r} cannot be written to a .zmx file (it is read as "
                                f"{STOP_SIZES[0]!r}): write the lens as TOML")
    lines = ["MODE SEQ", f"NAME {_one_line(p.name)}", "UNIT MM", f"ENPD {p.entrance_pupil_diameter_mm!r}",
             f"FTYP {0 if p.object_at_infinity else 1} 0 {len(p.fields)} {len(p.wavelengths_um)} 0 0 0",
             "XFLN" + " 0" * len(p.fields), "YFLN " + " ".join(repr(f) for f in p.fields)]
    lines += [f"WAVM {i} {w!r} 1" for i, w in enumerate(p.wavelengths_um, start=1)]
    primary = min(range(len(p.wavelengths_um)), key=lambda i: abs(p.wavelengths_um[i] - p.primary_wavelength_um))
    lines += [f"PWAV {primary + 1}", "SURF 0", "  TYPE STANDARD", "  CURV 0",
              "  DISZ " + ("INFINITY" if p.object_at_infinity else repr(p.object_distance_mm))]
    for i, s in enumerate(p.surfaces, start=1):
        kind = s.surface_kind
        if kind.zemax_type is None:
            raise PrescriptionError(f"surface {i}: a {kind.name} surface ({kind.label}) cannot be written to a .zmx "
                                    "file: its Zemax surface type and parameters are not known to this tool; write "
                                    "the lens as TOML")
        lines += [f"SURF {i}"] + ["  " + line for line in kind.zmx_lines(s)]
        lines += ["  STOP"] if i == p.stop_surface else []
        lines.append(f"  DISZ {s.thickness_mm!r}")
        if isinstance(s.material, tuple):
            lines.append(f"  GLAS ___BLANK 1 0 {s.material[0]!r} {s.material[1]!r} 0 0 0 0 0 0")
        elif not s.is_air:
            if len(s.material.split()) != 1:
                raise PrescriptionError(f"surface {i}: glass name {s.material!r} cannot be written to a .zmx file "
                                        "(a name without spaces)")
            lines.append(f"  GLAS {s.material}")
        lines += [f"  DIAM {s.semi_diameter_mm!r}"] if s.semi_diameter_mm is not None else []
        lines += [f"  COMM {_one_line(s.comment)}"] if s.comment else []
    lines += [f"SURF {len(p.surfaces) + 1}", "  TYPE STANDARD", "  CURV 0", "  DISZ 0"]
    return "\n".join(lines) + "\n"


def write_zmx(prescription: Prescription, path) -> Path:
    """Write ``prescription`` to the Zemax file ``path`` atomically (:func:`prescription_zmx`; read back equal by
    :func:`read_zmx`, its name, comments and extras aside); returns the path."""
    return atomic_write_text(path, prescription_zmx(prescription))


def read_zmx(path) -> Prescription:
    """The sequential lens of the Zemax file ``path`` (see the module docstring for what is read and refused).

    Errors, each one line naming the file: :class:`lenssim.io.files.InputFileError` (a file that cannot be read),
    :class:`lenssim.model.prescription.PrescriptionError` (anything else: not a lens file, a binary file, a keyword
    that is not supported, with the surface number as in the file and the line)."""
    what = "Zemax lens file"
    p = check_input_file(path, what)
    try:
        size = p.stat().st_size
        if size > MAX_ZMX_BYTES:
            raise PrescriptionError(f"{what} {_shown(path)} is {size / 2**20:.1f} MiB: not a lens file (a lens file is a "
                                    f"few kilobytes; at most {MAX_ZMX_BYTES // 2**20} MiB are read)")
        with open(p, "rb") as fh:
            raw = fh.read(MAX_ZMX_BYTES + 1)
    except OSError as exc:
        raise InputFileError(describe_os_error(exc, path, what)) from None
    try:
        text = _decode(raw)
        reader = _Reader()
        for ln, line in enumerate(text.splitlines(), start=1):
            reader.line(ln, line)
        return reader.prescription(source=f"Zemax file {Path(path).name}")
    except _Fail as exc:
        msg = str(exc)
        sep = " " if msg.startswith(("is ", "has ")) else ": "
        raise PrescriptionError(f"{what} {_shown(path)}{sep}{msg}") from None
