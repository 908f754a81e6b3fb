"""The third-order (Seidel) wavefront of any centred sequential lens: the paper's Eq. (2) generalised from the thin
singlet to a prescription, for ``lenssim tradeoff --wavefront third_order``.

At field angle ``alpha`` and wavelength ``lambda`` the wavefront is a sum of the pupil monomials of
:data:`SEIDEL_TERMS` (``rho_r`` towards the image point, as :mod:`lenssim.optics.aberrations`)::

    W = S_I/8 rho^4 + S_II/2 rho^3 cos(theta) + S_III/2 rho^2 cos^2(theta) + ((S_III + S_IV)/4 + W020) rho^2
        + W111 rho cos(theta)

with the Seidel sums ``S_I .. S_IV`` summed surface by surface at ``lambda`` (Welford, *Aberrations of Optical
Systems*, Ch. 7: :meth:`lenssim.optics.sequential.SequentialLens.seidel_surfaces`, conics and ``A4`` included; the
paper's closed form for its thin lens with the stop on it is the special case, to 1e-10). ``S_V`` (distortion) is
left out: each PSF is about its Gaussian image point at the primary wavelength (the image registered, as the paper's
singlet and the exact route's default). Beyond the paper's monochromatic singlet, two first-order terms:

* ``W020`` (defocus): the image plane's distance ``delta`` beyond the paraxial focus at ``lambda`` (the design's
  image shift, and axial colour at other wavelengths): ``W020 = n' u'^2 delta t_f / (2 (t_f + delta))``, ``u'`` the
  marginal ray's image-space slope at ``lambda`` and ``t_f`` the exit pupil's distance to its focus (for the thin
  lens: :func:`lenssim.optics.aberrations.defocus_mm`'s ``delta y^2 / (2 t_f t_img)``);
* ``W111`` (lateral colour): the tilt that moves the PSF at ``lambda`` by ``Delta``, the paraxial chief ray's height
  on the image plane at ``lambda`` less the primary wavelength's (towards the image point): ``W111 = -n' (h_xp /
  t_img) Delta`` (the transverse aberration ``eps = -(t_img / (n' h_xp)) dW/drho``); zero at the primary wavelength.

Higher-order asphere coefficients (``A6`` ...) and vignetting do not enter third order: a trade-off that varies them
is refused (:func:`check_third_order_parameters`). The PSF's scale is the image-space working F-number
``N_w = 1 / (2 n' |u'|)``: :func:`equivalent_thin_lens` is the thin lens with that F-number and the entrance pupil, the
camera on which the paper's OTF criteria (:func:`lenssim.metrics.otf_criteria_bank`) read these coefficients.
"""

from __future__ import annotations

import math

import torch

from ..model.lens import Lens
from .aberrations import TERMS, Term
from .sequential import SequentialLens

__all__ = ["SEIDEL_TERMS", "third_order_coefficients", "equivalent_thin_lens", "check_third_order_parameters",
           "THIRD_ORDER_KINDS"]

SEIDEL_TERMS = TERMS + (Term("W111", 0, 1),)
"""The paper's four monomials (:data:`lenssim.optics.aberrations.TERMS`) and the lateral-colour tilt ``rho_r``."""

THIRD_ORDER_KINDS = ("curvature", "radius", "conic", "thickness", "A4", "bending", "focus")
"""Free-parameter kinds (:mod:`lenssim.model.lens_parameters`) that change the third-order wavefront."""


def _image_space(seq: SequentialLens, h: float, u: float, lam: float) -> tuple[float, float]:
    """A paraxial ray's height on the last surface and its slope after it."""
    hs, us = seq._ynu(h, u, lam)
    return hs[-1], us[-1]


def _first_order(seq: SequentialLens, alpha_deg: float, lam: float) -> tuple[float, float, float]:
    """At ``lam``: the defocus ``W020`` (mm), the factor ``n' h_xp / t_img`` of the tilt, and the paraxial chief ray's
    height (mm) on the image plane at ``alpha_deg``."""
    p = seq.prescription
    par = seq.paraxial(lam)
    n_img = seq.index_after(len(p.surfaces) - 1, lam)
    z_last = float(seq._z[-1])
    r_ep = p.entrance_pupil_diameter_mm / 2
    mh, mu = _image_space(seq, r_ep, 0.0, lam)
    z_f = z_last - mh / mu
    delta = seq.image_z_mm - z_f
    if math.isfinite(par.exit_pupil_z_mm):
        t_f = z_f - par.exit_pupil_z_mm
        ratio = t_f / (t_f + delta)  # h_xp / t_img = |u'| t_f / t_img
    else:  # image-side telecentric: the exit pupil at infinity
        ratio = 1.0
    w020 = n_img * mu**2 * delta * ratio / 2
    tilt = n_img * abs(mu) * ratio
    t = math.tan(math.radians(alpha_deg))
    ch, cu = _image_space(seq, -par.entrance_pupil_z_mm * t, t, lam)
    return w020, tilt, ch + cu * (seq.image_z_mm - z_last)


def third_order_coefficients(seq: SequentialLens, angles_deg, wavelengths_um) -> torch.Tensor:
    """The coefficients of :data:`SEIDEL_TERMS` in waves, ``(A, K, 5)`` float64, at field angles ``angles_deg``
    (deg, object at infinity) and ``wavelengths_um`` (see the module docstring): the centred lens's (misalignments
    are left out)."""
    p = seq.prescription
    if not p.object_at_infinity:
        raise ValueError("the third-order wavefront is for an object at infinity (field angles); this lens images a "
                         "finite object")
    lam0 = seq.primary_wavelength_um
    rows = []
    for a in angles_deg:
        a = float(a)
        y0 = _first_order(seq, a, lam0)[2]
        per = []
        for lam in wavelengths_um:
            lam = float(lam)
            S = seq.seidel_surfaces(a, lam).sum(0)
            w020, tilt, y = _first_order(seq, a, lam)
            toward = math.copysign(1.0, y0) if y0 else 0.0  # rho_r points from the axis to the image point
            w111 = -tilt * (y - y0) * toward
            lam_mm = lam * 1e-3
            per.append(torch.stack([S[0] / 8, S[1] / 2, S[2] / 2, (S[2] + S[3]) / 4 + w020,
                                    torch.tensor(w111, dtype=torch.float64, device=S.device)]) / lam_mm)
        rows.append(torch.stack(per))
    return torch.stack(rows)


def equivalent_thin_lens(seq: SequentialLens, angles_deg) -> Lens:
    """The thin lens that sets the PSF's scale on the sensor: the entrance pupil's radius and the image-space working
    F-number (``focal_length_mm = N_w x EPD``; for the paper's singlet, its own focal length), the field angles
    ``angles_deg``. Its glass and Seidel sums are not used: the wavefront is :func:`third_order_coefficients`."""
    par = seq.paraxial()
    epd = seq.prescription.entrance_pupil_diameter_mm
    return Lens(focal_length_mm=par.working_f_number * epd, pupil_radius_mm=epd / 2, glass=1.5,
                field_angles_deg=tuple(float(a) for a in angles_deg))


def check_third_order_parameters(parameters) -> None:
    """Refuse a free parameter that does not change the third-order wavefront (``A6`` and higher), in one line."""
    for par in parameters:
        if par.kind not in THIRD_ORDER_KINDS:
            raise ValueError(f"free parameter {par.name} does not enter the third-order wavefront (curvatures, conics, "
                             "A4, thicknesses, bendings and focus do): use --wavefront exact")
