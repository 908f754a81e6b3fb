"""Print the paper's quantitative claims beside the values measured on a sweep file.

    python benchmarks/reproduce_numbers.py results/paper_grid_fast.nc

Grid optima of RMS_W, MSE_S and MSE_R (27.6 dB), MSE_R of each design at 27.6 dB relative to the
best (the paper: ~37% and ~7% worse for the RMS_W and MSE_S designs), their C_a, and the optima
at the three noise levels.
"""

from __future__ import annotations

import sys

import xarray as xr

from lenssim.cli import find_optimum


def main(path: str) -> int:
    with xr.open_dataset(path) as ds:
        ds = ds.load()
    print(f"sweep {path}: {ds.sizes['s']} s x {ds.sizes['Q']} Q x {ds.sizes['alpha']} angles; "
          f"config digest {ds.attrs.get('config_digest', '?')}")
    best = {c: find_optimum(ds, c, 27.6) for c in ("rms_w", "mse_s", "mse_r")}
    ref = best["mse_r"]["mse_r"]["27.6"]
    print("| design (optimises) | s | Q | RMS_W [waves] | MSE_S @27.6 | MSE_R @27.6 | MSE_R / best | C_a |")
    print("|---|---|---|---|---|---|---|---|")
    for c, r in best.items():
        print(f"| {c.upper()} | {r['s']:g} | {r['Q']:g} | {r['rms_w_waves']:.4f} | {r['mse_s']['27.6']:.5f} | "
              f"{r['mse_r']['27.6']:.5f} | {r['mse_r']['27.6'] / ref:.3f} | {r['cost_Ca']:.3e} |"
              + (" (grid boundary)" if r["on_grid_boundary"] else ""))
    for s, Q, name in ((-0.725, -10.0, "paper RMS_W design"), (-0.775, -2.4, "paper end-to-end design")):
        at = ds.sel(s=s, Q=Q, method="nearest")
        print(f"{name} (s={s}, Q={Q}): MSE_R@27.6 = {float(at['mse_r'].sel(snr=27.6)):.5f} "
              f"({float(at['mse_r'].sel(snr=27.6)) / ref:.3f} x best), C_a = {float(at['cost']):.3e}")
    for snr in ds["snr"].values:
        r = find_optimum(ds, "mse_r", float(snr))
        print(f"MSE_R optimum at {snr:g} dB: s = {r['s']:g}, Q = {r['Q']:g}, MSE_R = {r['value']:.5f}, C_a = {r['cost_Ca']:.3e}")
        r = find_optimum(ds, "mse_s", float(snr))
        print(f"MSE_S optimum at {snr:g} dB: s = {r['s']:g}, Q = {r['Q']:g}, MSE_S = {r['value']:.5f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
