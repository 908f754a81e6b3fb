"""The camera chain (issue 31): its cost on a 24 MP frame beside the optics blur, and its photon transfer curve.

    python benchmarks/bench_camera_chain.py [--size 4000 6000] [--ptc docs/figures/camera_ptc.png] [--skip-frame]

1. Photon transfer curve (EMVA 1288 release 4.0, the standard's method): a flat field at 24 exposure levels through the
   sensor side of the chain (the ``sony_imx477`` preset: read noise 3 e-, 12-bit, black level 256 DN, plus 5 e-/s of
   dark current over 100 ms and 1 e- of DSNU to show every term), 256 x 256 pixels each; the mean and the variance of
   the DN against the model ``mu_y = K (mu_e + mu_d) + black``, ``sigma_y^2 = K^2 (mu_e + sigma_d^2) + 1/12``;
   plotted (log-log variance vs mean above the black level) with the largest deviation in Monte Carlo standard errors.
2. Cost on a frame (default 4000 x 6000, RGB, the paper's lens ``end_to_end_paper`` on a generated scene): the windowed
   blur (simulate's default scheme) timed once, then the chain's stages on its output: capture (mosaic, photon and read
   noise, ADC), linearise, white balance, demosaic by each method; the ratio of each to the blur, measured in the same
   process. Nothing is downloaded; no timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import math
import time

import torch


def ptc(path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dataclasses import replace

    from lenssim.io.sensor_file import load_sensor
    from pipeline.camera_chain import CameraChain

    s = replace(load_sensor("sony_imx477"), dark_current_e_per_s=5.0, dsnu_e=1.0)
    fw = s.full_well_for_iso(100)
    chain = CameraChain(s, exposure_ms=100.0)
    K = 1 / s.conversion_gain_e_per_dn(fw)
    n = 256
    levels = [0.0] + list(torch.logspace(-4, math.log10(0.95), 23).tolist())
    mus, vars_, mu_m, var_m, worst = [], [], [], [], 0.0
    for k, lv in enumerate(levels):
        raw = chain.capture(torch.full((1, 3, n, n), lv, dtype=torch.float64), fw, fw,  # a grey field, mosaicked
                            generator=torch.Generator().manual_seed(k))
        mu_e = lv * fw
        m = K * (mu_e + chain.dark_electrons) + s.black_level_dn
        v = K**2 * (mu_e + s.read_noise_e**2 + chain.dark_electrons + s.dsnu_e**2) + 1 / 12
        N = n * n
        dm = (raw.mean().item() - m) / math.sqrt(v / N)
        dv = (raw.var().item() - v) / (v * math.sqrt(2 / (N - 1)))
        worst = max(worst, abs(dm), abs(dv))
        mus.append(raw.mean().item() - s.black_level_dn)
        vars_.append(raw.var().item())
        mu_m.append(m - s.black_level_dn)
        var_m.append(v)
    print(f"photon transfer: {len(levels)} levels, largest deviation from the model {worst:.2f} standard errors "
          f"(K = {K:.4f} DN/e-, black {s.black_level_dn} DN, read noise {s.read_noise_e} e-)")
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    ax.loglog(mu_m[1:], var_m[1:], "-", color="0.4", label="model: K^2 (mu_e + read^2 + dark + DSNU^2) + 1/12")
    ax.loglog(mus[1:], vars_[1:], "o", ms=4, label=f"simulated, {n} x {n} px per level")
    ax.axhline(var_m[0], ls=":", color="0.6", label=f"dark floor {var_m[0]:.2f} DN^2")
    ax.set_xlabel("mean signal above the black level [DN]")
    ax.set_ylabel("variance [DN^2]")
    ax.set_title(f"Photon transfer curve (EMVA 1288): {s.name.split(';')[0]}\nISO 100, {fw:g} e- at full scale, "
                 f"12-bit, read noise {s.read_noise_e:g} e-, dark 5 e-/s x 100 ms, DSNU 1 e-", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def frame(size) -> None:
    from lenssim import LensPSF
    from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
    from pipeline.blur import PAPER_SCHEME, blur_windowed
    from pipeline.camera_chain import CameraChain
    from pipeline.cfa import DEMOSAIC_METHODS
    from pipeline.scene import resolution_scene
    from dataclasses import replace

    torch.set_num_threads(torch.get_num_threads())
    H, W = size
    scene = resolution_scene(H, W, geometry=PAPER_CAMERA.geometry)
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    t0 = time.perf_counter()
    blurred = blur_windowed(scene, psf, scheme=PAPER_SCHEME)
    t_blur = time.perf_counter() - t0
    print(f"{W} x {H} RGB frame: windowed blur {t_blur:.1f} s")
    s = replace(PAPER_CAMERA.sensor, cfa="RGGB", read_noise_e=3.0, bit_depth=12)
    e = 3200 / float(blurred.amax())
    for method in DEMOSAIC_METHODS:
        chain = CameraChain(s, demosaic=method)
        t = {}
        t0 = time.perf_counter()
        raw = chain.capture(blurred, e, 3200.0, generator=torch.Generator().manual_seed(0))
        t["capture"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        units = chain.linearise(raw, e, 3200.0)
        gains = chain.white_balance_gains(units)
        t["linearise + white balance"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        chain.develop(units, gains=gains)
        t["develop (demosaic)"] = time.perf_counter() - t0
        total = sum(t.values())
        print(f"  {method:10s}: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items())
              + f"; chain {total:.1f} s = {total / t_blur:.2f} x the blur")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, nargs=2, default=[4000, 6000], metavar=("H", "W"))
    p.add_argument("--ptc", default="docs/figures/camera_ptc.png")
    p.add_argument("--skip-frame", action="store_true")
    a = p.parse_args()
    ptc(a.ptc)
    if not a.skip_frame:
        frame(a.size)


if __name__ == "__main__":
    main()
