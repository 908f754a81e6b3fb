"""Every shipped lens (or the lenses named) through the tool: its figures, a crop mosaic and a PSNR table.

    python examples/any_lens_gallery.py [PHOTO] [--lenses cooke_triplet double_gauss ...] [--out any_lens_gallery]

For each lens: ``lenssim inspect LENS --json --mtf 10 30 50`` (paraxial data and, per field, RMS/PV wavefront, RMS
spot, Strehl, MTF), ``lenssim fig8 PHOTO --lens LENS`` (its sensor image and restorations at ISO 400, 100 and 25, a
row per crop angle: ``LENS/lens_mosaic.png``); then one ``lenssim psnr-table PHOTO --lens ... --designs
end_to_end_paper`` beside the paper's end-to-end design. Each lens spans the photo with its own field. Writes
``gallery.md`` (the tables; the mosaics linked) in ``--out``. PHOTO defaults to ``skimage:camera`` (512 px, shipped
with scikit-image); nothing is downloaded. A few minutes on a laptop's CPU.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
from pathlib import Path

from lenssim.io.resources import lenses_dir
from lenssim_cli.main import main as lenssim

DEFAULT_PHOTO = "skimage:camera"
MTF_CPMM = ("10", "30", "50")


def _run(argv: list[str]) -> str:
    """``lenssim ARGV`` in this process; its standard output (an error stops the gallery)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = lenssim(argv)
    if rc != 0:
        raise SystemExit(f"lenssim {' '.join(argv)} failed ({rc})")
    return buf.getvalue()


def _figures(name: str, r: dict) -> list[str]:
    lines = [f"## {r.get('name') or name}", "",
             f"EFL {r['efl_mm']:.4g} mm, BFL {r['bfl_mm']:.4g} mm, entrance pupil {r['epd_mm']:.4g} mm, "
             f"F/{r['f_number']:.3g} (working F/{r['working_f_number']:.3g}); asphere cost C_a {r['cost']:.3g}.", "",
             "| field (deg) | RMS OPD (waves) | PV OPD (waves) | RMS spot (um) | Strehl | vignetted % | "
             + " | ".join(f"MTF {f:g} c/mm (sag / tan)" for f in r["mtf_frequencies_cpmm"]) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(r["mtf_frequencies_cpmm"])]
    for i, a in enumerate(r["field_angles_deg"]):
        mtf = [f"{s:.2f} / {t:.2f}" for s, t in zip(r["mtf_sagittal"][i], r["mtf_tangential"][i])]
        lines.append(f"| {a:g} | {r['rms_opd_waves'][i]:.3f} | {r['pv_opd_waves'][i]:.3f} | {r['rms_spot_um'][i]:.2f} | "
                     f"{r['strehl'][i]:.3f} | {100 * r['vignetted_fraction'][i]:.1f} | " + " | ".join(mtf) + " |")
    return lines + ["", f"![{name}: sensor and restored crops]({name}/lens_mosaic.png)", ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photo", nargs="?", default=DEFAULT_PHOTO)
    ap.add_argument("--lenses", nargs="+", default=sorted(p.stem for p in lenses_dir().glob("*.toml")))
    ap.add_argument("--out", default="any_lens_gallery")
    args = ap.parse_args()
    out = Path(args.out)
    md = [f"# Any-lens gallery ({args.photo})", ""]
    for name in args.lenses:
        print(f"{name}: inspect, fig8", flush=True)
        report = json.loads(_run(["inspect", name, "--json", "--mtf", *MTF_CPMM]))
        _run(["fig8", args.photo, "--lens", name, "--out", str(out / Path(name).stem)])
        md += _figures(Path(name).stem, report)
    print("psnr-table", flush=True)
    table = _run(["psnr-table", args.photo, "--lens", *args.lenses, "--designs", "end_to_end_paper", "--out",
                  str(out / "psnr_table")])
    md += ["## PSNR (dB) beside the paper's end-to-end design", "", table.strip(), ""]
    (out / "gallery.md").write_text("\n".join(md))
    print(f"wrote {out / 'gallery.md'}")


if __name__ == "__main__":
    main()
    from pipeline.io import exit_without_teardown

    exit_without_teardown()
