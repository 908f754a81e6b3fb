"""PSFs of any sequential lens (lenssim.optics.psf_bank, lenssim.optics.psf_provider.SequentialPSF), each check against something independent: the Airy
pattern's encircled energy (closed form), the rays' centroid (geometric optics), today's thin-lens PSFs, the lens's
mirror symmetry, and a table traced directly at the angle asked."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import Design
from lenssim.io.prescription_file import read_lens
from lenssim.model.prescription import Prescription
from lenssim.model.prescription import PrescriptionSurface as S
from lenssim.model.sensor import Sensor
from lenssim.model.spectrum import Spectrum
from lenssim.optics.sequential import SequentialLens, pupil_grid
from lenssim.optics.psf_bank import psfs_from_table, wavefront_table
from lenssim.optics.psf_provider import SequentialPSF

N_GLASS = 1.5
LAM = 0.55


def _sensor(pitch_um):
    return Sensor(pixel_pitch_um=pitch_um, width_px=1000, height_px=1000)


@pytest.fixture(scope="module")
def cooke():
    return SequentialLens(read_lens("cooke_triplet"))


def _centroid(p):
    n = p.shape[-1]
    c = torch.arange(n, dtype=torch.float64) - n // 2
    p = p.to(torch.float64)
    return float((p.sum(-1) * c).sum()), float((p.sum(-2) * c).sum())  # rows (y), cols (x)


def test_a_perfect_lens_gives_the_airy_pattern():
    f, epd = 50.0, 10.0  # F/5; flat side to the object, hyperbolic back: no aberration on axis
    p = Prescription((S(0.0, 3.0, (N_GLASS, 0.0)), S(-1 / ((N_GLASS - 1) * f), f, "air", conic=-N_GLASS**2)), 1, epd,
                     fields=(0.0, 1.0), wavelengths_um=(LAM,), primary_wavelength_um=LAM)
    seq = SequentialLens(p)
    F = seq.paraxial().working_f_number
    pitch = LAM * F / 4  # twice Nyquist: point samples resolve the rings
    prov = SequentialPSF(seq, _sensor(pitch), Spectrum.monochromatic(LAM), sampling="point")
    n = 129
    psf = prov.psf_at_pixels(torch.tensor([0.0]), torch.tensor([0.0]), (0.0, 0.0), n, dtype=torch.float64)[0]
    assert float(psf.sum()) == pytest.approx(1.0, abs=1e-12)
    c = torch.arange(n, dtype=torch.float64) - n // 2
    r = torch.hypot(c[:, None], c[None, :]) * pitch  # um
    from scipy.special import j0, j1

    k = prov.extent_px(torch.tensor([0.0]), torch.tensor([0.0]), (0.0, 0.0))  # the support computed (odd here)
    assert k < n
    level = float(psf[0, 0])  # the pedestal: the light beyond the support, spread evenly over the n x n grid
    for radius in (1.22 * LAM * F, 2.23 * LAM * F, 5.0 * LAM * F):  # first two dark rings, and beyond
        v = math.pi * radius / (LAM * F)
        expect = 1 - j0(v) ** 2 - j1(v) ** 2
        inside = r <= radius
        assert float(psf[inside].sum()) - level * int(inside.sum()) == pytest.approx(expect, abs=2e-3)
    assert float(psf[n // 2, n // 2]) == pytest.approx(float(psf.max()))
    # the pedestal's share is the Airy pattern's beyond the support: between its share beyond the square support's
    # circumscribed and inscribed circles
    share = level * n * n

    def beyond(radius_px):
        v = math.pi * radius_px * pitch / (LAM * F)
        return j0(v) ** 2 + j1(v) ** 2

    assert beyond(k / 2 * math.sqrt(2)) * 0.8 < share < beyond(k / 2) * 1.2


@pytest.mark.parametrize("field", [3.0, 8.0])
def test_the_psf_centroid_is_where_the_rays_land(cooke, field):
    """Geometric optics: the PSF's centroid is the centroid of the rays' image points (it holds for any aberration
    of a uniformly lit pupil; our PSF maps the pupil linearly, so it holds to the oblique beam's 1/cos factors)."""
    pitch = 4.0
    prov = SequentialPSF(cooke, _sensor(pitch), Spectrum.monochromatic(LAM), max_field_deg=10.0)
    g = prov.geometry
    r = g.radius_px(field)
    n = 2 * int(prov.extent_px(torch.tensor([r]), torch.tensor([0.0]), (0.0, 0.0))) | 1  # odd, wide: the wings too
    # the FFT's window itself, n x n (psf_at_pixels computes the PSF's support only and spreads the wings beyond it as
    # a uniform pedestal): the far wings' first moment converges slowly (their light falls as 1/r^3)
    x, y = g.offsets_mm(torch.tensor([r]), torch.tensor([0.0]), (0.0, 0.0))
    psf, held = psfs_from_table(prov.table(), prov.quadrature()[1], torch.tensor([field], dtype=torch.float64),
                                torch.atan2(y, x).to(torch.float64), n, prov.oversample(), prov.fft_size(n), pitch,
                                prov.working_f_number, prov.sampling, complex_dtype=torch.complex128)
    assert 0.999 < float(held) < 1  # the window holds all but the far wings
    cy, cx = _centroid(psf[0, 0])
    px, py = pupil_grid(96)
    w = cooke.wavefront(field, px, py, LAM)
    rays = w.image_mm[w.valid][:, 1].mean() - prov.image_scale_mm * math.tan(math.radians(field))
    rays_px = float(rays) / (pitch * 1e-3)
    chief_px = float(w.chief_mm[1] - prov.image_scale_mm * math.tan(math.radians(field))) / (pitch * 1e-3)
    assert abs(rays_px - chief_px) > 0.3  # the aberrations move the light: the check is not empty
    # 2% of the aberrations' shift: the real rays' directions are not quite linear in the pupil coordinate (1% at
    # this aperture); 0.03 px: the light beyond the PSF's window
    assert cy == pytest.approx(rays_px, abs=0.03 + 0.02 * abs(rays_px - chief_px))
    assert cx == pytest.approx(0.0, abs=1e-6)  # mirror symmetry about the meridional plane


def test_psfs_follow_the_lens_symmetry(cooke):
    prov = SequentialPSF(cooke, _sensor(6.0), Spectrum.monochromatic(LAM), max_field_deg=10.0)  # the table above
    r = prov.geometry.radius_px(6.0)
    d = r / math.sqrt(2)
    rows = torch.tensor([r, 0.0, -r, d, d])
    cols = torch.tensor([0.0, r, 0.0, d, -d])
    n = prov.extent_px(rows, cols, (0.0, 0.0))
    p = prov.psf_at_pixels(rows, cols, (0.0, 0.0), n, dtype=torch.float64)
    assert torch.allclose(p[1], p[0].T, atol=1e-10)  # +x is +y turned 90 degrees about the axis
    assert torch.allclose(p[2], p[0].flip(0).flip(1), atol=1e-10)
    assert torch.allclose(p[4], p[3].flip(1), atol=1e-10)  # mirror image about the column axis
    assert not torch.allclose(p[0], p[0].flip(0), atol=1e-3)  # off axis, the PSF is not symmetric radially


@pytest.mark.parametrize("n", [41, 60])
def test_a_wide_grid_holds_the_support_and_a_pedestal(cooke, n):
    """On a grid wider than the PSF's support ``k`` (the window of a blur), the PSF is the support's PSF, scaled by the
    light its window holds, in the middle, and the rest of the light spread evenly over the grid: unit sum, symmetric
    about the meridian (``k`` takes ``n``'s parity), no light moved into the core."""
    prov = SequentialPSF(cooke, _sensor(6.0), Spectrum.monochromatic(LAM), max_field_deg=10.0)
    r = torch.tensor([prov.geometry.radius_px(6.0)])
    c = torch.tensor([0.0])
    k = prov.extent_px(r, c, (0.0, 0.0))
    k += (n - k) % 2
    assert k < n
    p = prov.psf_at_pixels(r, c, (0.0, 0.0), n, dtype=torch.float64)[0]
    x, y = prov.geometry.offsets_mm(r, c, (0.0, 0.0))
    small, held = psfs_from_table(prov.table(), prov.quadrature()[1], torch.tensor([6.0], dtype=torch.float64),
                                  torch.atan2(y, x).to(torch.float64), k, prov.oversample(), prov.fft_size(k), 6.0,
                                  prov.working_f_number, prov.sampling, complex_dtype=torch.complex128)
    level = (1 - float(held)) / n**2
    assert 0 < level
    assert float(p.sum()) == pytest.approx(1.0, abs=1e-12)
    assert torch.allclose(p[0], torch.full((n,), level, dtype=torch.float64))  # beyond the support: the pedestal only
    o = n // 2 - k // 2
    assert torch.allclose(p[o:o + k, o:o + k], small[0, 0] * held + level, atol=1e-15)
    # the meridian is the column through the centre: column n//2 + d mirrors n//2 - d (an even grid's first column,
    # and an even support's, have no partner)
    d = torch.arange(k // 2 + k % 2)
    assert torch.allclose(p[:, n // 2 + d], p[:, n // 2 - d], atol=1e-12)


def test_a_table_traced_many_nodes_at_once_is_the_table_traced_node_by_node():
    """The double Gauss's table at a tolerance that refines it unevenly (19 nodes, bisected near the axis), its nodes
    traced in bundles (lenssim.optics.psf_bank.TABLE_TRACE_FIELDS; each node's map as alone, bit for bit:
    test_several_fields_at_once_are_each_field_traced_alone_bit_for_bit) and each round's mid-nodes checked in the
    bisection's order: the nodes and error the node-by-node table gave before bundles existed (1953cdf), and its sums
    pinned (2026-12-02; at 1953cdf, where every ray of a field stepped until the field's last had converged, they
    were 1.6e-9 relative higher: |OPD| 1449153.7119259683 waves, spots 8.624135074090853 mm)."""
    from lenssim.optics.psf_provider import image_scale_mm

    seq = SequentialLens(read_lens("double_gauss"))
    bundled = wavefront_table(seq, (0.5876,), max(seq.prescription.fields), image_scale_mm(seq), grid=32,
                              tolerance_waves=0.01)
    step = 12.41 / 32
    want = [0, 1, 2, 3, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30, 32]
    assert bundled.angles_deg.tolist() == pytest.approx([step * k for k in want], abs=1e-12)
    assert bundled.interpolation_error_waves == pytest.approx(0.009936937571858095, rel=1e-6)
    assert float(bundled.opd_waves.abs().sum()) == pytest.approx(1449153.7096748785, rel=1e-9)
    assert float(bundled.spot_radius_mm.sum()) == pytest.approx(8.624135072674692, rel=1e-9)
    assert float(bundled.distortion_mm.abs().sum()) == pytest.approx(2.2691957030620626, rel=1e-9)


def test_the_table_interpolates_to_the_directly_traced_psf(cooke):
    """Between the table's nodes, the OPD is within twice the table's tolerance of the OPD traced at that very angle
    (a table with the angle as a node), and the PSFs differ by no more than that phase error allows."""
    lam = (LAM,)
    scale = SequentialPSF(cooke, _sensor(5.0), Spectrum.monochromatic(LAM), max_field_deg=9.0).image_scale_mm
    table = wavefront_table(cooke, lam, 9.0, scale)
    assert table.interpolation_error_waves <= 0.01
    between = 0.5 * float(table.angles_deg[5] + table.angles_deg[6]) + 0.1
    direct = wavefront_table(cooke, lam, between, scale, max_nodes=0)  # no bisection: nodes 0..between evenly
    assert float(direct.angles_deg[-1]) == pytest.approx(between)
    a = torch.tensor([between], dtype=torch.float64)
    g = torch.linspace(-1, 1, 81, dtype=torch.float64)
    Y, X = torch.meshgrid(g, g, indexing="ij")
    W1, V1 = table.sample(0, a, X[None], Y[None])
    W2, V2 = direct.sample(0, a, X[None], Y[None])
    both = (V1 <= 1) & (V2 <= 1) & (X**2 + Y**2 <= 1)[None]
    assert int(both.sum()) > 0.8 * int(((V2 <= 1) & (X**2 + Y**2 <= 1)[None]).sum())
    dw = float((W1 - W2)[both].abs().max())
    assert dw <= 0.02


    phi = torch.tensor([0.3], dtype=torch.float64)
    args = (((1.0,),), a, phi, 45, 5, 320, 5.0, cooke.paraxial().working_f_number, "area")
    p1 = psfs_from_table(table, *args, complex_dtype=torch.complex128)[0]
    p2 = psfs_from_table(direct, *args, complex_dtype=torch.complex128)[0]
    # |U + dU|^2 - |U|^2 ~ 2 Re(U* dU): its L1 is at most 2 |U| |dU| = 4 pi max|dW| (Parseval, unit energy); the
    # vignetting's edge, interpolated in angle, adds a few samples
    assert float((p1 - p2).abs().sum()) < 4 * math.pi * dw + 0.01


def test_the_thin_singlet_as_a_prescription_gives_todays_exact_psfs():
    from lenssim import LensPSF
    from lenssim_studies.paper import PAPER_CAMERA

    lens = PAPER_CAMERA.lens
    d = Design(s=-0.775, Q_back=-2.4).to(torch.float64)
    s1, s2 = lens.surfaces(d)
    lam = PAPER_CAMERA.spectrum.wavelengths_um[0]
    p = Prescription((S(float(s1.curvature), 0.0, (lens.refractive_index, 0.0)),
                      S(float(s2.curvature), lens.image_distance_mm, "air", conic=float(s2.conic))), 1,
                     2 * lens.pupil_radius_mm, fields=lens.field_angles_deg, wavelengths_um=(lam,),
                     primary_wavelength_um=lam)
    seq = SequentialPSF(SequentialLens(p), PAPER_CAMERA.sensor, PAPER_CAMERA.spectrum, sampling="point")
    ref = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), wavefront="exact")
    g = ref.geometry
    assert seq.geometry.pixel_pitch_um == g.pixel_pitch_um
    assert seq.image_scale_mm == pytest.approx(g.focal_length_mm, rel=1e-9)
    for alpha in (0.0, 7.0, 13.0):
        row, col = torch.tensor([g.radius_px(alpha)]), torch.tensor([0.0])
        n = int(max(seq.extent_px(row, col, (0.0, 0.0)), ref.extent_px(row, col, (0.0, 0.0)))) | 1  # all the light
        a = seq.psf_at_pixels(row, col, (0.0, 0.0), n, dtype=torch.float64, pedestal=False)[0]
        b = ref.psf_at_pixels(row, col, (0.0, 0.0), n, dtype=torch.float64)[0]
        # today's PSFs spread the light diffracted beyond their grid as a uniform pedestal; ours renormalise the window
        ped = ref.pedestal_fractions(n)[0]
        assert 0 < ped < 0.1
        b = (b - ped / n**2) / (1 - ped)
        # L1 of unit-sum PSFs: today's exact model fits the OPD with degree-8 polynomials on a circular pupil with
        # an anti-aliased rim, ours interpolates a traced table on the FFT's samples
        assert float((a - b).abs().sum()) < 0.05
        assert _centroid(a)[0] == pytest.approx(_centroid(b)[0], rel=0.01, abs=0.02)
        assert _centroid(b)[0] > 10 or alpha < 7  # the field moves the light: the check is not empty


def test_colour_channels_give_one_psf_each(cooke):
    chans = (Spectrum((0.6, 0.65), (1.0, 1.0)), Spectrum((0.5, 0.55), (1.0, 1.0)), Spectrum((0.45,), (1.0,)))
    prov = SequentialPSF(cooke, _sensor(5.0), Spectrum.monochromatic(LAM), chans, max_field_deg=0.5)
    assert prov.channels == 3
    lams, w = prov.quadrature()
    assert lams == (0.45, 0.5, 0.55, 0.6, 0.65) and w[2] == (1.0, 0, 0, 0, 0)
    p = prov.psf_at_pixels(torch.tensor([0.0, 100.0]), torch.tensor([0.0, 0.0]), (0.0, 0.0), 33)
    assert p.shape == (2, 3, 33, 33) and p.dtype == torch.float32
    assert torch.allclose(p.sum(dim=(-2, -1)), torch.ones(2, 3), atol=1e-5)
    assert not torch.allclose(p[0, 0], p[0, 2], atol=1e-3)  # axial colour: red and blue PSFs differ


def test_bad_requests_are_refused(cooke):
    light = Spectrum.monochromatic(LAM)
    with pytest.raises(ValueError, match="sampling"):
        SequentialPSF(cooke, _sensor(5.0), light, sampling="nearest")
    with pytest.raises(ValueError, match="below lambda N_w"):
        SequentialPSF(cooke, _sensor(5.0), light, sampling="point")
    prov = SequentialPSF(cooke, _sensor(5.0), light, max_field_deg=2.0)
    with pytest.raises(ValueError, match="beyond the 2 deg"):
        prov.extents_px(torch.tensor([2000.0]), torch.tensor([0.0]), (0.0, 0.0))
    finite = Prescription((S(0.02, 3.0, (N_GLASS, 0.0)), S(-0.02, 40.0, "air")), 1, 5.0, object_distance_mm=200.0,
                          fields=(0.0, 1.0))
    with pytest.raises(ValueError, match="finite distance"):
        SequentialPSF(SequentialLens(finite), _sensor(5.0), light)
