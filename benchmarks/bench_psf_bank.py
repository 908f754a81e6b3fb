"""PSF/OTF-bank throughput against a per-PSF loop with prysm, side by side in one process.

    python benchmarks/bench_psf_bank.py [--n 512] [--repeat 3]
    python benchmarks/bench_psf_bank.py --sweep configs/paper_grid.toml --out results/paper_grid.nc

Both sides compute, for the same coefficient sets and FFT size, PSF -> OTF -> (MSE_S, MSE_R) at
the paper's three SNRs. The baseline is what a user would write with prysm 0.21 (the
`bench` extra): an ``N/2``-sample pupil, ``prysm.propagation.focus(.., Q=2)``, ``prysm.otf.otf_from_psf``
and the same MSE formulas in numpy, one PSF at a time. Prints the ratio of throughputs and the
agreement of the metrics. No timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

import numpy as np
import torch

from lenssim import Design, Numerics, image_psd, noise_variance, otf_criteria_bank, spectral_coefficients

from lenssim_studies.paper import PAPER_CAMERA, PAPER_SNR_DB
from lenssim_studies.paper import PAPER_RHO0

SNR = PAPER_SNR_DB
NATIVE = Numerics(oversample=1)


def mse_bank(c, sizes):
    out = otf_criteria_bank(PAPER_CAMERA, c, sizes, SNR, numerics=NATIVE, rho0=PAPER_RHO0)
    return out["mse_s"], out["mse_r"]


def prysm_loop(coeffs: np.ndarray, n: int) -> np.ndarray:
    from prysm.coordinates import cart_to_polar, make_xy_grid
    from prysm.geometry import circle
    from prysm.otf import otf_from_psf

    from prysm.propagation import focus

    m = n // 2
    x, y = make_xy_grid(m, diameter=2.0)
    r, t = cart_to_polar(x, y)
    amp = circle(1.0, r)
    rho_r = y  # field along +y, as in lenssim
    P = np.fft.fftshift(image_psd(n, dtype=torch.float64, rho0=PAPER_RHO0).numpy())
    s2 = noise_variance(SNR).numpy()
    out = np.empty((coeffs.shape[0], 2, len(SNR)))
    for i, (a, b, c, d) in enumerate(coeffs):
        W = a * r**4 + b * r**2 * rho_r + c * rho_r**2 + d * r**2
        E = focus(amp * np.exp(-2j * np.pi * W), Q=2)
        psf = np.abs(E) ** 2
        psf /= psf.sum()
        H = otf_from_psf(psf, dx=PAPER_CAMERA.pixel_pitch_um)  # centred, H[n//2, n//2] = 1
        H = H.data if hasattr(H, "data") else H
        blur = np.mean(np.abs(1 - H) ** 2 * P)
        out[i, 0] = s2 + blur
        out[i, 1] = [np.mean(s * P / (np.abs(H) ** 2 * P + s)) for s in s2]
    return out


def bench_bank(n: int, repeat: int) -> None:
    s = torch.tensor([-0.775, -0.725], dtype=torch.float64)[:, None]
    Q = torch.tensor([-2.4, -10.0], dtype=torch.float64)[:, None]
    c = spectral_coefficients(PAPER_CAMERA, Design(s=s, Q_back=Q)).reshape(-1, 1, 4)  # 30 PSFs: 2 designs x 15 angles
    c = torch.cat([c] * 2)  # 60 PSFs
    sizes = torch.full((c.shape[0],), n)
    cf = c.float()
    mse_bank(cf[:2], sizes[:2])  # warm caches
    t_ours, t_prysm = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        ms, mr = mse_bank(cf, sizes)
        t_ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ref = prysm_loop(c[:, 0].numpy(), n)
        t_prysm.append(time.perf_counter() - t0)
    ours, base = min(t_ours), min(t_prysm)
    k = c.shape[0]
    print(f"FFT size {n}, {k} PSFs (paper's two designs x 15 angles, x2), torch threads {torch.get_num_threads()}")
    print(f"  lenssim bank : {k / ours:8.1f} PSF/s  ({ours:.3f} s, best of {repeat})")
    print(f"  prysm loop   : {k / base:8.1f} PSF/s  ({base:.3f} s)")
    print(f"  ratio        : {base / ours:8.2f} x prysm throughput")
    rs = np.abs(ms.numpy() / ref[:, 0] - 1).max()
    rr = np.abs(mr.numpy() / ref[:, 1] - 1).max()
    print(f"  agreement    : max relative difference MSE_S {rs:.2e}, MSE_R {rr:.2e} "
          "(lenssim: anti-aliased, area-normalised pupil; prysm: hard-edged circle)")


def bench_sweep(config: str, out: str) -> None:
    from lenssim_studies.sweep import load_config, run_sweep

    cfg = load_config(config)
    t0 = time.perf_counter()
    run_sweep(cfg, out)
    dt = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    n = len(cfg.s_values) * len(cfg.Q_values) * len(cfg.lens.field_angles_deg)
    print(f"sweep {config}: {n} PSFs in {dt:.1f} s ({n / dt:.1f} PSF/s), peak RSS {peak:.2f} GiB")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=512, help="FFT size for the bank comparison")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sweep", help="also time a full sweep of this config")
    ap.add_argument("--out", default="results/bench_sweep.nc")
    args = ap.parse_args()
    try:
        import prysm  # noqa: F401
    except ImportError:
        print("prysm is not installed: pip install -c constraints.txt -e '.[bench]'", file=sys.stderr)
        return 2
    bench_bank(args.n, args.repeat)
    if args.sweep:
        bench_sweep(args.sweep, args.out)
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())  # no nanobind "leaked" noise at exit
