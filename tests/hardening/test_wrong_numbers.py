"""Class 1 (issue 9): no silent wrong numbers. Every result is finite and means what its label says,
or the call stops with a ValueError naming the input."""

from __future__ import annotations

import json
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lenssim import Camera, Design, LensError, LensPSF, Numerics, evaluate, noise_variance

from lenssim_studies.paper import PAPER_CAMERA
from lenssim.io.files import json_text
from lenssim.validate import ModelValidityWarning, NumericalError
from pipeline import (NoiseModel, add_poisson_noise, blur_windowed, crop_at_field_angle, gentle_denoise, richardson_lucy_windowed,
                      simulate_crops, wiener_windowed)
from pipeline.blur import WindowScheme
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM

CAM2 = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 10.0)), PAPER_SENSOR, PAPER_SPECTRUM)
FAST = Numerics(min_size=64, oversample=1)
PSF = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))
SCHEME = WindowScheme(64, 16, 32)
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=40, deadline=None)
@given(s=st.floats(-3.0, 3.0), Q=st.floats(-60.0, 60.0))
def test_evaluate_is_finite_or_refuses(s, Q):
    with _quiet():
        try:
            r = evaluate(CAM2, Design(s=s, Q_back=Q), [27.6], numerics=FAST.replace(max_fft_size=1024), rho0=PAPER_RHO0)
        except (LensError, ValueError):
            return
    for k in ("rms_w", "mse_s", "mse_r", "cost"):
        assert torch.isfinite(r[k]).all(), (s, Q, k)
    assert float(r["mse_r"][0]) <= float(r["mse_s"][0]) + 1e-12  # restoration never worse than the sensor image


class _quiet:
    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", ModelValidityWarning)

    def __exit__(self, *a):
        return self._w.__exit__(*a)


@settings(max_examples=60, deadline=None)
@given(snr=FLOATS)
def test_noise_variance_is_finite_positive_or_refuses(snr):
    with _quiet():
        try:
            v = noise_variance(snr)
        except ValueError as exc:
            assert "SNR" in str(exc)
            return
    assert torch.isfinite(v).all() and float(v) > 0


def test_the_cost_is_finite_up_to_the_conic_limit():
    """Just inside the limit (Q_back < 48.5933 at s = -0.775) the cost was NaN; now finite and growing."""
    from lenssim import slope_departure_cost
    from lenssim_studies.paper import PAPER_LENS

    with _quiet():
        c = [float(slope_departure_cost(PAPER_LENS, Design(s=-0.775, Q_back=q))) for q in (40.0, 48.0, 48.59, 48.5932)]
    assert all(math.isfinite(v) for v in c) and c == sorted(c)
    with pytest.raises(LensError, match="Q_back must be < 48.59"):
        slope_departure_cost(PAPER_LENS, Design(s=-0.775, Q_back=48.6))


def test_json_never_holds_nan_and_writes_infinity_as_null():
    assert json.loads(json_text({"psnr": math.inf, "x": [1.0, -math.inf]})) == {"psnr": None, "x": [1.0, None]}
    with pytest.raises(NumericalError, match="crops\\[0\\].psnr is NaN"):
        json_text({"crops": [{"psnr": math.nan}]})


@pytest.mark.parametrize("value", [math.inf, math.nan, 1e30, 0.0, -5.0, 0.5])
def test_full_well_outside_the_model_is_refused(value):
    img = torch.rand(1, 1, 32, 32, dtype=torch.float64)
    with pytest.raises(ValueError, match="full_well"):
        add_poisson_noise(img, value, seed=0)
    with pytest.raises(ValueError, match="full_well"):
        simulate_crops(img, PSF, value, [(0, 16, 0, 16)], scheme=SCHEME, sensor=PAPER_SENSOR)


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("fn", ["blur", "wiener", "rl", "denoise", "noise", "simulate"])
def test_a_non_finite_pixel_is_refused_by_every_image_function(fn, bad):
    img = torch.rand(1, 3, 40, 40, dtype=torch.float32, generator=torch.Generator().manual_seed(0)) + 0.1
    img[0, 1, 7, 9] = float(bad)
    call = {"blur": lambda: blur_windowed(img, PSF, scheme=SCHEME),
            "wiener": lambda: wiener_windowed(img, PSF, noise=NoiseModel(100.0), scheme=SCHEME),
            "rl": lambda: richardson_lucy_windowed(img, PSF, iterations=2, scheme=SCHEME),
            "denoise": lambda: gentle_denoise(img, 0.5),
            "noise": lambda: add_poisson_noise(img, 800.0, seed=0),
            "simulate": lambda: simulate_crops(img, PSF, 800.0, [(0, 16, 0, 16)], scheme=SCHEME, sensor=PAPER_SENSOR)}[fn]
    with pytest.raises(ValueError, match=r"NaN or infinite pixel values \(first at index \(0, 1, 7, 9\)"):
        call()


@pytest.mark.parametrize("fn, match", [
    (lambda x: add_poisson_noise(-x, 800.0, seed=0), "negative values"),
    (lambda x: simulate_crops(-x, PSF, 800.0, [(0, 16, 0, 16)], scheme=SCHEME, sensor=PAPER_SENSOR), "negative values"),
    (lambda x: simulate_crops(x * 0, PSF, 800.0, [(0, 16, 0, 16)], scheme=SCHEME, sensor=PAPER_SENSOR), "black"),
    (lambda x: blur_windowed((x * 255).to(torch.uint8), PSF, scheme=SCHEME), "dtype torch.uint8"),
    (lambda x: wiener_windowed(x, PSF, noise=NoiseModel(100.0, -1.0), scheme=SCHEME), "signal_independent_var=-1.0"),
    (lambda x: wiener_windowed(x, PSF, noise=NoiseModel(math.nan), scheme=SCHEME), "electrons_per_unit=nan"),
    (lambda x: wiener_windowed(x, PSF, noise=100.0, scheme=SCHEME), "noise is a float: expected a pipeline"),
    (lambda x: simulate_crops(x, PSF, 800.0, [(0, 99, 0, 16)], scheme=SCHEME, sensor=PAPER_SENSOR), r"box \(0, 99, 0, 16\)"),
])
def test_nonsense_images_and_settings_are_refused(fn, match):
    x = torch.rand(1, 1, 40, 40, dtype=torch.float64) + 0.1
    with pytest.raises(ValueError, match=match):
        fn(x)


@pytest.mark.parametrize("angle, match", [(45.0, "field angle=45.0 is not allowed: a finite number >= 0 deg and <= 1.787"),
                                          (-5.0, "field angle=-5.0"), (math.nan, "field angle=nan")])
def test_crops_outside_the_frame_are_refused_not_moved(angle, match):
    with pytest.raises(ValueError, match=match):
        crop_at_field_angle((1, 3, 600, 800), angle, 64, PAPER_CAMERA.geometry)


def test_a_crop_moved_inside_the_frame_says_so():
    with pytest.warns(ModelValidityWarning, match="moved inside, to 1.29 deg"):
        crop_at_field_angle((1, 3, 600, 800), 1.63, 200, PAPER_CAMERA.geometry)


@pytest.mark.parametrize("name", ["psf", "otf", "otf_quarter", "wavefront", "rms_wavefront", "max_wavefront_slope",
                                  "fft_size", "field_rms_wavefront"])
def test_every_coefficient_function_refuses_non_finite_coefficients(name):
    import lenssim

    c = torch.zeros(2, 1, 4, dtype=torch.float64)
    c[1, 0, 2] = math.nan
    calls = {"psf": lambda: lenssim.psf(PAPER_CAMERA, c, 64), "otf": lambda: lenssim.otf(PAPER_CAMERA, c, 64),
             "otf_quarter": lambda: lenssim.otf_quarter(c[:, 0], 64, pupil_radius_px=16.0),
             "wavefront": lambda: lenssim.wavefront(c[:, 0], torch.zeros(3), torch.zeros(3)),
             "rms_wavefront": lambda: lenssim.rms_wavefront(c[:, 0]),
             "max_wavefront_slope": lambda: lenssim.max_wavefront_slope(c[:, 0]),
             "fft_size": lambda: lenssim.fft_size(PAPER_CAMERA, c),
             "field_rms_wavefront": lambda: lenssim.field_rms_wavefront(c[:, 0])}
    with pytest.raises(ValueError, match=r"coeffs holds NaN or infinite values \(first at index \(1, "):
        calls[name]()


@settings(max_examples=60, deadline=None)
@given(dtype=st.sampled_from([torch.float16, torch.float32, torch.float64, torch.complex64]),
       n=st.integers(1, 2000), bad=st.sampled_from([math.nan, math.inf, -math.inf]), where=st.floats(0, 1),
       huge=st.booleans())
def test_the_finite_check_finds_every_nan_and_infinity_and_passes_huge_finite_values(dtype, n, bad, where, huge):
    """The fast path (a finite sum proves all finite) may not hide a bad element, and a sum that overflows on
    finite values (here near the dtype's maximum) may not refuse good data."""
    from lenssim.validate import check_finite

    big = torch.finfo(dtype if not dtype.is_complex else torch.float32).max / 2
    t = torch.full((n,), big if huge else 1.0, dtype=dtype)
    assert check_finite("t", t) is t
    i = min(n - 1, int(where * n))
    t[i] = bad
    with pytest.raises(ValueError, match=rf"t holds NaN or infinite values \(first at index \({i},\)"):
        check_finite("t", t)
