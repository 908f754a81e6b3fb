"""A Monte Carlo of manufactured copies of any sequential lens (issue 29: tolerances per surface).

:func:`run_lens_tolerance` draws ``N`` copies of a lens (:class:`lenssim.model.surface_tolerances.SurfaceTolerances`:
radius, thickness, conic and index per surface, the image plane's despace; each copy focused at assembly unless
switched off, :func:`manufactured_lens`) and evaluates each on the nominal lens's sensor, at a few field angles
(:data:`TOLERANCE_ANGLES`, from the axis to the largest, evenly) with
:func:`lenssim.metrics.evaluate_sequential`:

* ``mse_r``: Wiener-restored with the copy's own PSFs (a camera calibrated per unit);
* ``mse_r_nominal``: restored with the Wiener filter designed for the nominal lens (a camera that knows only the
  design): never below ``mse_r``, the matched filter being the minimum-MSE linear filter;
* ``mse_s`` (the sensor image) and ``rms_w`` (waves).

A copy with decentred or tilted surfaces or elements is not rotationally symmetric: it is evaluated along the four
image azimuths :data:`MISALIGNED_AZIMUTHS_DEG` (each as the ``+y`` field of
:meth:`lenssim.optics.sequential.SequentialLens.rotated`, the PSFs not mirror-symmetric, about the chief ray's point),
and its field average is over those too. Its image plane is focused on the centred copy's paraxial focus.

**Coarser numerics for the copies** (``coarse=True``, the default): each copy's wavefront table is traced at the
table's initial field-angle nodes only (:data:`lenssim.optics.sequential_psf.TABLE_INITIAL_NODES`, 9 from the axis
to the largest angle), without the bisection that otherwise adds nodes until the angle interpolation holds 0.01 wave
(every interval's mid-node is traced even when it passes, so the default table has at least 17 nodes: the coarse one
traces about half the rays). Everything else (pupil grid, FFT sizes, the MSE integrals' ``numerics``) is unchanged.
The nominal lens is evaluated twice: at the copies' numerics (the reference of ``mse_r_nominal`` and the ``nominal_*``
variables, so that a copy without errors equals it exactly) and at the default numerics; their relative difference is
reported as ``coarse_effect`` (measured in the summary of every run). Measured on the shipped lenses (4 angles):
the test singlet (3 deg) about 1e-6 relative on ``mse_r``; see ``docs/any-lens.md``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable

import torch

from .model.tolerances import (SurfacePerturbations, SurfaceTolerances, copy_misalignments,
                               perturbed_prescription)
from .optics.sequential import SequentialLens
from .optics.sequential_psf import TABLE_INITIAL_NODES, TABLE_MAX_NODES, SequentialPSF
from .metrics import evaluate_sequential, evaluation_angles
from .torch_utils import HOST, tensor_of

__all__ = ["manufactured_lens", "copy_provider", "nominal_criteria", "copy_criteria", "tolerance_angles",
           "lens_tolerance_dataset", "run_lens_tolerance", "summarise_lens_tolerance",
           "lens_tolerance_report", "TOLERANCE_ANGLES", "DEFAULT_LENS_COPIES", "CRITERIA"]

TOLERANCE_ANGLES = 4
"""Field angles of each copy's field average, from the axis to the largest, evenly."""
DEFAULT_LENS_COPIES = 20
"""Copies of a Monte Carlo of any lens by default: each traces its own wavefront table (seconds to tens of seconds
for a multi-element lens on a CPU), so a few tens; the mean of 20 copies is within about 20% (1 / sqrt(20) of the
spread) of the population's."""
CRITERIA = ("mse_s", "mse_r", "mse_r_nominal", "rms_w")
NOT_MODELLED = ("surface form (figure) errors, the image plane's tilt, and a decentred copy's own focus (the centred "
                "copy's paraxial focus is used)")
MISALIGNED_AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)
"""Image azimuths (deg) at which a decentred or tilted copy is evaluated (each field angle at each; a multiple of 90
degrees maps the pixel grid onto itself, so a centred lens gives the same value at each)."""
"""What a Monte Carlo of any lens leaves out (recorded with every run)."""


def manufactured_lens(nominal: SequentialLens, pert: SurfacePerturbations, i: int) -> SequentialLens:
    """Copy ``i`` of ``pert`` of the lens ``nominal`` (its prescription and image plane): radii, thicknesses and conics
    changed, index offsets on the glasses (their dispersion kept), and the image plane placed (see
    :mod:`lenssim.model.surface_tolerances`): with focus compensation its distance from the copy's paraxial focus
    (primary wavelength) is the nominal's, plus the despace; without, the nominal distance behind the last surface,
    plus the despace. Zero errors give the nominal lens exactly (same image shift, same :meth:`cache_key`)."""
    p0 = nominal.prescription
    p, offsets = perturbed_prescription(p0, pert, i)
    shift = nominal.image_shift_mm + float(pert.despace_mm[i])
    copy = SequentialLens(p, image_shift_mm=0.0, index_offsets=offsets)
    if pert.tolerances.focus_compensated:  # on the paraxial focus: the centred copy's (decentres and tilts left out)
        dz = copy.paraxial().image_z_mm - nominal.paraxial().image_z_mm  # the copy's focus moved by (0 if no error)
        shift += dz + (p0.image_z_mm - p.image_z_mm)
    return SequentialLens(p, image_shift_mm=shift, index_offsets=offsets, misalignments=copy_misalignments(p, pert, i))


def copy_provider(psf: SequentialPSF, lens: SequentialLens, *, coarse: bool = True) -> SequentialPSF:
    """The provider of ``lens`` on ``psf``'s sensor, light and field (its wavefront table at the initial nodes only
    with ``coarse``, see the module docstring)."""
    return dataclasses.replace(psf, lens=lens, table_max_nodes=TABLE_INITIAL_NODES if coarse else TABLE_MAX_NODES)


def _values(r: dict) -> dict:
    return {k: r[k] for k in CRITERIA if k in r}


def nominal_criteria(psf: SequentialPSF, snr_db, *, rho0: float, angles_deg, numerics, coarse: bool = True,
                     compare_default: bool = True):
    """The nominal lens of ``psf`` evaluated as the copies are: ``(provider, values, default_values)``: its provider at
    the copies' numerics (the reference of every copy's ``mse_r_nominal``), its criteria there, and its criteria at
    the default numerics (the same values when ``coarse`` is off or ``compare_default`` is False)."""
    kw = dict(rho0=rho0, angles_deg=angles_deg, numerics=numerics)
    nominal = copy_provider(psf, psf.lens, coarse=coarse)
    nom = _values(evaluate_sequential(nominal, snr_db, criteria=CRITERIA, reference=nominal, **kw))
    full = nom if not (coarse and compare_default) else _values(
        evaluate_sequential(copy_provider(psf, psf.lens, coarse=False), snr_db, criteria=CRITERIA, **kw))
    return nominal, nom, full


def copy_criteria(psf: SequentialPSF, nominal: SequentialPSF, pert: SurfacePerturbations, i: int, snr_db, *,
                  rho0: float, angles_deg, numerics, coarse: bool = True) -> dict:
    """Copy ``i`` of ``pert`` (:func:`manufactured_lens`) evaluated on ``psf``'s sensor and light at ``angles_deg``,
    restored with its own PSFs and with ``nominal``'s Wiener filter: the :data:`CRITERIA` (torch tensors, per SNR where
    they depend on it), its image-plane shift and its focal length (mm). A copy that cannot be evaluated is a
    ``ValueError`` naming it."""
    lens = manufactured_lens(psf.lens, pert, i)
    runs = []
    try:
        for phi in (0.0,) if lens.is_centred else MISALIGNED_AZIMUTHS_DEG:
            runs.append(_values(evaluate_sequential(copy_provider(psf, lens.rotated(phi), coarse=coarse), snr_db,
                                                    criteria=CRITERIA, reference=nominal, rho0=rho0,
                                                    angles_deg=angles_deg, numerics=numerics)))
    except ValueError as exc:
        raise ValueError(f"manufactured copy {i}: {exc}") from None
    if len(runs) == 1:
        r = runs[0]
    else:  # the field average over the azimuths too: the mean of the MSEs, the root of the mean square wavefront
        r = {k: torch.stack([v[k] for v in runs]).mean(dim=0) for k in CRITERIA if k != "rms_w"}
        r["rms_w"] = torch.stack([v["rms_w"] for v in runs]).square().mean().sqrt()
    return r | {"image_shift_mm": lens.image_shift_mm, "efl_mm": lens.paraxial().efl_mm}


def tolerance_angles(psf: SequentialPSF, angles_deg=None) -> tuple[float, ...]:
    """The field angles (deg) of a Monte Carlo: ``angles_deg``, or :data:`TOLERANCE_ANGLES` from the axis to the
    provider's largest, evenly."""
    return (evaluation_angles(psf.max_field_deg, TOLERANCE_ANGLES) if angles_deg is None
            else tuple(float(a) for a in angles_deg))


def lens_tolerance_dataset(psf: SequentialPSF, tolerances: SurfaceTolerances, pert: SurfacePerturbations, rows,
                           nom: dict, full: dict, *, snr_db, seed: int, angles_deg, rho0: float, coarse: bool):
    """The :class:`xarray.Dataset` ``(lens, snr)`` of a Monte Carlo from its per-copy ``rows``
    (:func:`copy_criteria`) and the nominal's values (:func:`nominal_criteria`): see :func:`run_lens_tolerance`."""
    import xarray as xr

    n = len(rows)
    snr = tensor_of(snr_db, torch.float64).reshape(-1)
    coords = {"lens": torch.arange(n, device=HOST).numpy(), "snr": snr.numpy()}
    data = {}
    for k in CRITERIA:
        per_snr = tensor_of(rows[0][k]).ndim > 0
        v = torch.stack([tensor_of(r[k], torch.float64) for r in rows]).numpy()
        data[k] = (("lens", "snr") if per_snr else ("lens",), v, {"units": "waves" if k == "rms_w" else "1"})
        data[f"nominal_{k}"] = (("snr",) if per_snr else (), tensor_of(nom[k]).numpy(),
                                {"about": "the nominal lens at the copies' numerics"})
        data[f"nominal_default_{k}"] = (("snr",) if per_snr else (), tensor_of(full[k]).numpy(),
                                        {"about": "the nominal lens at the default numerics"})
    for k in ("image_shift_mm", "efl_mm"):
        data[k] = (("lens",), torch.tensor([float(r[k]) for r in rows], dtype=torch.float64, device=HOST).numpy(),
                   {"units": "mm", "about": "the copy's image-plane shift from its own file's plane" if
                    k == "image_shift_mm" else "the copy's paraxial focal length (primary wavelength)"})
    for name, (v, unit, about) in pert.variables().items():
        data[f"error_{name}"] = (("lens",), v[:n].numpy(), {"units": unit, "about": about})
    attrs = {"lens": psf.lens.prescription.name, "prescription": json.dumps(psf.lens.prescription.to_dict(),
                                                                            default=str),
             "nominal_image_shift_mm": psf.lens.image_shift_mm, "nominal_efl_mm": psf.lens.paraxial().efl_mm,
             "tolerances": json.dumps(tolerances.to_dict()), "seed": int(seed), "angles_deg": list(angles_deg),
             "pixel_pitch_um": psf.sensor.pixel_pitch_um, "sampling": psf.sampling, "rho0": float(rho0),
             "coarse_numerics": int(bool(coarse)),
             "numerics": "copies: wavefront table at its initial field-angle nodes only" if coarse else "default",
             "not_modelled": NOT_MODELLED}
    return xr.Dataset({k: xr.Variable(*v) for k, v in data.items()}, coords=coords, attrs=attrs)


def run_lens_tolerance(psf: SequentialPSF, tolerances: SurfaceTolerances, n: int, *, seed: int, snr_db, rho0: float,
                       angles_deg=None, coarse: bool = True, numerics=None, compare_default: bool = True,
                       progress: Callable[[int], None] | None = None):
    """``n`` copies of ``psf.lens`` (see the module docstring) as an :class:`xarray.Dataset` ``(lens, snr)``: the
    criteria per copy, the sampled errors per copy (one variable per surface and term), the nominal lens's criteria
    (``nominal_*``, at the copies' numerics; ``nominal_default_*`` at the default numerics), and the run's settings
    as attributes (``compare_default=False``: the nominal's default-numerics values are not computed, and are the
    coarse ones). ``progress(k)`` is called with the number of copies done. In memory, in one go: the resumable run
    is :mod:`lenssim_studies.lens_tolerance`'s."""
    from .model.numerics import DEFAULT_NUMERICS

    numerics = DEFAULT_NUMERICS if numerics is None else numerics
    angles = tolerance_angles(psf, angles_deg)
    pert = tolerances.sample(psf.lens.prescription, n, seed=seed)
    kw = dict(rho0=rho0, angles_deg=angles, numerics=numerics)
    nominal, nom, full = nominal_criteria(psf, snr_db, coarse=coarse, compare_default=compare_default, **kw)
    rows = []
    for i in range(n):
        rows.append(copy_criteria(psf, nominal, pert, i, snr_db, coarse=coarse, **kw))
        if progress is not None:
            progress(1)
    return lens_tolerance_dataset(psf, tolerances, pert, rows, nom, full, snr_db=snr_db, seed=seed, angles_deg=angles,
                                  rho0=rho0, coarse=coarse)


def _snr_index(ds, ref_snr: float) -> int:
    snr = [float(v) for v in ds["snr"].values]
    for j, v in enumerate(snr):
        if math.isclose(v, ref_snr, abs_tol=1e-9):
            return j
    raise ValueError(f"reference SNR {ref_snr:g} dB is not allowed: one of the run's {snr}")


def summarise_lens_tolerance(ds, ref_snr: float) -> dict:
    """Mean, median and 90th percentile over the copies of ``mse_r`` and ``mse_r_nominal`` at ``ref_snr`` (and of
    ``mse_s``, ``rms_w``), with the nominal's values beside them, and the coarse numerics' effect on the nominal."""
    j = _snr_index(ds, ref_snr)
    out = {"reference_snr_db": float(ref_snr), "lenses": int(ds.sizes["lens"])}
    for k in CRITERIA:
        v = tensor_of(ds[k].values, torch.float64)
        nom = tensor_of(ds[f"nominal_{k}"].values, torch.float64)
        full = tensor_of(ds[f"nominal_default_{k}"].values, torch.float64)
        if v.ndim == 2:
            v, nom, full = v[:, j], nom[j], full[j]
        out[k] = {"mean": float(v.mean()), "median": float(v.median()) if v.numel() % 2 else float(v.quantile(0.5)),
                  "p90": float(v.quantile(0.9)), "min": float(v.min()), "max": float(v.max()),
                  "nominal": float(nom), "nominal_default_numerics": float(full),
                  "coarse_effect": float(nom / full - 1) if float(full) else 0.0}
    return out


def lens_tolerance_report(ds, summary: dict) -> str:
    """A short Markdown report of a run (:func:`run_lens_tolerance`, :func:`summarise_lens_tolerance`)."""
    tol = json.loads(ds.attrs["tolerances"])
    lines = [f"# Tolerance Monte Carlo: {ds.attrs['lens'] or 'lens'}", "",
             f"{summary['lenses']} manufactured copies (seed {ds.attrs['seed']}), pixels "
             f"{ds.attrs['pixel_pitch_um']:.4g} um ({ds.attrs['sampling']}), field angles "
             + ", ".join(f"{a:.3g}" for a in ds.attrs["angles_deg"]) + " deg, SNR "
             f"{summary['reference_snr_db']:g} dB.", "",
             "Tolerances (+/- limits, each 2 standard deviations): " + ", ".join(
                 f"{k} {v:g}" for k, v in tol.items() if k != "focus_compensated")
             + f"; focus compensated: {'yes' if tol['focus_compensated'] else 'no'}. Not modelled: "
             + ds.attrs["not_modelled"] + ".",
             "", "| criterion | nominal | mean | median | p90 | max |", "|---|---|---|---|---|---|"]
    for k in CRITERIA:
        s = summary[k]
        lines.append(f"| {k} | {s['nominal']:.5g} | {s['mean']:.5g} | {s['median']:.5g} | {s['p90']:.5g} | "
                     f"{s['max']:.5g} |")
    lines += ["", "mse_r: restored with each copy's own PSFs; mse_r_nominal: with the Wiener filter of the nominal "
              "lens. Copies at coarser numerics (" + ds.attrs["numerics"] + "): the nominal's mse_r differs from the "
              f"default numerics by {summary['mse_r']['coarse_effect']:+.2e} (relative).", ""]
    return "\n".join(lines)
