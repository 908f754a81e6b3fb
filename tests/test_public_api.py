"""The public API over a device x dtype fixture: results follow the input's device and dtype, agree
with the CPU float64 result to the precision of the dtype, and tensor contracts are checked at the
boundary by one helper (``lenssim.check_shape``)."""

from __future__ import annotations

import math

import pytest
import torch

import lenssim
import pipeline
from lenssim import Design, LensPSF, check_shape, evaluate, otf_quarter_spectrum, psf, psf_at, spectral_coefficients
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline import NoiseModel, WindowScheme, add_poisson_noise, blur_windowed, wiener_windowed
from lenssim_studies.paper import PAPER_RHO0

E2E = PAPER_DESIGNS["end_to_end_paper"]
TOL = {torch.float32: 1e-4, torch.float64: 1e-10}


def _close(a: torch.Tensor, ref: torch.Tensor, dtype) -> None:
    scale = ref.abs().max().clamp_min(1e-30)
    assert float((a.detach().cpu().to(torch.float64) - ref.cpu().to(torch.float64)).abs().max() / scale) < TOL[dtype]


def test_psf_and_otf_banks_follow_device_and_dtype(device_dtype):
    dev, dt = device_dtype
    c64 = spectral_coefficients(PAPER_CAMERA, E2E, [0.0, 9.0])
    c = c64.to(device=dev, dtype=dt)
    p = psf(PAPER_CAMERA, c, 256)
    assert p.device.type == dev.type and p.dtype == dt and p.shape == (2, 256, 256)
    _close(p, psf(PAPER_CAMERA, c64, 256), dt)
    H = otf_quarter_spectrum(PAPER_CAMERA, c[:, :], 256)
    assert H.device.type == dev.type and H.dtype == (torch.complex64 if dt == torch.float32 else torch.complex128)
    _close(H.abs(), otf_quarter_spectrum(PAPER_CAMERA, c64, 256).abs(), dt)


def test_psf_at_and_design_tensors_follow_device_and_dtype(device_dtype):
    dev, dt = device_dtype
    d = Design(s=torch.tensor([-0.775, -0.725], device=dev, dtype=dt), Q_back=torch.tensor([-2.4, -10.0], device=dev, dtype=dt))
    x = torch.tensor([0.5, -1.0], device=dev, dtype=dt)
    p, n = psf_at(PAPER_CAMERA, d, x, x * 0.5, n=256)
    assert p.device.type == dev.type and p.dtype == dt and p.shape == (2, 256, 256)
    ref, _ = psf_at(PAPER_CAMERA, d.to(torch.float64, "cpu"), x.double().cpu(), x.double().cpu() * 0.5, n=256)
    _close(p, ref, dt)


def test_evaluate_runs_on_the_device(device_dtype):
    dev, dt = device_dtype
    r = evaluate(PAPER_CAMERA, E2E, [27.6], fft_size=256, dtype=dt, device=dev, rho0=PAPER_RHO0)
    ref = evaluate(PAPER_CAMERA, E2E, [27.6], fft_size=256, dtype=torch.float64, rho0=PAPER_RHO0)
    assert r["mse_r"].dtype == torch.float64  # criteria are accumulated in float64 whatever the OTF dtype
    assert r["mse_r"].device.type == dev.type
    _close(r["mse_r"], ref["mse_r"], dt)


def test_image_pipeline_follows_device_and_dtype(device_dtype):
    dev, dt = device_dtype
    g = torch.Generator().manual_seed(0)
    img64 = torch.rand(1, 3, 64, 80, generator=g, dtype=torch.float64) * 0.8 + 0.1
    img = img64.to(device=dev, dtype=dt)
    kw = dict(scheme=WindowScheme(128, 32, 64), optical_center=(-300.0, -400.0))
    psf_ = LensPSF(PAPER_CAMERA, E2E)
    b = blur_windowed(img, psf_, **kw)
    assert b.device.type == dev.type and b.dtype == dt
    _close(b, blur_windowed(img64, psf_, **kw), dt)
    r = wiener_windowed(b, psf_, noise=NoiseModel(3200.0), **kw)
    assert r.device.type == dev.type and r.dtype == dt and torch.isfinite(r).all()
    n = add_poisson_noise(b.clamp_min(0), 3200.0, seed=1)
    assert n.device.type == dev.type and n.dtype == dt


def test_mirror_groups_on_the_device_match_every_window_s_own_psf(device_dtype):
    """The axis-symmetric window grid's shared PSFs (flipped and transposed spectra) on the device and in the
    dtype, against each window's own PSF (a provider that declares no symmetry), and the window-chunk rule."""
    from lenssim import FunctionPSF
    from pipeline.blur import window_chunk

    dev, dt = device_dtype
    g = torch.Generator().manual_seed(1)
    img = (torch.rand(1, 3, 96, 128, generator=g, dtype=torch.float64) * 0.8 + 0.1).to(device=dev, dtype=dt)
    lens = LensPSF(PAPER_CAMERA, E2E)
    pitch = lens.geometry.pitch_mm
    class Own(FunctionPSF):  # each window's own PSF, with the lens's support at each position (the same sizes)
        def extents_px(self, rows, cols, optical_center):
            return lens.extents_px(rows, cols, optical_center)

        def pedestal_fractions(self, n):  # and its pedestal, convolved apart as the lens's is
            return lens.pedestal_fractions(n)

    own = Own(lambda x, y, n: lens.psf_at_pixels(y / pitch, x / pitch, (0.0, 0.0), n, dtype=torch.float64),
              lens.geometry, extent=60)
    for fit in (True, False):  # blur windows fitted to the PSF, and all of the scheme's 128 px
        kw = dict(scheme=WindowScheme(128, 32, 64, fit=fit), optical_center=(47.5, 63.5))
        shared = blur_windowed(img, lens, **kw)
        assert shared.device.type == dev.type and shared.dtype == dt
        _close(shared, blur_windowed(img, own, **kw), dt)
    k = window_chunk(img, 512)
    assert k >= 1 and (dev.type == "cuda" or k == max(1, 32 * 2**20 // (3 * 3 * 512 * 512 * img.element_size())))


@pytest.mark.parametrize("fn, bad, match", [
    (lambda x: blur_windowed(x, LensPSF(PAPER_CAMERA, E2E)), torch.zeros(8, 8), r"image has shape \(8, 8\)"),
    (lambda x: wiener_windowed(x, LensPSF(PAPER_CAMERA, E2E), noise=NoiseModel(1.0)), torch.zeros(1, 8, 8),
     r"observed has shape \(1, 8, 8\)"),
    (lambda x: psf(PAPER_CAMERA, x, 64), torch.zeros(2, 5), r"expected a floating tensor of shape \(\*, K, 4\)"),
    (lambda x: blur_windowed(x, LensPSF(PAPER_CAMERA, E2E)), torch.zeros(1, 1, 8, 8, dtype=torch.int64),
     "dtype torch.int64"),
])
def test_shape_contracts_are_checked_at_the_boundary(fn, bad, match):
    with pytest.raises(ValueError, match=match):
        fn(bad)


def test_check_shape_names_dimensions():
    assert check_shape(torch.zeros(2, 3, 4, 5), "B C H W") == {"B": 2, "C": 3, "H": 4, "W": 5}
    assert check_shape(torch.zeros(7, 2, 4), "* K 4") == {"K": 2}
    with pytest.raises(ValueError, match="dimension N differs"):
        check_shape(torch.zeros(3, 4), "N N")
    with pytest.raises(ValueError, match="is a list"):
        check_shape([1, 2], "N")


def test_public_names_exist():
    for mod in (lenssim, pipeline):
        for name in mod.__all__:
            assert hasattr(mod, name), f"{mod.__name__}.{name}"


def test_psf_provider_must_be_a_provider():
    with pytest.raises(ValueError, match="expected a PSF provider"):
        blur_windowed(torch.zeros(1, 1, 8, 8), (-0.775, -2.4))
    assert math.isclose(LensPSF(PAPER_CAMERA, E2E).geometry.pixel_pitch_um, 1.5625)
