"""The paper's singlet through its two routes, one cause at a time (issue 44): from ``evaluate --design
end_to_end_paper --wavefront exact`` to ``evaluate --lens paper_singlet``, changing one thing per row.

    python benchmarks/crosscheck_singlet_routes.py [--snr 27.6] [--s -0.775] [--q-back -2.4]

Rows (each the field average over the paper's 15 angles at the SNR; the last columns the change from the row named):

A. the named design's exact route as the command runs it (RMS_W of third order, each angle on its own FFT size);
B. RMS_W of the exact (ray-traced, fitted) wavefront instead;
C. every angle on one grid (the prescription's largest support over the variants below);
D. the prescription's route on the paper's thin lens (``tests/lenssim/test_singlet_one_answer.py``: a flat stop at
   the vertex, no clear apertures) on that grid, RMS_W by the Gauss pupil quadrature: what is left is the two routes'
   numerics (a traced table read bilinearly, a hard-edged pupil, a windowed PSF; against a fit, an anti-aliased
   pupil, a periodic PSF); D' the same about the paraxial point (``registered=False``), D'' the exact route with a
   hard-edged pupil (``supersample=1``), for scale;
E. the prescription's default RMS_W quadrature (a 64 x 64 grid inside the disc);
F. the stop on the curved front surface, as the shipped file has it (real aiming lays the pupil there);
G. the shipped file's 2 mm semi-diameters (they vignette oblique rays on the back surface);
H. the prescription's own grid: ``evaluate --lens paper_singlet``.

Prints a table; nothing is asserted (the test above holds the agreement). About 10 minutes on two busy cores.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import torch

from lenssim import Design
from lenssim.metrics import evaluate_sequential, exact_criteria
from lenssim.model.numerics import DEFAULT_NUMERICS
from lenssim.optics.sequential import SequentialLens
from lenssim.optics.wavefront_models import validate_wavefront_model
from lenssim_studies.tradeoff import sequential_provider
from lenssim_studies.paper import PAPER_CAMERA, PAPER_RHO0

NAMES = ("rms_w", "mse_s", "mse_r", "mtf50", "strehl")
ANGLES = tuple(float(a) for a in range(15))
"""The paper's field angles (deg)."""


def _test_module():
    """The lens builder of the test (one copy of it)."""
    path = Path(__file__).parents[1] / "tests" / "lenssim" / "test_singlet_one_answer.py"
    spec = importlib.util.spec_from_file_location("test_singlet_one_answer", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _sequential(p, snr, **kw):
    seq = SequentialLens(p)
    nyquist = seq.primary_wavelength_um * seq.paraxial().working_f_number / 2
    psf = sequential_provider(p, seq, pitch_um=nyquist, sampling="point", max_field_deg=max(ANGLES))
    return evaluate_sequential(psf, snr, rho0=PAPER_RHO0, **kw), psf


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--snr", type=float, default=27.6)
    ap.add_argument("--s", type=float, default=-0.775)
    ap.add_argument("--q-back", type=float, default=-2.4)
    args = ap.parse_args(argv)
    snr, s, q = [args.snr], args.s, args.q_back
    lens = _test_module().singlet_prescription
    thin = lens(s, q, ANGLES)
    curved = lens(s, q, ANGLES, plane_stop=False)
    shipped = lens(s, q, ANGLES, plane_stop=False, apertures=True)
    design = Design(s=s, Q_back=q)
    rows = {}  # label: (values, grid, the row it is compared with)

    def add(label, r, grid, base):
        rows[label] = ({k: float(torch.as_tensor(r[k]).reshape(-1)[0]) for k in NAMES}, grid, base)
        print(f"[{time.strftime('%H:%M:%S')}] {label}", flush=True)

    a = validate_wavefront_model("exact").evaluate(PAPER_CAMERA, design, snr, rho0=PAPER_RHO0,
                                                   numerics=DEFAULT_NUMERICS)
    add("A", a, "256..960", None)
    add("B", exact_criteria(PAPER_CAMERA, design, snr, rho0=PAPER_RHO0), "256..960", "A")
    n = max(int(_sequential(p, snr, criteria=["rms_w"])[0]["psf_grid_px"]) for p in (thin, curved, shipped))
    add("C", exact_criteria(PAPER_CAMERA, design, snr, rho0=PAPER_RHO0, fft_size=n), n, "B")
    d, psf = _sequential(thin, snr, grid_px=n, rms_quadrature="gauss")
    add("D", d, n, "C")
    add("D'", _sequential(thin, snr, grid_px=n, rms_quadrature="gauss", registered=False)[0], n, "D")
    add("D''", exact_criteria(PAPER_CAMERA, design, snr, rho0=PAPER_RHO0, fft_size=n,
                              numerics=DEFAULT_NUMERICS.replace(supersample=1)), n, "C")
    add("E", _sequential(thin, snr, grid_px=n)[0], n, "D")
    add("F", _sequential(curved, snr, grid_px=n)[0], n, "E")
    add("G", _sequential(shipped, snr, grid_px=n)[0], n, "F")
    h, _ = _sequential(shipped, snr)
    add("H", h, h["psf_grid_px"], "G")

    print(f"\nThe paper's singlet (s = {s:g}, Q_back = {q:g}) at {snr[0]:g} dB, 15 field angles 0..14 deg; the thin "
          f"lens's distortion {float(psf.table().distortion_mm.abs().max()):.2g} mm at most (D' = D)\n")
    print(f"{'row':4s} {'grid px':>8s} " + " ".join(f"{k:>9s}" for k in NAMES) + "   change (%) from the row")
    for label, (v, grid, base) in rows.items():
        change = "" if base is None else f"{base:4s}" + " ".join(f"{100 * (v[k] / rows[base][0][k] - 1):+8.3f}"
                                                               for k in NAMES)
        print(f"{label:4s} {str(grid):>8s} " + " ".join(f"{v[k]:9.6g}" for k in NAMES) + "   " + change)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
