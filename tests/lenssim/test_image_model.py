import math

import pytest
import torch
from scipy import integrate

from lenssim import image_psd, noise_variance, psd_continuous
from lenssim_studies.paper import PAPER_RHO0


def test_continuous_psd_integrates_to_unit_variance():
    val, _ = integrate.quad(lambda f: 2 * math.pi * f * float(psd_continuous(torch.tensor(f, dtype=torch.float64), PAPER_RHO0)),
                            0, math.inf, limit=500)
    assert val == pytest.approx(1.0, rel=1e-6)


def test_discrete_psd_is_the_aliased_continuous_psd():
    """Poisson summation: the sampled correlation's spectrum is sum_k P_c(f + k)."""
    n = 64
    P = image_psd(n, dtype=torch.float64, rho0=PAPER_RHO0)
    K = 60
    k = torch.arange(-K, K + 1, dtype=torch.float64)
    a = -math.log(0.97)
    for iy, ix in [(0, 0), (0, 5), (7, 3), (32, 32), (16, 0)]:
        fy, fx = iy / n, ix / n
        s = psd_continuous(torch.hypot(fy + k[:, None], fx + k[None, :]), PAPER_RHO0).sum()
        tail = a / (2 * math.pi * (K + 0.5) * 1.128)  # integral of a/(4 pi^2 |k|^3) beyond the box (disc of equal area)
        assert float(P[iy, ix]) == pytest.approx(float(s) + tail, rel=2e-4)


def test_discrete_psd_has_unit_variance_and_symmetry():
    P = image_psd(2048, dtype=torch.float64, rho0=PAPER_RHO0)
    assert float(P.mean()) == pytest.approx(1.0, abs=1e-9)  # = correlation at lag 0 (aliases below 1e-26)
    torch.testing.assert_close(P, torch.roll(torch.flip(P, [0]), 1, 0))  # P(-f) = P(f)
    torch.testing.assert_close(P, P.T)
    assert torch.all(P > 0)


def test_psd_options_and_errors():
    Pc = image_psd(128, model="continuous", dtype=torch.float64, rho0=PAPER_RHO0)
    assert Pc[0, 0] == pytest.approx(2 * math.pi / (-math.log(0.97)) ** 2)
    assert image_psd(16, PAPER_RHO0).dtype == torch.float32
    with pytest.raises(ValueError, match="rho0=1.2"):
        image_psd(16, rho0=1.2)
    with pytest.raises(ValueError, match="model='gauss'"):
        image_psd(16, model="gauss", rho0=PAPER_RHO0)
    with pytest.raises(ValueError, match="n=1"):
        image_psd(1, PAPER_RHO0)


def test_noise_variance_from_snr():
    torch.testing.assert_close(noise_variance([21.6, 27.6, 33.6]),
                               torch.tensor([10**-2.16, 10**-2.76, 10**-3.36], dtype=torch.float64))
    # the paper's linear (amplitude) SNR of 24 is 27.6 dB, i.e. sigma_w^2 = 1/24^2
    assert 20 * math.log10(24) == pytest.approx(27.6, abs=0.01)
    assert float(noise_variance(27.6)) == pytest.approx(1 / 24**2, rel=2e-3)
    with pytest.raises(ValueError, match=r"SNR \[inf\] dB is not allowed"):
        noise_variance(float("inf"))
