"""The image quality of a sequential lens per field: wavefront RMS and peak to valley, RMS spot, Strehl ratio, MTF.

From :class:`lenssim.optics.sequential.SequentialLens` at one wavelength, the image plane where the lens puts it:

* the OPD on a square grid of ``grid x grid`` points over the entrance pupil's unit disc (equal area per point),
  vignetted points left out: RMS (piston removed, tilt kept: the reference sphere is centred on the chief ray's image
  point) and peak to valley, in waves;
* RMS spot radius (um) of the same rays about their centroid;
* the PSF ``|FFT(A exp(2 pi i W))|^2`` of the pupil (amplitude ``A`` 1 where a ray passes), zero-padded
  ``PSF_PADDING`` times; the Strehl ratio is its peak over the peak of the same pupil without aberration;
* the MTF, the modulus of the pupil's normalised autocorrelation (the PSF's Fourier transform), at the frequencies
  asked (cycles/mm), sagittal (x) and tangential (y): a shift of the whole pupil diameter is the cutoff
  ``1 / (lambda N_w)`` with ``N_w`` the paraxial working F-number.

The PSF and MTF map the entrance pupil's grid linearly onto the exit pupil (pupil aberrations and the oblique beam's
foreshortening neglected: they scale the off-axis PSF by ``1/cos`` factors, as in :mod:`lenssim.optics.exact_wavefront`).
"""

from __future__ import annotations

import math

import torch

from .sequential import SequentialLens
from ..torch_utils import HOST, abs_square

__all__ = ["lens_report", "field_quality", "REPORT_GRID", "PSF_PADDING", "DEFAULT_MTF_FREQUENCIES_CPMM",
           "MAX_PHASE_STEP_WAVES", "MAX_REPORT_GRID"]

REPORT_GRID = 64
"""Pupil samples across the entrance pupil's diameter for the per-field figures."""
PSF_PADDING = 8
"""The PSF's FFT is this many times the pupil grid (PSF samples of ``lambda N_w / PSF_PADDING``)."""
MAX_PHASE_STEP_WAVES = 0.5
"""The largest OPD step (waves) between neighbouring pupil samples whose PSF is faithful: the Nyquist limit of the
pupil's phase (a steeper wavefront's rays land beyond the PSF grid's half width and wrap round it)."""
MAX_REPORT_GRID = 512
"""The finest pupil grid a field's figures are computed on (its PSF's FFT is ``PSF_PADDING`` times that: 4096)."""
DEFAULT_MTF_FREQUENCIES_CPMM = (10.0, 30.0, 50.0)
"""MTF frequencies (cycles/mm) reported when none are asked (the photographic lens's customary three)."""


def _square_pupil(n: int):
    g = (torch.arange(n, dtype=torch.float64, device=HOST) + 0.5) / n * 2 - 1
    Y, X = torch.meshgrid(g, g, indexing="ij")
    return X, Y, X**2 + Y**2 <= 1


def _pupil_phase(seq: SequentialLens, field: float, lam: float, grid: int):
    """The traced wavefront of one field on a ``grid x grid`` pupil: ``(w, amp, phase, step)``, ``step`` the largest
    OPD difference (waves) between neighbouring unvignetted samples."""
    X, Y, inside = _square_pupil(grid)
    w = seq.wavefront(field, X[inside], Y[inside], lam)
    if not bool(w.valid.any()):
        raise ValueError(f"field {field:g}: every ray is vignetted")
    amp = torch.zeros(grid, grid, dtype=torch.float64, device=X.device)
    phase = torch.zeros(grid, grid, dtype=torch.float64, device=X.device)
    idx = torch.nonzero(inside, as_tuple=True)
    v = w.valid
    amp[idx[0][v], idx[1][v]] = 1.0
    phase[idx[0][v], idx[1][v]] = w.opd_waves[v] - w.opd_waves[v].mean()
    both_x, both_y = (amp[:, 1:] * amp[:, :-1]) > 0, (amp[1:] * amp[:-1]) > 0
    dx, dy = (phase[:, 1:] - phase[:, :-1]).abs()[both_x], (phase[1:] - phase[:-1]).abs()[both_y]
    step = max(float(dx.max()) if dx.numel() else 0.0, float(dy.max()) if dy.numel() else 0.0)
    return w, amp, phase, step


def field_quality(seq: SequentialLens, field: float, frequencies_cpmm=DEFAULT_MTF_FREQUENCIES_CPMM, *,
                  grid: int = REPORT_GRID, wavelength_um: float | None = None) -> dict:
    """The figures of one field (see the module docstring): a dict of floats and lists.

    The PSF, and with it the Strehl ratio and the MTF, holds the blur only where the pupil's phase is sampled finely
    enough: at most :data:`MAX_PHASE_STEP_WAVES` between neighbouring samples (beyond, the rays' slopes alias and the
    PSF wraps round its grid). The grid is doubled until it is (up to :data:`MAX_REPORT_GRID`); where it cannot be,
    the Strehl ratio and the MTF are None and ``psf_not_sampled`` says why (the ray figures stay: they are exact)."""
    lam = seq.primary_wavelength_um if wavelength_um is None else float(wavelength_um)
    w, amp, phase, step = _pupil_phase(seq, field, lam, grid)
    while step > MAX_PHASE_STEP_WAVES and grid < MAX_REPORT_GRID:
        need = grid * step / MAX_PHASE_STEP_WAVES  # the step shrinks as the grid grows (a smooth wavefront)
        if need > 2 * MAX_REPORT_GRID:
            break  # no grid within the bound would do: not traced again
        grid = min(MAX_REPORT_GRID, 2 ** math.ceil(math.log2(need)))
        w, amp, phase, step = _pupil_phase(seq, field, lam, grid)
    rays = {"rms_opd_waves": w.rms_waves(), "pv_opd_waves": w.pv_waves(), "rms_spot_um": w.rms_spot_mm() * 1e3,
            "vignetted_fraction": w.vignetted_fraction, "chief_ray_image_height_mm": float(w.chief_mm[1]),
            "pupil_grid": grid}
    if step > MAX_PHASE_STEP_WAVES:
        return {**rays, "strehl": None, "mtf_sagittal": [None] * len(frequencies_cpmm),
                "mtf_tangential": [None] * len(frequencies_cpmm),
                "psf_not_sampled": f"the wavefront changes by up to {step:.3g} waves between neighbouring samples of a "
                                   f"{grid} x {grid} pupil grid (at most {MAX_PHASE_STEP_WAVES:g} resolves the PSF): "
                                   "the blur is too large for a diffraction PSF; no Strehl ratio or MTF"}
    m = grid * PSF_PADDING
    pupil = torch.zeros(m, m, dtype=torch.complex128, device=amp.device)
    pupil[:grid, :grid] = amp * torch.exp(2j * math.pi * phase)
    field_ = torch.fft.fft2(pupil)
    psf = abs_square(field_)
    strehl = float(psf.max() / amp.sum() ** 2)  # the aberration-free pupil's peak is (sum A)^2
    otf = torch.fft.ifft2(psf)
    mtf = (otf.abs() / otf.abs()[0, 0])
    n_w = seq.paraxial(lam).working_f_number
    cutoff = 1.0 / (lam * 1e-3 * n_w)  # cycles/mm
    out_s, out_t = [], []
    for nu in frequencies_cpmm:
        k = nu / cutoff * grid  # pupil-sample shift of this frequency
        if k >= grid:
            out_s.append(0.0)
            out_t.append(0.0)
            continue
        k0, frac = int(math.floor(k)), k - math.floor(k)
        out_s.append(float((1 - frac) * mtf[0, k0] + frac * mtf[0, k0 + 1]))
        out_t.append(float((1 - frac) * mtf[k0, 0] + frac * mtf[k0 + 1, 0]))
    return {**rays, "strehl": strehl, "mtf_sagittal": out_s, "mtf_tangential": out_t, "psf_not_sampled": None}


def lens_report(seq: SequentialLens, fields=None, frequencies_cpmm=DEFAULT_MTF_FREQUENCIES_CPMM, *,
                grid: int = REPORT_GRID) -> dict:
    """Paraxial data, Seidel sums and per-field figures of a lens at its primary wavelength (a JSON-ready dict;
    lists per field in the order of ``fields``, default the prescription's)."""
    p = seq.prescription
    fields = tuple(p.fields if fields is None else fields)
    par = seq.paraxial()
    per = [field_quality(seq, f, frequencies_cpmm, grid=grid) for f in fields]
    seidel = seq.seidel_surfaces(max(fields)).sum(0)
    key = "field_angles_deg" if p.object_at_infinity else "object_heights_mm"
    out = {
        "name": p.name, "wavelength_um": par.wavelength_um,
        "efl_mm": par.efl_mm, "bfl_mm": par.bfl_mm, "epd_mm": par.epd_mm, "f_number": par.f_number,
        "working_f_number": par.working_f_number, "entrance_pupil_z_mm": par.entrance_pupil_z_mm,
        "exit_pupil_z_mm": par.exit_pupil_z_mm, "exit_pupil_diameter_mm": par.exit_pupil_diameter_mm,
        "paraxial_image_z_mm": par.image_z_mm, "image_z_mm": seq.image_z_mm,
        "paraxial_image_heights_mm": [float(h) for h in seq.paraxial_heights(fields)],
        "seidel_sums_mm": {"field": max(fields), **dict(zip(("S_I", "S_II", "S_III", "S_IV", "S_V"),
                                                              (float(v) for v in seidel)))},
        key: list(fields),
        "mtf_frequencies_cpmm": list(frequencies_cpmm),
    }
    for k in per[0]:
        out[k] = [d[k] for d in per]
    return out
