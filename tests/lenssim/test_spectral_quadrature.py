"""The shared spectral quadrature (issue 21): a few wavelengths serve every colour channel.

References: the dense 5 nm table of colour-science (every wavelength of the colour model, the exact sum the
quadrature approximates), integrals of functions the rule must integrate exactly, and the per-channel path of the
metrics and PSFs (each channel computing its own wavelengths).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from lenssim import FAST_NUMERICS, Camera, Design, LensPSF, evaluate
from lenssim.model.numerics import Numerics
from lenssim.model.spectrum import (DEFAULT_SPECTRAL_TOL, Spectrum, channel_spectra, channel_table, shared_quadrature,
                                    shared_wavelengths)
from lenssim.optics.psf_bank import fft_size, otf_quarter_spectrum, psf_at, spectral_coefficients
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM

pytestmark = pytest.mark.filterwarnings("ignore::lenssim.validate.ModelValidityWarning")


def colour_camera(glass: str, angles=None) -> Camera:
    lens = dataclasses.replace(PAPER_LENS, glass=glass, **({} if angles is None else {"field_angles_deg": angles}))
    return Camera(lens, PAPER_SENSOR, PAPER_SPECTRUM, channels=channel_table())


def test_the_table_is_colour_sciences_data_on_shared_wavelengths():
    import colour

    tab = channel_table("Nikon 5100 (NPL)", "D65")
    assert shared_wavelengths(tab) and len(tab) == 3
    msds = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    lam_nm = np.asarray(msds.wavelengths)
    e = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(380, 780, 5)).values
    w = np.clip(msds.values[:, 1], 0, None) * e
    keep = np.isin(np.round(lam_nm), np.round(np.asarray(tab[1].wavelengths_um) * 1e3))
    np.testing.assert_allclose(tab[1].weights, w[keep] / w.sum(), rtol=1e-12)
    assert channel_spectra() == tab  # the default colour model is the table
    assert not shared_wavelengths(channel_spectra(per_channel=4))


def test_the_rule_integrates_functions_linear_in_the_arc_exactly_and_keeps_weights_nonnegative():
    tab = channel_table()
    lam = np.asarray(tab[0].wavelengths_um)
    arc = np.cumsum(np.r_[0.0, np.diff(lam) * (1 + 40 * (0.6 - lam[1:]) ** 2)]) * 100  # any increasing arc
    chans, est = shared_quadrature(tab, arc, 0.5)
    K = len(chans[0])
    assert 2 < K < len(lam) and shared_wavelengths(chans)
    nodes_u = np.interp(chans[0].wavelengths_um, lam, arc)
    for c, ch in enumerate(chans):
        w = np.asarray(ch.weights)
        assert (w >= 0).all() and math.isclose(w.sum(), 1.0, rel_tol=1e-12)
        for f in (lambda u: np.ones_like(u), lambda u: 3.0 - 0.7 * u):
            exact = float(np.dot(tab[c].weights, f(arc)))
            assert abs(float(np.dot(w, f(nodes_u))) - exact) < 1e-10 * max(1.0, abs(exact))
        # exp(i pi u), the OTF at the Nyquist frequency of a PSF moving by u px: not exact, and its error is at most
        # the indicator times the arc's span (the bound before the division by the span)
        ex = np.dot(tab[c].weights, np.exp(1j * math.pi * arc))
        ap = np.dot(w, np.exp(1j * math.pi * nodes_u))
        assert 1e-6 < abs(ex - ap) <= est[c] * (arc[-1] - arc[0])
    assert (est <= 0.5).all()


def test_a_smaller_bound_takes_more_wavelengths_and_the_whole_table_is_exact():
    tab = channel_table()
    cam = colour_camera("N-BK7")
    arc = cam.spectral_arc_px(tab[0].wavelengths_um)
    counts = [len(shared_quadrature(tab, arc, tol)[0][0]) for tol in (1.0, 0.2, 0.05)]
    assert counts[0] < counts[1] < counts[2]
    full, est = shared_quadrature(tab, arc, 1e-9)
    assert full == tab and not est.any()


def test_reducing_twice_changes_nothing():
    """A camera already on its shared wavelengths is not reduced again (its nodes are no table), so evaluating or
    blurring with it gives what the table camera gives."""
    cam = colour_camera("N-BK7", angles=(0.0, 10.0))
    assert cam.with_quadrature(1e-9) == cam  # the whole table, which stays a table
    q = cam.with_quadrature(DEFAULT_SPECTRAL_TOL)
    assert len(q.channels[0]) < len(cam.channels[0])
    assert q.with_quadrature(DEFAULT_SPECTRAL_TOL) is q and q.with_quadrature(0.05) is q
    d = Design(s=-0.775, Q_back=-2.4)
    a = evaluate(cam, d, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)["mse_r_per_channel"]
    b = evaluate(q, d, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)["mse_r_per_channel"]
    torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_the_count_follows_the_glass_dispersion():
    """More axial colour (a longer spectral arc) takes more wavelengths: the paper's glass (no dispersion: only the
    Airy scale changes) fewest, the flint N-SF5 most."""
    k = {g: len(colour_camera(g).with_quadrature(DEFAULT_SPECTRAL_TOL).channels[0]) for g in ("paper", "N-BK7", "PMMA", "N-SF5")}
    assert k["paper"] < k["N-BK7"] <= k["PMMA"] < k["N-SF5"] <= 32
    assert k["N-BK7"] < 48 / 2  # fewer than half the former 16 per channel


def test_the_arc_is_the_marginal_ray_shift_plus_the_airy_scale():
    cam = colour_camera("N-BK7")
    lens = cam.lens
    lam = (0.4861, 0.5876, 0.6563)
    arc = cam.spectral_arc_px(lam)
    t = [lens.focus_distance_mm(v) for v in lam]
    ray = [lens.pupil_radius_mm * (lens.image_distance_mm - tv) / tv * 1e3 / cam.pixel_pitch_um for tv in t]
    airy = [v * lens.f_number / cam.pixel_pitch_um for v in lam]
    expect = abs(ray[1] - ray[0]) + abs(airy[1] - airy[0])
    assert arc[1] == pytest.approx(expect, rel=1e-12)
    # F to C: 0.39 mm of axial colour seen through f/6.25 is ~20 px of marginal ray shift
    assert 18 < arc[2] - (airy[2] - airy[0]) < 22


def test_the_shared_path_equals_each_channel_computing_its_own_wavelengths():
    cam = colour_camera("N-BK7", angles=(0.0, 9.0))
    q = cam.with_quadrature(DEFAULT_SPECTRAL_TOL)
    d = Design(s=torch.tensor([-0.775, -1.2]), Q_back=torch.tensor([-2.4, -1.0]))
    shared = evaluate(cam, d, [27.6], rho0=PAPER_RHO0, fft_size=384, numerics=FAST_NUMERICS)
    for c, sub in enumerate(q.channel_cameras()):
        one = evaluate(sub, d, [27.6], rho0=PAPER_RHO0, fft_size=384, numerics=FAST_NUMERICS)
        for k in ("mse_r", "mse_s", "strehl", "rms_w", "cost"):
            torch.testing.assert_close(shared[f"{k}_per_channel"][c], one[k], rtol=2e-6, atol=1e-9)
    # the PSF provider: one PSF per channel from the shared wavelengths, as each channel's own
    p = LensPSF(cam, Design(s=-0.775, Q_back=-2.4))
    rows, cols = torch.tensor([100, 1500]), torch.tensor([200, 2500])
    got = p.psf_at_pixels(rows, cols, (2000, 3000), 256)
    x, y = p.geometry.offsets_mm(rows, cols, (2000, 3000))
    dd = Design(s=torch.full((2,), -0.775, dtype=torch.float64), Q_back=torch.full((2,), -2.4, dtype=torch.float64))
    ref = torch.stack([psf_at(sub, dd, x, y, n=256)[0] for sub in q.channel_cameras()], dim=1)
    torch.testing.assert_close(got, ref, rtol=0, atol=1e-12)
    torch.testing.assert_close(got.sum(dim=(-2, -1)), torch.ones(2, 3, dtype=got.dtype), rtol=0, atol=1e-12)


def test_wavelengths_on_their_own_fft_size_equal_the_common_size_where_the_psf_fits():
    """Zero-padding a wavelength's PSF from the size it needs to the largest changes the OTF by the diffraction tails
    the smaller grid folds (the metrics' own sampling rule), not more."""
    cam = colour_camera("N-BK7", angles=(14.0,))
    nodes, w = cam.with_quadrature(DEFAULT_SPECTRAL_TOL).node_camera()
    d = Design(s=-0.775, Q_back=-2.4, focus_shift_um=-450.0).to(torch.float64).broadcast()
    c = spectral_coefficients(nodes, d).reshape(-1, len(nodes.spectrum), 4)
    per_k = fft_size(nodes, c, per_wavelength=True)[0]
    n = int(per_k.max())
    assert int(per_k.min()) < n  # some wavelength needs less than the largest
    a = otf_quarter_spectrum(nodes, c, n, channel_weights=w)
    b = otf_quarter_spectrum(nodes, c, n, channel_weights=w, wavelength_sizes=per_k.tolist())
    assert (a - b).abs().max() < 2e-3
    # exactly equal when every wavelength is given the common size
    same = otf_quarter_spectrum(nodes, c, n, channel_weights=w, wavelength_sizes=[n] * len(per_k))
    torch.testing.assert_close(same, a, rtol=0, atol=0)


@pytest.mark.parametrize("glass, design", [
    ("N-BK7", dict(s=-0.775, Q_back=-2.4, focus_shift_um=0.0)),  # d-line focus: blue and red 1-2 waves out
    ("N-SF5", dict(s=-1.329, Q_back=-1.88, focus_shift_um=-631.7)),  # the flint's white-light optimum
])
def test_the_default_quadrature_is_within_half_a_percent_of_the_dense_table(glass, design):
    """Every channel's MSE_R (the mean over the lens's 15 field angles) with the default shared wavelengths within 0.5%
    of every table wavelength (the whole design set: benchmarks/bench_spectral_quadrature.py, docs/white-light.md; a
    single field angle can be further off, up to 2% on the axis, where the chromatic blur is all the blur there is)."""
    cam = colour_camera(glass)
    d = Design(**design)
    got = evaluate(cam, d, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)["mse_r_per_channel"][:, 0]
    dense = evaluate(cam, d, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS.replace(spectral_tol=1e-9))
    ref = dense["mse_r_per_channel"][:, 0]
    assert len(cam.with_quadrature(1e-9).channels[0]) == len(channel_table()[0])
    assert ((got / ref - 1).abs() < 5e-3).all(), (got / ref - 1)


@pytest.mark.parametrize("glass", ["N-BK7", "N-SF5"])
def test_the_colour_psf_support_holds_every_channel_s_light(glass):
    """The support (diameter, px) the windows are sized by, scanned once over the shared wavelengths, holds each
    channel's computed PSF: outside that disc only diffraction's share is left (0.3% here; a support scanned over too
    few wavelengths, or a radius taken for the diameter, would leave out tens of percent)."""
    cam = colour_camera(glass)
    provider = LensPSF(cam, Design(s=-0.775, Q_back=-2.4, focus_shift_um=-342.4))
    center, row, col = (0.0, 0.0), torch.tensor([1700.0]), torch.tensor([2600.0])  # 11 degrees off axis
    ext = int(provider.extents_px(row, col, center)[0])
    n = 1024
    p = provider.psf_at_pixels(row, col, center, n)[0]  # (3, n, n), centred at [n/2, n/2]
    d = torch.arange(n, dtype=torch.float64) - n // 2
    r = torch.sqrt(d[:, None] ** 2 + d[None, :] ** 2)
    outside = (p * (r > (ext - provider.numerics.margin_px) / 2)).sum(dim=(-2, -1)) / p.sum(dim=(-2, -1))
    half_disc = (p * (r > (ext - provider.numerics.margin_px) / 4)).sum(dim=(-2, -1)) / p.sum(dim=(-2, -1))
    print(glass, ext, outside.tolist(), half_disc.tolist())
    assert 300 < ext < n - 100
    assert float(outside.max()) < 0.01
    assert float(half_disc.min()) > 0.01  # light reaches beyond half the radius: the support is not loose by 2x


def test_bad_quadrature_inputs_are_refused():
    tab = channel_table()
    arc = np.arange(len(tab[0]), dtype=float)
    with pytest.raises(ValueError, match="one table"):
        shared_quadrature(channel_spectra(per_channel=4), arc)
    with pytest.raises(ValueError, match="increasing"):
        shared_quadrature(tab, arc[::-1])
    with pytest.raises(ValueError, match="tol"):
        shared_quadrature(tab, arc, 0.0)
    with pytest.raises(ValueError, match="spectral_tol"):
        Numerics(spectral_tol=float("nan"))
    with pytest.raises(ValueError, match="channel_weights"):
        nodes = Camera(PAPER_LENS, PAPER_SENSOR, Spectrum((0.5, 0.6), (1, 1)))
        otf_quarter_spectrum(nodes, torch.zeros(1, 2, 4), 256, channel_weights=[[1.0, -1.0]])
