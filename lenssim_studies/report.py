"""One-command reproduction: sweep (reused or resumed), trade-off, figures, Table 1 and a report.

``lenssim reproduce --out DIR`` writes ``DIR/sweep.nc``, ``DIR/tradeoff.nc``, ``DIR/fig3..6.{png,svg}``,
``DIR/table1.{csv,md}`` and ``DIR/report.md``, which lists each quantitative claim of the paper
beside the measured value. A second run reuses what is there.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import xarray as xr

from .chunks import stamp_result, verify_result
from .figures import TABLE1_CRITERIA, all_figures, table1
from lenssim.io.files import atomic_write, atomic_write_text
from .paper import PAPER_COST_LEVELS, PAPER_DESIGNS, REFERENCE_SNR_DB
from .sweep import SweepConfig, design_dims, run_sweep
from .tradeoff import find_optimum, min_cost_for_quality, tradeoff

__all__ = ["reproduce", "report_text"]


def _load_or_compute_tradeoff(ds: xr.Dataset, path: Path) -> xr.Dataset:
    digest = ds.attrs.get("config_digest", "")
    if path.exists():
        with xr.open_dataset(path) as old:
            if old.attrs.get("sweep_digest") == digest:
                trade = old.load()
                verify_result(trade, path, "reproduction", "remove it and run `lenssim reproduce` again")
                return trade
    trade = tradeoff(ds, levels=PAPER_COST_LEVELS, criteria=TABLE1_CRITERIA)  # the paper's three design strategies
    trade.attrs["sweep_digest"] = digest
    stamp_result(trade)  # verified when a second run reuses it
    atomic_write(path, lambda tmp: trade.to_netcdf(tmp, engine="scipy"))
    return trade


def _fmt_design(s, Q):
    return f"s = {s:g}, Q_back = {Q:g}"


def report_text(ds: xr.Dataset, trade: xr.Dataset, rows: list[dict], snr: float = REFERENCE_SNR_DB) -> str:
    """The report: the paper's claims beside the measured values (Markdown); needs an (s, Q_back) sweep."""
    if design_dims(ds) != ("s", "Q_back"):
        raise ValueError(f"the paper's report needs a sweep over (s, Q_back); this one is over {list(design_dims(ds))}")
    best = {c: find_optimum(ds, c, snr) for c in ("rms_w", "mse_s", "mse_r")}
    snrs = [float(v) for v in ds["snr"].values]
    opt_r = {v: find_optimum(ds, "mse_r", v) for v in snrs}
    p_rms, p_e2e = PAPER_DESIGNS["rms_w_paper"].floats(), PAPER_DESIGNS["end_to_end_paper"].floats()
    e2e_paper = ds.sel(p_e2e, method="nearest")
    rel = {r["design"]: r["mse_r_relative"] for r in rows}
    cost = {r["design"]: r["cost_Ca"] for r in rows}
    grid_is_paper = ds.sizes["s"] == 122 and ds.sizes["Q_back"] == 113 and ds.sizes["alpha"] == 15
    e2e_val = float(e2e_paper["mse_r"].sel(snr=snr, method="nearest"))
    spread = max(abs(opt_r[a]["design"]["s"] - opt_r[b]["design"]["s"]) for a in snrs for b in snrs)
    qspread = max(abs(opt_r[a]["design"]["Q_back"] - opt_r[b]["design"]["Q_back"]) for a in snrs for b in snrs)
    lines = [
        "# Reproduction report",
        "",
        f"Sweep: {ds.sizes['s']} s x {ds.sizes['Q_back']} Q_back x {ds.sizes['alpha']} field angles, SNR {snrs} dB "
        f"({'the paper grid' if grid_is_paper else 'NOT the paper grid: claims about grid optima are indicative'}); "
        f"config digest {ds.attrs.get('config_digest', '?')}.",
        "",
        "| paper's claim | paper | measured | verdict |",
        "|---|---|---|---|",
        f"| RMS_W optimum | {_fmt_design(p_rms['s'], p_rms['Q_back'])} | {_fmt_design(best['rms_w']['design']['s'], best['rms_w']['design']['Q_back'])} | "
        f"{'reproduced' if np.isclose(best['rms_w']['design']['s'], p_rms['s']) and np.isclose(best['rms_w']['design']['Q_back'], p_rms['Q_back']) else 'differs'} |",
        f"| end-to-end (MSE_R, {snr:g} dB) design | {_fmt_design(p_e2e['s'], p_e2e['Q_back'])} | {_fmt_design(best['mse_r']['design']['s'], best['mse_r']['design']['Q_back'])}; "
        f"the paper's design is {100 * (e2e_val / best['mse_r']['value'] - 1):.3f}% above it | "
        f"{'reproduced' if abs(best['mse_r']['design']['s'] - p_e2e['s']) <= 0.0251 and abs(best['mse_r']['design']['Q_back'] - p_e2e['Q_back']) <= 0.101 else 'differs'} "
        "(within one grid step) |",
        f"| RMS_W design's MSE_R vs best | about 37% worse | {100 * (rel['RMS_W'] - 1):.1f}% worse | "
        f"{'reproduced' if abs(rel['RMS_W'] - 1.37) < 0.03 else 'differs'} |",
        f"| MSE_S design's MSE_R vs best | about 7% worse | {100 * (rel['MSE_S'] - 1):.1f}% worse (MSE_S optimum "
        f"{_fmt_design(best['mse_s']['design']['s'], best['mse_s']['design']['Q_back'])}{', on the grid boundary' if best['mse_s']['on_grid_boundary'] else ''}) | "
        f"{'reproduced' if abs(rel['MSE_S'] - 1.07) < 0.02 else 'not reproduced: the MSE_S optimum sits on the |Q| bound, so this ratio depends on where the grid stops'} |",
        f"| end-to-end design costs less than the sequential ones (Table 1) | yes | C_a: MSE_R {cost['MSE_R']:.3e}, "
        f"MSE_S {cost['MSE_S']:.3e}, RMS_W {cost['RMS_W']:.3e} | "
        f"{'reproduced' if cost['MSE_R'] < min(cost['MSE_S'], cost['RMS_W']) else 'differs'} |",
        f"| trade-off barely depends on the noise level | yes | MSE_R optima at {', '.join(f'{v:g}' for v in snrs)} dB: "
        + "; ".join(_fmt_design(opt_r[v]['design']['s'], opt_r[v]['design']['Q_back']) for v in snrs)
        + f" (spread {spread:.3f} in s, {qspread:.2f} in Q) | {'reproduced' if spread <= 0.051 and qspread <= 0.21 else 'differs'} |",
        f"| zero-cost contour is Q = 0 or s = 1 | yes | max C_a on Q = 0: {float(ds['cost'].sel(Q_back=0, method='nearest').max()):.1e} | "
        "reproduced |",
    ]
    ref = trade.attrs.get("reference_snr_db", snr)
    e2e = trade["value"].sel(criterion=f"mse_r@{ref:g}")
    gains = {c: trade["mse_r_ref"].sel(criterion=c) / e2e for c in ("rms_w", f"mse_s@{ref:g}")}
    lv = trade["level"].values
    lines += [
        f"| MSE improvement of end-to-end over sequential designs along the trade-off (Fig. 6) | ~37% (RMS_W), ~7% (MSE_S) | "
        f"at each design's own best cost: RMS_W {100 * (float(trade['mse_r_ref'].sel(criterion='rms_w').isel(level=int(np.nanargmin(trade['value'].sel(criterion='rms_w').values)))) / float(e2e.min()) - 1):.0f}%, "
        f"MSE_S {100 * (float(trade['mse_r_ref'].sel(criterion=f'mse_s@{ref:g}').isel(level=int(np.nanargmin(trade['value'].sel(criterion=f'mse_s@{ref:g}').values)))) / float(e2e.min()) - 1):.0f}%; "
        f"largest at low cost (level {lv[1]:.1e}: {100 * (float(gains['rms_w'][1]) - 1):.0f}% and {100 * (float(gains[f'mse_s@{ref:g}'][1]) - 1):.0f}%) | see Fig. 6 |",
        f"| a single optimal cost beyond which more cost is counterproductive (end-to-end) | yes | MSE_R along the trade-off is "
        f"smallest at C_a = {lv[int(np.nanargmin(e2e.values))]:.2e} and rises on both sides | "
        f"{'reproduced' if 0 < int(np.nanargmin(e2e.values)) < len(lv) - 1 else 'differs'} |",
        f"| (view: minimal cost for a given quality) | - | cheapest iso-cost level whose end-to-end optimum is within 1% of "
        f"the best MSE_R: C_a = {min_cost_for_quality(trade, f'mse_r@{ref:g}', 1.01 * float(e2e.min())):.2e}; "
        f"within 5%: {min_cost_for_quality(trade, f'mse_r@{ref:g}', 1.05 * float(e2e.min())):.2e} | - |",
        "",
        "Figures: `fig3_cost`, `fig4_landscapes`, `fig5_tradeoff_configs`, `fig6_performance_vs_cost` (PNG and SVG).",
        "Table 1: `table1.md`, `table1.csv`. Trade-off data: `tradeoff.nc` (" + trade.attrs.get("method", "") + ").",
    ]
    return "\n".join(lines) + "\n"


def reproduce(out_dir: str | os.PathLike, cfg: SweepConfig, *, device: str = "auto", show_progress: bool = True) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ds = run_sweep(cfg, out / "sweep.nc", device=device, show_progress=show_progress)
    trade = _load_or_compute_tradeoff(ds, out / "tradeoff.nc")
    all_figures(ds, trade, out)
    _, _, rows = table1(ds, out, trade.attrs.get("reference_snr_db", REFERENCE_SNR_DB))
    text = report_text(ds, trade, rows, trade.attrs.get("reference_snr_db", REFERENCE_SNR_DB))
    atomic_write_text(out / "report.md", text)
    write_index(out, ds, text, rows, trade.attrs.get("reference_snr_db", REFERENCE_SNR_DB))
    return out / "report.md"


FIGURE_CAPTIONS = {
    "fig3_cost": "Fig. 3: the industrial cost C_a over the design grid, with the iso-cost levels.",
    "fig4_landscapes": "Fig. 4: the RMS_W, MSE_S and MSE_R landscapes (red circles: grid optima).",
    "fig5_tradeoff_configs": "Fig. 5: the best design of each criterion on every iso-cost curve.",
    "fig6_performance_vs_cost": "Fig. 6: performance against cost, sequential vs end-to-end design.",
}


def write_index(out: Path, ds: xr.Dataset, report: str, rows: list[dict], snr: float) -> Path:
    """``out/index.html``: the report (claims vs measured), Table 1 and Figures 3-6 in one self-contained page."""
    from lenssim_studies import html

    dims = design_dims(ds)
    t1 = html.table(["design (optimises)", *dims, f"MSE_R at {snr:g} dB", "relative to best", "C_a"],
                    [[r["design"], *(f"{r['parameters'][d]:g}" for d in dims), f"{r['mse_r']:.5f}",
                      f"{r['mse_r_relative']:.3f}", f"{r['cost_Ca']:.3e}"] for r in rows],
                    caption="Table 1: the designs that optimise each criterion, judged by MSE_R")
    figs = [html.image(out / f"{name}.png", cap) for name, cap in FIGURE_CAPTIONS.items() if (out / f"{name}.png").exists()]
    body = [html.markdown(report), "<h2>Table 1</h2>", t1, "<h2>Figures</h2>", *figs]
    return html.write_page(out / "index.html", "lenssim: reproduction of the paper's cost-performance analysis", body,
                           note=f"sweep config digest {ds.attrs.get('config_digest', '?')}; files beside this page: "
                                "report.md, table1.csv/.md, fig3-6 .png/.svg, sweep.nc, tradeoff.nc")
