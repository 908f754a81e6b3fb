"""Outside cross-check of lenssim's sequential ray tracer against Optiland (an independent optical-design library).

For each shipped lens (``configs/lenses/*.toml``) the script builds the same lens in Optiland from our prescription
and compares, at the primary wavelength:

* paraxial data: EFL, BFL, entrance-pupil diameter and position, F-number, exit-pupil position and diameter;
* per field of the file, the image plane where the file puts it: RMS OPD (waves; piston removed, tilt kept) and
  peak-to-valley OPD over the unvignetted pupil, RMS spot radius (um) about the centroid, the vignetted fraction of the
  pupil samples and the real chief ray's image height.

Like with like:

* glasses: Optiland gets, at every wavelength, the index our model glass gives (a material wrapping
  :meth:`lenssim.optics.sequential.SequentialLens.index_after`), so the catalogues are not what is compared;
* pupil sampling: the same points on both sides, ours (``pupil_grid(64)``: a 64 x 64 grid, cell centred, inside the
  unit disc, equal area per point), given to Optiland as a custom distribution;
* ray aiming (``--aim real``, the default): ours aims each pupil point ``(px, py)`` at the stop surface, at
  ``(px, py)`` times the stop's *paraxial* radius (Newton on real rays). Optiland's real aiming ("iterative")
  normally targets the real marginal ray's height at the stop (the ray entering at EPD / 2): a different scaling of
  the same aiming, not a different trace. To compare like with like its system aperture is set to "float by stop
  size" with the stop's paraxial diameter (Optiland's own paraxial marginal-ray height at the stop, x 2), which makes
  its real aimers target ``(Px, Py)`` times that radius; the "stop radius, real-aim target" rows show how far
  Optiland's default target is from that. A lens whose file says ``[aperture] stop_size = "real"`` (the stop sized
  by the real axial ray, :data:`lenssim.model.prescription.STOP_SIZES`) is compared with Optiland's own EPD aperture
  and real aiming, which is that convention (``tests/data/lenses/cooke_stop_inside.toml``, stop inside the lens:
  the two conventions differ by 2.7% of the RMS OPD at 20 deg, and each agrees with Optiland's to ~1e-6;
  ``tests/lenssim/test_stop_inside.py`` holds the figures). The script uses Optiland's "robust" aimer (the "iterative" aimer's Newton
  polish, tolerance 1e-9 mm at the stop), which returns NaN for a ray that cannot reach its stop point instead of
  aborting the batch: "iterative" fails on the double Gauss at 12.41 deg, where 24 rim rays miss a surface (ours too
  finds them untraceable, even through the surfaces extended beyond their semi-diameters). ``--aim paraxial``: both sides aim through the paraxial entrance pupil
  (Optiland's default, ours with ``aim="paraxial"``);
* vignetting: every clear semi-diameter of the file is an Optiland radial aperture on that surface, except the stop's
  (ours does not clip at the stop; on the Optiland side the stop's aperture is its paraxial radius, which aimed rays do
  not reach), so both sides drop the same rays; the table gives each side's vignetted fraction;
* OPD: both take the reference sphere centred on the real chief ray's point on the image plane, through the paraxial
  exit pupil (ours: through the chief ray's point on the exit pupil's plane; Optiland: through the exit pupil's axial
  point), sign ``OPL(chief) - OPL(ray)``; Optiland's ``OPD.rms()`` keeps piston, so here the mean of the unvignetted
  samples is removed from Optiland's OPD before the RMS (tilt kept, as ours).

What the comparison found (Optiland 0.6.3, 64 x 64 grid): paraxial data agree to ~1e-15 relative; rays (spot, chief
ray heights, vignetting) to ~1e-11; the OPD to ~1e-10 waves per sample on axis and ~1e-9 waves off axis once two
things are accounted for, neither an error of either trace (one is a default of Optiland's, one a convention):

* Optiland's surface factory gives even aspheres a Newton tolerance of 1e-6 mm on the sag residual (``tol`` in
  ``surfaces.add``; the geometry class's own default is 1e-10): the conic seed is accepted wherever the asphere's
  departure is below 1e-6 mm, i.e. near the axis (the aspheric singlet's innermost samples are ~2.9e-4 waves off, the
  on-axis PV 1.3e-3 relative). The script passes ``tol=1e-12`` (``--asphere-tol``);
* the reference sphere's radius: ours runs from the chief ray's image point to the chief ray's point on the paraxial
  exit pupil's plane, Optiland's to the exit pupil's point on the axis. Off axis the radii differ (by 0.3 mm of 188 mm
  for the double Gauss at 12.41 deg), which changes the OPD by up to 2.4e-3 waves per sample (RMS 2e-5 relative);
  recomputed with Optiland's radius ours agrees to ~3e-9 waves. The "reference sphere radius" rows show it.

Ours come from :meth:`SequentialLens.wavefront` on the same grid (``lenssim inspect`` reports the same figures, on a
pupil grid it refines until the OPD is sampled for its Strehl ratio and MTF).

A misaligned lens (``--misaligned``, :func:`misaligned_case`): the Cooke triplet with its second element decentred
0.05 mm in y and tilted 0.1 deg about x (an element tilt, pivot at surface 3's vertex) and its stop decentred (0.05,
-0.03) mm and tilted 0.2 deg about y; on the Optiland side each moved surface's coordinate system gets the same rigid
motion (:func:`misalign_optic`: the same right-handed rotation about x or y, the vertex moved where ours goes). Both
keep the centred lens's first-order data (Optiland warns that its paraxial trace takes the surfaces as centred) and
both real aimers put the pupil on the moved stop in its own frame. Besides the table rows (now with the chief ray's
image x), the same rays (ours, aimed) are traced by both tracers from the same start points to the image plane. What
it found (Optiland 0.6.3, 64 x 64 grid): the same rays agree to 6e-14 mm in the image plane, 2.4e-15 in direction
and 3e-13 mm in optical path; with real aiming the chief ray's image point to ~1e-11 mm (its x, 1e-4 mm from the
stop's decentre, to 5e-13 relative), the vignetted fractions exactly, RMS spot to 1e-11 relative, RMS OPD to 8e-10
relative on axis and 2e-8 / 1e-6 off axis (the reference sphere's radius, as for the centred lenses above).

Run: ``python benchmarks/crosscheck_optiland.py [--lens NAME ...] [--aim real|paraxial|both] [--grid 64]
[--misaligned]``. Needs the ``bench`` extra (``optiland``). Downloads nothing.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings

import numpy as np

SHIPPED = ("cooke_triplet", "double_gauss", "aspheric_singlet", "paper_singlet")


def _optiland():
    try:
        import optiland  # noqa: F401
    except ImportError:
        sys.exit("optiland is not installed: pip install -e '.[bench]' (or pip install optiland==0.6.3)")
    import optiland.backend as be
    from optiland.distribution import BaseDistribution
    from optiland.materials.base import BaseMaterial

    class LenssimGlass(BaseMaterial):
        """An Optiland material whose index is lenssim's glass after surface ``i`` (0-based) of ``seq``."""

        def __init__(self, seq, i):
            super().__init__()
            self._seq, self._i = seq, i

        def _cache_state(self):
            return ()  # immutable: the index depends on the wavelength only

        def _calculate_n(self, wavelength, **kwargs):
            w = np.asarray(be.to_numpy(wavelength), dtype=np.float64)
            uniq, inv = np.unique(w.reshape(-1), return_inverse=True)
            n = np.array([self._seq.index_after(self._i, float(v)) for v in uniq])[inv].reshape(w.shape)
            return be.array(n) if n.ndim else float(n)

        def _calculate_k(self, wavelength, **kwargs):
            w = np.asarray(be.to_numpy(wavelength), dtype=np.float64)
            return be.array(np.zeros_like(w)) if w.ndim else 0.0

    class FixedPoints(BaseDistribution):
        """Pupil points given from outside (ours)."""

        def __init__(self, x, y):
            super().__init__()
            self.x, self.y = be.array(np.asarray(x, dtype=np.float64)), be.array(np.asarray(y, dtype=np.float64))

        def generate_points(self, num_points=None):
            pass

    return LenssimGlass, FixedPoints


def build_optic(p, seq, aim: str, LenssimGlass, asphere_tol_mm: float = 1e-12):
    """The Optiland :class:`Optic` of prescription ``p`` (see the module docstring). ``aim``: "real" (iterative
    aiming, aperture = the stop's paraxial diameter, or the EPD if the lens's stop size is "real") or "paraxial"
    (paraxial aiming, aperture = the EPD)."""
    import optiland.backend as be
    from optiland.optic import Optic
    from optiland.physical_apertures import RadialAperture

    if not p.object_at_infinity:
        raise ValueError("this cross-check handles objects at infinity (field angles) only")
    op = Optic(name=p.name)
    op.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    k = p.stop_index
    for i, s in enumerate(p.surfaces):
        kw = dict(radius=be.inf if s.curvature_per_mm == 0 else 1.0 / s.curvature_per_mm, thickness=s.thickness_mm,
                  conic=s.conic)
        if s.aspheric_coefficients:
            # Optiland's C1 is the r^2 term; its surface factory's Newton tolerance on the sag residual is 1e-6 mm by
            # default (the geometry class's own default is 1e-10): tightened, so that the trace is what is compared
            kw.update(surface_type="even_asphere", coefficients=[0.0, *s.aspheric_coefficients], tol=asphere_tol_mm)
        if s.semi_diameter_mm is not None and i != k:
            kw["aperture"] = RadialAperture(r_max=s.semi_diameter_mm)
        mat = "air" if seq._glasses[i] is None else LenssimGlass(seq, i)
        op.surfaces.add(index=i + 1, is_stop=(i == k), material=mat, comment=s.comment, **kw)
    op.surfaces.add(index=len(p.surfaces) + 1)
    op.set_aperture(aperture_type="EPD", value=p.entrance_pupil_diameter_mm)
    op.fields.set_type(field_type="angle")
    for f in p.fields:
        op.fields.add(y=f)
    for w in p.wavelengths_um:
        op.wavelengths.add(value=w, is_primary=abs(w - p.primary_wavelength_um) < 1e-12)
    if aim == "real" and p.stop_size == "real":  # Optiland's own convention: the real axial ray's height at the stop
        op.ray_tracer.set_aiming("robust", max_iter=50, tol=1e-9)
    elif aim == "real":
        y_marg, _ = op.paraxial.marginal_ray()
        r_stop = abs(float(be.to_numpy(y_marg[k + 1]).ravel()[0]))  # Optiland's own paraxial stop radius
        op.surfaces[k + 1].aperture = RadialAperture(r_max=r_stop)
        op.set_aperture(aperture_type="float_by_stop_size", value=2 * r_stop)
        op.ray_tracer.set_aiming("robust", max_iter=50, tol=1e-9)
    return op


def _f(x) -> float:
    import optiland.backend as be

    return float(np.asarray(be.to_numpy(x)).ravel()[0])


def paraxial_optiland(op, p) -> dict:
    par = op.paraxial
    z_img = sum(s.thickness_mm for s in p.surfaces)
    xpl = _f(par.XPL())
    return {"EFL (mm)": _f(par.f2()), "BFL (mm)": p.surfaces[-1].thickness_mm + _f(par.F2()),
            "EPD (mm)": _f(par.EPD()), "entrance pupil z (mm)": _f(par.EPL()), "F-number": _f(par.FNO()),
            "exit pupil z (mm)": z_img + xpl, "exit pupil diameter (mm)": abs(_f(par.XPD()))}


def paraxial_ours(seq) -> dict:
    par = seq.paraxial()
    return {"EFL (mm)": par.efl_mm, "BFL (mm)": par.bfl_mm, "EPD (mm)": par.epd_mm,
            "entrance pupil z (mm)": par.entrance_pupil_z_mm, "F-number": par.f_number,
            "exit pupil z (mm)": par.exit_pupil_z_mm, "exit pupil diameter (mm)": par.exit_pupil_diameter_mm}


def fields_ours(seq, fields, px, py, aim: str) -> list[dict]:
    import torch

    out = []
    for f in fields:
        w = seq.wavefront(f, torch.as_tensor(px), torch.as_tensor(py), aim=aim)
        out.append({"RMS OPD (waves)": w.rms_waves(), "PV OPD (waves)": w.pv_waves(),
                    "RMS spot (um)": w.rms_spot_mm() * 1e3, "vignetted (%)": 100 * w.vignetted_fraction,
                    "chief ray image y (mm)": float(w.chief_mm[1]), "reference sphere radius (mm)": w.reference_radius_mm})
    return out


def fields_optiland(op, p, dist) -> list[dict]:
    import optiland.backend as be
    from optiland.analysis import SpotDiagram
    from optiland.wavefront import OPD

    wl = p.primary_wavelength_um
    fmax = max(p.fields)
    out = []
    for f in p.fields:
        hy = f / fmax if fmax > 0 else 0.0
        opd = OPD(op, (0.0, hy), wl, distribution=dist, strategy="chief_ray")
        d = opd.get_data(opd.fields[0], opd.wavelengths[0])
        keep = be.to_numpy(d.intensity) > 0
        w = be.to_numpy(d.opd)[keep]
        spot = SpotDiagram(op, fields=[(0.0, hy)], wavelengths=[wl], distribution=dist, reference="centroid")
        chief = op.trace_generic(0.0, hy, 0.0, 0.0, wl)
        out.append({"RMS OPD (waves)": float(np.sqrt(np.mean((w - w.mean()) ** 2))),
                    "PV OPD (waves)": float(w.max() - w.min()),
                    "RMS spot (um)": 1e3 * _f(spot.rms_spot_radius()[0][0]),
                    "vignetted (%)": 100 * (1 - keep.mean()),
                    "chief ray image y (mm)": _f(chief.y), "reference sphere radius (mm)": float(d.radius)})
    return out


def _rel(a: float, b: float) -> str:
    if a == b:
        return "0"
    den = max(abs(a), abs(b))
    return f"{(b - a) / den:+.2e}" if den > 0 else "-"


def _num(v: float) -> str:
    return f"{v:.10g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.6e}"


def compare_lens(name: str, aim: str, grid: int, rows: list, timings: dict, asphere_tol_mm: float = 1e-12,
                 stop_size: str | None = None) -> None:
    from optiland.rays.ray_aiming.initialization import RealReferenceStrategy

    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.sequential import SequentialLens, pupil_grid

    LenssimGlass, FixedPoints = _optiland()
    p = read_lens(name)
    if stop_size is not None:
        from dataclasses import replace

        p = replace(p, stop_size=stop_size)
    seq = SequentialLens(p)
    px, py = pupil_grid(grid)
    px, py = px.numpy(), py.numpy()

    t0 = time.perf_counter()
    par_o = paraxial_ours(seq)
    fo = fields_ours(seq, p.fields, px, py, aim)
    t1 = time.perf_counter()
    # the file's EPD as the aperture (Optiland's default, paraxial aiming): the paraxial data
    op_epd = build_optic(p, seq, "paraxial", LenssimGlass, asphere_tol_mm)
    par_x = paraxial_optiland(op_epd, p)
    r_native = RealReferenceStrategy(op_epd).calculate_stop_radius()
    op = op_epd if aim == "paraxial" else build_optic(p, seq, aim, LenssimGlass, asphere_tol_mm)
    fx = fields_optiland(op, p, FixedPoints(px, py))
    t2 = time.perf_counter()
    timings[name] = (t1 - t0, t2 - t1)

    for q in par_o:
        rows.append((name, q, "-", par_o[q], par_x[q]))
    rows.append((name, f"stop radius, real-aim target (mm) [ours: {p.stop_size}; Optiland default: real marginal ray]",
                 "-", seq.aimed_stop_radius_mm(), r_native))
    for f, a, b in zip(p.fields, fo, fx):
        for q in a:
            rows.append((name, q, f"{f:g} deg", a[q], b[q]))


def misaligned_case():
    """The misaligned lens of ``--misaligned``: the Cooke triplet, its second element (surfaces 3 and 4) decentred
    0.05 mm in y and tilted 0.1 deg about x (pivot at surface 3's vertex), and its stop (surface 5) decentred (0.05,
    -0.03) mm and tilted 0.2 deg about y (about its vertex). Returns the prescription and the misalignments."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.misalignment import Misalignment, element_misalignment

    p = read_lens("cooke_triplet")
    m = element_misalignment(p, 2, 3, decentre_y_mm=0.05, tilt_x_deg=0.1)
    m[4] = Misalignment(decentre_x_mm=0.05, decentre_y_mm=-0.03, tilt_y_deg=0.2)
    return p, m


def misalign_optic(op, p, misalignments) -> None:
    """Move Optiland's surfaces as lenssim's ``misalignments`` move ours. Optiland places surface ``i + 1`` (ours
    ``i``, 0-based) by its coordinate system: a local point ``v`` is at ``R_z R_y R_x v + (x, y, z)``, the rotations
    right-handed (radians), i.e. rotated about the surface's own vertex. Ours moves a nominal point ``X`` to
    ``R (X - pivot) + pivot + decentre``; with the vertex ``V = (0, 0, z_i)`` that is ``R v + R (V - pivot) + pivot +
    decentre``: the same rotation, the origin moved there. For a tilt about one axis R is Optiland's R_x or R_y; with
    both (Optiland's R_y R_x against our rotation vector, a second-order difference) this is refused."""
    for i, mi in misalignments.items():
        if mi.tilt_x_deg and mi.tilt_y_deg:
            raise ValueError(f"surface {i + 1}: tilts about both x and y are not mapped to Optiland here")
        R = np.array(mi.rotation_matrix())
        z_v = p.vertex_z_mm[i]
        pivot = z_v if mi.pivot_z_mm is None else mi.pivot_z_mm
        origin = R @ np.array([0.0, 0.0, z_v - pivot]) + np.array([mi.decentre_x_mm, mi.decentre_y_mm, pivot])
        cs = op.surfaces[i + 1].geometry.cs
        cs.x, cs.y, cs.z = (float(v) for v in origin)
        cs.rx, cs.ry = math.radians(mi.tilt_x_deg), math.radians(mi.tilt_y_deg)


def same_rays(seq, op, field: float, px, py) -> dict:
    """Our aimed rays of ``field`` (real aiming) traced by both tracers from the same start points and directions to
    the image plane: the largest differences of the image points (mm), of the directions, and of the optical paths
    (mm, each ray's minus the chief ray's: the two count from different planes), over the rays both let through."""
    import optiland.backend as be
    import torch
    from optiland.rays import RealRays

    lam = seq.primary_wavelength_um
    zero = torch.zeros(1, dtype=torch.float64)
    P, d, o = seq.aim(field, torch.cat([zero, torch.as_tensor(px)]), torch.cat([zero, torch.as_tensor(py)]))
    b = seq.trace(P, d, opl_start=o)
    s = (seq.image_z_mm - b.points[:, 2]) / b.directions[:, 2]  # the image space is air in the shipped lenses
    img = (b.points + s[:, None] * b.directions).numpy()
    opl = (b.opl + s - (P * d).sum(-1)).numpy()  # from the start points, as Optiland counts
    Pn, dn = P.numpy(), d.numpy()
    rays = RealRays(Pn[:, 0], Pn[:, 1], Pn[:, 2], dn[:, 0], dn[:, 1], dn[:, 2], np.ones(len(Pn)), np.full(len(Pn), lam))
    op.surface_group.trace(rays, skip=1)
    X = np.stack([be.to_numpy(v) for v in (rays.x, rays.y, rays.z)], -1)
    D = np.stack([be.to_numpy(v) for v in (rays.L, rays.M, rays.N)], -1)
    W = be.to_numpy(rays.opd)
    ok = b.valid.numpy() & (be.to_numpy(rays.i) > 0)
    both = bool(ok[0])  # the chief ray passes on both sides
    return {"rays (ours, Optiland, both)": (int(b.valid.sum()), int((be.to_numpy(rays.i) > 0).sum()), int(ok.sum())),
            "image point (mm)": float(np.abs(X[ok] - img[ok]).max()) if both else math.nan,
            "direction": float(np.abs(D[ok] - b.directions.numpy()[ok]).max()) if both else math.nan,
            "OPL - chief's (mm)": float(np.abs((W[ok] - W[0]) - (opl[ok] - opl[0])).max()) if both else math.nan}


def compare_misaligned(aim: str, grid: int, rows: list, timings: dict, traces: list) -> None:
    """The misaligned case (:func:`misaligned_case`) on both sides: per field of the file, the same figures as the
    shipped lenses plus the chief ray's image x; ``traces`` gets :func:`same_rays`'s differences per field."""
    import torch

    from lenssim.optics.sequential import SequentialLens, pupil_grid

    LenssimGlass, FixedPoints = _optiland()
    p, m = misaligned_case()
    name = "cooke_triplet, misaligned"
    nominal = SequentialLens(p)
    seq = SequentialLens(p, misalignments=m)
    px, py = pupil_grid(grid)
    t0 = time.perf_counter()
    fo = []
    for f in p.fields:
        w = seq.wavefront(f, px, py, aim=aim)
        fo.append({"RMS OPD (waves)": w.rms_waves(), "PV OPD (waves)": w.pv_waves(),
                   "RMS spot (um)": w.rms_spot_mm() * 1e3, "vignetted (%)": 100 * w.vignetted_fraction,
                   "chief ray image x (mm)": float(w.chief_mm[0]), "chief ray image y (mm)": float(w.chief_mm[1]),
                   "reference sphere radius (mm)": w.reference_radius_mm})
    t1 = time.perf_counter()
    from optiland.paraxial_path import ParaxialDomainWarning

    op = build_optic(p, nominal, aim, LenssimGlass)  # our centred lens's paraxial stop radius, as compare_lens
    misalign_optic(op, p, m)
    with warnings.catch_warnings():  # Optiland's first-order data take the surfaces as centred (as ours) and say so
        warnings.simplefilter("ignore", ParaxialDomainWarning)
        fx = fields_optiland(op, p, FixedPoints(px.numpy(), py.numpy()))
        fmax = max(p.fields)
        for f, row in zip(p.fields, fx):
            chief = op.trace_generic(0.0, f / fmax if fmax > 0 else 0.0, 0.0, 0.0, p.primary_wavelength_um)
            row["chief ray image x (mm)"] = _f(chief.x)
    t2 = time.perf_counter()
    timings[name] = (t1 - t0, t2 - t1)
    for f, a, b in zip(p.fields, fo, fx):
        for q in a:
            rows.append((name, q, f"{f:g} deg", a[q], b[q]))
    if aim == "real":
        sub = torch.linspace(0, len(px) - 1, min(len(px), 512)).round().long()  # a subset of the grid's points
        for f in p.fields:
            traces.append((f, same_rays(seq, op, f, px[sub].numpy(), py[sub].numpy())))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", nargs="+", default=list(SHIPPED), help="shipped lens names or .toml/.zmx files")
    ap.add_argument("--aim", choices=("real", "paraxial", "both"), default="real")
    ap.add_argument("--grid", type=int, default=64, help="pupil samples across the diameter (ours: 64)")
    ap.add_argument("--asphere-tol", type=float, default=1e-12, metavar="MM",
                    help="Optiland's Newton tolerance on an even asphere's sag residual (mm); its surface factory's "
                         "default is 1e-6, which leaves near-axis intersections ~3e-7 mm off (see the docstring)")
    ap.add_argument("--stop-size", choices=("paraxial", "real"), default=None,
                    help="how the entrance pupil sizes the stop the real rays are aimed at (default: the lens file's)")
    ap.add_argument("--misaligned", action="store_true",
                    help="compare the misaligned Cooke triplet instead (element 2 decentred and tilted, the stop "
                         "decentred and tilted; see misaligned_case)")
    args = ap.parse_args(argv)
    from importlib.metadata import version

    _optiland()
    warnings.filterwarnings("ignore", module=r"numba(\..*)?")  # numba's internal "not in scope" checks (its JIT)

    aims = ("real", "paraxial") if args.aim == "both" else (args.aim,)
    t_start = time.perf_counter()
    for aim in aims:
        rows, timings, traces = [], {}, []
        for name in ([] if args.misaligned else args.lens):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                compare_lens(name, aim, args.grid, rows, timings, args.asphere_tol, args.stop_size)
        if args.misaligned:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                compare_misaligned(aim, args.grid, rows, timings, traces)
        print(f"\n## lenssim vs Optiland {version('optiland')}: {aim} ray aiming, {args.grid} x {args.grid} pupil "
              "grid, primary wavelength, image plane of the file\n")
        print("| lens | quantity | field | ours | Optiland | relative difference |")
        print("| --- | --- | --- | --- | --- | --- |")
        for lens, q, f, a, b in rows:
            print(f"| {lens} | {q} | {f} | {_num(a)} | {_num(b)} | {_rel(a, b)} |")
        if traces:
            print("\nthe same rays (ours, real aiming) through both tracers to the image plane: largest differences\n")
            print("| field | rays (ours, Optiland, both) | image point (mm) | direction | OPL - chief's (mm) |")
            print("| --- | --- | --- | --- | --- |")
            for f, t in traces:
                n, x, dd, w = t.values()
                print(f"| {f:g} deg | {n} | {x:.1e} | {dd:.1e} | {w:.1e} |")
        print("\nseconds (ours, Optiland): " + ", ".join(f"{k} {a:.1f}, {b:.1f}" for k, (a, b) in timings.items()))
    print(f"total {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
