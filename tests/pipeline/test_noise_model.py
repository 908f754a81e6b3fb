"""One camera forward model (issue 44): the paper's exposure is the camera chain with its other stages off, and the
noise description every restoration is given (:meth:`CameraChain.noise_model`) equals the variance of the noise the
chain simulates, by Monte Carlo."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import FunctionPSF, Sensor
from lenssim_studies.paper import PAPER_CAMERA, PAPER_SENSOR
from pipeline import NoiseModel
from pipeline.blur import WindowScheme
from pipeline.camera_chain import CameraChain
from pipeline.restoration import RESTORATION_METHODS, RestorationMethod
from pipeline.simulate import simulate_crops, simulate_frame

FW = 3200.0
"""Full well (e-) of the Monte Carlo runs: the paper's ISO 100."""
SIDE_PX = 512
"""Side of the flat frames the Monte Carlo draws: 262,144 pixels per level (two fixed-pattern tiles a side)."""
SIGMAS = 4.0
"""Tolerance in Monte Carlo standard errors (a false alarm about once in 16,000 comparisons)."""
LEVELS = (0.0, 0.02, 0.3, 0.8)
"""Signal levels (fractions of the full well): dark, deep shadow, mid-tone, near the top (below the white level)."""


def _sensor(**kw) -> Sensor:
    return Sensor(pixel_pitch_um=1.5625, width_px=64, height_px=64, **kw)


# name -> (chain, image channels); the ADC's step (3200 e- over 239 DN = 13.4 e-) is coarse enough that its rounding
# (15 e-^2) is 15% of the variance in the dark, yet the Gaussian noise before it (9.2 e- = 0.69 DN) smooths the counts
# so that the rounding error is uniform and uncorrelated with the signal (its variance off gain^2 / 12 by 2e-4 relative)
CHAINS = {
    "paper": (CameraChain(PAPER_SENSOR), 1),
    "read_dark_dsnu_adc": (CameraChain(_sensor(read_noise_e=8.0, dark_current_e_per_s=100.0, dsnu_e=4.0, bit_depth=8,
                                               black_level_dn=16), exposure_ms=50.0), 1),
    "prnu_qe_read": (CameraChain(_sensor(prnu_percent=1.5, quantum_efficiency=(0.45, 0.8, 0.6), read_noise_e=2.0)), 3),
}


def _sample_moments(y: torch.Tensor) -> tuple[float, float, float]:
    """Mean, variance (1/N) and the standard error of that variance from the sample's fourth central moment:
    ``sqrt((m4 - m2^2) / N)`` (any distribution: Poisson counts, rounded values, fixed patterns)."""
    y = y.flatten().double()
    n = y.numel()
    d = y - y.mean()
    m2 = float(d.square().mean())
    m4 = float(d.square().square().mean())
    return float(y.mean()), m2, math.sqrt(max(m4 - m2 * m2, 0.0) / n)


@pytest.mark.parametrize("name", list(CHAINS))
@pytest.mark.parametrize("level", LEVELS)
def test_noise_description_equals_the_variance_of_the_simulated_noise(name, level):
    chain, channels = CHAINS[name]
    img = torch.full((1, channels, SIDE_PX, SIDE_PX), level, dtype=torch.float64)
    out = chain.expose(img, FW, FW, generator=torch.Generator().manual_seed(17), origin=(300, 41))
    noise = chain.noise_model(FW, FW)
    qe = chain.sensor.qe(channels)
    for c in range(channels):
        x = level * qe[c] / max(qe)  # the expected signal in the sensor's units (QE relative to the largest)
        mean, var, se = _sample_moments(out[0, c])
        want = noise.variance(x)
        assert abs(var - want) <= SIGMAS * se + 1e-15, (name, level, c, var, want, se)
        assert abs(mean - x) <= SIGMAS * math.sqrt(var / out[0, c].numel()) + 1e-15  # black level, dark mean removed


def test_each_term_is_in_the_description_exactly_where_its_stage_runs():
    """The ADC's rounding is gain^2 / 12 (the old paper path's ``read_noise_variance`` promised it and left it out);
    a term whose stage is off adds nothing; the Monte Carlo above would see any term counted twice or missed."""
    e = 1000.0
    s = _sensor(read_noise_e=3.0, bit_depth=10, black_level_dn=23, dsnu_e=2.0, dark_current_e_per_s=40.0,
                prnu_percent=0.5)
    chain = CameraChain(s, exposure_ms=25.0)
    gain = FW / (1023 - 23)
    m = chain.noise_model(e, FW)
    assert m.signal_independent_var == pytest.approx((9.0 + 1.0 + 4.0 + gain**2 / 12) / e**2, rel=1e-15)
    assert m.prnu == 0.005 and m.electrons_per_unit == e
    assert m.variance(0.25) == pytest.approx(0.25 / e + (0.005 * 0.25) ** 2 + m.signal_independent_var, rel=1e-15)
    assert m.variance(-1.0) == m.signal_independent_var  # a negative mean counts as no signal
    paper = CameraChain(PAPER_SENSOR).noise_model(e, FW)
    assert (paper.signal_independent_var, paper.prnu) == (0.0, 0.0)
    only_adc = CameraChain(_sensor(bit_depth=10)).noise_model(e, FW)
    assert only_adc.signal_independent_var == (FW / 1023) ** 2 / 12 / e**2
    assert NoiseModel(math.inf).variance(torch.tensor([0.5]))[0] == 0.0


def test_noise_model_refuses_nonsense():
    with pytest.raises(ValueError, match="electrons_per_unit=0 is not allowed"):
        NoiseModel(0)
    with pytest.raises(ValueError, match="signal_independent_var=nan is not allowed"):
        NoiseModel(10.0, float("nan"))
    with pytest.raises(ValueError, match="prnu=-0.1 is not allowed"):
        NoiseModel(10.0, 0.0, -0.1)


def _delta_psf():
    def fn(x_mm, y_mm, n):
        p = torch.zeros(len(x_mm), n, n, dtype=torch.float64)
        p[:, n // 2, n // 2] = 1
        return p
    return FunctionPSF(fn, PAPER_CAMERA.geometry, extent=1, mirror_symmetric=True)


@pytest.mark.parametrize("chain", [CameraChain(_sensor(read_noise_e=2.0, bit_depth=12, dsnu_e=1.0)),
                                   CameraChain(_sensor(read_noise_e=2.0, bit_depth=12, cfa="RGGB"))],
                         ids=["the exposure is the image", "a mosaic, developed"])
def test_every_restoration_is_given_the_chains_noise_description(chain):
    """A restoration method that records what it is given, run by crops and by a frame: its ``noise`` is the chain's
    :meth:`noise_model` at the run's electrons per unit (no second formula on the way)."""
    seen = []

    def probe(observed, psf, *, noise):
        seen.append(noise)
        return observed

    RESTORATION_METHODS["probe"] = RestorationMethod("probe", "probe", "records its noise", probe)
    try:
        img = torch.rand(1, 3, 96, 96, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.5 + 0.25
        scheme = WindowScheme(32, 8, 16)
        (r,) = simulate_crops(img, _delta_psf(), FW, [(30, 62, 30, 62)], sensor=chain, scheme=scheme, methods=("probe",),
                              dtype=torch.float64)
        f = simulate_frame(img, _delta_psf(), FW, sensor=chain, scheme=scheme, method="probe", dtype=torch.float64)
    finally:
        del RESTORATION_METHODS["probe"]
    crop_e = FW / float(img.amax())  # crops: the ideal image's peak at the full well; the frame: its blurred peak
    assert seen == [chain.noise_model(crop_e, FW), chain.noise_model(f.electrons_per_unit, FW)]
    assert seen[0].signal_independent_var > 0 and r.methods == ("probe",)


def test_simulate_takes_a_sensor_or_a_chain_and_a_sensor_is_its_default_chain():
    img = torch.rand(1, 3, 96, 96, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.5 + 0.25
    s = _sensor(read_noise_e=2.0, bit_depth=12, dark_current_e_per_s=30.0, dsnu_e=1.5)
    kw = dict(scheme=WindowScheme(32, 8, 16), dtype=torch.float64, seed=3, methods=("wiener:stats=16",))
    (a,) = simulate_crops(img, _delta_psf(), FW, [(30, 62, 30, 62)], sensor=s, **kw)
    (b,) = simulate_crops(img, _delta_psf(), FW, [(30, 62, 30, 62)], sensor=CameraChain(s), **kw)
    assert a.scores == b.scores and torch.equal(a.sensor, b.sensor)
    with pytest.raises(ValueError, match="sensor is a str: expected a lenssim.Sensor or a pipeline.camera_chain"):
        simulate_crops(img, _delta_psf(), FW, [(30, 62, 30, 62)], sensor="paper", **kw)
    with pytest.raises(TypeError, match="chain"):
        simulate_crops(img, _delta_psf(), FW, [(30, 62, 30, 62)], sensor=s, chain=CameraChain(s), **kw)
