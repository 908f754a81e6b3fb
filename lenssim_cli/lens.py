"""``lenssim inspect LENS``: any lens from a prescription (a .zmx or .toml file, or a shipped lens's name): its
surfaces, paraxial data, Seidel sums and, per field, the wavefront, spot, Strehl ratio and MTF."""

from __future__ import annotations

import json
import math

from .common import table

__all__ = ["register", "cmd_inspect", "REFOCUS_CHOICES"]

REFOCUS_CHOICES = ("file", "paraxial", "best")
"""Where the image plane goes: where the file puts it, the paraxial focus, or the focus of least field-averaged RMS
wavefront error."""


def _best_focus_shift(seq_cls, prescription, fields, start_mm: float, half_range_mm: float) -> float:
    from scipy.optimize import minimize_scalar

    from lenssim.optics.sequential import pupil_grid

    px, py = pupil_grid(24)

    def mean_rms(shift):
        seq = seq_cls(prescription, image_shift_mm=float(shift))
        return sum(seq.wavefront(f, px, py).rms_waves() for f in fields) / len(fields)

    res = minimize_scalar(mean_rms, bounds=(start_mm - half_range_mm, start_mm + half_range_mm), method="bounded",
                          options={"xatol": 1e-6})
    return float(res.x)


def cmd_inspect(args) -> int:
    from dataclasses import replace

    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.lens_report import DEFAULT_MTF_FREQUENCIES_CPMM, lens_report
    from lenssim.optics.sequential import SequentialLens

    freqs = tuple(args.mtf) if args.mtf else DEFAULT_MTF_FREQUENCIES_CPMM
    for v in freqs:
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"--mtf {v:g} is not allowed: frequencies in cycles/mm, > 0")
    p = read_lens(args.lens)
    if args.angles:
        p = replace(p, fields=tuple(args.angles))  # checked by the prescription (0 to below 90 deg, or heights >= 0)
    seq = SequentialLens(p)
    shift = 0.0
    if args.refocus == "paraxial":
        shift = seq.paraxial().image_z_mm - p.image_z_mm
    elif args.refocus == "best":
        par = seq.paraxial()
        depth = 40 * (seq.primary_wavelength_um * 1e-3) * par.working_f_number**2  # +-10 focal depths (4 lambda N^2)
        shift = _best_focus_shift(SequentialLens, p, p.fields, par.image_z_mm - p.image_z_mm, depth)
    seq = SequentialLens(p, image_shift_mm=shift)
    rep = lens_report(seq, p.fields, freqs)
    rep["refocus"] = args.refocus
    rep["image_shift_mm"] = shift
    if args.json:
        print(json.dumps(rep, allow_nan=False))
        return 0
    unit = "deg" if p.object_at_infinity else "mm"
    print(f"{p.name or args.lens}" + (f"  ({p.source})" if p.source else ""))
    rows = [[str(i + 1) + (" (stop)" if i == p.stop_index else ""), f"{s.radius_mm:.6g}", f"{s.thickness_mm:.6g}",
             s.material if isinstance(s.material, str) else f"n_d {s.material[0]:g}, V_d {s.material[1]:g}",
             f"{s.conic:g}", " ".join(f"{a:.4g}" for a in s.aspheric_coefficients) or "-",
             "-" if s.semi_diameter_mm is None else f"{s.semi_diameter_mm:g}"] for i, s in enumerate(p.surfaces)]
    print(table(rows, ["surface", "radius mm", "thickness mm", "material after", "conic", "A4.. (mm^1-2k)",
                       "semi-diam mm"]))
    print(f"\nparaxial at {rep['wavelength_um']:g} um: EFL {rep['efl_mm']:.4f} mm, BFL {rep['bfl_mm']:.4f} mm, "
          f"EPD {rep['epd_mm']:g} mm, F/{rep['f_number']:.3f} (working F/{rep['working_f_number']:.3f}), entrance "
          f"pupil at z = {rep['entrance_pupil_z_mm']:.4f} mm, exit pupil at z = {rep['exit_pupil_z_mm']:.4f} mm "
          f"(diameter {rep['exit_pupil_diameter_mm']:.4f} mm); image plane at z = {rep['image_z_mm']:.4f} mm "
          f"({args.refocus}; paraxial focus {rep['paraxial_image_z_mm']:.4f} mm)")
    s = rep["seidel_sums_mm"]
    print(f"Seidel sums at {s['field']:g} {unit} (mm): " + ", ".join(f"{k} {s[k]:.5g}" for k in
                                                                       ("S_I", "S_II", "S_III", "S_IV", "S_V")))
    key = "field_angles_deg" if p.object_at_infinity else "object_heights_mm"
    rows = []
    for i, f in enumerate(rep[key]):
        mtf = " / ".join(f"{a:.3f},{b:.3f}" for a, b in zip(rep["mtf_sagittal"][i], rep["mtf_tangential"][i]))
        rows.append([f"{f:g}", f"{rep['paraxial_image_heights_mm'][i]:.4f}", f"{rep['rms_opd_waves'][i]:.4f}",
                     f"{rep['pv_opd_waves'][i]:.4f}", f"{rep['rms_spot_um'][i]:.3f}", f"{rep['strehl'][i]:.4f}",
                     f"{100 * rep['vignetted_fraction'][i]:.1f}", mtf])
    print()
    print(table(rows, [f"field {unit}", "image height mm", "RMS OPD waves", "PV OPD waves", "RMS spot um", "Strehl",
                       "vignetted %", "MTF sag,tan at " + ", ".join(f"{v:g}" for v in freqs) + " c/mm"]))
    return 0


def register(sub) -> None:
    from lenssim.optics.lens_report import DEFAULT_MTF_FREQUENCIES_CPMM

    i = sub.add_parser("inspect", help="any lens from a prescription: paraxial data, Seidel sums, image quality per field",
                       description="LENS is a Zemax OpticStudio .zmx file, a TOML prescription, or the name of a "
                                   "shipped lens (see configs/lenses). Surfaces are numbered as in the file (object = "
                                   "0). Per field, at the primary wavelength: RMS and peak-to-valley OPD (waves; piston "
                                   "removed, tilt kept), RMS spot radius (um), Strehl ratio, MTF.")
    i.add_argument("lens", help="a .zmx or .toml prescription, or a shipped lens's name")
    i.add_argument("--json", action="store_true", help="one JSON object on stdout")
    i.add_argument("--angles", type=float, nargs="+", metavar="FIELD",
                   help="fields to report (degrees; object heights in mm for a finite object): default the file's")
    i.add_argument("--mtf", type=float, nargs="+", metavar="CPMM",
                   help="MTF frequencies, cycles/mm (default " + ", ".join(f"{v:g}" for v in
                                                                           DEFAULT_MTF_FREQUENCIES_CPMM) + ")")
    i.add_argument("--refocus", choices=REFOCUS_CHOICES, default="file",
                   help="image plane: where the file puts it (default), the paraxial focus, or the best focus (least "
                        "RMS wavefront error averaged over the fields)")
    i.set_defaults(func=cmd_inspect)
