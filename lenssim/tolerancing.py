"""Manufactured copies of a lens, of either kind: their criteria over the field, restored with their own PSFs
(calibrated, ``mse_r``) and with the nominal lens's Wiener filter (``mse_r_nominal``: never below ``mse_r``, the matched
filter being the minimum-MSE linear filter).

**The paper's singlet** (:func:`as_built_criteria`, issues 19): the batched closed form, a third-order wavefront per
as-built lens (:func:`lenssim.optics.as_built.as_built_coefficients`) for ``N`` lenses at once, in bounded-memory chunks.
An as-built lens has no rotational symmetry, so its field is sampled at every field angle of the lens and at the
azimuths :data:`AZIMUTHS_DEG` (the axis once): a field average is the mean over each angle's azimuths, then over the
angles, as the nominal lens's is over its angles. Its OTFs come from the general (non-symmetric) path,
:func:`lenssim.optics.psf_bank.otf_quarter_pair`, and a criterion's full-plane mean is the mean of its two quarter
planes. The nominal lens's OTF at the same field point and FFT size is the reference of criteria that need one.

**Any sequential lens** (:func:`run_lens_tolerance`, issue 29: tolerances per surface): ``N`` copies drawn from a
:class:`lenssim.model.tolerances.SurfaceTolerances` (radius, thickness, conic and index per surface, the image
plane's despace, decentres and tilts; each copy focused at assembly unless switched off, :func:`manufactured_lens`),
each traced on real rays and evaluated on the nominal lens's sensor at a few field angles (:data:`TOLERANCE_ANGLES`,
from the axis to the largest, evenly) with :func:`lenssim.metrics.evaluate_sequential`: the
:data:`COPY_CRITERIA` ``mse_s``, ``mse_r``, ``mse_r_nominal`` and ``rms_w`` (waves). A copy with decentred or tilted
surfaces or elements is not rotationally symmetric: it is evaluated along the same image azimuths
:data:`AZIMUTHS_DEG` (each as the ``+y`` field of :meth:`lenssim.optics.sequential.SequentialLens.rotated`, the PSFs
not mirror-symmetric, about the chief ray's point), and its field average is over those too. Its image plane is focused
on the centred copy's paraxial focus.

**Coarser numerics for the copies** (``coarse=True``, the default): each copy's wavefront table is traced at the
table's initial field-angle nodes only (:data:`lenssim.optics.psf_bank.TABLE_INITIAL_NODES`, 9 from the axis
to the largest angle), without the bisection that otherwise adds nodes until the angle interpolation holds 0.01 wave
(every interval's mid-node is traced even when it passes, so the default table has at least 17 nodes: the coarse one
traces about half the rays). Everything else (pupil grid, FFT sizes, the MSE integrals' ``numerics``) is unchanged.
The nominal lens is evaluated twice: at the copies' numerics (the reference of ``mse_r_nominal`` and the ``nominal_*``
variables, so that a copy without errors equals it exactly) and at the default numerics; their relative difference is
reported as ``coarse_effect`` (measured in the summary of every run). Measured on the shipped lenses (4 angles):
the test singlet (3 deg) about 1e-6 relative on ``mse_r``; see ``docs/any-lens.md``.

The resumable Monte Carlo of either kind, its summaries and reports are :mod:`lenssim_studies.tolerance`'s.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable

import torch

from .criteria import CRITERIA, OTFContext, otf_criteria, quarter_weights
from .model.camera import Camera
from .model.design import Design
from .model.numerics import DEFAULT_NUMERICS, Numerics
from .model.tolerances import (Perturbations, SurfacePerturbations, SurfaceTolerances, Tolerances, copy_misalignments,
                               perturbed_prescription)
from .optics.as_built import AS_BUILT_TERMS, as_built_coefficients, field_points
from .optics.cost import slope_departure_cost
from .optics.exact_wavefront import pupil_quadrature
from .optics.image_model import image_psd_quarter, noise_variance
from .optics.psf_bank import fft_size, otf_quarter_pair, otf_quarter_spectrum
from .optics.sequential import SequentialLens
from .optics.psf_bank import TABLE_INITIAL_NODES, TABLE_MAX_NODES
from .optics.psf_provider import SequentialPSF
from .optics.aberrations import pupil_monomials
from .metrics import evaluate_sequential, evaluation_angles
from .torch_utils import HOST, abs_square, chunk_budget_bytes, tensor_of
from .validate import NumericalError, check_memory

__all__ = ["AZIMUTHS_DEG", "as_built_criteria", "AS_BUILT_CRITERIA", "manufactured_lens", "copy_provider",
           "nominal_criteria", "copy_criteria", "tolerance_angles", "lens_tolerance_dataset", "lens_copies",
           "run_lens_tolerance",
           "TOLERANCE_ANGLES", "DEFAULT_LENS_COPIES", "COPY_CRITERIA", "NOT_MODELLED"]

AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)
"""Azimuths (deg) at which an as-built lens's field is sampled, at each field angle (a singlet's, and a decentred or
tilted copy of any lens: a multiple of 90 degrees maps the pixel grid onto itself, so a centred lens gives the same
value at each)."""


def AS_BUILT_CRITERIA() -> tuple[str, ...]:
    """The criteria an as-built evaluation reports: every OTF criterion (those comparing with the nominal lens
    included), ``rms_w`` and ``cost``."""
    return otf_criteria(reference=True) + ("rms_w", "cost")


def _field_mean(v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Mean over field points ``(..., F)``: over each angle's azimuths, then over the angles."""
    out = []
    for a in torch.unique(alpha):
        out.append(v[..., alpha == a].mean(dim=-1))
    return torch.stack(out, dim=-1).mean(dim=-1)


def _otf(camera, coeffs, n, oversample, numerics, symmetric):
    """The two quarter planes ``(B, 2, m/2+1, m/2+1)``: of the general path, or for mirror-symmetric wavefronts the
    fast quarter bank twice (the two quarters are equal)."""
    if symmetric:
        H = otf_quarter_spectrum(camera, coeffs, n, oversample=oversample, numerics=numerics, terms=AS_BUILT_TERMS)
        return torch.stack([H, H], dim=1)
    return otf_quarter_pair(camera, coeffs, n, oversample=oversample, numerics=numerics, terms=AS_BUILT_TERMS)


def as_built_criteria(camera: Camera, design: Design, pert: Perturbations, snr_db, *, rho0: float,
                      psd_model: str = "discrete", numerics: Numerics = DEFAULT_NUMERICS, alpha_deg=None,
                      azimuths_deg=AZIMUTHS_DEG, dtype=torch.float32, device=None,
                      progress: Callable[[int], None] | None = None) -> dict:
    """Criteria of ``N`` as-built lenses of one design: ``{name: (N, S)}`` (``(N,)`` for a criterion that does not
    depend on the SNR) for the names of :func:`AS_BUILT_CRITERIA`, float64, field averages; ``mse_r`` is the lens
    restored with its own PSFs (calibrated), ``mse_r_nominal`` with the nominal lens's. Also ``snr_db`` ``(S,)``,
    ``alpha_deg`` and ``azimuth_deg`` ``(F,)`` (the field points) and ``fft_size`` ``(N, F)``.

    ``alpha_deg``: field angles (default the lens's). Rotationally symmetric lenses (no decentre, tilt or
    non-symmetric figure error: :attr:`Perturbations.rotationally_symmetric`) take one azimuth per angle and the
    mirror-symmetric OTF bank, chosen automatically. A colour camera is evaluated channel by channel and averaged,
    as :func:`lenssim.metrics.evaluate` does. ``progress(k)`` after each chunk of ``k`` OTFs.
    """
    if camera.channels:
        parts = [as_built_criteria(c, design, pert, snr_db, rho0=rho0, psd_model=psd_model, numerics=numerics,
                                   alpha_deg=alpha_deg, azimuths_deg=azimuths_deg, dtype=dtype, device=device,
                                   progress=progress)
                 for c in camera.with_quadrature(numerics.spectral_tol).channel_cameras()]
        out = dict(parts[0])
        for k in AS_BUILT_CRITERIA():
            out[k] = torch.stack([p[k] for p in parts]).mean(dim=0)
        out["fft_size"] = torch.stack([p["fft_size"] for p in parts]).amax(dim=0)
        return out
    d64 = design.to(torch.float64)
    d64.floats()  # one design
    camera.lens.check_design(d64)
    symmetric = pert.rotationally_symmetric  # the mirror-symmetric fast path, one azimuth per angle
    al, az = field_points(camera.lens.field_angles_deg if alpha_deg is None else alpha_deg,
                          azimuths_deg[:1] if symmetric else azimuths_deg)
    N, F, K = len(pert), al.numel(), len(camera.spectrum)
    c = as_built_coefficients(camera, d64, pert, al, az)  # (N, F, K, 6)
    c0 = as_built_coefficients(camera, d64, Tolerances().sample(1, seed=0), al, az)[0]  # (F, K, 6) the nominal
    if not bool(torch.isfinite(c).all()):
        raise NumericalError("an as-built wavefront is not finite; no result is reported")
    flat = c.reshape(N * F, K, len(AS_BUILT_TERMS))
    n_lens = fft_size(camera, flat, numerics, terms=AS_BUILT_TERMS).reshape(N, F)
    n_nom = fft_size(camera, c0, numerics, terms=AS_BUILT_TERMS)  # (F,)
    sizes = torch.maximum(n_lens, n_nom[None])  # the lens and its reference on one grid
    snr = tensor_of(snr_db, torch.float64).reshape(-1)
    sigma2 = noise_variance(snr).reshape(-1)
    S = snr.numel()
    names = otf_criteria(reference=True)
    per = {k: torch.empty((N, F, S) if CRITERIA[k].per_snr else (N, F), dtype=torch.float64, device=HOST)
           for k in names}
    oversample = numerics.oversample
    flat_sizes = sizes.reshape(-1)
    point = torch.arange(F, device=HOST).repeat(N)
    for n in torch.unique(flat_sizes).tolist():
        idx = torch.nonzero(flat_sizes == n).flatten()
        m = n * oversample
        psd_q = image_psd_quarter(m, rho0, model=psd_model, dtype=dtype, device=device)
        weights = quarter_weights(m, psd_q.dtype, psd_q.device)
        pw = psd_q * weights
        per_psf = 2 * 4 * m * m * (2 * dtype.itemsize)  # lens + reference, 2 quarters
        check_memory(per_psf, f"one as-built OTF of {m} x {m} samples", setting="max_fft_size")
        step = max(1, int(chunk_budget_bytes(device or HOST, numerics.chunk_bytes) // per_psf))
        nominal = {}
        for start in range(0, idx.numel(), step):
            sel = idx[start:start + step]
            H = _otf(camera, flat[sel].to(dtype=dtype, device=device), n, oversample, numerics, symmetric)
            pts = point[sel]
            need = sorted(set(pts.tolist()) - set(nominal))
            if need:
                H0 = _otf(camera, c0[need].to(dtype=dtype, device=device), n, oversample, numerics, symmetric)
                nominal.update({f: H0[i] for i, f in enumerate(need)})
            ref = torch.stack([nominal[f] for f in pts.tolist()])
            B = sel.numel()
            Hf, Rf = H.reshape(2 * B, *H.shape[-2:]), ref.reshape(2 * B, *H.shape[-2:])
            ctx = OTFContext(Hf, abs_square(Hf), psd_q, weights, pw, sigma2.to(psd_q.device), n,
                             camera, numerics, reference=Rf)
            for k in names:
                v = CRITERIA[k].from_otf(ctx).cpu()
                v = v.reshape(B, 2, *v.shape[1:]).mean(dim=1)
                per[k].reshape(N * F, *per[k].shape[2:])[sel] = v
            if progress is not None:
                progress(B)
    out = {}
    for k in names:
        v = per[k].movedim(1, -1) if CRITERIA[k].per_snr else per[k]  # (N, S, F) or (N, F)
        out[k] = _field_mean(v, al)
    # RMS_W as the paper's (no piston removed): sqrt of the field mean of the pupil mean of W^2, per wavelength
    rr, rt, w = pupil_quadrature()
    basis = pupil_monomials(rr, rt, AS_BUILT_TERMS)  # (6, P)
    spec = camera.spectrum
    ms = sum(wk * ((((c[..., k, :] * (lam / spec.reference_um)) @ basis) ** 2) * w).sum(-1)
             for k, (lam, wk) in enumerate(zip(spec.wavelengths_um, spec.weights)))  # (N, F) waves^2
    out["rms_w"] = torch.sqrt(_field_mean(ms, al))
    out["cost"] = slope_departure_cost(camera.lens, d64).reshape(()).expand(N).clone()
    out["snr_db"], out["alpha_deg"], out["azimuth_deg"], out["fft_size"] = snr, al, az, sizes
    for k in AS_BUILT_CRITERIA():
        if not bool(torch.isfinite(out[k]).all()):
            raise NumericalError(f"as-built criterion {k} is not finite (numerical breakdown); no result is reported")
    return out


TOLERANCE_ANGLES = 4
"""Field angles of each copy's field average, from the axis to the largest, evenly."""
DEFAULT_LENS_COPIES = 20
"""Copies of a Monte Carlo of any lens by default: each traces its own wavefront table (seconds to tens of seconds
for a multi-element lens on a CPU), so a few tens; the mean of 20 copies is within about 20% (1 / sqrt(20) of the
spread) of the population's."""
COPY_CRITERIA = ("mse_s", "mse_r", "mse_r_nominal", "rms_w")
"""The criteria of a manufactured copy of any lens (per SNR, but ``rms_w`` in waves)."""
NOT_MODELLED = ("surface form (figure) errors, the image plane's tilt, and a decentred copy's own focus (the centred "
                "copy's paraxial focus is used)")
"""What a Monte Carlo of any lens leaves out (recorded with every run)."""


def manufactured_lens(nominal: SequentialLens, pert: SurfacePerturbations, i: int) -> SequentialLens:
    """Copy ``i`` of ``pert`` of the lens ``nominal`` (its prescription and image plane): radii, thicknesses and conics
    changed, index offsets on the glasses (their dispersion kept), and the image plane placed (see
    :mod:`lenssim.model.tolerances`): with focus compensation its distance from the copy's paraxial focus
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


def _copy_values(r: dict) -> dict:
    return {k: r[k] for k in COPY_CRITERIA if k in r}


def nominal_criteria(psf: SequentialPSF, snr_db, *, rho0: float, angles_deg, numerics, coarse: bool = True,
                     compare_default: bool = True):
    """The nominal lens of ``psf`` evaluated as the copies are: ``(provider, values, default_values)``: its provider at
    the copies' numerics (the reference of every copy's ``mse_r_nominal``), its criteria there, and its criteria at
    the default numerics (the same values when ``coarse`` is off or ``compare_default`` is False)."""
    kw = dict(rho0=rho0, angles_deg=angles_deg, numerics=numerics)
    nominal = copy_provider(psf, psf.lens, coarse=coarse)
    nom = _copy_values(evaluate_sequential(nominal, snr_db, criteria=COPY_CRITERIA, reference=nominal, **kw))
    full = nom if not (coarse and compare_default) else _copy_values(
        evaluate_sequential(copy_provider(psf, psf.lens, coarse=False), snr_db, criteria=COPY_CRITERIA, **kw))
    return nominal, nom, full


def copy_criteria(psf: SequentialPSF, nominal: SequentialPSF, pert: SurfacePerturbations, i: int, snr_db, *,
                  rho0: float, angles_deg, numerics, coarse: bool = True) -> dict:
    """Copy ``i`` of ``pert`` (:func:`manufactured_lens`) evaluated on ``psf``'s sensor and light at ``angles_deg``,
    restored with its own PSFs and with ``nominal``'s Wiener filter: the :data:`COPY_CRITERIA` (torch tensors, per SNR
    where they depend on it), its image-plane shift and its focal length (mm). A copy that cannot be evaluated is a
    ``ValueError`` naming it."""
    lens = manufactured_lens(psf.lens, pert, i)
    runs = []
    try:
        for phi in (0.0,) if lens.is_centred else AZIMUTHS_DEG:
            runs.append(_copy_values(evaluate_sequential(copy_provider(psf, lens.rotated(phi), coarse=coarse), snr_db,
                                                         criteria=COPY_CRITERIA, reference=nominal, rho0=rho0,
                                                         angles_deg=angles_deg, numerics=numerics)))
    except ValueError as exc:
        raise ValueError(f"manufactured copy {i}: {exc}") from None
    if len(runs) == 1:
        r = runs[0]
    else:  # the field average over the azimuths too: the mean of the MSEs, the root of the mean square wavefront
        r = {k: torch.stack([v[k] for v in runs]).mean(dim=0) for k in COPY_CRITERIA if k != "rms_w"}
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
    for k in COPY_CRITERIA:
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


def lens_copies(psf: SequentialPSF, tolerances: SurfaceTolerances, n: int, *, seed: int, snr_db, rho0: float,
                angles_deg=None, coarse: bool = True, numerics=None, compare_default: bool = True):
    """A Monte Carlo of ``n`` copies of ``psf.lens`` made ready (see the module docstring), its nominal lens evaluated
    first (:func:`nominal_criteria`): ``(copy, dataset)``, ``copy(i)`` copy ``i``'s row (:func:`copy_criteria`),
    ``dataset(rows)`` the :class:`xarray.Dataset` of the rows of copies ``0..n-1`` (:func:`lens_tolerance_dataset`).
    Field angles ``angles_deg`` (None: :func:`tolerance_angles`); ``compare_default=False``: the nominal's
    default-numerics values are not computed, and are the coarse ones."""
    numerics = DEFAULT_NUMERICS if numerics is None else numerics
    angles = tolerance_angles(psf, angles_deg)
    pert = tolerances.sample(psf.lens.prescription, n, seed=seed)
    kw = dict(rho0=rho0, angles_deg=angles, numerics=numerics)
    nominal, nom, full = nominal_criteria(psf, snr_db, coarse=coarse, compare_default=compare_default, **kw)
    return (lambda i: copy_criteria(psf, nominal, pert, i, snr_db, coarse=coarse, **kw),
            lambda rows: lens_tolerance_dataset(psf, tolerances, pert, rows, nom, full, snr_db=snr_db, seed=seed,
                                                angles_deg=angles, rho0=rho0, coarse=coarse))


def run_lens_tolerance(psf: SequentialPSF, tolerances: SurfaceTolerances, n: int, *,
                       progress: Callable[[int], None] | None = None, **settings):
    """``n`` copies of ``psf.lens`` (:func:`lens_copies`, ``settings`` as there) as an :class:`xarray.Dataset`
    ``(lens, snr)``: the criteria per copy, the sampled errors per copy (one variable per surface and term), the
    nominal lens's criteria (``nominal_*``, at the copies' numerics; ``nominal_default_*`` at the default numerics),
    and the run's settings as attributes. ``progress(k)`` is called with the number of copies done. In memory, in one
    go: the resumable run is :func:`lenssim_studies.tolerance.run_tolerance`'s."""
    copy, dataset = lens_copies(psf, tolerances, n, **settings)
    rows = []
    for i in range(n):
        rows.append(copy(i))
        if progress is not None:
            progress(1)
    return dataset(rows)
