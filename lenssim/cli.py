"""``lenssim`` command line: evaluate designs, run sweeps, find optima.

Subcommands::

    lenssim demo                              the paper's two designs and a small sweep (default job)
    lenssim evaluate (--design NAME | --s S --Q Q) [--snr DB ...] [--json]
    lenssim sweep CONFIG --out FILE [--device auto|cpu|cuda]
    lenssim optimum FILE --criterion rms_w|mse_s|mse_r|cost [--snr DB] [--json]
    lenssim reproduce --out DIR [--config CONFIG]   figures 3-6, Table 1 and a report vs the paper
    lenssim designs                           list named designs
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .designs import load_designs
from .image_model import PAPER_SNR_DB
from .lens import PAPER_LENS, LensError

CRITERIA = ("rms_w", "mse_s", "mse_r", "cost")


def _configs_dir() -> Path:
    return Path(__file__).resolve().parent.parent / "configs"


def _designs(path: str | None):
    if path is None:
        default = _configs_dir() / "designs.toml"
        return load_designs(default if default.exists() else None)
    return load_designs(path)


def _evaluate_design(s: float, Q: float, snr, device: str = "auto") -> dict:
    from .metrics import evaluate
    from .sweep import select_device

    res = evaluate(PAPER_LENS, s, Q, snr, device=select_device(device))
    return {
        "s": s,
        "Q": Q,
        "rms_w_waves": float(res["rms_w"]),
        "rms_w_piston_removed_waves": float(res["rms_w_piston_removed"]),
        "cost_Ca": float(res["cost"]),
        "snr_db": [float(v) for v in res["snr_db"]],
        "mse_s": [float(v) for v in res["mse_s"]],
        "mse_r": [float(v) for v in res["mse_r"]],
        "fft_size_per_angle": [int(v) for v in res["fft_size"]],
        "alpha_deg": [float(v) for v in res["alpha_deg"]],
    }


def _table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    line = lambda r: "  ".join(str(x).rjust(w) for x, w in zip(r, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths])] + [line(r) for r in rows])


def _design_table(results: list[tuple[str, dict]]) -> str:
    snrs = results[0][1]["snr_db"]
    header = ["design", "s", "Q", "RMS_W [waves]", "C_a"] + [f"MSE_S@{v:g}dB" for v in snrs] + \
        [f"MSE_R@{v:g}dB" for v in snrs]
    rows = [[name, f"{r['s']:g}", f"{r['Q']:g}", f"{r['rms_w_waves']:.4f}", f"{r['cost_Ca']:.3e}"]
            + [f"{v:.5f}" for v in r["mse_s"]] + [f"{v:.5f}" for v in r["mse_r"]] for name, r in results]
    return _table(rows, header)


def cmd_evaluate(args) -> int:
    if args.design is not None:
        designs = _designs(args.designs)
        if args.design not in designs:
            raise ValueError(f"--design {args.design!r} is not known; choose from {sorted(designs)}")
        d = designs[args.design]
        name, s, Q = d.name, d.s, d.Q
    else:
        if args.s is None or args.Q is None:
            raise ValueError("give --design NAME, or both --s and --Q")
        name, s, Q = "custom", args.s, args.Q
    t0 = time.perf_counter()
    r = _evaluate_design(s, Q, args.snr, args.device)
    if args.json:
        print(json.dumps({"design": name, **r}, indent=2))
    else:
        print(_design_table([(name, r)]))
        print(f"\nFFT sizes per field angle {r['alpha_deg'][0]:g}..{r['alpha_deg'][-1]:g} deg: "
              f"{r['fft_size_per_angle']}  ({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_sweep(args) -> int:
    from .sweep import load_config, run_sweep

    cfg = load_config(args.config)
    t0 = time.perf_counter()
    run_sweep(cfg, args.out, device=args.device, show_progress=not args.quiet, keep_chunks=args.keep_chunks)
    print(f"wrote {args.out} ({len(cfg.s_values)} s x {len(cfg.Q_values)} Q x "
          f"{len(cfg.lens.field_angles_deg)} angles) in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def find_optimum(ds, criterion: str, snr: float | None = None) -> dict:
    """Grid argmin of ``criterion`` in a sweep dataset (``snr`` in dB picks the noise level)."""
    if criterion not in CRITERIA:
        raise ValueError(f"--criterion {criterion!r} is not allowed: one of {', '.join(CRITERIA)}")
    da = ds[criterion]
    if "snr" in da.dims:
        if snr is None:
            snr = 27.6 if 27.6 in ds["snr"].values else float(ds["snr"].values[len(ds["snr"]) // 2])
        if not np.any(np.isclose(ds["snr"].values, snr)):
            raise ValueError(f"--snr {snr!r} is not in the sweep; available: {list(ds['snr'].values)}")
        da = da.sel(snr=snr, method="nearest")
    idx = np.unravel_index(int(np.nanargmin(da.values)), da.shape)
    s, Q = float(ds["s"].values[idx[0]]), float(ds["Q"].values[idx[1]])
    at = dict(s=idx[0], Q=idx[1])
    out = {"criterion": criterion, "snr_db": snr, "s": s, "Q": Q, "value": float(da.values[idx]),
           "rms_w_waves": float(ds["rms_w"][at]), "cost_Ca": float(ds["cost"][at])}
    for k in ("mse_s", "mse_r"):
        out[k] = {f"{v:g}": float(ds[k][at].sel(snr=v)) for v in ds["snr"].values}
    out["on_grid_boundary"] = bool(idx[0] in (0, ds.sizes["s"] - 1) or idx[1] in (0, ds.sizes["Q"] - 1))
    return out


def cmd_optimum(args) -> int:
    import xarray as xr

    path = Path(args.file)
    if not path.exists():
        raise FileNotFoundError(f"sweep file {str(path)!r} does not exist")
    with xr.open_dataset(path) as ds:
        r = find_optimum(ds.load(), args.criterion, args.snr)
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        snr_txt = f" at {r['snr_db']:g} dB" if r["snr_db"] is not None else ""
        print(f"best {r['criterion']}{snr_txt}: s = {r['s']:g}, Q = {r['Q']:g}  (value {r['value']:.6g})"
              + ("  [on the grid boundary]" if r["on_grid_boundary"] else ""))
        print(f"  RMS_W = {r['rms_w_waves']:.4f} waves, C_a = {r['cost_Ca']:.4e}")
        for k in ("mse_s", "mse_r"):
            print(f"  {k.upper()}: " + ", ".join(f"{v:.5f} @ {snr} dB" for snr, v in r[k].items()))
    return 0


def cmd_demo(args) -> int:
    from .sweep import load_config, run_sweep

    designs = _designs(None)
    results = [(n, _evaluate_design(designs[n].s, designs[n].Q, PAPER_SNR_DB, args.device))
               for n in ("rms_w_paper", "end_to_end_paper")]
    print("The paper's two highlighted designs (f = 25 mm, f/6.25, n = 1.5, 0.5 um, 0-14 deg):\n")
    print(_design_table(results))
    cfg_path = _configs_dir() / "small_grid.toml"
    if cfg_path.exists():
        cfg = load_config(cfg_path)
    else:  # installed without the repository's configs/: the same coarse grid, built in
        from .lens import ThinLens
        from .sweep import SweepConfig

        cfg = SweepConfig(lens=ThinLens(field_angles_deg=tuple(range(0, 15, 2))), s=(-2.0, 1.0, 0.25), Q=(-10.0, 1.0, 1.0))
    out = Path(args.out)
    print(f"\nSmall sweep {cfg_path.name}: {len(cfg.s_values)} s x {len(cfg.Q_values)} Q x "
          f"{len(cfg.lens.field_angles_deg)} angles -> {out}", file=sys.stderr)
    ds = run_sweep(cfg, out, device=args.device, show_progress=not args.quiet)
    rows = []
    for crit in ("rms_w", "mse_s", "mse_r", "cost"):
        snrs = ds["snr"].values if crit in ("mse_s", "mse_r") else [None]
        for snr in snrs:
            r = find_optimum(ds, crit, snr)
            rows.append([crit + (f"@{snr:g}dB" if snr is not None else ""), f"{r['s']:g}", f"{r['Q']:g}",
                         f"{r['value']:.5g}", f"{r['rms_w_waves']:.3f}", f"{r['cost_Ca']:.3e}",
                         f"{r['mse_r']['27.6']:.5f}" if "27.6" in r["mse_r"] else "-"])
    print("\nGrid optima of the small sweep (coarse grid; the paper's grid is configs/paper_grid.toml):\n")
    print(_table(rows, ["criterion", "s", "Q", "value", "RMS_W", "C_a", "MSE_R@27.6dB"]))
    return 0


def cmd_reproduce(args) -> int:
    from .report import reproduce
    from .sweep import load_config

    cfg_path = Path(args.config) if args.config else _configs_dir() / "paper_grid_fast.toml"
    cfg = load_config(cfg_path)
    t0 = time.perf_counter()
    report = reproduce(args.out, cfg, device=args.device, show_progress=not args.quiet)
    print(report.read_text())
    print(f"wrote {args.out}/ (report.md, fig3..6 .png/.svg, table1.csv/.md) in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr)
    return 0


def cmd_designs(args) -> int:
    for d in _designs(args.designs).values():
        print(f"{d.name:20s} s = {d.s:7g}  Q = {d.Q:7g}  {d.description}")
    return 0


def build_parser(extend=None) -> argparse.ArgumentParser:
    """The ``lenssim`` parser; ``extend(subparsers)`` lets an upper layer (``pipeline.cli``) add commands."""
    p = argparse.ArgumentParser(prog="lenssim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"lenssim {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    e = sub.add_parser("evaluate", help="metrics of one design")
    e.add_argument("--design", help="a named design (see `lenssim designs`)")
    e.add_argument("--designs", help="TOML file of named designs (default: configs/designs.toml)")
    e.add_argument("--s", type=float, help="shape factor")
    e.add_argument("--Q", type=float, help="conic constant of the back surface")
    e.add_argument("--snr", type=float, nargs="+", default=list(PAPER_SNR_DB), help="SNRs in dB (default: 21.6 27.6 33.6)")
    e.add_argument("--device", default="auto")
    e.add_argument("--json", action="store_true", help="JSON output for scripts")
    e.set_defaults(func=cmd_evaluate)

    s = sub.add_parser("sweep", help="run or resume a design sweep")
    s.add_argument("config", help="sweep config (TOML), e.g. configs/paper_grid.toml")
    s.add_argument("--out", required=True, help="output NetCDF file")
    s.add_argument("--device", default="auto", help="auto (GPU if present), cpu, cuda")
    s.add_argument("--keep-chunks", action="store_true", help="keep OUT.partial/ after finishing")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_sweep)

    o = sub.add_parser("optimum", help="best grid configuration of a sweep")
    o.add_argument("file", help="sweep NetCDF file")
    o.add_argument("--criterion", required=True, help="rms_w, mse_s, mse_r or cost")
    o.add_argument("--snr", type=float, help="SNR in dB for mse_s/mse_r (default 27.6)")
    o.add_argument("--json", action="store_true")
    o.set_defaults(func=cmd_optimum)

    d = sub.add_parser("demo", help="the default job: the paper's designs and a small sweep")
    d.add_argument("--out", default="lenssim-demo-sweep.nc", help="where the small sweep is written (reused if present)")
    d.add_argument("--device", default="auto")
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=cmd_demo)

    r = sub.add_parser("reproduce", help="the paper's figures 3-6, Table 1 and a claims report")
    r.add_argument("--out", required=True, help="output folder (a second run reuses what is there)")
    r.add_argument("--config", help="sweep config (default: configs/paper_grid_fast.toml, ~10 min on 2 cores)")
    r.add_argument("--device", default="auto")
    r.add_argument("--quiet", action="store_true")
    r.set_defaults(func=cmd_reproduce)

    g = sub.add_parser("designs", help="list named designs")
    g.add_argument("--designs", help="TOML file of named designs")
    g.set_defaults(func=cmd_designs)
    if extend is not None:
        extend(sub)
    return p


def main(argv: list[str] | None = None, extend=None) -> int:
    parser = build_parser(extend)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (LensError, ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"lenssim {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
