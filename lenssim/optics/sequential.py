"""Any sequential lens from a prescription, centred or with decentred and tilted surfaces: paraxial data, Seidel sums,
real rays and the exact wavefront.

:class:`SequentialLens` reads a :class:`lenssim.model.prescription.Prescription` (surfaces numbered as in the file,
object = 0) and answers, at any wavelength of the prescription:

* paraxial data with the stop anywhere (:meth:`SequentialLens.paraxial`): focal length, back focal distance, entrance
  and exit pupils, F-number (focal length / entrance-pupil diameter), working F-number, paraxial image heights, by the
  ``y-nu`` trace of Welford ch. 7 (``n'u' = n u - h c (n' - n)``, ``h' = h + d u'``);
* Seidel sums surface by surface (:meth:`SequentialLens.seidel_surfaces`, :func:`lenssim.optics.paraxial.seidel_surface_sums`
  with the chief ray through the stop's centre; an even asphere's ``A4`` included) and the chromatic sums
  ``C_I = A h D(dn/n)``, ``C_II = Abar h D(dn/n)`` (Welford sec. 8.2);
* real rays (:meth:`SequentialLens.trace`), batched in torch (float64), through any surface kind
  (:meth:`lenssim.model.surface_kinds.SurfaceKind.intersect`: its base conic's closed-form intersection refined by
  Newton's method on the full sag), vignetted by every clear
  semi-diameter, with optical path lengths; rays aimed at the stop (:meth:`SequentialLens.aim`): each pupil point
  ``(px, py)`` of the unit disc is the ray that meets the stop surface at ``(px, py)`` times the stop's paraxial
  radius, found by Newton iterations on real rays (``aim="real"``), or the ray through the paraxial entrance
  pupil's plane at that point (``aim="paraxial"``, what the optical-design programs call ray aiming off);
* the optical path difference (:meth:`SequentialLens.wavefront`) to the reference sphere centred on the chief ray's
  point on the image plane and passing through the chief ray's point on the paraxial exit pupil's plane (the
  convention of the optical-design programs), in waves, sign as :func:`lenssim.optics.exact_wavefront.opd` (Welford's:
  ``W = OPL(chief) - OPL(ray)``); RMS and peak-to-valley over the unvignetted pupil; spot diagrams.

Conventions: the axis is ``z``, surface 1's vertex at ``z = 0``; fields lie along ``+y`` (a field angle ``a`` is the
chief ray's direction ``(0, sin a, cos a)`` in object space; an object height ``h`` sits at ``y = -h``, so both image
above the axis for a positive lens). Units: mm, um for wavelengths, waves for wavefronts.

Misalignment (decentre and tilt, ``misalignments``; :mod:`lenssim.model.misalignment` gives the rigid motion, its
signs and its pivot): the real rays (:meth:`SequentialLens.trace`, so :meth:`SequentialLens.aim` and
:meth:`SequentialLens.wavefront`) meet each moved surface in its own nominal frame (the rays' points and directions
carried through the inverse of the surface's motion, intersected, refracted, vignetted by the semi-diameter there,
and carried back); the real aiming puts pupil point ``(px, py)`` at ``(px, py)`` times the stop's paraxial radius in
the stop's own frame (the chief ray through the moved stop's centre). The image plane stays where it was, normal to
the axis; the rest keeps the centred lens: the paraxial data (:meth:`SequentialLens.paraxial`, so the entrance and
exit pupils, the aiming's starting guess and the reference sphere's exit-pupil plane), the Seidel and chromatic sums
are those of the lens without its misalignments. A misaligned lens is not rotationally symmetric: a field at image
azimuth ``phi`` is the field along ``+y`` of :meth:`SequentialLens.rotated` ``(phi)``. With no misalignment every
result is bit for bit what it was before misalignments existed.

References
----------
.. [1] W. T. Welford, *Aberrations of Optical Systems* (Adam Hilger, 1986), ch. 4 (optical path, reference sphere),
   ch. 7-8 (paraxial trace, Seidel and chromatic sums surface by surface).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import torch

from ..model.glass import as_glass
from ..model.misalignment import Misalignment
from ..model.prescription import AIR, Prescription, PrescriptionError, PrescriptionSurface
from ..model.surface import Surface
from ..model.surface_kinds import NEWTON_ITERATIONS, refract
from .paraxial import seidel_surface_sums
from ..torch_utils import HOST

__all__ = ["SequentialLens", "Fields", "ParaxialData", "RayBundle", "WavefrontMap", "AIM_METHODS", "AIM_TOLERANCE",
           "AIM_ITERATIONS", "NEWTON_ITERATIONS", "RayTraceError", "surfaces_lens", "trace_rays_opl", "trace_rays"]

AIM_METHODS = ("real", "paraxial")
AIM_ITERATIONS = 60
"""Most Newton steps of the real-ray aiming (each a real trace of the rays still searching and two of their
neighbours). Through a lens of floats each ray stops as soon as it has converged (usually in a few steps: rays grazing
a steep rim can take tens), so a ray's result does not depend on the rays traced with it; a batch of designs steps
every ray until its last has converged."""
AIM_TOLERANCE = 1e-9
"""Aiming converged: every ray meets the stop within this fraction of the stop's radius of its target."""
AXIAL_RIM_RAYS = 64
"""Rays around the axial beam's rim that :meth:`SequentialLens.check_aperture` traces."""
APERTURE_SLACK = 0.01
"""The stop radius the entrance pupil implies may exceed the stop's semi-diameter by this fraction (published
semi-diameters are rounded to 0.1 mm)."""
FD_STEP = 1e-7
"""Relative step (of the entrance-pupil radius) of the aiming's finite-difference Jacobian."""


def _any(condition) -> bool:
    """A condition on numbers that may be floats or tensors (a batch of designs): true if it holds for any."""
    return bool(condition.any()) if torch.is_tensor(condition) else bool(condition)


def _times(v: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    """``v @ A`` for vectors ``v`` ``(..., 3)`` and a ``(3, 3)`` matrix, element by element: the same numbers whatever
    the leading shape (a matrix product's kernel, and so its rounding, depends on the number of rows)."""
    return v[..., 0:1] * A[0] + v[..., 1:2] * A[1] + v[..., 2:3] * A[2]


class Fields:
    """Several fields traced at once (a lens of floats): their values ``(F, 1)`` (deg or mm, float64) and, for an
    object at infinity, each angle's sine, cosine and tangent ``(F, 1)``, computed as a single field's are (Python's
    ``math``), so that every ray is traced as it would be alone, bit for bit. Rays of ``F`` fields are ``(F, R, ...)``."""

    def __init__(self, values, device=HOST):
        vals = [float(v) for v in (values.reshape(-1).tolist() if torch.is_tensor(values) else values)]
        if not vals:
            raise ValueError("fields: at least one field")
        self._values = vals

        def col(v):
            return torch.tensor(v, dtype=torch.float64, device=device).reshape(-1, 1)

        self.field = col(vals)
        rad = [math.radians(v) for v in vals]
        self.sin, self.cos, self.tan = col([math.sin(a) for a in rad]), col([math.cos(a) for a in rad]), \
            col([math.tan(a) for a in rad])

    @property
    def values(self) -> list[float]:
        """The fields (deg or mm), in order."""
        if self._values is None:
            self._values = self.field.reshape(-1).tolist()
        return self._values

    def __len__(self) -> int:
        return self.field.shape[0]

    def to(self, device) -> "Fields":
        """The same fields with their columns on ``device`` (itself if they are there already)."""
        if self.field.device == torch.device(device):
            return self
        out = object.__new__(Fields)
        out._values = self._values
        out.field, out.sin, out.cos, out.tan = (v.to(device) for v in (self.field, self.sin, self.cos, self.tan))
        return out

    def take(self, index: torch.Tensor) -> "Fields":
        """The fields at ``index`` (a 1-D tensor of positions, repeats allowed), in that order."""
        out = object.__new__(Fields)
        out._values = None
        out.field, out.sin, out.cos, out.tan = (v[index] for v in (self.field, self.sin, self.cos, self.tan))
        return out


def _field_named(field, index=None) -> str:
    """A field's value for a message: ``field`` a float, or of :class:`Fields` the one at ``index`` (a flat index into
    rays ``(F, R)``, or the field's own)."""
    if not isinstance(field, Fields):
        return f"{field:g}"
    return f"{field.values[0 if index is None else index]:g}"


class RayTraceError(ValueError):
    """Rays that cannot be traced (a field whose chief ray misses, aiming that does not converge): the message names
    the field and what failed."""


@dataclass(frozen=True)
class ParaxialData:
    """First-order data at one wavelength (mm unless named). ``z`` positions are on the axis, surface 1's vertex at 0."""

    wavelength_um: float
    efl_mm: float
    """Focal length ``-h_1 / u'_k`` of a ray parallel to the axis (the image-side focal length; in air, the EFL)."""
    bfl_mm: float
    """Back focal distance: last surface's vertex to the paraxial focus of a parallel beam."""
    epd_mm: float
    entrance_pupil_z_mm: float
    exit_pupil_z_mm: float
    exit_pupil_diameter_mm: float
    stop_radius_mm: float
    """The stop's radius that the entrance-pupil diameter implies (paraxial)."""
    f_number: float
    """``efl / epd`` (object at infinity's F-number)."""
    working_f_number: float
    """``1 / (2 n' |u'|)`` of the marginal ray in image space (paraxial)."""
    image_z_mm: float
    """The paraxial image of the object (the focus of a parallel beam for an object at infinity)."""
    image_heights_mm: tuple[float, ...]
    """Paraxial chief-ray height at the paraxial image, per field."""


@dataclass
class RayBundle:
    """Rays after a trace: ``points (R, 3)`` and ``directions (R, 3)`` after the last surface, ``opl (R,)`` (mm, from
    the object's wavefront), ``valid (R,)`` (False: vignetted by a semi-diameter, missed a surface, totally reflected),
    ``clipped_at (R,)`` (the first surface number that stopped the ray, or whose semi-diameter it crossed, 0 if
    none), ``passed (R,)`` (True: traced and within every semi-diameter; with ``vignette=False`` ``valid`` holds the
    rays traced through the surfaces extended beyond their semi-diameters, and ``passed`` those a real lens lets
    through), ``aperture_ratio (R,)`` (the largest of the ray's height over the semi-diameter at the surfaces that have
    one, the stop aside: <= 1 where the ray passes; a smooth function of the ray, whose level 1 is the vignetting's
    edge)."""

    points: torch.Tensor
    directions: torch.Tensor
    opl: torch.Tensor
    valid: torch.Tensor
    clipped_at: torch.Tensor
    passed: torch.Tensor
    aperture_ratio: torch.Tensor
    reflected_at: torch.Tensor | None = None
    """``(R,)``: the surface number where the ray was totally internally reflected, 0 if it was not."""


@dataclass
class WavefrontMap:
    """The OPD over the pupil at one field and wavelength: pupil points ``px, py`` (unit disc of the entrance pupil),
    ``opd_waves`` (NaN where vignetted; with ``vignette=False`` NaN only where a ray cannot be traced), ``valid``, the chief ray's image point ``chief_mm (3,)``, the image-plane
    points of the rays ``image_mm (R, 3)``, and the reference sphere's radius (mm)."""

    px: torch.Tensor
    py: torch.Tensor
    opd_waves: torch.Tensor
    valid: torch.Tensor
    chief_mm: torch.Tensor
    image_mm: torch.Tensor
    reference_radius_mm: float
    aperture_ratio: torch.Tensor | None = None
    """Per ray, its largest height over a surface's semi-diameter (:attr:`RayBundle.aperture_ratio`)."""

    @property
    def vignetted_fraction(self) -> float:
        return float(1 - self.valid.to(torch.float64).mean())

    def rms_waves(self) -> float:
        """RMS of the OPD over the unvignetted pupil, piston removed, tilt kept (equal weight per sample)."""
        w = self.opd_waves[self.valid]
        return float(torch.sqrt(((w - w.mean()) ** 2).mean()))

    def pv_waves(self) -> float:
        w = self.opd_waves[self.valid]
        return float(w.max() - w.min())

    def rms_spot_mm(self) -> float:
        """RMS radius (mm) of the rays' image points about their centroid."""
        p = self.image_mm[self.valid][:, :2]
        return float(torch.sqrt(((p - p.mean(dim=0)) ** 2).sum(-1).mean()))


class SequentialLens:
    """A sequential lens (see the module docstring) built from a :class:`Prescription`.

    ``image_shift_mm`` moves the image plane along the axis from where the prescription puts it (refocusing).
    ``index_offsets``: ``{surface index (0-based): dn}``, an absolute refractive-index error added at every wavelength
    to the glass after that surface (a manufactured copy's melt: the catalogue glass keeps its dispersion); only
    glass may carry one.
    ``misalignments``: ``{surface index (0-based): Misalignment}``, each surface's decentre and tilt
    (:class:`lenssim.model.misalignment.Misalignment`; an element's from
    :func:`lenssim.model.misalignment.element_misalignment`), or a tuple of them applied in order (e.g. a surface's
    own wedge within its element, then the element's motion in the barrel); zero ones are dropped. They change the real rays only
    (module docstring): the paraxial data and the Seidel sums remain the centred lens's.
    """

    def __init__(self, prescription: Prescription, *, image_shift_mm: float = 0.0, index_offsets=None,
                 misalignments=None, numbers=None):
        self.prescription = prescription
        self.numbers = None if numbers is None else tuple(numbers)
        if self.numbers is None:
            self.image_shift_mm = float(image_shift_mm)
            self._surfs = prescription.surfaces
        else:
            self._surfs = self._check_numbers(prescription, self.numbers)
            self.image_shift_mm = image_shift_mm
        self._glasses = []
        for i, s in enumerate(prescription.surfaces):
            self._glasses.append(self._material(s.material, i + 1))
        offsets = {}
        for i, dn in dict(index_offsets or {}).items():
            if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(self._glasses):
                raise ValueError(f"index offset at surface index {i!r} is not allowed: 0 to {len(self._glasses) - 1}")
            if self._glasses[i] is None:
                raise ValueError(f"surface {i + 1}: an index offset needs a glass after the surface, not air")
            if isinstance(dn, bool) or not isinstance(dn, (int, float)) or not math.isfinite(dn):
                raise ValueError(f"surface {i + 1}: index offset {dn!r} is not allowed: a finite number")
            if dn:
                offsets[i] = float(dn)
        self.index_offsets = dict(sorted(offsets.items()))
        self._z = torch.tensor(prescription.vertex_z_mm, dtype=torch.float64, device=HOST)
        if self.numbers is None:
            self._vz = [float(z) for z in self._z]
        else:  # each vertex from the design's own thicknesses
            self._vz, z = [], 0.0
            for s in self._surfs:
                self._vz.append(z)
                z = z + s.thickness_mm
        moved = {}
        for i, m in dict(misalignments or {}).items():
            if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(self._glasses):
                raise ValueError(f"misalignment at surface index {i!r} is not allowed: 0 to {len(self._glasses) - 1}")
            motions = (m,) if isinstance(m, Misalignment) else tuple(m) if isinstance(m, (tuple, list)) else (m,)
            for one in motions:
                if not isinstance(one, Misalignment):
                    raise ValueError(f"surface {i + 1}: misalignment {one!r} is not allowed: a "
                                     "lenssim.model.misalignment.Misalignment (or a sequence of them)")
            motions = tuple(one for one in motions if not one.is_zero)
            if motions:
                moved[i] = motions[0] if len(motions) == 1 else motions
        self.misalignments = dict(sorted(moved.items()))
        self._frames = {}  # surface index -> (A (3, 3), b (3,)), float64: a nominal point X goes to A X + b
        for i, m in self.misalignments.items():
            A = torch.eye(3, dtype=torch.float64, device=HOST)
            b = torch.zeros(3, dtype=torch.float64, device=HOST)
            for one in (m,) if isinstance(m, Misalignment) else m:  # applied in order: X -> R (X - pivot) + pivot + dec
                R = torch.tensor(one.rotation_matrix(), dtype=torch.float64, device=HOST)
                pivot = torch.tensor([0.0, 0.0, float(self._z[i]) if one.pivot_z_mm is None else one.pivot_z_mm],
                                     dtype=torch.float64, device=HOST)
                dec = torch.tensor([one.decentre_x_mm, one.decentre_y_mm, 0.0], dtype=torch.float64, device=HOST)
                A, b = R @ A, R @ (b - pivot) + pivot + dec
            self._frames[i] = (A, b)

    @staticmethod
    def _check_numbers(prescription: Prescription, numbers) -> tuple:
        """The design's surfaces (:attr:`numbers`): one per surface of ``prescription``, of the same kind, their
        numbers floats or float64 tensors of one batch shape ``(B, 1)`` on one device."""
        if len(numbers) != len(prescription.surfaces):
            raise ValueError(f"numbers: {len(numbers)} surfaces given for a lens of {len(prescription.surfaces)}")
        devices = set()
        for i, (s, q) in enumerate(zip(numbers, prescription.surfaces)):
            if type(s.surface_kind) is not type(q.surface_kind) and not (s.kind == q.kind == ""):
                raise ValueError(f"numbers: surface {i + 1} is a {s.surface_kind.name}, the lens's a "
                                 f"{q.surface_kind.name}")
            for v in (s.curvature_per_mm, s.conic, s.thickness_mm, *s.aspheric_coefficients):
                if torch.is_tensor(v):
                    if v.dtype != torch.float64 or v.dim() != 2 or v.shape[1] != 1:
                        raise ValueError(f"numbers: surface {i + 1}: a tensor number must be float64 of shape (B, 1), "
                                         f"not {v.dtype} {tuple(v.shape)}")
                    devices.add(v.device)
        if len(devices) > 1:
            raise ValueError(f"numbers: tensors on several devices ({', '.join(sorted(map(str, devices)))})")
        return tuple(numbers)

    @property
    def batched(self) -> bool:
        """The lens's numbers are tensors (:attr:`numbers`): a batch of ``B`` designs, rays ``(B, R, 3)``,
        differentiable through every real-ray result."""
        return self.numbers is not None

    @property
    def batch_size(self) -> int:
        """``B``, the number of designs of a :attr:`batched` lens."""
        return max(v.shape[0] for s in self._surfs for v in (s.curvature_per_mm, s.conic, s.thickness_mm,
                                                               *s.aspheric_coefficients) if torch.is_tensor(v))

    @property
    def device(self) -> torch.device:
        """Where the rays are traced: the numbers' device (:data:`HOST` for a lens of floats)."""
        for s in self._surfs:
            for v in (s.curvature_per_mm, s.conic, s.thickness_mm, *s.aspheric_coefficients):
                if torch.is_tensor(v):
                    return v.device
        return HOST

    # -- materials -------------------------------------------------------------------------------------------------
    @staticmethod
    def _material(mat, number: int):
        if isinstance(mat, tuple):
            from ..model.glass import ModelGlass

            return None if mat == (1.0, 0.0) else ModelGlass(*mat)
        if mat.lower() == "air":
            return None
        try:
            return as_glass(mat)
        except ValueError as exc:
            raise PrescriptionError(f"surface {number}: {exc}") from None

    def index_after(self, i: int, wavelength_um: float) -> float:
        """Refractive index after surface ``i`` (0-based; air is 1)."""
        g = self._glasses[i]
        return 1.0 if g is None else float(g.index(wavelength_um)) + self.index_offsets.get(i, 0.0)

    def cache_key(self) -> str:
        """A stable text naming everything that sets this lens's optics (the prescription, the image plane, any
        index offsets and misalignments): equal keys, equal rays. Without index offsets and misalignments it is what
        it was before they existed."""
        import json

        parts = [self.prescription.to_dict(), self.image_shift_mm]
        if self.index_offsets:
            parts.append({"index_offsets": {str(k): v for k, v in self.index_offsets.items()}})
        if self.misalignments:
            parts.append({"misalignments": {str(k): m.to_dict() if isinstance(m, Misalignment) else
                                            [one.to_dict() for one in m] for k, m in self.misalignments.items()}})
        return json.dumps(parts, sort_keys=True, default=str)

    @property
    def is_centred(self) -> bool:
        """No surface decentred or tilted (the lens is rotationally symmetric about ``z``)."""
        return not self.misalignments

    def rotated(self, azimuth_deg: float) -> "SequentialLens":
        """The same lens seen in a frame turned about ``z`` (:meth:`Misalignment.rotated`): same prescription, image
        shift and index offsets, each misalignment turned so that this new lens's field along ``+y`` is this lens's
        field at image-plane azimuth ``azimuth_deg`` (degrees, from ``+y`` toward ``+x``). Its rays are this lens's
        rotated: a point or direction ``(x, y, z)`` of this lens's trace at that azimuth is ``(x c - y s, x s + y c,
        z)`` in the new lens's (``c, s = cos, sin(azimuth)``); e.g. after ``rotated(90)`` the field along ``+y`` is this
        lens's field along ``+x``, and an image point ``(x, y)`` here is ``(-y, x)`` there. A centred lens is its own
        rotation."""
        return SequentialLens(self.prescription, image_shift_mm=self.image_shift_mm, index_offsets=self.index_offsets,
                              misalignments={i: m.rotated(azimuth_deg) if isinstance(m, Misalignment) else
                                             tuple(one.rotated(azimuth_deg) for one in m)
                                             for i, m in self.misalignments.items()})

    def _to_local(self, i: int, points: torch.Tensor) -> torch.Tensor:
        """Points ``(R, 3)`` of the lens's frame in surface ``i``'s nominal frame (its misalignment undone; the
        identity for an aligned surface)."""
        if i not in self._frames:
            return points
        A, b = self._frames[i]
        return _times(points - b, A)

    @property
    def primary_wavelength_um(self) -> float:
        return self.prescription.primary_wavelength_um

    @property
    def image_z_mm(self) -> float:
        """The image plane (mm on the axis): the prescription's, moved by ``image_shift_mm`` (a tensor ``(B, 1)`` for
        a :attr:`batched` lens)."""
        if self.numbers is None:
            return self.prescription.image_z_mm + self.image_shift_mm
        return self._vz[-1] + self._surfs[-1].thickness_mm + self.image_shift_mm

    def surfaces(self, wavelength_um: float | None = None) -> list[Surface]:
        """The model's :class:`lenssim.model.surface.Surface` list at ``wavelength_um`` (default the primary)."""
        lam = self.primary_wavelength_um if wavelength_um is None else wavelength_um
        out = []
        for i, s in enumerate(self.prescription.surfaces):  # each kind as the even asphere of its third order
            c, k, a4 = s.surface_kind.seidel_terms(s)
            out.append(Surface(c, k, self.index_after(i, lam), s.thickness_mm, aspheric=s.is_aspheric,
                               semi_aperture_mm=s.semi_diameter_mm, aspheric_coefficients=(a4,) if a4 else ()))
        return out

    # -- paraxial ----------------------------------------------------------------------------------------------------
    def _ynu(self, h, u, lam, upto: int | None = None):
        """Paraxial trace from surface 1 with height ``h`` and slope ``u`` in object space (air): heights at each
        surface and the slope after each, as lists (floats)."""
        n = 1.0
        hs, us = [], []
        surfs = self._surfs
        for i, s in enumerate(surfs if upto is None else surfs[:upto + 1]):
            n2 = self.index_after(i, lam)
            u = (n * u - h * s.paraxial_curvature_per_mm * (n2 - n)) / n2
            hs.append(h)
            us.append(u)
            h = h + s.thickness_mm * u
            n = n2
        return hs, us

    def _entrance_pupil_z(self, lam) -> float:
        """The entrance pupil (mm on the axis): where a chief ray in object space, aimed at the stop's centre,
        crosses the axis (linear in the ray's height at surface 1)."""
        k = self.prescription.stop_index
        if k == 0:
            return 0.0
        ubar = 1e-3
        h_a = self._ynu(0.0, ubar, lam, k)[0][k]
        h_b = self._ynu(1.0, ubar, lam, k)[0][k]
        if _any(h_b == h_a):
            raise PrescriptionError(f"surface {k + 1}: the stop is imaged to infinity in object space (an object-space "
                                    "telecentric lens); not supported")
        h1 = -h_a / (h_b - h_a)  # the chief ray's height at surface 1
        return -h1 / ubar

    def paraxial(self, wavelength_um: float | None = None) -> ParaxialData:
        """First-order data at ``wavelength_um`` (default the primary); see :class:`ParaxialData`. Those of the centred
        lens: misalignments are left out."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        p = self.prescription
        surfs = self._surfs
        n_img = self.index_after(len(surfs) - 1, lam)
        hs, us = self._ynu(1.0, 0.0, lam)
        u_last, h_last = us[-1], hs[-1]
        if _any(u_last == 0):
            raise PrescriptionError("the lens is afocal (a parallel beam leaves it parallel): no focal length")
        efl = -1.0 / u_last * n_img / n_img  # f' = -h1 / u'_k (image-space focal length f' = n' f; air: equal)
        z_last = self._vz[-1]
        bfl = -h_last / u_last
        z_ep = self._entrance_pupil_z(lam)
        r_ep = p.entrance_pupil_diameter_mm / 2
        k = p.stop_index
        # the marginal ray from the axial object point through the rim of the entrance pupil
        if p.object_at_infinity:
            h0, u0 = r_ep, 0.0
        else:
            u0 = r_ep / (p.object_distance_mm + z_ep)
            h0 = u0 * p.object_distance_mm
        mh, mu = self._ynu(h0, u0, lam)
        stop_r = abs(mh[k])
        u_img = mu[-1]
        if torch.is_tensor(u_img):
            if _any(u_img == 0):
                raise PrescriptionError("a design's image of the object is at infinity (afocal in image space)")
            image_z = z_last - mh[-1] / u_img
        else:
            image_z = z_last + (-mh[-1] / u_img if u_img != 0 else math.inf)
        # the chief ray (unit slope in object space through the entrance pupil's centre) in image space
        ch, cu = self._ynu(-z_ep * 1e-3, 1e-3, lam)
        if torch.is_tensor(cu[-1]):
            if _any(cu[-1] == 0):
                raise PrescriptionError("a design's exit pupil is at infinity (telecentric in image space): a batch of "
                                        "designs needs a finite exit pupil")
            z_xp = z_last - ch[-1] / cu[-1]
            d_xp = 2 * abs(mh[-1] + mu[-1] * (z_xp - z_last))
        elif cu[-1] == 0:
            z_xp, d_xp = math.inf, math.inf
        else:
            z_xp = z_last - ch[-1] / cu[-1]
            d_xp = 2 * abs(mh[-1] + mu[-1] * (z_xp - z_last))
        heights = []
        for f in p.fields:
            if p.object_at_infinity:
                t = math.tan(math.radians(f))
                h1, u1 = -z_ep * t, t
            else:
                u1 = f / (p.object_distance_mm + z_ep)
                h1 = -f + u1 * p.object_distance_mm
            chh, chu = self._ynu(h1, u1, lam)
            heights.append(chh[-1] + chu[-1] * (image_z - z_last))
        return ParaxialData(lam, efl, bfl, p.entrance_pupil_diameter_mm, z_ep, z_xp, d_xp, stop_r,
                            efl / p.entrance_pupil_diameter_mm,
                            1 / (2 * n_img * abs(u_img)) if torch.is_tensor(u_img) or u_img != 0 else math.inf, image_z,
                            tuple(heights))

    def seidel_surfaces(self, field: float, wavelength_um: float | None = None) -> torch.Tensor:
        """Seidel sums ``(S_I .. S_V)`` (mm) of each surface at ``field`` (deg or mm): ``(N, 5)``, float64; the marginal
        ray at the entrance pupil's rim, the chief ray through the stop's centre; sum over the surfaces for the lens's. The
        centred lens's: misalignments are left out."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        p = self.prescription
        z_ep = self._entrance_pupil_z(lam)
        r_ep = p.entrance_pupil_diameter_mm / 2
        if p.object_at_infinity:
            h, u = r_ep, 0.0
            ubar = math.tan(math.radians(field))
            hbar = -z_ep * ubar
        else:
            u = r_ep / (p.object_distance_mm + z_ep)
            h = u * p.object_distance_mm
            ubar = field / (p.object_distance_mm + z_ep)
            hbar = -field + ubar * p.object_distance_mm
        surfs = self.surfaces(lam)
        rows = []
        for i in range(len(surfs)):  # one surface at a time, each with the rays arriving at it
            hs, us = self._ynu(h, u, lam, i)
            hbs, ubs = self._ynu(hbar, ubar, lam, i)
            n_before = 1.0 if i == 0 else surfs[i - 1].n_after
            h_i, u_i = hs[i], (u if i == 0 else us[i - 1])
            hb_i, ub_i = hbs[i], (ubar if i == 0 else ubs[i - 1])
            t = lambda v: torch.tensor(v, dtype=torch.float64, device=HOST)  # noqa: E731
            rows.append(seidel_surface_sums([surfs[i]], t(h_i), t(u_i), t(hb_i), t(ub_i), n_object=n_before))
        return torch.stack(rows)

    def chromatic_surfaces(self, short_um: float, long_um: float, wavelength_um: float | None = None) -> torch.Tensor:
        """Chromatic sums ``(C_I, C_II)`` (mm) of each surface, ``(N, 2)``: ``C_I = A h D(dn/n)``, ``C_II = Abar h
        D(dn/n)`` with ``dn = n(short) - n(long)`` (e.g. the F and C lines), rays at ``wavelength_um`` (default the
        primary); ``C_II`` for a chief ray of unit slope in object space (``tan`` of the field angle = 1: multiply by
        the field's tangent). Axial colour ``-sum C_I / (n' u'^2)`` (Welford 8.2)."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        p = self.prescription
        z_ep = self._entrance_pupil_z(lam)
        r_ep = p.entrance_pupil_diameter_mm / 2
        h, u = (r_ep, 0.0) if p.object_at_infinity else (r_ep * p.object_distance_mm / (p.object_distance_mm + z_ep),
                                                          r_ep / (p.object_distance_mm + z_ep))
        ubar = 1e-3  # per unit field slope, scaled below by the caller's field if needed
        hbar = -z_ep * ubar
        hs, us = self._ynu(h, u, lam)
        hbs, ubs = self._ynu(hbar, ubar, lam)
        rows = []
        n, dn = 1.0, 0.0
        for i, s in enumerate(p.surfaces):
            n2 = self.index_after(i, lam)
            dn2 = self.index_after(i, short_um) - self.index_after(i, long_um)
            u_in = u if i == 0 else us[i - 1]
            ub_in = ubar if i == 0 else ubs[i - 1]
            c = s.paraxial_curvature_per_mm
            A, Ab = n * (hs[i] * c + u_in), n * (hbs[i] * c + ub_in)
            d = dn2 / n2 - dn / n
            rows.append((A * hs[i] * d, Ab * hs[i] * d / ubar))
            n, dn = n2, dn2
        return torch.tensor(rows, dtype=torch.float64, device=HOST)

    # -- real rays ---------------------------------------------------------------------------------------------------
    def _intersect(self, P, d, s, z_v, valid):
        """Intersection with surface ``s`` (vertex at ``z_v``), by its kind: points, unit normals (towards -z),
        distances, the rays that meet it, and ``x^2 + y^2`` there."""
        if torch.is_tensor(z_v):  # a batch of designs: (B, 1) vertices, rays (B, R, 3)
            v = torch.stack([torch.zeros_like(z_v), torch.zeros_like(z_v), z_v], dim=-1)
        else:
            v = torch.tensor([0.0, 0.0, z_v], dtype=P.dtype, device=P.device)
        X, N, t, ok, rho = s.surface_kind.intersect(s, P - v, d, valid)
        return X + v, N, t, ok, rho

    def trace(self, starts: torch.Tensor, directions: torch.Tensor, wavelength_um: float | None = None, *,
              upto: int | None = None, opl_start: torch.Tensor | None = None, vignette: bool = True) -> RayBundle:
        """Trace rays from ``starts`` ``(R, 3)`` along ``directions`` ``(R, 3)`` (object space, air) through the
        surfaces (up to index ``upto`` included, 0-based); OPL counted from ``opl_start`` (default: the plane through
        the origin normal to each ray's direction, ``n (P . d)``). ``vignette``: clip by the semi-diameters (a
        misaligned surface's in its own frame). Points and directions are in the lens's frame, after any
        misalignment."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        P = starts.to(torch.float64)
        d = directions.to(torch.float64)
        d = d / torch.linalg.norm(d, dim=-1, keepdim=True)
        n = 1.0
        opl = n * (P * d).sum(-1) if opl_start is None else opl_start.to(torch.float64)
        valid = torch.isfinite(P).all(-1) & torch.isfinite(d).all(-1)
        clipped = torch.zeros(P.shape[:-1], dtype=torch.int64, device=P.device)
        reflected = torch.zeros_like(clipped)
        inside = torch.ones_like(valid)
        ratio = torch.zeros(P.shape[:-1], dtype=torch.float64, device=P.device)
        surfs = self._surfs
        stop = self.prescription.stop_index
        for i, s in enumerate(surfs if upto is None else surfs[:upto + 1]):
            frame = self._frames.get(i)
            if frame is None:
                X, N, t, ok, rho = self._intersect(P, d, s, self._vz[i], valid)
            else:  # in the surface's nominal frame (its motion undone), then back: distances and angles kept
                A, b = frame
                X, N, t, ok, rho = self._intersect(_times(P - b, A), _times(d, A), s, self._vz[i], valid)
                X = _times(X, A.T) + b
                N = _times(N, A.T)
            if s.semi_diameter_mm is not None and i != stop:
                within = rho <= s.semi_diameter_mm**2 * (1 + 1e-12)
                ratio = torch.maximum(ratio, torch.sqrt(rho.clamp(min=0)) / s.semi_diameter_mm)
                clipped = torch.where(ok & inside & ~within & (clipped == 0), i + 1, clipped)
                inside = inside & within
                if vignette:
                    ok = ok & within
            n2 = self.index_after(i, lam)
            met = ok
            d2, ok = refract(d, N, n, n2, ok)
            reflected = torch.where(met & ~ok & (reflected == 0), i + 1, reflected)
            clipped = torch.where(valid & ~ok & (clipped == 0), i + 1, clipped)
            valid = ok
            opl = opl + n * t
            P, d, n = X, d2, n2
        return RayBundle(P, d, opl, valid, clipped, valid & inside, ratio, reflected)

    # -- aiming ------------------------------------------------------------------------------------------------------
    def _beam(self, field: float, x, y, lam, z_start):
        """Rays of a field, parametrised by ``(x, y)``: the point on the plane ``z_start`` (object at infinity) or the
        point on the plane of surface 1's vertex the ray aims at (finite object). Returns starts, directions, OPL."""
        p = self.prescription
        several = isinstance(field, Fields)
        if p.object_at_infinity:
            if several:  # (F, 1, 3), each field's direction
                d = torch.stack([torch.zeros_like(field.sin), field.sin, field.cos], dim=-1).expand(*x.shape, 3)
            else:
                a = math.radians(field)
                d = torch.tensor([0.0, math.sin(a), math.cos(a)], dtype=torch.float64, device=x.device)
                d = d.expand(*x.shape, 3)
            z = z_start.expand_as(x) if torch.is_tensor(z_start) else torch.full_like(x, z_start)
            P = torch.stack([x, y, z], dim=-1)
            return P, d, None
        if several:
            O = torch.stack([torch.zeros_like(field.field), -field.field,
                             torch.full_like(field.field, -p.object_distance_mm)], dim=-1).expand(*x.shape, 3)
        else:
            O = torch.tensor([0.0, -field, -p.object_distance_mm], dtype=torch.float64, device=x.device)
        if self.numbers is not None:  # surface 1's vertex is at z = 0 whatever the design: the object does not move
            O = O.expand(*x.shape, 3)
        target = torch.stack([x, y, torch.zeros_like(x)], dim=-1)
        d = target - O
        P = O.expand_as(d)
        return P, d, torch.zeros_like(x)

    def aimed_stop_radius_mm(self, wavelength_um: float | None = None) -> float:
        """The stop radius (mm) the real aiming fills at ``wavelength_um`` (default the primary), as the prescription's
        ``stop_size`` says (:data:`lenssim.model.prescription.STOP_SIZES`): the paraxial marginal ray's height at the
        stop, or the height there of the real axial ray through the paraxial entrance pupil's rim (in the stop's own
        frame if it is misaligned)."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        par = self.paraxial(lam)
        if self.prescription.stop_size == "paraxial":
            return par.stop_radius_mm
        one = torch.ones(1, dtype=torch.float64, device=self.device)
        P, d, o = self.aim(0.0, 0 * one, one, lam, method="paraxial")
        b = self.trace(P, d, lam, upto=self.prescription.stop_index, opl_start=o, vignette=False)
        if not bool(b.valid.all()):
            raise RayTraceError(f"the axial ray through the entrance pupil's rim ({lam:g} um) does not reach the stop "
                                f"(surface {self.prescription.stop_surface}): the stop cannot be sized by real rays")
        local = self._to_local(self.prescription.stop_index, b.points)
        if self.numbers is not None:
            return local[..., :2].norm(dim=-1)  # (B, 1)
        return float(local[0, :2].norm())

    def aim(self, field, px: torch.Tensor, py: torch.Tensor, wavelength_um: float | None = None,
            method: str = "real"):
        """Rays of ``field`` (deg or mm; or :class:`Fields`, several at once: rays ``(F, R, 3)``, each field's as if
        aimed alone, bit for bit) through pupil points ``(px, py)`` (unit disc): ``(starts, directions,
        opl_start)`` (a start of NaN, not traced, where the aiming did not converge for a point beyond the unit disc or
        a ray that would not pass the lens's semi-diameters; for a ray within the disc that would pass it is a
        :class:`RayTraceError`). ``method``: ``"real"`` (each ray meets the stop surface at
        ``(px, py)`` times the stop's radius,
        in the stop's own frame if it is decentred or tilted; Newton on real rays) or ``"paraxial"`` (through the
        paraxial entrance pupil at ``(px, py)`` times its radius).

        A :attr:`batched` lens gives rays ``(B, R, 3)`` (its device), the same pupil points for every design; the
        real aiming's Newton steps run without a gradient and one last step carries it (the implicit function
        theorem: at convergence the aimed ray's derivative in the design's numbers is ``-J^-1 dr/dnumbers``, ``J`` the
        stop point's Jacobian in the ray), leaving the rays' values those of the converged search."""
        if method not in AIM_METHODS:
            raise ValueError(f"ray aiming {method!r} is not known; one of {', '.join(AIM_METHODS)}")
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        p = self.prescription
        par = self.paraxial(lam)
        r_ep = p.entrance_pupil_diameter_mm / 2
        batch = self.numbers is not None
        several = isinstance(field, Fields)
        if several and batch:
            raise ValueError("several fields at once are traced through a lens of floats, not a batch of designs")
        px = px.to(torch.float64).reshape(-1)
        py = py.to(torch.float64).reshape(-1)
        if batch:
            px, py = px.to(self.device), py.to(self.device)
        if several:  # the fields' columns follow the pupil points' device
            field = field.to(px.device)
        z_ep = par.entrance_pupil_z_mm
        if p.object_at_infinity:
            # a plane before the lens and the entrance pupil
            z_start = (torch.clamp(z_ep, max=0.0) if torch.is_tensor(z_ep) else min(0.0, z_ep)) - r_ep
            t = field.tan if several else math.tan(math.radians(field))
            x0, y0 = px * r_ep, py * r_ep + (z_start - z_ep) * t
        else:
            z_start = 0.0
            s = p.object_distance_mm / (p.object_distance_mm + z_ep)  # from the object through the pupil to z = 0
            f = field.field if several else field
            x0 = px * r_ep * s
            y0 = -f + (py * r_ep + f) * s
        if batch or several:  # every design's rays (B, R), or every field's (F, R)
            shape = (self.batch_size if batch else len(field), px.shape[0])
            x0, y0 = torch.broadcast_to(x0, shape), torch.broadcast_to(y0, shape)
        x, y = x0.clone(), y0.clone()
        if method == "paraxial":
            return self._beam(field, x, y, lam, z_start)
        k = p.stop_index
        stop_r = self.aimed_stop_radius_mm(lam)
        target = torch.stack([px, py], dim=-1) * (stop_r.unsqueeze(-1) if torch.is_tensor(stop_r) else stop_r)

        def at_stop(xv, yv, fld=field):
            P, d, o = self._beam(fld, xv, yv, lam, z_start)
            b = self.trace(P, d, lam, upto=k, opl_start=o, vignette=False)
            return self._to_local(k, b.points)[..., :2], b.valid  # in the stop's own frame if it is misaligned

        h = FD_STEP * r_ep

        def newton_step(s0, ok, r, xv=None, yv=None, fld=field):
            """The Newton step ``J^-1 r`` (where it can be taken, else 0) at ``(xv, yv)`` (default ``(x, y)``), ``J``
            by differences (no gradient: only ``r`` may carry one)."""
            xv, yv = (x, y) if xv is None else (xv, yv)
            with torch.no_grad():
                s0 = s0.detach()
                sx, okx = at_stop(xv + h, yv, fld)
                sy, oky = at_stop(xv, yv + h, fld)
                J = torch.stack([(sx - s0) / h, (sy - s0) / h], dim=-1)  # (R, 2 [stop xy], 2 [x, y])
                det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
                good = ok & okx & oky & (det.abs() > 0)
                det = torch.where(good, det, torch.ones_like(det))
            dx = (J[..., 1, 1] * r[..., 0] - J[..., 0, 1] * r[..., 1]) / det
            dy = (-J[..., 1, 0] * r[..., 0] + J[..., 0, 0] * r[..., 1]) / det
            return torch.where(good, dx, torch.zeros_like(dx)), torch.where(good, dy, torch.zeros_like(dy))

        if not batch:  # a lens of floats: each ray steps until it has converged, and only those are traced
            x, y = self._aim_rays(field if several else Fields([field], device=px.device), x, y, px, py, lam, z_start,
                                  target, stop_r, at_stop, newton_step)
            return self._beam(field, x, y, lam, z_start)
        grad = torch.is_grad_enabled()
        converged = False
        with torch.no_grad() if grad else contextlib.nullcontext():
            for _ in range(AIM_ITERATIONS):
                s0, ok = at_stop(x, y)
                r = s0 - target
                if bool(((r.abs().amax(-1) <= AIM_TOLERANCE * stop_r) | ~ok).all()):
                    converged = True
                    break
                dx, dy = newton_step(s0, ok, r)
                x = x - dx
                y = y - dy
        if grad:  # the implicit step: zero in value, -J^-1 dr/dnumbers in derivative
            s0, ok = at_stop(x, y)
            dx, dy = newton_step(s0, ok, s0 - target)
            x = x - (dx - dx.detach())
            y = y - (dy - dy.detach())
        if not converged:
            s0, ok = at_stop(x, y)
            bad = ok & ((s0 - target).abs().amax(-1) > AIM_TOLERANCE * stop_r)
            if bool(bad.any()):
                x = self._unaimed(field, bad, x, y, px, py, lam, z_start)
        return self._beam(field, x, y, lam, z_start)

    def _aim_rays(self, fields: Fields, x, y, px, py, lam, z_start, target, stop_r, at_stop, newton_step):
        """The real aiming of a lens of floats (:meth:`aim`): the rays of every field of ``fields`` (starting points
        ``x, y``, ``(R,)`` for one field or ``(F, R)``) as one flat bundle, each ray taking Newton steps until it meets
        its target within :data:`AIM_TOLERANCE` (or cannot be traced to the stop), then left where it is, so a ray
        is what it would be traced alone, in any bundle, bit for bit. Returns ``x, y`` of the input's shape (NaN where
        the aiming was tolerated not to converge)."""
        shape = x.shape
        F, R = len(fields), px.shape[0]
        X, Y = x.reshape(-1).clone(), y.reshape(-1).clone()
        rows = torch.arange(F, device=X.device).repeat_interleave(R)
        goal = target.reshape(-1, 2).repeat(F, 1)  # (F R, 2)
        tol = AIM_TOLERANCE * stop_r

        def at(idx, fld):
            s, o = at_stop(X[idx, None], Y[idx, None], fld)
            return s[:, 0], o[:, 0]

        active = torch.arange(F * R, device=X.device)
        s0, ok = at(active, fields.take(rows))
        for _ in range(AIM_ITERATIONS):
            r = s0[active] - goal[active]
            left = ((r.abs().amax(-1) > tol) & ok[active])
            active, r = active[left], r[left]
            if not active.numel():
                break
            fld = fields.take(rows[active])
            dx, dy = newton_step(s0[active, None], ok[active, None], r[:, None], X[active, None], Y[active, None], fld)
            X[active], Y[active] = X[active] - dx[:, 0], Y[active] - dy[:, 0]
            s0[active], ok[active] = at(active, fld)
        else:
            r = s0[active] - goal[active]
            active = active[(r.abs().amax(-1) > tol) & ok[active]]
        if active.numel():  # not converged in AIM_ITERATIONS steps
            bad = torch.zeros(F * R, dtype=torch.bool, device=X.device)
            bad[active] = True
            X = self._unaimed(fields, bad.reshape(F, R), X.reshape(F, R), Y.reshape(F, R), px, py, lam,
                              z_start).reshape(-1)
        return X.reshape(shape), Y.reshape(shape)

    def _unaimed(self, field, bad, x, y, px, py, lam, z_start):
        """``x`` with NaN at the rays ``bad`` whose aiming did not converge, where that is tolerated (not traced): a
        point beyond the unit disc (a table's margin for interpolation), or a ray that would not pass the lens where
        the search stopped (grazing a rim it is vignetted by); any other is a :class:`RayTraceError` naming its
        field."""
        P, d, o = self._beam(field, x, y, lam, z_start)
        passes = self.trace(P, d, lam, opl_start=o, vignette=False).passed
        fatal = bad & (px.square() + py.square() <= 1.0) & passes
        if bool(fatal.any()):
            several = isinstance(field, Fields)
            j = int(torch.nonzero(fatal.reshape(-1, fatal.shape[-1]).any(-1))[0]) if several else 0
            one = fatal.reshape(-1, fatal.shape[-1])[j] if several else fatal
            raise RayTraceError(f"field {_field_named(field, j)}: ray aiming at the stop (surface "
                                f"{self.prescription.stop_index + 1}) did not converge in {AIM_ITERATIONS} steps for "
                                f"{int(one.sum())} of {one.numel()} pupil points")
        return torch.where(bad, torch.full_like(x, math.nan), x)

    # -- wavefront ---------------------------------------------------------------------------------------------------
    def wavefront(self, field, px: torch.Tensor, py: torch.Tensor, wavelength_um: float | None = None, *,
                  aim: str = "real", reference_mm: tuple[float, float] | None = None,
                  vignette: bool = True) -> WavefrontMap:
        """The OPD (waves at ``wavelength_um``, default the primary) at pupil points ``(px, py)`` of ``field`` against
        the reference sphere centred on the chief ray's point on the image plane (or on the image-plane point
        ``reference_mm = (x, y)`` mm: the OPD then holds the tilt that moves the image from there to where the rays
        go), through the chief ray's point on the paraxial exit pupil's plane (a plane there if the exit pupil is at
        infinity: then the chief ray's point is the reference). ``vignette=False``: the OPD also where a ray crosses
        a semi-diameter (the surfaces extended), ``valid`` still False there (the smooth continuation of the wavefront
        beyond the vignetting's edge).

        A :attr:`batched` lens gives every design's map at once: ``opd_waves``, ``valid (B, R)``, ``chief_mm (B, 3)``,
        ``image_mm (B, R, 3)``, the radius ``(B,)``, differentiable in the design's numbers; ``reference_mm`` may then
        hold tensors ``(B,)``. Several fields at once (``field`` a :class:`Fields` of ``F``, a lens of floats): the
        same leading axis ``(F, ...)``, each field's map what it would be alone, bit for bit; ``reference_mm`` then
        holds a value per field."""
        return self.through_focus(field, px, py, wavelength_um, aim=aim, vignette=vignette)(reference_mm=reference_mm)

    def through_focus(self, field, px: torch.Tensor, py: torch.Tensor, wavelength_um: float | None = None, *,
                      aim: str = "real", vignette: bool = True):
        """:meth:`wavefront` as a function of a further image-plane shift: ``at(shift_mm=0.0, reference_mm=None)``
        gives the map :meth:`wavefront` gives (the same numbers, bit for bit) for this lens with its image plane moved
        ``shift_mm`` (mm) further along the axis. The rays are traced once, here: moving the plane moves only the
        reference sphere (its centre, and its radius through the exit pupil), so a focus search costs a trace per
        field, not per plane."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        par = self.paraxial(lam)
        n_img = self.index_after(len(self.prescription.surfaces) - 1, lam)
        batch = self.numbers is not None
        several = isinstance(field, Fields)
        lead = batch or several  # a leading axis: designs (B, ...) or fields (F, ...)
        dev = self.device if batch else px.device
        zero = torch.zeros(1, dtype=torch.float64, device=dev)
        P0, d0, o0 = self.aim(field, zero, zero, lam, aim)
        chief = self.trace(P0, d0, lam, opl_start=o0)
        if not bool(chief.valid.all()):
            j = int(torch.nonzero(~chief.valid.reshape(-1))[0])
            where = int(chief.clipped_at.reshape(-1)[j])
            raise RayTraceError(f"field {_field_named(field, j if several else None)}: the chief ray does not pass "
                                f"(stopped at surface {where}: its semi-diameter, a missed surface or total internal "
                                "reflection)")
        P, d, o = self.aim(field, px, py, lam, aim)
        rays = self.trace(P, d, lam, opl_start=o, vignette=vignette)
        z_xp0 = par.exit_pupil_z_mm

        def at(shift_mm: float = 0.0, reference_mm: tuple[float, float] | None = None) -> WavefrontMap:
            z_img, z_xp = self.image_z_mm + shift_mm, z_xp0
            if batch:  # as (B, 1) tensors whichever numbers are free
                z_img, z_xp = (torch.as_tensor(v, dtype=torch.float64, device=dev).expand(self.batch_size, 1)
                               for v in (z_img, z_xp))
            cp, cd = chief.points[..., 0, :], chief.directions[..., 0, :]  # (3,), or (B, 3) for a batch
            Q = cp + ((z_img - cp[..., 2:]) / cd[..., 2:]) * cd
            finite_xp = True if torch.is_tensor(z_xp) else math.isfinite(z_xp)  # a batch's is finite (paraxial())
            if reference_mm is not None:
                if not finite_xp:
                    raise ValueError("reference_mm needs an exit pupil at a finite distance (this lens is telecentric "
                                     "in image space)")
                if batch:
                    rx, ry = (torch.as_tensor(v, dtype=torch.float64, device=dev).reshape(-1, 1) for v in reference_mm)
                    Q = torch.cat([rx.expand_as(z_img), ry.expand_as(z_img), z_img], dim=-1)
                elif several:  # a point per field (F, 3)
                    rx, ry = (torch.as_tensor(v, dtype=torch.float64, device=dev).reshape(-1, 1).expand(len(field), 1)
                              for v in reference_mm)
                    Q = torch.cat([rx, ry, torch.full_like(rx, z_img)], dim=-1)
                else:
                    Q = torch.tensor([float(reference_mm[0]), float(reference_mm[1]), z_img], dtype=torch.float64,
                                     device=px.device)
            Qr = Q.unsqueeze(-2)  # against the rays (R, 3) or (B, R, 3)
            if finite_xp:
                E = cp + ((z_xp - cp[..., 2:]) / cd[..., 2:]) * cd
                R2 = ((Q - E) ** 2).sum(-1, keepdim=True)
                # the chief ray's path to the sphere
                rc = chief.opl[..., :1] + n_img * ((E - cp) * cd).sum(-1, keepdim=True)
                b = ((rays.points - Qr) * rays.directions).sum(-1)
                c = ((rays.points - Qr) ** 2).sum(-1) - R2
                root = torch.sqrt(torch.clamp(b * b - c, min=0.0))
                s_plane = (z_xp - rays.points[..., 2]) / rays.directions[..., 2]
                s1, s2 = -b - root, -b + root
                s = torch.where((s1 - s_plane).abs() <= (s2 - s_plane).abs(), s1, s2)
                valid = rays.valid & (b * b - c >= 0)
                radius = torch.sqrt(R2)[..., 0] if lead else float(torch.sqrt(R2))
            else:  # image-space telecentric: the reference "sphere" is the plane through the chief ray normal to it
                rc = chief.opl[..., :1]
                s = (((cp.unsqueeze(-2) - rays.points) * cd.unsqueeze(-2)).sum(-1)
                     / (rays.directions * cd.unsqueeze(-2)).sum(-1))
                valid = rays.valid
                radius = math.inf
            W = (rc - (rays.opl + n_img * s)) / (lam * 1e-3)
            img = (rays.points
                   + ((z_img - rays.points[..., 2]) / rays.directions[..., 2]).unsqueeze(-1) * rays.directions)
            W = torch.where(valid, W, torch.full_like(W, math.nan))  # traced (through extended surfaces unless vignette)
            valid = valid & rays.passed
            return WavefrontMap(px.reshape(-1).to(torch.float64), py.reshape(-1).to(torch.float64), W, valid, Q, img,
                                radius, rays.aperture_ratio)

        return at

    def paraxial_beam_heights_mm(self, wavelength_um: float | None = None) -> list[float]:
        """Per surface, the paraxial beam's extent (mm): the axial marginal ray's height plus the chief ray's at the
        largest field (object at infinity: field angle; finite: object height)."""
        lam = self.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
        p = self.prescription
        z_ep = self.paraxial(lam).entrance_pupil_z_mm
        r_ep = p.entrance_pupil_diameter_mm / 2
        f = max(p.fields) if p.fields else 0.0
        if p.object_at_infinity:
            h0, u0 = r_ep, 0.0
            t = math.tan(math.radians(f))
            h1, u1 = -z_ep * t, t
        else:
            u0 = r_ep / (p.object_distance_mm + z_ep)
            h0 = u0 * p.object_distance_mm
            u1 = f / (p.object_distance_mm + z_ep)
            h1 = -f + u1 * p.object_distance_mm
        mh = self._ynu(h0, u0, lam)[0]
        ch = self._ynu(h1, u1, lam)[0]
        return [abs(a) + abs(b) for a, b in zip(mh, ch)]

    def check_aperture(self) -> None:
        """Refuse, in one line naming the surface and the quantity, a lens whose axial beam (the entrance-pupil
        diameter the prescription gives, at every wavelength, through the surfaces extended beyond their
        semi-diameters) does not pass: a surface it misses or where it is totally internally reflected; or whose stop
        is smaller than the entrance pupil says (its semi-diameter below the stop radius the entrance-pupil diameter
        implies at the primary wavelength, beyond :data:`APERTURE_SLACK`). A surface whose semi-diameter clips part of
        a beam is vignetting, reported per field (:attr:`WavefrontMap.vignetted_fraction`), not refused: a fast lens's
        real beam differs from the paraxial one (pupil aberration)."""
        p = self.prescription
        k = p.stop_index
        t = torch.linspace(0, 2 * math.pi, AXIAL_RIM_RAYS + 1, dtype=torch.float64, device=HOST)[:-1]
        px, py = torch.cos(t), torch.sin(t)
        sd = p.surfaces[k].semi_diameter_mm
        stop_r = self.aimed_stop_radius_mm()
        if sd is not None and stop_r > sd * (1 + APERTURE_SLACK):  # at the primary wavelength, as the
            lam = self.primary_wavelength_um  # optical-design programs size the stop from the entrance pupil
            raise PrescriptionError(f"surface {k + 1} (the stop): the entrance-pupil diameter "
                                    f"{p.entrance_pupil_diameter_mm:g} mm needs a stop radius of "
                                    f"{stop_r:.4g} mm at {lam:g} um ({p.stop_size} stop size), larger than its semi-diameter "
                                    f"{sd:g} mm")
        for lam in p.wavelengths_um:
            field = 0.0
            P, d, o = self.aim(field, px, py, lam, method="paraxial")
            b = self.trace(P, d, lam, opl_start=o, vignette=False)
            if not bool(b.valid.all()):
                j = int(torch.nonzero(~b.valid)[0])
                n = int(b.clipped_at[j])
                how = "is totally internally reflected" if int(b.reflected_at[j]) == n else "misses the surface"
                raise PrescriptionError(f"surface {n}: the axial beam's rim (entrance-pupil diameter "
                                        f"{p.entrance_pupil_diameter_mm:g} mm, {lam:g} um) {how}")

    def paraxial_heights(self, fields, wavelength_um: float | None = None) -> list[float]:
        """Paraxial chief-ray heights (mm) on the paraxial image plane at ``fields`` (deg or mm)."""
        from dataclasses import replace

        seq = SequentialLens(replace(self.prescription, fields=tuple(fields)), image_shift_mm=self.image_shift_mm,
                             index_offsets=self.index_offsets)  # paraxial: the centred lens's
        return list(seq.paraxial(wavelength_um).image_heights_mm)


def pupil_grid(n: int, dtype=torch.float64):
    """Points of an ``n x n`` square grid inside the unit disc (equal area per point): ``(px, py)``."""
    g = (torch.arange(n, dtype=dtype, device=HOST) + 0.5) / n * 2 - 1
    Y, X = torch.meshgrid(g, g, indexing="ij")
    inside = X**2 + Y**2 <= 1
    return X[inside], Y[inside]


# -- model surfaces (the singlet's exact trace is this one) ------------------------------------------------------------
def surfaces_lens(surfaces: list[Surface]) -> SequentialLens:
    """The :class:`SequentialLens` of model surfaces at one wavelength (:class:`lenssim.model.surface.Surface`, e.g.
    :meth:`lenssim.Lens.surfaces`: curvatures, conics, even-asphere terms, the index after each, the separations, each
    surface's decentre and its tilt about its vertex, about x then y), surface 1's vertex at ``z = 0`` (a zero
    separation is the thin lens's limit: a ray may travel a signed negative distance, its optical path with its
    sign). What :func:`trace_rays_opl` reads is the surfaces only: the stop is surface 1, the entrance pupil 1 mm
    across, the image plane 1 mm after the last surface."""
    surfs, moved = [], {}
    for i, s in enumerate(surfaces):
        if any(torch.is_tensor(v) and v.requires_grad for v in (s.curvature, s.conic, s.n_after, s.thickness_after_mm)):
            raise ValueError("the real-ray trace takes the surfaces' numbers, not a gradient through them: give "
                             "surfaces without requires_grad (the third-order route is differentiable)")
        n = float(s.n_after)
        surfs.append(PrescriptionSurface(float(s.curvature), 1.0 if i == len(surfaces) - 1 else float(s.thickness_after_mm),
                                         AIR if n == 1 else (n, 0.0), conic=float(s.conic),
                                         aspheric_coefficients=tuple(float(a) for a in s.aspheric_coefficients)))
        (dx, dy), (tx, ty) = s.decentre_mm, s.tilt_deg
        if dx or dy or tx or ty:  # the tilt about x, then about y and the decentre
            moved[i] = (Misalignment(tilt_x_deg=tx), Misalignment(decentre_x_mm=dx, decentre_y_mm=dy, tilt_y_deg=ty))
    return SequentialLens(Prescription(tuple(surfs), 1, 1.0), misalignments=moved)


def trace_rays_opl(surfaces, starts: torch.Tensor, direction: torch.Tensor):
    """Trace rays from ``starts`` ``(*, 3)`` along ``direction`` ``(3,)`` or ``(*, 3)`` (object space, air) through
    model surfaces (a list, :func:`surfaces_lens`; or that lens) extended beyond their apertures. Returns
    ``(points, directions, opl)``: each ray's point on the last surface ``(*, 3)`` (mm), its unit direction after it
    ``(*, 3)``, and its optical path (mm) from the plane through the origin normal to its incoming direction (a plane
    wavefront of the object at infinity), float64. ``ValueError`` if a ray misses a surface or is totally internally
    reflected."""
    seq = surfaces if isinstance(surfaces, SequentialLens) else surfaces_lens(surfaces)
    shape = starts.shape
    b = seq.trace(starts.reshape(-1, 3), direction.expand(shape).reshape(-1, 3), vignette=False)
    if not bool(b.valid.all()):
        raise ValueError("a ray misses a surface or is totally internally reflected in the ray trace; reduce the "
                         "aperture or field")
    return b.points.reshape(shape), b.directions.reshape(shape), b.opl.reshape(shape[:-1])


def trace_rays(surfaces, starts: torch.Tensor, direction: torch.Tensor, z_image_mm: float) -> torch.Tensor:
    """:func:`trace_rays_opl`'s rays on the plane ``z = z_image_mm``: their points ``(*, 3)`` (mm)."""
    P, d, _ = trace_rays_opl(surfaces, starts, direction)
    return P + ((z_image_mm - P[..., 2]) / d[..., 2]).unsqueeze(-1) * d
