"""``lenssim inspect LENS``: any lens from a prescription (a .zmx or .toml file, or a shipped lens's name): its
surfaces, paraxial data, Seidel sums and, per field, the wavefront, spot, Strehl ratio and MTF."""

from __future__ import annotations

import json
import math
import sys

from .common import table

__all__ = ["register", "cmd_inspect", "REFOCUS_CHOICES", "refocused_lens", "add_lens_arguments", "lens_psf_from_args",
           "check_lens_arguments", "each_lens", "lens_label", "lens_provider", "cmd_evaluate_lens"]

REFOCUS_CHOICES = ("file", "paraxial", "best")
"""Where the image plane goes: where the file puts it, the paraxial focus, or the focus of least field-averaged RMS
wavefront error."""


def refocused_lens(p, refocus: str):
    """The :class:`lenssim.optics.sequential.SequentialLens` of prescription ``p`` with its image plane where
    ``refocus`` (:data:`REFOCUS_CHOICES`) puts it, and the shift (mm) from the file's plane."""
    from lenssim.optics.sequential import SequentialLens

    seq = SequentialLens(p)
    shift = 0.0
    if refocus == "paraxial":
        shift = seq.paraxial().image_z_mm - p.image_z_mm
    elif refocus == "best":
        from lenssim.optics.lens_solves import best_focus_shift

        shift = best_focus_shift(p)
    return SequentialLens(p, image_shift_mm=shift), shift


def cmd_inspect(args) -> int:
    from dataclasses import replace

    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.cost import prescription_costs
    from lenssim.optics.lens_report import DEFAULT_MTF_FREQUENCIES_CPMM, lens_report

    freqs = tuple(args.mtf) if args.mtf else DEFAULT_MTF_FREQUENCIES_CPMM
    for v in freqs:
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"--mtf {v:g} is not allowed: frequencies in cycles/mm, > 0")
    p = read_lens(args.lens)
    if args.angles:
        p = replace(p, fields=tuple(args.angles))  # checked by the prescription (0 to below 90 deg, or heights >= 0)
    from lenssim.optics.sequential import SequentialLens

    SequentialLens(p).check_aperture()
    seq, shift = refocused_lens(p, args.refocus)
    rep = lens_report(seq, p.fields, freqs)
    rep["refocus"] = args.refocus
    rep["image_shift_mm"] = shift
    costs = prescription_costs(p)
    rep["asphere_cost"] = {str(k): v for k, v in costs.items()}
    rep["cost"] = sum(v["cost"] for v in costs.values())
    if args.json:
        print(json.dumps(rep, allow_nan=False))
        return 0
    unit = "deg" if p.object_at_infinity else "mm"
    print(f"{p.name or args.lens}" + (f"  ({p.source})" if p.source else ""))
    rows = [[str(i + 1) + (" (stop)" if i == p.stop_index else ""), f"{s.radius_mm:.6g}", f"{s.thickness_mm:.6g}",
             s.material if isinstance(s.material, str) else f"n_d {s.material[0]:g}, V_d {s.material[1]:g}",
             f"{s.conic:g}", (f"{s.kind}: " if s.kind else "") + " ".join(f"{a:.4g}" for a in s.aspheric_coefficients)
             or "-",
             "-" if s.semi_diameter_mm is None else f"{s.semi_diameter_mm:g}"] for i, s in enumerate(p.surfaces)]
    print(table(rows, ["surface", "radius mm", "thickness mm", "material after", "conic", "A4.. (mm^1-2k)",
                       "semi-diam mm"]))
    print(f"\nparaxial at {rep['wavelength_um']:g} um: EFL {rep['efl_mm']:.4f} mm, BFL {rep['bfl_mm']:.4f} mm, "
          f"EPD {rep['epd_mm']:g} mm, F/{rep['f_number']:.3f} (working F/{rep['working_f_number']:.3f}), entrance "
          f"pupil at z = {rep['entrance_pupil_z_mm']:.4f} mm, exit pupil at z = {rep['exit_pupil_z_mm']:.4f} mm "
          f"(diameter {rep['exit_pupil_diameter_mm']:.4f} mm); image plane at z = {rep['image_z_mm']:.4f} mm "
          f"({args.refocus}; paraxial focus {rep['paraxial_image_z_mm']:.4f} mm)")
    if costs:
        print("asphere cost C_a (RMS slope departure from the best-fitting sphere, slope units): "
              + ", ".join(f"surface {k} {v['cost']:.4g} over {v['radius_mm']:g} mm" for k, v in costs.items())
              + (f"; total {rep['cost']:.4g}" if len(costs) > 1 else ""))
    else:
        print("asphere cost C_a: 0 (no aspheric surface)")
    s = rep["seidel_sums_mm"]
    print(f"Seidel sums at {s['field']:g} {unit} (mm): " + ", ".join(f"{k} {s[k]:.5g}" for k in
                                                                       ("S_I", "S_II", "S_III", "S_IV", "S_V")))
    key = "field_angles_deg" if p.object_at_infinity else "object_heights_mm"
    rows = []
    for i, f in enumerate(rep[key]):
        sampled = rep["psf_not_sampled"][i] is None
        mtf = " / ".join(f"{a:.3f},{b:.3f}" for a, b in zip(rep["mtf_sagittal"][i], rep["mtf_tangential"][i])) \
            if sampled else "n/a *"
        rows.append([f"{f:g}", f"{rep['paraxial_image_heights_mm'][i]:.4f}", f"{rep['rms_opd_waves'][i]:.4f}",
                     f"{rep['pv_opd_waves'][i]:.4f}", f"{rep['rms_spot_um'][i]:.3f}",
                     f"{rep['strehl'][i]:.4f}" if sampled else "n/a *", f"{100 * rep['vignetted_fraction'][i]:.1f}", mtf])
    print()
    print(table(rows, [f"field {unit}", "image height mm", "RMS OPD waves", "PV OPD waves", "RMS spot um", "Strehl",
                       "vignetted %", "MTF sag,tan at " + ", ".join(f"{v:g}" for v in freqs) + " c/mm"]))
    unsampled = [(f, why) for f, why in zip(rep[key], rep["psf_not_sampled"]) if why is not None]
    if unsampled:
        print(f"\n* field {', '.join(f'{f:g}' for f, _ in unsampled)} {unit}: {unsampled[-1][1]}")
    return 0


def add_lens_arguments(p, *, pitch_help: str = "--lens: the sensor's pixel pitch (um) instead of the photo spanning the "
                                                "lens's field", many: bool = False) -> None:
    """``--lens LENS`` (``many``: ``--lens LENS [LENS ...]``), ``--refocus``, ``--pixel-pitch UM`` of the camera
    commands."""
    p.add_argument("--lens", metavar="LENS", nargs="+" if many else None,
                   help=("lenses besides (or instead of) the paper's designs: " if many else
                         "any lens instead of the paper's singlet: ") + "a .zmx or .toml prescription, or a shipped "
                        "lens's name (see docs/any-lens.md); by default the photo spans the lens's largest field at its "
                        "corners")
    p.add_argument("--refocus", choices=REFOCUS_CHOICES, default=None,
                   help="--lens: the image plane where the file puts it (default), at the paraxial focus, or at the "
                        "best focus (least RMS wavefront averaged over the file's fields)")
    p.add_argument("--pixel-pitch", type=float, metavar="UM", help=pitch_help)


PAPER_ONLY_FLAGS = (("--design", "design"), ("--glass", "glass"), ("--as-built", "as_built"),
                    ("--designs-file", "designs_file"), ("--designs", "designs"))
"""Flags that describe the paper's singlet (its design, glass, manufactured samples): refused beside ``--lens``."""


def check_lens_arguments(args):
    """``--lens`` and the flags that go with it, before any work (one-line ``ValueError``); the prescription read
    (None without ``--lens``)."""
    lens = getattr(args, "lens", None)
    if lens is None:
        for flag, name in (("--refocus", "refocus"), ("--pixel-pitch", "pixel_pitch")):
            if getattr(args, name, None) is not None:
                raise ValueError(f"{flag} applies to --lens LENS (any lens); the paper's singlet has its own focus "
                                 "and sensor")
        return
    given = [f for f, k in PAPER_ONLY_FLAGS if getattr(args, k, None) not in (None, False)]
    given += [f"--{k[len('param_'):]}" for k, v in vars(args).items() if k.startswith("param_") and v is not None]
    if given:
        raise ValueError(f"{', '.join(given)} describe(s) the paper's singlet; --lens {lens} brings its own surfaces "
                         "and glasses: leave them out")
    pitch = getattr(args, "pixel_pitch", None)
    if pitch is not None and not (math.isfinite(pitch) and pitch > 0):
        raise ValueError(f"--pixel-pitch {pitch:g} is not allowed: a pixel pitch in um, > 0")
    from lenssim.io.prescription_file import read_lens

    p = read_lens(lens)
    from lenssim.optics.sequential import SequentialLens

    SequentialLens(p).check_aperture()
    if not p.object_at_infinity:
        raise ValueError(f"--lens {lens}: the object is at {p.object_distance_mm:g} mm; the camera commands take a "
                         "lens focused on a distant scene (object at infinity)")
    return p


def each_lens(args, *, beside=("designs", "designs_file")):
    """For ``--lens LENS [LENS ...]``: one namespace per lens (``args`` with ``lens`` set to it and the flags
    ``beside``, which may go with lenses in this command, cleared), each lens checked by :func:`check_lens_arguments`
    before any work (a lens given twice is refused)."""
    import argparse

    lenses = list(args.lens or ())
    for v in lenses:
        if lenses.count(v) > 1:
            raise ValueError(f"--lens {v} is given twice; each lens once")
    if not lenses:
        check_lens_arguments(args)  # --refocus and --pixel-pitch without a lens
        return []
    out = []
    for v in lenses:
        ns = argparse.Namespace(**{**vars(args), "lens": v, **{k: None for k in beside}})
        check_lens_arguments(ns)
        out.append(ns)
    return out


def lens_label(ns) -> str:
    """How a table names a lens of ``--lens``: its shipped name, or its file's name."""
    from pathlib import Path

    return f"lens {Path(ns.lens).name}"


def lens_psf_from_args(args, shape, *, progress=None):
    """The :class:`lenssim.optics.psf_provider.SequentialPSF` of ``--lens`` for a frame of ``shape`` ``(..., H, W)``:
    the lens's own wavelengths (equal weights) or the colour channels of ``--spectrum``; the paper's sensor (its noise
    and full wells) with the pixel pitch of ``--pixel-pitch`` or, by default, the one that puts the lens's largest
    field at the frame's corners; the table of wavefronts traced out to the corners' field angle."""
    from lenssim_studies.tradeoff import PhotoFieldError, photo_field

    p = check_lens_arguments(args)
    seq, _ = refocused_lens(p, args.refocus or "file")
    H, W = shape[-2:]
    if args.pixel_pitch is None and max(p.fields) <= 0:
        raise ValueError(f"--lens {args.lens} has only the axial field: give --pixel-pitch UM for the sensor")
    margin = args.scheme[2] if getattr(args, "scheme", None) else 0
    try:
        pitch, amax = photo_field(p, seq, shape, pitch_um=args.pixel_pitch, margin_px=margin)
    except PhotoFieldError as exc:
        fit = "; or leave --pixel-pitch out (the photo then spans the lens's field)" if exc.fit_um else ""
        raise ValueError(f"--pixel-pitch {args.pixel_pitch:g} is not allowed with --lens {args.lens} on this "
                         f"{W} x {H} px photo: {exc}{fit}") from None
    psf = lens_provider(args, p, seq, pitch_um=pitch, width_px=int(W), height_px=int(H), max_field_deg=amax)
    # the work bounded before any PSF: the PSF's size from a few rays, then its FFT against --max-fft-size
    extent = psf.estimated_extent_px()
    if extent > max(H, W):
        raise ValueError(f"--lens {args.lens}: its PSF spans about {extent} px ({extent * pitch * 1e-3:.3g} mm) on "
                         f"{pitch:.4g} um pixels, more than the {W} x {H} px photo: nothing of the scene would be "
                         "resolved (is the lens far out of focus? try --refocus best)")
    psf.check_fft_size(extent, f"--lens {args.lens}")
    return psf


def note_lens_field(args, psf) -> None:
    """Say on stderr (once every input is checked, as the work starts) the sensor a lens's photo is taken on: the pixel
    pitch, where it comes from, and the field angles of the photo's corners and of the farthest PSF the blur asks for."""
    corner = psf.geometry.max_field_angle_deg((psf.sensor.height_px, psf.sensor.width_px))
    how = "--pixel-pitch" if args.pixel_pitch is not None else "chosen so the photo spans the lens's field"
    print(f"lenssim {args.command}: note: {lens_label(args)}: pixel pitch {psf.sensor.pixel_pitch_um:.4g} um ({how}); "
          f"the photo's corners at {corner:.4g} deg, PSFs traced to {psf.max_field_deg:.4g} deg (the lens's field: "
          f"{max(psf.lens.prescription.fields):g} deg)", file=sys.stderr)


def lens_provider(args, p, seq, *, pitch_um: float, width_px: int, height_px: int, max_field_deg: float,
                  sampling: str = "area"):
    """The :class:`lenssim.optics.psf_provider.SequentialPSF` of the lens ``seq`` (prescription ``p``) on the paper's
    sensor (its noise and full wells) with pixels of ``pitch_um``, in the lens's own wavelengths (equal weights) or the
    colour channels of ``--spectrum``, traced out to ``max_field_deg``."""
    from lenssim.model.spectrum import channel_spectra
    from lenssim_studies.tradeoff import sequential_provider

    from .common import DEFAULT_ILLUMINANT

    spec = getattr(args, "spectrum", "paper") or "paper"
    chans = () if spec == "paper" else channel_spectra(spec, args.illuminant or DEFAULT_ILLUMINANT,
                                                       args.wavelengths_per_channel)
    from .common import numerics_from_args

    return sequential_provider(p, seq, pitch_um=pitch_um, sampling=sampling, max_field_deg=max_field_deg,
                               width_px=width_px, height_px=height_px, colour_channels=chans,
                               numerics=numerics_from_args(args))


def cmd_evaluate_lens(args) -> int:
    """``lenssim evaluate --lens LENS``: every criterion of any lens (:func:`lenssim.metrics.evaluate_sequential`)
    over its field, on a sensor of ``--pixel-pitch`` (default: the Nyquist pitch ``lambda N_w / 2`` at the primary
    wavelength, point samples, as the paper's camera)."""
    import time

    from lenssim import select_device
    from lenssim.criteria import CRITERIA
    from lenssim.io.files import json_text
    from lenssim.metrics import EVALUATION_FIELDS, evaluate_sequential
    from lenssim_studies.paper import PAPER_RHO0

    from .common import numerics_from_args, table

    if getattr(args, "best_focus", None):
        raise ValueError("--best-focus applies to the paper's singlet; with --lens use --refocus best")
    select_device(args.device)
    p = check_lens_arguments(args)
    t0 = time.perf_counter()
    seq, shift = refocused_lens(p, args.refocus or "file")
    par = seq.paraxial()
    amax = max(p.fields)
    nyquist = seq.primary_wavelength_um * par.working_f_number / 2
    pitch = nyquist if args.pixel_pitch is None else float(args.pixel_pitch)
    sampling = args.sampling or ("point" if args.pixel_pitch is None else "area")
    numerics = numerics_from_args(args)
    psf = lens_provider(args, p, seq, pitch_um=pitch, width_px=1, height_px=1, max_field_deg=amax, sampling=sampling)
    r = evaluate_sequential(psf, args.snr, rho0=PAPER_RHO0, numerics=numerics)
    names = [k for k in CRITERIA if k in r]
    out = {"lens": p.name or str(args.lens), "file": str(args.lens), "source": p.source, "refocus": args.refocus or "file",
           "image_shift_mm": shift, "efl_mm": par.efl_mm, "working_f_number": par.working_f_number,
           "pixel_pitch_um": pitch, "sampling": sampling, "spectrum": psf.light.name if not psf.colour_channels
           else [c.name for c in psf.colour_channels], "snr_db": [float(v) for v in r["snr_db"]],
           "alpha_deg": [float(v) for v in r["alpha_deg"]], "psf_grid_px": int(r["psf_grid_px"])}
    for name in names:
        v = r[name]
        out[name] = [float(x) for x in v] if CRITERIA[name].per_snr else float(v)
        if f"{name}_alpha" in r:  # per field angle (not the cost: a property of the surfaces)
            out[f"{name}_alpha"] = r[f"{name}_alpha"].tolist()
        if f"{name}_per_channel" in r:
            out[f"{name}_per_channel"] = r[f"{name}_per_channel"].tolist()
    out["rms_w_piston_removed_waves"] = float(r["rms_w_piston_removed"])
    out["cost_per_surface"] = {str(k): v for k, v in r["cost_per_surface"].items()}
    out["units"] = {name: CRITERIA[name].units for name in names}
    out["about"] = ("field averages over " + (f"{EVALUATION_FIELDS} field angles" if amax > 0 else "the axis")
                    + f" from 0 to {amax:g} deg; each PSF about its chief ray's image point (distortion is the lens's "
                    "mapping, not blur); Strehl against the same vignetted pupil without aberration")
    if args.json:
        print(json_text(out))
        return 0
    print(f"{out['lens']}" + (f"  ({p.source})" if p.source else ""))
    print(f"EFL {par.efl_mm:.4f} mm, working F/{par.working_f_number:.3f}, image plane {args.refocus or 'file'} "
          f"(shift {shift:+.4g} mm); pixels {pitch:.4g} um ({sampling} samples), spectrum "
          + (psf.light.name if not psf.colour_channels else "; ".join(c.name for c in psf.colour_channels)))
    header, row = [], []
    for name in names:
        c = CRITERIA[name]
        if c.per_snr:
            header += [f"{c.label}@{v:g}dB" for v in out["snr_db"]]
            row += [f"{v:.5f}" for v in out[name]]
        else:
            header.append(f"{c.label} [{c.units.split()[0]}]")
            row.append(f"{out[name]:.4g}")
    print(table([row], header))
    print(f"\n{out['about']}; PSFs on {out['psf_grid_px']} px grids ({time.perf_counter() - t0:.1f} s)")
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
