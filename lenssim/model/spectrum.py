"""The light the lens images: wavelengths (um) with relative weights.

The paper works at one wavelength, 0.5 um (:data:`lenssim.paper.PAPER_SPECTRUM`). A PSF for a
spectrum is the weighted sum of the unit-sum PSFs at each wavelength on the sensor's fixed pixel
grid (each wavelength has its own pupil scale), so its OTF is the weighted sum of the OTFs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..validate import listed, quoted

__all__ = ["Spectrum", "channel_spectra", "channel_table", "camera_sensitivity_names", "shared_wavelengths",
           "shared_quadrature", "DEFAULT_WAVELENGTHS_PER_CHANNEL", "DEFAULT_SPECTRAL_TOL"]

DEFAULT_WAVELENGTHS_PER_CHANNEL = 16
"""The former default (before issue 21) of ``channel_spectra(per_channel=...)``, each channel on its own wavelengths
(equal-weight quadrature of sensitivity x illuminant); the default colour model is now the 5 nm table through the
shared quadrature, which is more accurate with 17-24 wavelengths in all. Chosen by the
convergence test in tests/lenssim/test_colour.py: per-channel MSE_R of the paper's end-to-end design in N-BK7
focused at the d line (the harshest case: blue and red 1-2 waves out of focus) within 0.7% of the 32-wavelength
value (measured 0.23 / 0.19 / 0.64% for R / G / B; against 48 wavelengths 0.26 / 0.21 / 0.50%; with 5
wavelengths up to 4%)."""


DEFAULT_SPECTRAL_TOL = 0.2
"""Error indicator bound (px) of the shared spectral quadrature (:func:`shared_quadrature`; 17 / 18 / 24 wavelengths
for N-BK7 / PMMA / N-SF5 behind the Nikon 5100 channels). Against the dense 5 nm table
(benchmarks/bench_spectral_quadrature.py, docs/white-light.md) every channel's MSE_R is within 0.5% at 32 of the
33 tested designs in N-BK7, N-SF5 and PMMA; the exception, N-BK7's RMS_W optimum (focus -914 um), is 1.0% off in
blue (0.16% for the channel mean); 0.1 px (22 wavelengths) brings it to 0.4%."""


@dataclass(frozen=True)
class Spectrum:
    """Wavelengths ``wavelengths_um`` (> 0) with weights (>= 0, normalised here to sum 1)."""

    wavelengths_um: tuple[float, ...]
    weights: tuple[float, ...]
    name: str = ""

    def __post_init__(self):
        try:
            lam = tuple(float(v) for v in self.wavelengths_um)
            w = tuple(float(v) for v in self.weights)
        except (TypeError, ValueError):
            raise ValueError(f"spectrum {self.wavelengths_um!r} / {self.weights!r} is not allowed: "
                             "sequences of numbers") from None
        if not lam or len(lam) != len(w):
            raise ValueError(f"spectrum: {len(lam)} wavelengths and {len(w)} weights; give at least one of each, "
                             "equally many")
        if not all(math.isfinite(v) and v > 0 for v in lam):
            raise ValueError(f"wavelengths_um={lam!r} is not allowed: finite values > 0 um")
        if not all(math.isfinite(v) and v >= 0 for v in w) or not sum(w) > 0:
            raise ValueError(f"weights={w!r} is not allowed: finite values >= 0 with a positive sum")
        total = sum(w)
        object.__setattr__(self, "wavelengths_um", lam)
        object.__setattr__(self, "weights", tuple(v / total for v in w))
        if not self.name:
            object.__setattr__(self, "name", f"monochromatic {lam[0]:g} um" if len(lam) == 1
                               else f"{len(lam)} wavelengths {min(lam):g}-{max(lam):g} um")

    @classmethod
    def monochromatic(cls, wavelength_um: float) -> "Spectrum":
        return cls((wavelength_um,), (1.0,))

    def __len__(self) -> int:
        return len(self.wavelengths_um)

    @property
    def reference_um(self) -> float:
        """Weighted mean wavelength (um): the unit of wavefront errors reported in waves."""
        if len(self.wavelengths_um) == 1:
            return self.wavelengths_um[0]
        return sum(l * w for l, w in zip(self.wavelengths_um, self.weights))

    @property
    def shortest_um(self) -> float:
        return min(self.wavelengths_um)

    def to_dict(self) -> dict:
        return {"wavelengths_um": list(self.wavelengths_um), "weights": list(self.weights), "name": self.name}


def camera_sensitivity_names() -> list[str]:
    """Camera RGB sensitivities that colour-science ships (``colour.MSDS_CAMERA_SENSITIVITIES``)."""
    import colour

    return sorted(colour.MSDS_CAMERA_SENSITIVITIES)


def channel_spectra(camera: str = "Nikon 5100 (NPL)", illuminant: str = "D65",
                    per_channel: int | None = None) -> tuple[Spectrum, ...]:
    """One :class:`Spectrum` per colour channel: the camera's spectral sensitivity times the illuminant,
    both from colour-science's data sets; ``per_channel=None`` (the default): on the data's 5 nm table
    (:func:`channel_table`), which the optics integrate with a few wavelengths shared by all channels
    (:func:`shared_quadrature`, under ``Numerics.spectral_tol``); an integer: sampled at ``per_channel``
    wavelengths of the channel's own (the former quadrature, 16 by default before issue 21).

    Quadrature: the channel's weight ``w(lambda)`` (5 nm table, piecewise constant) is cut into
    ``per_channel`` bins of equal weight; each bin contributes its weighted mean wavelength with its
    weight. Channels in the camera's order (red, green, blue).
    """
    import numpy as np

    if per_channel is None:
        return channel_table(camera, illuminant)
    if isinstance(per_channel, bool) or not isinstance(per_channel, int) or not 1 <= per_channel <= 64:
        raise ValueError(f"per_channel={per_channel!r} is not allowed: a whole number in [1, 64]")
    lam_nm, table_w, labels = _camera_weights(camera, illuminant)
    out = []
    for c, label in enumerate(labels):
        w = table_w[c]
        cdf = np.concatenate([[0.0], np.cumsum(w)]) / w.sum()
        edges = np.linspace(0, 1, per_channel + 1)
        lams, weights = [], []
        for a, b in zip(edges[:-1], edges[1:]):
            # share of each 5 nm sample inside the bin [a, b] of cumulative weight
            share = np.clip(np.minimum(cdf[1:], b) - np.maximum(cdf[:-1], a), 0, None) * w.sum()
            lams.append(float((share * lam_nm).sum() / share.sum()) * 1e-3)
            weights.append(float(share.sum()))
        out.append(Spectrum(tuple(lams), tuple(weights), name=f"{camera} {label}, {illuminant}, {per_channel} wavelengths"))
    return tuple(out)


def _camera_weights(camera: str, illuminant: str):
    """The 5 nm table: wavelengths (nm) ``(J,)``, the channels' weights (sensitivity x illuminant) ``(C, J)``, labels."""
    import colour
    import numpy as np

    if camera not in colour.MSDS_CAMERA_SENSITIVITIES:
        raise ValueError(f"camera sensitivities {quoted(camera)} are not known; choose from "
                         f"{listed(camera_sensitivity_names(), near=[camera])}")
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"illuminant {quoted(illuminant)} is not known; e.g. D65, A, D50")
    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    lam_nm = np.asarray(msds.wavelengths, dtype=np.float64)
    ill = colour.SDS_ILLUMINANTS[illuminant].copy().align(colour.SpectralShape(lam_nm[0], lam_nm[-1], lam_nm[1] - lam_nm[0]))
    e = np.asarray(ill.values, dtype=np.float64)
    w = np.clip(np.asarray(msds.values, dtype=np.float64), 0, None).T * e[None, :]
    return lam_nm, w, tuple(msds.labels)


def channel_table(camera: str = "Nikon 5100 (NPL)", illuminant: str = "D65") -> tuple[Spectrum, ...]:
    """One :class:`Spectrum` per colour channel on the data's own wavelengths (colour-science's 5 nm table of the
    camera's sensitivity times the illuminant, 380-780 nm, where a channel's weight may be 0): the colour model itself,
    every channel on the same wavelengths. The metrics and the PSFs integrate it with :func:`shared_quadrature`
    (a few wavelengths shared by all channels, chosen for the lens); this table is its dense reference."""
    lam_nm, w, labels = _camera_weights(camera, illuminant)
    keep = w.sum(axis=0) > 0  # a wavelength no channel sees is left out
    lam = tuple(float(v) * 1e-3 for v in lam_nm[keep])
    return tuple(Spectrum(lam, tuple(float(v) for v in w[c, keep]),
                          name=f"{camera} {label}, {illuminant}, {len(lam)} wavelengths (5 nm table)")
                 for c, label in enumerate(labels))


def shared_wavelengths(channels) -> bool:
    """True if every channel (at least one) integrates the same wavelengths (e.g. :func:`channel_table`)."""
    return bool(channels) and all(c.wavelengths_um == channels[0].wavelengths_um for c in channels[1:])


def shared_quadrature(channels, arc, tol: float = DEFAULT_SPECTRAL_TOL, *, max_nodes: int | None = None):
    """A few wavelengths shared by every channel, with a weight per channel, for channels on one table.

    ``channels``: spectra on the same wavelengths ``lambda_j`` (:func:`shared_wavelengths`); ``arc`` ``(J,)``: the
    spectral arc length at each ``lambda_j``, increasing: how far the PSF changes between wavelengths, in pixels of
    ray displacement (:meth:`lenssim.Camera.spectral_arc_px`). An OTF at ``nu`` cycles/pixel turns by
    ``2 pi nu du`` over an arc ``du``, so at the Nyquist frequency it is ``exp(i pi u)`` to first order.

    Rule: ``K`` nodes ``u_1 < ... < u_K`` spread over the table's span with density ``(w_max(u))^(1/3)`` (the
    optimal density of piecewise-linear interpolation whose error is weighted by ``w_max``, the largest channel
    weight per unit arc), and each table wavelength's weight split between the two nodes around it linearly in
    ``u`` (hat functions: the channel's OTF is integrated exactly where it is linear in ``u``, every weight >= 0).
    The error of interpolating ``exp(i pi u)`` linearly is at most ``(pi^2 / 2) (u - u_k)(u_{k+1} - u)``; its
    weighted sum over the table, divided by the table's whole arc ``U`` (px), is each channel's error indicator (px),
    and ``K`` is the smallest with every channel's indicator <= ``tol`` (at most ``max_nodes``, default every table
    wavelength: then the table itself, exact). The division by ``U`` is empirical: the MSE integrals weigh the low
    frequencies, which a wider chromatic blur leaves, and the convergence test against the table (N-BK7, N-SF5,
    PMMA: spans of 57-122 px) found the MSE_R error to follow ``indicator``, not the raw Nyquist bound.

    Returns ``(channels, indicators)``: the channels on the ``K`` nodes (a node's wavelength is interpolated in
    ``u``) and each channel's indicator (px).
    """
    import numpy as np

    if not shared_wavelengths(channels):
        raise ValueError("shared_quadrature needs channels on one table of wavelengths (see channel_table)")
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol={tol!r} is not allowed: a positive number (px, the error indicator's bound)")
    lam = np.asarray(channels[0].wavelengths_um, dtype=np.float64)
    m = np.asarray([c.weights for c in channels], dtype=np.float64)  # (C, J), each row sums to 1
    u = np.asarray(arc, dtype=np.float64).reshape(-1)
    J = lam.size
    if u.size != J or not np.all(np.isfinite(u)) or not np.all(np.diff(u) > 0):
        raise ValueError(f"arc: {u.size} finite, strictly increasing values expected, one per wavelength ({J})")
    if not np.all(np.diff(lam) > 0):
        raise ValueError("the channels' wavelengths must increase")
    max_nodes = J if max_nodes is None else max(2, min(int(max_nodes), J))
    if J <= 2:
        return tuple(channels), np.zeros(len(channels))
    # node density (w(u))^(1/2), w the largest channel weight per unit arc on each interval between table wavelengths
    # (1/2 beat the L1-optimal 1/3 and 0.7 in the convergence test: the tails carry little weight but long arcs)
    du = np.diff(u)
    dens = np.sqrt(0.5 * (m[:, 1:] + m[:, :-1]).max(axis=0) / du) + 1e-9
    g = np.concatenate([[0.0], np.cumsum(dens * du)])
    g /= g[-1]

    def rule(K):
        nodes_u = np.interp(np.linspace(0, 1, K), g, u)
        k = np.clip(np.searchsorted(nodes_u, u, side="right") - 1, 0, K - 2)
        a, b = nodes_u[k], nodes_u[k + 1]
        t = np.clip((u - a) / (b - a), 0, 1)
        W = np.zeros((m.shape[0], K))
        np.add.at(W.T, k, (m * (1 - t)).T)
        np.add.at(W.T, k + 1, (m * t).T)
        est = 0.5 * math.pi**2 * (m * ((u - a) * (b - u)).clip(min=0)).sum(axis=1) / (u[-1] - u[0])
        return nodes_u, W, est

    K = 2
    nodes_u, W, est = rule(K)
    while est.max() > tol and K < max_nodes:
        K += 1
        nodes_u, W, est = rule(K)
    if K >= J:
        return tuple(channels), np.zeros(len(channels))
    nodes_lam = tuple(float(v) for v in np.interp(nodes_u, u, lam))
    out = tuple(Spectrum(nodes_lam, tuple(float(v) for v in W[c]),
                         name=f"{ch.name.split(',')[0]}, {K} shared wavelengths") for c, ch in enumerate(channels))
    return out, est
