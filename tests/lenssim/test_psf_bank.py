import math

import pytest
import torch
from scipy.special import j1

from lenssim import Camera, Design, Numerics, Spectrum, fft_size, otf, otf_quarter, psf, psf_at, pupil_amplitude, spectral_coefficients, wavefront

from lenssim_studies.paper import PAPER_CAMERA, PAPER_LENS
from lenssim.optics.psf_bank import nice_fft_size
import dataclasses
from lenssim_studies.paper import PAPER_SENSOR, PAPER_SPECTRUM

D = torch.float64
CAM = PAPER_CAMERA
ZERO = torch.zeros(1, 1, 4, dtype=D)  # (B, K, T): one PSF, one wavelength, no aberration
LAMBDA_UM = 0.5
PITCH_UM = CAM.pixel_pitch_um


def design(s, Q):
    return Design(s=s, Q_back=Q)


E2E = design(-0.775, -2.4)


def coeffs(s, Q, alpha=None):
    """Coefficients (A, K, T) of the paper camera (one wavelength)."""
    return spectral_coefficients(CAM, design(s, Q), alpha)


def quarter(c, n, **kw):
    """otf_quarter of (B, T) coefficients at the paper camera's sampling."""
    return otf_quarter(c, n, pupil_radius_px=CAM.pupil_radius_px(n, LAMBDA_UM), **kw)


def analytic_mtf(nu):
    nu = nu.clamp(0, 1)
    return 2 / math.pi * (torch.acos(nu) - nu * torch.sqrt(1 - nu**2))


def test_pupil_fills_half_the_grid_at_the_nyquist_pitch():
    assert CAM.pupil_radius_px(256, LAMBDA_UM) == pytest.approx(64.0)
    amp, _ = pupil_amplitude(CAM, 256, dtype=D)
    assert float(amp.sum()) == pytest.approx(math.pi * 64**2, rel=1e-4)  # anti-aliased area

    with pytest.raises(ValueError, match="pixel_pitch_um=3.2 is not allowed.*would not fit"):
        Camera(sensor=dataclasses.replace(PAPER_SENSOR, pixel_pitch_um=3.2), lens=PAPER_LENS, spectrum=PAPER_SPECTRUM).pupil_radius_px(256, LAMBDA_UM)
    with pytest.warns(UserWarning, match="undersample wavelengths below 0.64 um"):
        assert Camera(sensor=dataclasses.replace(PAPER_SENSOR, pixel_pitch_um=2.0), lens=PAPER_LENS, spectrum=PAPER_SPECTRUM).pupil_radius_px(256, LAMBDA_UM) == pytest.approx(81.92)


def test_undersampled_psf_samples_are_the_continuous_psf_at_the_pixel_centres():
    """A pitch coarser than Nyquist: the FFT still gives the Airy pattern's values at the pixel centres
    (the aliasing is the sampling's, as a real sensor's), checked against the closed form."""

    with pytest.warns(UserWarning, match="undersample"):
        cam = Camera(sensor=dataclasses.replace(PAPER_SENSOR, pixel_pitch_um=2.2), lens=PAPER_LENS, spectrum=PAPER_SPECTRUM)
        n = 256
        p = psf(cam, ZERO, n)[0]
    c = n // 2
    yy, xx = torch.meshgrid(torch.arange(n, dtype=D) - c, torch.arange(n, dtype=D) - c, indexing="ij")
    v = math.pi * torch.hypot(yy, xx) * 2.2 / (LAMBDA_UM * PAPER_LENS.f_number)
    airy = torch.where(v > 0, (2 * torch.from_numpy(j1(v.numpy())) / v.clamp_min(1e-12)) ** 2, torch.ones(()))
    win = torch.hypot(yy, xx) <= 6
    assert ((p / p[c, c] - airy)[win]).abs().max() < 3e-3


def test_diffraction_limited_psf_is_the_airy_pattern():
    n = 512
    p = psf(CAM, ZERO, n)[0]
    c = n // 2
    yy, xx = torch.meshgrid(torch.arange(n, dtype=D) - c, torch.arange(n, dtype=D) - c, indexing="ij")
    r_um = torch.hypot(yy, xx) * PITCH_UM
    v = math.pi * r_um / (LAMBDA_UM * PAPER_LENS.f_number)
    airy = torch.where(v > 0, (2 * torch.from_numpy(j1(v.numpy())) / v.clamp_min(1e-12)) ** 2, torch.ones(()))
    win = torch.hypot(yy, xx) <= 12
    diff = (p / p[c, c] - airy)[win]
    assert diff.abs().max() < 2e-3
    # first dark ring at 1.22 lambda f# = 2.44 pixels
    assert float(p[c, c + 2] / p[c, c]) < 0.05 and float(p[c, c + 1] / p[c, c]) > 0.3


@pytest.mark.parametrize("n,tol", [(128, 4e-3), (256, 2e-3), (512, 1e-3)])
def test_diffraction_limited_otf_is_the_analytic_mtf(n, tol):
    H = otf(CAM, ZERO, n)[0]
    k = torch.fft.fftfreq(n, dtype=D)
    nu = torch.hypot(k[:, None], k[None, :]) / 0.5  # cutoff 1/(lambda f#) = 0.5 cycles/pixel
    assert (H.real - analytic_mtf(nu)).abs().max() < tol
    assert H.imag.abs().max() < 1e-12


def test_energy_parseval_and_otf_bounds():
    c = coeffs(-0.775, -2.4, [0.0, 7.0, 14.0])
    n = 768
    p = psf(CAM, c, n)
    torch.testing.assert_close(p.sum(dim=(-2, -1)), torch.ones(3, dtype=D))
    amp, rho = pupil_amplitude(CAM, n, dtype=D)
    field = amp * torch.exp(-2j * math.pi * torch.zeros_like(amp))
    F = torch.fft.fft2(field)
    assert float(F.abs().square().sum()) == pytest.approx(n * n * float(amp.square().sum()), rel=1e-12)
    H = otf(CAM, c, n)
    assert torch.all(H.abs() <= 1 + 1e-9)
    assert torch.all(H[:, 0, 0].real == 1)


def test_quarter_bank_equals_full_otf():
    g = torch.Generator().manual_seed(1)
    c = torch.randn(4, 4, generator=g, dtype=D) * torch.tensor([2.0, 1.0, 3.0, 2.0], dtype=D)
    n = 320
    q = quarter(c, n)
    torch.testing.assert_close(q, otf(CAM, c[:, None], n)[:, : n // 2 + 1, : n // 2 + 1], rtol=0, atol=1e-12)
    q2 = quarter(c, n, oversample=2)
    torch.testing.assert_close(q2[:, ::2, ::2], q, rtol=0, atol=1e-12)  # same OTF, finer grid
    q32 = quarter(c.float(), n)
    assert q32.dtype == torch.complex64
    torch.testing.assert_close(q32.to(torch.complex128), q, rtol=0, atol=5e-5)


def _zero_pad_dft_order(p: torch.Tensor, m: int) -> torch.Tensor:
    """An ``(n, n)`` array in DFT order (origin at [0, 0]) zero-padded to ``(m, m)``, the Nyquist row and column
    split in halves between +n/2 and -n/2 (written out sample by sample: an independent reference)."""
    n = p.shape[-1]
    out = torch.zeros(p.shape[:-2] + (m, m), dtype=p.dtype)
    for r in range(n):
        ys = [(r, 1.0)] if r < n // 2 else [(m - (n - r), 1.0)] if r > n // 2 else [(n // 2, 0.5), (m - n // 2, 0.5)]
        for c in range(n):
            xs = [(c, 1.0)] if c < n // 2 else [(m - (n - c), 1.0)] if c > n // 2 else [(n // 2, 0.5), (m - n // 2, 0.5)]
            for y, wy in ys:
                for x, wx in xs:
                    out[..., y, x] += wy * wx * p[..., r, c]
    return out


def test_oversampled_bank_equals_the_zero_padded_psf_transform():
    """oversample = 2: every sample of the finer grid, odd ones included, is the 2n-point DFT of the n-point PSF
    zero-padded (here from psf() less its uniform pedestal, and a full complex fft2)."""
    g = torch.Generator().manual_seed(2)
    c = torch.randn(2, 4, generator=g, dtype=D) * torch.tensor([1.5, 1.0, 2.0, 1.0], dtype=D)
    n, m = 64, 128
    p = psf(CAM, c[:, None], n, centered=False)  # unit sum, origin at [0, 0]: |DFT(field)|^2 / (area n^2) + pedestal
    amp, _ = pupil_amplitude(CAM, n, dtype=D)
    p = p - float(1 - amp.square().sum() / amp.sum()) / n**2
    ref = torch.fft.fft2(_zero_pad_dft_order(p, m))
    got = quarter(c, n, oversample=2)
    ref_q = ref[:, : m // 2 + 1, : m // 2 + 1].clone()
    ref_q[:, 0, 0] = 1  # the bank sets H(0) = 1 (see _area_normalise)
    torch.testing.assert_close(got, ref_q, rtol=0, atol=1e-12)
    assert float((got[:, 1::2, 1::2] - got[:, ::2, ::2][:, :-1, :-1]).abs().max()) > 1e-3  # odd samples are new


def test_psf_centroid_is_the_mean_ray_aberration():
    """Coma direction: the PSF centroid is the pupil mean of eps = -(f/y) grad W (in pixels)."""
    s, Q, alpha = -0.725, -10.0, 10.0
    c = coeffs(s, Q, [alpha])
    n = int(fft_size(CAM, c)[0]) * 2
    p = psf(CAM, c, n)[0]
    off = torch.arange(n, dtype=D) - n // 2
    cy, cx = float((p.sum(1) * off).sum()), float((p.sum(0) * off).sum())
    # mean of -(f/y) dW/drho_r over the disc: W131 rho^2 rho_r -> <d/drho_r> = W131 <rho^2 + 2 rho_r^2> = W131
    # W222 rho_r^2 -> 0 ... so the centroid (px) = -4 * W131 (4 px per wave per unit radius at Nyquist)
    expected = -4 * float(c[0, 0, 1])
    assert cx == pytest.approx(0.0, abs=2e-3)  # (one unpaired column on an even grid)
    assert cy == pytest.approx(expected, rel=0.01)
    assert expected > 0 and float(c[0, 0, 1]) < 0  # this design's light moves away from the axis


def test_astigmatism_and_defocus_symmetries():
    n = 256
    astig = torch.tensor([[[0.0, 0.0, 3.0, 0.0]]], dtype=D)
    p = psf(CAM, astig, n, centered=False)[0]
    torch.testing.assert_close(p, torch.roll(torch.flip(p, [0]), 1, 0))  # y -> -y
    torch.testing.assert_close(p, torch.roll(torch.flip(p, [1]), 1, 1))  # x -> -x
    assert not torch.allclose(p, p.T, atol=1e-6)  # but not rotationally symmetric
    defocus = torch.tensor([[[0.5, 0.0, 0.0, 2.0]]], dtype=D)
    d = psf(CAM, defocus, n, centered=False)[0]
    torch.testing.assert_close(d, d.T)
    coma = torch.tensor([[[0.0, 2.0, 0.0, 0.0]]], dtype=D)
    cm = psf(CAM, coma, n, centered=False)[0]
    torch.testing.assert_close(cm, torch.roll(torch.flip(cm, [1]), 1, 1))  # symmetric about the meridian
    assert not torch.allclose(cm, torch.roll(torch.flip(cm, [0]), 1, 0), atol=1e-6)  # but not across it


def test_psf_at_rotates_the_pupil_exactly():
    r_mm = 25 * math.tan(math.radians(9.0))
    (p_y, n) = psf_at(CAM, E2E, 0.0, r_mm, n=256)
    p_x, _ = psf_at(CAM, E2E, r_mm, 0.0, n=256)
    p_nx, _ = psf_at(CAM, E2E, -r_mm, 0.0, n=256)
    # a 90-degree turn of the image point turns the PSF: offsets (dy, dx) -> (dx, -dy)
    torch.testing.assert_close(p_x[1:, 1:], torch.flip(p_y.T, [0])[:-1, 1:], rtol=0, atol=1e-7)
    torch.testing.assert_close(p_nx[:, 1:], torch.flip(p_x[:, 1:], [1]), rtol=0, atol=1e-7)
    ref = psf(CAM, coeffs(-0.775, -2.4, [9.0]), 256)[0]
    torch.testing.assert_close(p_y, ref, rtol=0, atol=1e-7)
    # arbitrary azimuth: the centroid points along the image point's radius
    ang = math.radians(30.0)
    p30, _ = psf_at(CAM, design(-0.725, -10.0), r_mm * math.cos(ang), r_mm * math.sin(ang), n=512)
    off = torch.arange(512, dtype=p30.dtype) - 256
    cy, cx = float((p30.sum(1) * off).sum()), float((p30.sum(0) * off).sum())
    assert math.atan2(cy, cx) == pytest.approx(ang, abs=0.01)  # outwards, as on the +y field axis


def test_fft_size_rules():
    assert nice_fft_size(1000) == 1024 and nice_fft_size(700) == 720 and nice_fft_size(17) == 32
    c = coeffs(-2.0, -10.0)
    n = fft_size(CAM, c, Numerics(fill=0.5))
    assert n.dtype == torch.int64 and n.shape == (15,)
    from lenssim import max_wavefront_slope

    G = max_wavefront_slope(c[..., 0, :])
    # pupil phase at most fill x 0.5 wave per sample, and the geometric PSF inside the grid
    assert torch.all(G / (n / 4) <= 0.25 + 1e-9)
    assert torch.all(8 * G < n)
    assert torch.all(fft_size(CAM, c * 0.1, Numerics(fill=0.5)) <= n)
    with pytest.raises(ValueError, match="fill=0"):
        Numerics(fill=0)


def test_bad_shapes_and_sizes_are_refused():
    with pytest.raises(ValueError, match=r"shape \(2, 3, 4\): expected a floating tensor of shape \(B, 4\)"):
        quarter(torch.zeros(2, 3, 4), 64)
    with pytest.raises(ValueError, match="n=65"):
        quarter(torch.zeros(1, 4), 65)
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        psf(CAM, torch.zeros(3), 64)
    with pytest.raises(ValueError, match="2 wavelengths, the camera's spectrum 1"):
        psf(CAM, torch.zeros(1, 2, 4), 64)
    with pytest.raises(ValueError, match="90 degrees"):
        psf_at(CAM, design(-0.5, -1.0), math.inf, 0.0, n=64)


def test_float32_psfs_match_float64_and_python_numbers_follow_the_tensors():
    """Working precision: float32 PSFs (the camera pipeline's) agree with float64 to ~1e-6 of the peak."""
    r = torch.tensor([0.5, 2.0, 5.0], dtype=D)
    p64, _ = psf_at(CAM, E2E, 0.6 * r, 0.8 * r, n=512)
    p32, _ = psf_at(CAM, E2E, 0.6 * r, 0.8 * r, n=512, dtype=torch.float32)
    assert p64.dtype == D and p32.dtype == torch.float32  # designs of Python numbers are float64
    err = ((p32.double() - p64).abs().amax(dim=(-2, -1)) / p64.amax(dim=(-2, -1))).max()
    assert float(err) < 5e-6
    # the pupil-box evaluation equals a brute-force full-grid field
    c = coeffs(-0.775, -2.4, torch.tensor([9.0], dtype=D))
    n = 128
    amp, rho = pupil_amplitude(CAM, n, dtype=D)
    W = wavefront(c[:, 0], rho[:, None].expand(n, n), rho[None, :].expand(n, n))
    brute = torch.fft.fft2(torch.polar(amp.expand_as(W), -2 * math.pi * W)).abs().square()
    # over the pupil area, plus the light the anti-aliased rim leaves out spread evenly (the metrics' OTF)
    brute = brute / (amp.sum() * n * n) + (1 - amp.square().sum() / amp.sum()) / (n * n)
    brute = torch.fft.fftshift(brute, dim=(-2, -1))
    torch.testing.assert_close(psf(CAM, c, n), brute, rtol=0, atol=1e-12)


def test_polychromatic_psf_is_the_weighted_sum_and_its_mtf_the_weighted_analytic_mtf():
    """A spectrum's PSF is the weighted sum of unit-sum PSFs on the fixed pixel grid; diffraction-limited,
    its MTF is the weighted sum of the analytic MTFs with cut-offs Delta / (lambda f#)."""
    lams, w = (0.45, 0.55, 0.65), (0.2, 0.5, 0.3)
    cam = Camera(sensor=dataclasses.replace(CAM.sensor, pixel_pitch_um=1.4), spectrum=Spectrum(lams, w), lens=PAPER_LENS)
    n = 512
    p = psf(cam, torch.zeros(1, 3, 4, dtype=D), n)[0]
    assert float(p.sum()) == pytest.approx(1.0, abs=1e-12)
    parts = [psf(Camera(sensor=cam.sensor, spectrum=Spectrum.monochromatic(l), lens=PAPER_LENS), ZERO, n)[0] for l in lams]
    torch.testing.assert_close(p, sum(wi * q for wi, q in zip(w, parts)), rtol=0, atol=1e-15)
    H = otf(cam, torch.zeros(1, 3, 4, dtype=D), n)[0]
    k = torch.fft.fftfreq(n, dtype=D)
    f = torch.hypot(k[:, None], k[None, :])
    mtf = sum(wi * analytic_mtf(f * l * 6.25 / 1.4) for wi, l in zip(w, lams))
    assert (H.real - mtf).abs().max() < 1e-3
    # the same from the quarter-plane bank used by the metrics
    from lenssim import otf_quarter_spectrum

    q = otf_quarter_spectrum(cam, torch.zeros(1, 3, 4, dtype=D), n)
    torch.testing.assert_close(q[0], H[: n // 2 + 1, : n // 2 + 1], rtol=0, atol=1e-12)


def test_monochromatic_spectrum_gives_back_the_single_wavelength_psf_exactly():
    c = coeffs(-0.775, -2.4, [9.0])
    two = Camera(spectrum=Spectrum((0.5, 0.5), (0.3, 0.7)), lens=PAPER_LENS, sensor=PAPER_SENSOR)
    p1 = psf(CAM, c, 256)
    p2 = psf(two, c.expand(1, 2, 4), 256)
    torch.testing.assert_close(p2, p1, rtol=0, atol=1e-15)


def test_a_spectrum_otf_summed_before_its_transform_equals_the_weighted_per_wavelength_otfs():
    """otf_quarter_spectrum sums the wavelengths' PSFs and transforms once; the reference transforms each
    wavelength on its own (otf_quarter) and weights the OTFs."""
    import warnings

    from lenssim import Camera, Design, Spectrum

    from lenssim_studies.paper import PAPER_CAMERA
    from lenssim.optics.psf_bank import otf_quarter, otf_quarter_spectrum, spectral_coefficients
    from lenssim.validate import ModelValidityWarning

    spec = Spectrum((0.46, 0.52, 0.61), (0.2, 0.5, 0.3))
    cam = Camera(dataclasses.replace(PAPER_LENS, glass="N-BK7"), PAPER_CAMERA.sensor, spec)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelValidityWarning)
        c = spectral_coefficients(cam, Design(s=-0.775, Q_back=-2.4), [0.0, 9.0]).to(torch.float64)  # (A, K, T)
        n = 384
        for oversample in (1, 2):
            got = otf_quarter_spectrum(cam, c, n, oversample=oversample)
            ref = sum(w * otf_quarter(c[:, k], n, pupil_radius_px=cam.pupil_radius_px(n, lam), oversample=oversample)
                      for k, (lam, w) in enumerate(zip(spec.wavelengths_um, spec.weights)))
            assert torch.allclose(got, ref, atol=1e-12, rtol=0)
            assert float(got[..., 0, 0].real.min()) == 1.0


def test_a_window_about_the_dft_origin_is_kept_as_slices_with_the_gather_s_values():
    """lenssim.optics.psf_bank._kept: a run of indices that wraps past the end (as the PSF window about frequency 0),
    one that does not, and indices that are no run, each equal to index_select, bit for bit, along either axis."""
    from lenssim.optics.psf_bank import _kept

    a = torch.randn(2, 12, 12, dtype=torch.complex128)
    for keep in (torch.tensor([9, 10, 11, 0, 1, 2]), torch.arange(3, 8), torch.tensor([0, 2, 5]),
                 torch.tensor([11, 0]), torch.arange(12).roll(4)):
        for dim in (-1, -2):
            assert torch.equal(_kept(a, dim, keep), a.index_select(dim, keep)), (keep, dim)
