"""The paper's Figures 3-6 and Table 1 from a sweep and its trade-off, and the trade-off of any lens against its cost
(matplotlib, headless).

Every function writes ``NAME.png`` and ``NAME.svg`` into ``out_dir`` and returns the PNG path.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import xarray as xr

from lenssim.criteria import CRITERIA
from lenssim.model.design import PARAMETERS
from lenssim.io.files import atomic_write, atomic_write_text
from .paper import PAPER_COST_LEVELS, REFERENCE_SNR_DB
from .sweep import design_dims
from .tradeoff import _criteria_columns, find_optimum

__all__ = ["fig3_cost", "fig4_landscapes", "fig5_tradeoff_configs", "fig6_performance_vs_cost", "table1",
           "all_figures", "tradeoff_figure", "gradient_figure"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out_dir: Path, name: str, dpi: int = 130) -> Path:
    """``fig`` written atomically as ``name.png`` (``dpi``) and ``name.svg`` in ``out_dir``, then closed."""
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / f"{name}.png"
    for path in (png, out_dir / f"{name}.svg"):
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi))
    _plt().close(fig)
    return png


def _axes_label(name: str) -> str:
    return f"{PARAMETERS[name].description} {name}"


def _yx(da: xr.DataArray):
    """The two design dimensions of a landscape: (y axis, x axis) = (first, second) sweep dimension."""
    dims = [d for d in da.dims if d in PARAMETERS]
    if len(dims) != 2:
        raise ValueError(f"a landscape needs two design dimensions; got {list(da.dims)}")
    return dims[0], dims[1]


def _landscape(ax, da: xr.DataArray, label: str, levels=None, log=False, cmap="viridis"):
    dy, dx = _yx(da)
    da = da.transpose(dy, dx)
    Q, s = da[dx].values, da[dy].values
    z = np.log10(da.values) if log else da.values
    im = ax.contourf(Q, s, z, levels=40, cmap=cmap)
    if levels is not None:
        ax.contour(Q, s, z, levels=levels, colors="white", linewidths=0.6, linestyles="solid")
    ax.set_xlabel(_axes_label(dx))
    ax.set_ylabel(_axes_label(dy))
    cb = ax.figure.colorbar(im, ax=ax)
    cb.set_label(("log10 " if log else "") + label)
    return im


def fig3_cost(ds: xr.Dataset, out_dir: Path, levels=None) -> Path:
    """C_a over (Q, s) with iso-cost contours; the zero-cost contour (Q = 0 or s = 1) in red."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 5), constrained_layout=True)
    levels = PAPER_COST_LEVELS[1:] if levels is None else levels
    dy, dx = design_dims(ds)
    _landscape(ax, ds["cost"], "C_a (RMS slope departure)", cmap="magma")
    cost = ds["cost"].transpose(dy, dx)
    ax.contour(ds[dx].values, ds[dy].values, cost.values, levels=levels, colors="white", linewidths=0.5)
    ax.axvline(0, color="red", lw=1.2, label=f"C_a = 0: {dx} = 0 or {dy} = 1")
    if ds[dy].values[-1] >= 1:
        ax.axhline(1, color="red", lw=1.2)
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title("Fig. 3: industrial cost C_a (white: iso-cost levels 0..2e-3)")
    return _save(fig, out_dir, "fig3_cost")


def fig4_landscapes(ds: xr.Dataset, out_dir: Path, snr: float = REFERENCE_SNR_DB) -> Path:
    """RMS_W, MSE_S and MSE_R (at ``snr`` dB) over (Q, s) with contours."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8), constrained_layout=True)
    for ax, (da, label) in zip(axes, [(ds["rms_w"], "RMS_W [waves]"),
                                      (ds["mse_s"].sel(snr=snr, method="nearest"), f"MSE_S at {snr:g} dB"),
                                      (ds["mse_r"].sel(snr=snr, method="nearest"), f"MSE_R at {snr:g} dB")]):
        _landscape(ax, da, label, levels=12, log=label.startswith("MSE"))
        dy, dx = _yx(da)
        da = da.transpose(dy, dx)
        i, j = np.unravel_index(int(np.argmin(da.values)), da.shape)
        ax.plot(da[dx].values[j], da[dy].values[i], "o", mfc="none", mec="red", ms=10, mew=2)
        ax.set_title(label + " (red circle: grid optimum)")
    fig.suptitle("Fig. 4: quality landscapes")
    return _save(fig, out_dir, "fig4_landscapes")


def fig5_tradeoff_configs(ds: xr.Dataset, trade: xr.Dataset, out_dir: Path, poly_degree: int = 3) -> Path:
    """Optimal trade-off configurations over the cost contours, with fitted polynomials."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 6), constrained_layout=True)
    dy, dx = design_dims(ds)
    ax.contour(ds[dx].values, ds[dy].values, ds["cost"].transpose(dy, dx).values, levels=trade["level"].values[1:],
               cmap="Greys", linewidths=0.6)
    snrs = [float(v) for v in ds["snr"].values]
    styles = [("mse_s@%g" % snrs[len(snrs) // 2], "x", "red", "MSE_S")]
    markers = [("^", "magenta", "low"), ("s", "blue", "medium"), ("v", "green", "high")]
    for snr, (m, col, word) in zip(sorted(snrs), markers if len(snrs) == 3 else markers[1:2] * len(snrs)):
        styles.append((f"mse_r@{snr:g}", m, col, f"MSE_R, {word} SNR ({snr:g} dB)"))
    for crit, m, col, label in styles:
        t = trade.sel(criterion=crit)
        s, Q = t[dy].values[1:], t[dx].values[1:]
        ok = np.isfinite(s)
        ax.plot(Q[ok], s[ok], m, color=col, mfc="none" if m != "x" else col, label=label)
        if ok.sum() > poly_degree + 1:
            p = np.polyfit(Q[ok], s[ok], poly_degree)
            qq = np.linspace(Q[ok].min(), Q[ok].max(), 200)
            ax.plot(qq, np.polyval(p, qq), ":", color=col, lw=1)
        da = ds[crit.split("@")[0]].sel(snr=float(crit.split("@")[1])).transpose(dy, dx)
        i, j = np.unravel_index(int(np.argmin(da.values)), da.shape)
        ax.plot(da[dx].values[j], da[dy].values[i], "o", ms=16, mfc="none", mec=col, mew=1.5)
    ax.set_xlabel(_axes_label(dx))
    ax.set_ylabel(_axes_label(dy))
    ax.set_title("Fig. 5: optimal cost-performance configurations (circles: absolute optima)")
    ax.legend(fontsize=8, loc="best")
    return _save(fig, out_dir, "fig5_tradeoff_configs")


def fig6_performance_vs_cost(trade: xr.Dataset, out_dir: Path) -> Path:
    """RMS_W / MSE_S and the expected MSE after restoration against C_a, sequential vs end-to-end."""
    plt = _plt()
    ref = trade.attrs.get("reference_snr_db", REFERENCE_SNR_DB)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
    e2e = trade.sel(criterion=f"mse_r@{ref:g}")
    for ax, crit, label in ((axes[0], "rms_w", "RMS_W [waves]"), (axes[1], f"mse_s@{ref:g}", f"MSE_S at {ref:g} dB")):
        t = trade.sel(criterion=crit)
        lv = trade["level"].values
        ax.plot(lv, t["value"], "-", color="tab:blue", label=f"{label} (optimising it)")
        ax.set_xlabel("C_a (iso-cost level, slope units)")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        ax.set_ylabel(label, color="tab:blue")
        ax2 = ax.twinx()
        ax2.plot(lv, t["mse_r_ref"], "-", color="darkorange", label="MSE after Wiener, sequential design")
        ax2.plot(lv, e2e["value"], "--", color="darkorange", label="MSE_R, end-to-end design")
        ax2.set_ylabel(f"expected MSE after restoration ({ref:g} dB)", color="darkorange")
        lines = ax.get_lines() + ax2.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper right")
    fig.suptitle("Fig. 6: performance against cost (|Q| bounded by the grid)")
    return _save(fig, out_dir, "fig6_performance_vs_cost")


TABLE1_CRITERIA = ("rms_w", "mse_s", "mse_r")


def table1(ds: xr.Dataset, out_dir: Path, snr: float = REFERENCE_SNR_DB) -> tuple[Path, Path, list[dict]]:
    """Table 1: for the designs optimising RMS_W, MSE_S, MSE_R, the relative MSE_R and C_a (CSV + Markdown).

    Each row: ``design`` (the criterion's label), ``parameters`` ``{name: value}``, ``mse_r``,
    ``mse_r_relative``, ``cost_Ca``.
    """
    from lenssim.criteria import CRITERIA

    dims = design_dims(ds)
    rows = []
    best = find_optimum(ds, "mse_r", snr)["value"]
    for crit in TABLE1_CRITERIA:
        r = find_optimum(ds, crit, snr)
        mr = r["mse_r"][f"{snr:g}"]
        rows.append({"design": CRITERIA[crit].label, "parameters": r["design"], "mse_r": mr, "mse_r_relative": mr / best,
                     "cost_Ca": r["cost"]})
    out_dir.mkdir(parents=True, exist_ok=True)
    csv = out_dir / "table1.csv"
    md = out_dir / "table1.md"
    params = lambda r, sep: sep.join(f"{r['parameters'][d]:g}" for d in dims)  # noqa: E731
    atomic_write_text(csv, f"design,{','.join(dims)},mse_r,mse_r_relative,cost_Ca\n" + "".join(
        f"{r['design']},{params(r, ',')},{r['mse_r']:.6g},{r['mse_r_relative']:.4f},{r['cost_Ca']:.4e}\n"
        for r in rows))
    atomic_write_text(md, f"| design (optimises) | {' | '.join(dims)} | MSE_R at {snr:g} dB | relative to best | C_a |\n"
                      f"|---|{'---|' * len(dims)}---|---|---|\n"
                      + "".join(f"| {r['design']} | {params(r, ' | ')} | {r['mse_r']:.5f} | {r['mse_r_relative']:.3f} | "
                                f"{r['cost_Ca']:.3e} |\n" for r in rows))
    return csv, md, rows


def all_figures(ds: xr.Dataset, trade: xr.Dataset, out_dir: Path) -> list[Path]:
    out_dir = Path(out_dir)
    ref = trade.attrs.get("reference_snr_db", REFERENCE_SNR_DB)
    return [fig3_cost(ds, out_dir), fig4_landscapes(ds, out_dir, ref), fig5_tradeoff_configs(ds, trade, out_dir),
            fig6_performance_vs_cost(trade, out_dir)]


# -- the trade-off of any lens --------------------------------------------------------------------------------------
def _cost_figure(panels: list[dict], out_dir: Path, title: str, figsize) -> Path:
    """Criteria against the asphere cost (png, svg, named ``tradeoff``), one axes per panel ``{"name": the criterion's
    base name, "snr": its SNR text or None, "sense", "points": (costs, values, label, size), "front": (costs, values,
    label, step: a staircase), "unconstrained": (cost, value, marker, size) or None, "note": the title's ending}``;
    the legend on the first."""
    plt = _plt()
    ncol = min(3, len(panels))
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=figsize(nrow, ncol), squeeze=False)
    for ax, p in zip(axes.flat, panels):
        c, v, label, size = p["points"]
        ax.scatter(c, v, s=size, color="0.6", label=label)
        c, v, label, step = p["front"]
        if step:
            ax.step(c, v, where="post", color="C1", label=label)
        else:
            ax.plot(c, v, "o-", color="C1", label=label)
        if p["unconstrained"] is not None:
            c, v, marker, size = p["unconstrained"]
            ax.plot([c], [v], marker, ms=size, color="C3", label="unconstrained optimum")
        unit = CRITERIA[p["name"]].units
        label = p["name"] if p["snr"] is None else f"{p['name']} at {p['snr']} dB"
        ax.set_xlabel("asphere cost C_a (RMS slope departure)")
        ax.set_ylabel(label if unit.startswith("1") else f"{label} ({unit})")
        ax.set_title(("lower" if p["sense"] == "min" else "higher") + " is better" + p["note"], fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, out_dir, "tradeoff")


def tradeoff_figure(ds: xr.Dataset, res: dict, out_dir: Path, title: str) -> Path:
    """Every criterion of a trade-off of any lens (:func:`lenssim_studies.tradeoff.run_lens_tradeoff`) against the cost:
    each valid design a dot, the optima per cost level a line (png, svg)."""
    cost = ds["cost"].values.reshape(-1)
    valid = ds["valid"].values.reshape(-1)
    panels = []
    for name, (v, sense) in _criteria_columns(ds).items():
        ok = valid & np.isfinite(v)
        order = np.argsort(cost[ok], kind="stable")
        c_sorted, v_sorted = cost[ok][order], v[ok][order]
        best = np.minimum.accumulate(v_sorted) if sense == "min" else np.maximum.accumulate(v_sorted)
        u = res["unconstrained"][name]
        base, _, at = name.partition("@")
        if CRITERIA[base].per_snr:  # the first SNR's column carries the bare name (as lenssim optimum names it)
            at = at or f"{float(ds['snr'].values[0]):g}"
        panels.append({"name": base, "snr": at or None, "sense": sense, "note": "",
                       "points": (cost[valid], v[valid], "grid designs", 8),
                       "front": (c_sorted, best, "best design at cost <= C_a (the front)", True),
                       "unconstrained": None if u is None else (u["cost"], u["value"], "o", None)})
    return _cost_figure(panels, out_dir, title, lambda nrow, ncol: (4.2 * ncol, 3.3 * nrow))


def gradient_figure(run, res: dict, out_dir: Path, title: str) -> Path:
    """The criterion a gradient run (:class:`lenssim_studies.tradeoff.LensGradientRun`) optimised against the asphere
    cost: every start's end point per level (grey), the best per level (the front, a line), the unconstrained optimum
    (png, svg)."""
    ends = [c for c in res["convergence"] if "value" in c]
    front = [o for o in res["optima"][run.criterion] if o is not None]
    u = res["unconstrained"][run.criterion]
    panel = {"name": run.criterion, "snr": f"{run.snr_db[0]:g}" if CRITERIA[run.criterion].per_snr else None,
             "sense": CRITERIA[run.criterion].sense,
             "note": "; " + ("real-ray" if run.wavefront == "exact" else "third-order") + " wavefront",
             "points": ([c["cost"] for c in ends], [c["value"] for c in ends], "each start's end point", 12),
             "front": ([o["cost"] for o in front], [o["value"] for o in front], "best per cost level", False),
             "unconstrained": None if u is None else (u["cost"], u["value"], "*", 12)}
    return _cost_figure([panel], out_dir, title, lambda nrow, ncol: (5.6, 4.0))
