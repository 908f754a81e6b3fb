"""The camera chain (issue 31): sensor terms, stages, the photon transfer curve (EMVA 1288), the ISP, restoration
on the mosaic or on RGB, and the paper's model unchanged without a chain."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from lenssim import FunctionPSF, Sensor
from lenssim.io.sensor_file import load_sensor, sensor_names
from lenssim_studies.paper import PAPER_CAMERA, PAPER_SENSOR
from pipeline.blur import WindowScheme
from pipeline.camera_chain import (CAMERA_STAGES, CameraChain, PlanePSF, fixed_pattern, pattern_at)
from pipeline.cfa import mosaic
from pipeline.noise import expose
from pipeline.simulate import simulate_crops, simulate_frame

FW = 3200.0


def _sensor(**kw) -> Sensor:
    return Sensor(pixel_pitch_um=1.5625, width_px=64, height_px=64, **kw)


@pytest.mark.parametrize("sensor", [PAPER_SENSOR, _sensor(read_noise_e=3.0, bit_depth=12)])
def test_chain_without_cfa_is_the_paper_noise_exactly(sensor):
    img = torch.rand(1, 3, 48, 40, generator=torch.Generator().manual_seed(0))
    e = FW / float(img.amax())
    chain = CameraChain(sensor)
    a = expose(img, e, sensor, FW, generator=torch.Generator().manual_seed(7))
    raw = chain.capture(img, e, FW, generator=torch.Generator().manual_seed(7))
    b = chain.linearise(raw, e, FW).to(img.dtype)
    assert torch.equal(a, b)
    assert chain.isp_stages == ("black_level",)


def _ptc_sensor(**kw):
    base = dict(read_noise_e=3.0, bit_depth=12, black_level_dn=64, dark_current_e_per_s=100.0, dsnu_e=2.0)
    return _sensor(**{**base, **kw})


@pytest.mark.parametrize("level", [0.0, 0.003, 0.03, 0.3, 0.8])
def test_photon_transfer_curve_matches_emva_1288_model(level):
    """EMVA 1288 (4.0) eq. (6)-(8): mean K (mu_e + mu_d) + black, variance K^2 (mu_e + sigma_d^2) + 1/12 DN^2, within
    four standard errors of a 512 x 512 Monte Carlo."""
    s = _ptc_sensor()
    chain = CameraChain(s, exposure_ms=50.0)
    K = 1 / s.conversion_gain_e_per_dn(FW)
    n = 512
    img = torch.full((1, 1, n, n), level, dtype=torch.float64)
    raw = chain.capture(img, FW, FW, generator=torch.Generator().manual_seed(3), origin=(100, 37))
    mu_e = level * FW
    mean = K * (mu_e + chain.dark_electrons) + s.black_level_dn
    var = K**2 * (mu_e + s.read_noise_e**2 + chain.dark_electrons + s.dsnu_e**2) + 1 / 12
    N = n * n
    assert abs(raw.mean().item() - mean) < 4 * math.sqrt(var / N) + 1e-9
    assert abs(raw.var().item() - var) < 4 * var * math.sqrt(2 / (N - 1))
    # the ISP's linearisation removes the black level and the mean dark signal: back to the signal, in image units
    assert abs(chain.linearise(raw, FW, FW).mean().item() - level) < 4 * math.sqrt(var / N) / K / FW + 1e-12


def test_prnu_adds_its_variance_in_proportion_to_the_signal():
    s = _sensor(prnu_percent=2.0)
    chain = CameraChain(s)
    n, level = 512, 0.9
    raw = chain.capture(torch.full((1, 1, n, n), level, dtype=torch.float64), FW, FW,
                        generator=torch.Generator().manual_seed(1))
    mu = level * FW
    var = mu + (0.02 * mu) ** 2
    assert abs(raw.var().item() - var) < 4 * var * math.sqrt(2 / (n * n - 1))


def test_adc_clips_at_the_white_level_and_quantises_to_whole_numbers():
    s = _sensor(bit_depth=10, black_level_dn=64, white_level_dn=1000)
    raw = CameraChain(s).capture(torch.full((1, 1, 8, 8), 2.0), FW, FW, generator=torch.Generator().manual_seed(0))
    assert torch.equal(raw, torch.full_like(raw, 1000.0))
    raw = CameraChain(s).capture(torch.rand(1, 1, 16, 16), FW, FW, generator=torch.Generator().manual_seed(0))
    assert torch.equal(raw, raw.round()) and raw.min() >= 0


def test_fixed_patterns_follow_the_frame_not_the_crop():
    whole = fixed_pattern(5, 1, (0, 0), (700, 600))
    part = fixed_pattern(5, 1, (301, 257), (222, 300))
    assert torch.equal(part, whole[301:523, 257:557])
    assert abs(whole.std().item() - 1) < 0.01
    assert not torch.equal(fixed_pattern(6, 1, (0, 0), (64, 64)), whole[:64, :64])


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_the_cfa_phase_of_a_crop_is_the_frames(pattern):
    img = torch.rand(1, 3, 10, 12)
    full = mosaic(img, pattern)
    for r, c in ((0, 0), (1, 0), (0, 1), (1, 1), (3, 6)):
        assert torch.equal(mosaic(img[..., r:, c:], pattern_at(pattern, r, c)), full[..., r:, c:])


class _StampedPSF(FunctionPSF):
    """A function's PSFs with a fingerprint (a checkpoint is kept only for providers that have one)."""

    def fingerprint(self):
        return f"gaussian {self.extent}"


def _gaussian_psf(sigma_px: float):
    def fn(x_mm, y_mm, n):
        ax = torch.arange(n, dtype=torch.float64) - n // 2
        g = torch.exp(-(ax[:, None] ** 2 + ax[None, :] ** 2) / (2 * sigma_px**2))
        return (g / g.sum()).expand(len(x_mm), n, n).clone()
    return _StampedPSF(fn, PAPER_CAMERA.geometry, extent=int(8 * sigma_px) + 1, mirror_symmetric=True)


@pytest.mark.parametrize("sigma", [1.5, 3.0])
def test_plane_psf_second_moment_is_the_frames_plus_the_tent_halved(sigma):
    """The plane's PSF: the frame's convolved with the tent [1/2, 1, 1/2] and sampled every other pixel. Its second
    moment (plane px^2) is (sum_j h_j j^2 + the frame PSF's mass at odd offsets) / 4 per axis (a frame sample at an odd
    offset j is split between j - 1 and j + 1): ~(sigma^2 + 1/2) / 4; unit sum, centred."""
    base = _gaussian_psf(sigma)
    p = PlanePSF(base, 1, 0).psf_at_pixels(torch.tensor([10.0]), torch.tensor([20.0]), (0.0, 0.0), 33,
                                           dtype=torch.float64)[0]
    h = base.psf_at_pixels(torch.tensor([21.0]), torch.tensor([40.0]), (1.0, 0.0), 67)[0].sum(1)
    j = torch.arange(67, dtype=torch.float64) - 33
    ref = ((h * j**2).sum() + h[j.remainder(2) == 1].sum()).item() / 4
    ax = torch.arange(33, dtype=torch.float64) - 16
    assert abs(p.sum().item() - 1) < 1e-12
    assert abs((p.sum(1) * ax).sum().item()) < 1e-12
    assert (p.sum(1) * ax**2).sum().item() == pytest.approx(ref, rel=1e-5)
    assert ref == pytest.approx((sigma**2 + 0.5) / 4, rel=1e-4)
    whole = replace(base, extent=0)  # support unknown: the plane's whole 2 n + 1 frame pixels asked for
    full = PlanePSF(whole, 1, 0).psf_at_pixels(torch.tensor([10.0]), torch.tensor([20.0]), (0.0, 0.0), 33,
                                               dtype=torch.float64)[0]
    assert torch.allclose(full, p, atol=1e-6)  # the Gaussian beyond its stated support: < 1e-6
    delta = PlanePSF(_gaussian_psf(0.05), 0, 1).psf_at_pixels(torch.tensor([0.0]), torch.tensor([0.0]), (0.0, 0.0), 9,
                                                             dtype=torch.float64)[0]
    assert delta[4, 4].item() == pytest.approx(1.0, abs=1e-12)


def test_white_balance_from_the_illuminant_and_grey_world_keep_a_grey_scene_grey():
    s = _sensor(quantum_efficiency=(0.45, 0.8, 0.6), cfa="RGGB")
    grey = torch.full((1, 3, 32, 32), 0.5, dtype=torch.float64)
    for wb in ("illuminant", "grey_world"):
        chain = CameraChain(s, white_balance=wb)
        raw = chain.capture(grey, 1e9, 1e9, generator=torch.Generator().manual_seed(0), origin=(1, 0))
        units = chain.linearise(raw, 1e9, 1e9)
        out = chain.develop(units, gains=chain.white_balance_gains(units, origin=(1, 0)), origin=(1, 0))
        assert torch.allclose(out, grey, atol=1e-4), wb


def test_colour_correction_is_colour_sciences_rgb_to_rgb():
    import colour

    m = colour.matrix_RGB_to_RGB(colour.RGB_COLOURSPACES["Adobe RGB (1998)"], colour.RGB_COLOURSPACES["sRGB"])
    s = _sensor(colour_matrix=tuple(map(tuple, m)))
    x = torch.rand(1, 3, 4, 5, dtype=torch.float64)
    ours = CAMERA_STAGES["colour_correction"].fn(x, type("C", (), {"sensor": s})())
    ref = colour.RGB_to_RGB(x[0].permute(1, 2, 0).numpy(), colour.RGB_COLOURSPACES["Adobe RGB (1998)"],
                            colour.RGB_COLOURSPACES["sRGB"])
    assert np.allclose(ours[0].permute(1, 2, 0).numpy(), ref, atol=1e-12)
    chain = CameraChain(s)
    scene = torch.rand(1, 3, 16, 16, dtype=torch.float64) * 0.2 + 0.4  # inside both gamuts
    raw = chain.capture(chain.scene_to_camera(scene), 1e12, 1e12, generator=torch.Generator().manual_seed(0))
    units = chain.linearise(raw, 1e12, 1e12)
    assert torch.allclose(chain.develop(units, gains=chain.white_balance_gains(units)), scene, atol=1e-5)
    xyz = np.asarray(chain.xyz_to_camera())  # a DNG's ColorMatrix1: XYZ -> camera, here via sRGB
    rgb = np.array([0.3, 0.5, 0.2])
    cam = np.linalg.solve(np.asarray(s.colour_matrix), rgb)
    assert np.allclose(xyz @ colour.RGB_to_XYZ(rgb, colour.RGB_COLOURSPACES["sRGB"]), cam, atol=1e-4)  # IEC 4-digit matrix


def test_chain_and_sensor_refuse_bad_terms():
    with pytest.raises(ValueError, match="black_level_dn=4095 is not allowed: below the white level"):
        _sensor(bit_depth=12, black_level_dn=4095)
    with pytest.raises(ValueError, match="read_noise_e=nan"):
        _sensor(read_noise_e=float("nan"))
    with pytest.raises(ValueError, match="dark_current_e_per_s=-1"):
        _sensor(dark_current_e_per_s=-1)
    with pytest.raises(ValueError, match="cfa='RGBG' is not allowed"):
        _sensor(cfa="RGBG")
    with pytest.raises(ValueError, match="need an ADC"):
        _sensor(black_level_dn=10)
    with pytest.raises(ValueError, match="needs a colour filter array"):
        CameraChain(PAPER_SENSOR, restore_on="mosaic")
    with pytest.raises(ValueError, match="exposure_ms=0"):
        CameraChain(PAPER_SENSOR, exposure_ms=0)
    with pytest.raises(ValueError, match="demosaicing method 'AHD' is not known; valid: bilinear, Malvar2004"):
        CameraChain(PAPER_SENSOR, demosaic="AHD")


def test_sensor_presets_and_files(tmp_path):
    assert {"paper", "sony_imx477", "sony_imx363", "sony_imx571"} <= set(sensor_names())
    paper = load_sensor("paper")
    assert replace(paper, name="", source="") == PAPER_SENSOR
    for name in sensor_names():
        s = load_sensor(name)
        assert s.source and s.isos
    imx = load_sensor("sony_imx477")
    assert (imx.read_noise_e, imx.bit_depth, imx.black_level_dn, imx.cfa) == (3.0, 12, 256, "BGGR")
    f = tmp_path / "s.toml"
    f.write_text("[sensor]\npixel_pitch_um = 2.0\nwidth_px = 10\nheight_px = 10\nread_noise = 3\n")
    with pytest.raises(ValueError, match=r"s.toml'?: unknown key\(s\) read_noise; allowed"):
        load_sensor(str(f))
    f.write_text("[sensor]\npixel_pitch_um = 2.0\nwidth_px = 10\nheight_px = 10\nbit_depth = 8\n"
                 "black_level_dn = 300\n")
    with pytest.raises(ValueError, match="s.toml.*white_level_dn=300 is not allowed|s.toml.*black_level_dn=300"):
        load_sensor(str(f))
    with pytest.raises(ValueError, match="not a shipped preset; presets: paper"):
        load_sensor("imx999")


def _scene(h=256, w=256):
    yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    r = 0.5 + 0.4 * torch.sin(xx / 5.0) * torch.cos(yy / 7.0)
    g = 0.5 + 0.4 * torch.sin((xx + yy) / 9.0)
    b = 0.5 + 0.3 * torch.cos(xx / 11.0)
    return torch.stack([r, g, b])[None].clamp(0.01, 1)


@pytest.mark.parametrize("place", ["rgb", "mosaic"])
def test_crops_through_the_chain_restore_and_keep_their_raw_data(place):
    img = _scene()
    psf = _gaussian_psf(1.5)
    s = replace(PAPER_SENSOR, cfa="GRBG", read_noise_e=2.0, bit_depth=12)
    chain = CameraChain(s, restore_on=place)
    scheme = WindowScheme(64, 16, 32)
    boxes = [(64, 160, 70, 166), (101, 197, 33, 129)]  # an odd corner: the CFA's phase there
    res = simulate_crops(img, psf, 12800.0, boxes, sensor=chain, scheme=scheme, seed=2, methods=("wiener:stats=32",))
    for r in res:
        assert r.scores["wiener"]["psnr_db"] > r.scores["sensor"]["psnr_db"] + 2
        assert r.images["raw"].shape == (1, 1, 96, 96)
        raw = r.images["raw"]
        assert torch.equal(raw, raw.round()) and 0 <= raw.min() and raw.max() <= 4095
    again = simulate_crops(img, psf, 12800.0, boxes, sensor=chain, scheme=scheme, seed=2, methods=("wiener:stats=32",))
    assert all(a.scores == b.scores for a, b in zip(res, again))


def test_a_frame_through_the_chain_equals_its_crops_source_and_resumes(tmp_path):
    img = _scene(256, 320)
    psf = _gaussian_psf(1.2)
    s = replace(PAPER_SENSOR, cfa="RGGB", read_noise_e=2.0, bit_depth=12, dark_current_e_per_s=50.0)
    chain = CameraChain(s)
    scheme = WindowScheme(64, 16, 32)
    a = simulate_frame(img, psf, 3200.0, sensor=chain, scheme=scheme, checkpoint=tmp_path / "ck",
                       method="wiener:stats=32")
    assert a.raw.shape == (1, 1, 256, 320) and not a.resumed
    b = simulate_frame(img, psf, 3200.0, sensor=chain, scheme=scheme, checkpoint=tmp_path / "ck",
                       method="wiener:stats=32")
    assert b.resumed and torch.equal(a.raw.float(), b.raw.float())
    assert torch.allclose(a.sensor, b.sensor, atol=1e-6) and torch.allclose(a.restored, b.restored, atol=1e-5)
    from pipeline.quality import psnr_srgb

    assert psnr_srgb(img, a.restored) > psnr_srgb(img, a.sensor) + 2
    with pytest.raises(ValueError, match="colour filter array samples an RGB image; this one has 1"):
        simulate_frame(img[:, :1], psf, 3200.0, sensor=chain, scheme=scheme, method="wiener:stats=32")


@pytest.mark.parametrize("fill", [1.0, 0.5])
def test_pixel_aperture_attenuates_a_sinusoid_by_the_box_average(fill):
    """Blurring a sinusoid of f cycles/px with the pixel aperture alone scales it by the average of cos over the
    box of side a = sqrt(fill): sin(pi a f) / (pi a f), the closed form of the integral."""
    from lenssim.optics.pixel_aperture import PixelAperturePSF
    from pipeline.blur import blur_exact

    n = 64
    f = 6 / 64
    x = torch.arange(n, dtype=torch.float64)
    img = (0.5 + 0.4 * torch.cos(2 * math.pi * f * x))[None, None, None, :].expand(1, 1, n, n).clone()
    psf = PixelAperturePSF(_gaussian_psf(0.01), fill)
    cols = torch.arange(16, 48)
    mid = blur_exact(img, psf, torch.full_like(cols, n // 2), cols, n=16)[0, 0] - 0.5
    a = math.sqrt(fill)
    box = math.sin(math.pi * a * f) / (math.pi * a * f)
    amp = (mid * torch.cos(2 * math.pi * f * x[16:48])).sum() / (torch.cos(2 * math.pi * f * x[16:48]) ** 2).sum()
    assert amp.item() == pytest.approx(0.4 * box, rel=2e-3)


def test_pixel_aperture_enters_every_otf_criterion():
    from lenssim import evaluate
    from lenssim.criteria import OTFContext
    from lenssim_studies.paper import PAPER_DESIGNS

    cam = PAPER_CAMERA
    boxed = replace(cam, sensor=replace(cam.sensor, fill_factor=1.0))
    a = evaluate(cam, PAPER_DESIGNS["end_to_end_paper"], (27.6,), rho0=0.2)
    b = evaluate(boxed, PAPER_DESIGNS["end_to_end_paper"], (27.6,), rho0=0.2)
    assert float(b["mse_s"]) > float(a["mse_s"]) and float(b["mse_r"].squeeze()) > float(a["mse_r"].squeeze())
    H = torch.ones(1, 9, 9, dtype=torch.complex128)
    ctx = OTFContext(H, H.real.square(), None, None, None, None, 16, boxed)
    f = torch.arange(9, dtype=torch.float64) / 16
    assert torch.allclose(ctx.H.real[0], torch.sinc(f)[:, None] * torch.sinc(f)[None, :])
    assert torch.allclose(ctx.H2[0], ctx.H.real[0].square())
