"""The device benchmark in one call (issue 46, item 4): four pieces of work, each on the device and on the CPU of the
same machine, in one process, the result beside each time; one Markdown table and one JSON line at the end.

    python benchmarks/bench_device.py [--device auto|cuda|cpu] [--quick]
        [--frame-px 4000 6000] [--cpu-crop-px 0 0] [--sweep-s-every 16] [--sweep-q-every 1]
        [--tradeoff-designs 256] [--lenses 64]

1. frame: the 24 MP colour full frame of ``lenssim simulate --full-frame`` (``simulate_frame`` + ``score_frame``,
   as benchmarks/profile_full_frame.py runs them): the generated default scene of the paper's camera (6000 x 4000 x 3,
   nothing read or downloaded), the paper's E2E design, ISO 100 (3200 e-), seed 0, the paper's scheme with the CLI's
   default zoned blur windows; the restored whole-frame PSNR (sRGB, dB) is the result. By default both run the whole
   frame (the CPU's ~60-70 s on 16 cores). With ``--cpu-crop-px ROWS COLS`` the CPU runs that centre crop of it
   instead (a frame of its own: its own centre, so its field angles are smaller), its time scaled to the whole frame
   by the windows' count (``est.`` in the table: likely a lower bound, the crop's smaller field having fewer of the
   grown windows of wide field; 768 x 512 on 2 cores: 2.8 s measured, 1.7 s estimated from 384 x 256), and the
   device runs the same crop too, so the two columns compare on the same work (a row of its own).
2. sweep: ``run_sweep`` of the paper grid (``paper_grid``: 122 s x 113 Q x 15 angles, 3 SNRs) on every
   ``--sweep-s-every``-th value of s and ``--sweep-q-every``-th value of Q (a stated fraction of the grid, as
   benchmarks/bench_sweep.py takes it), the same subset on both; the result: the mean restored MSE over the subset,
   and the largest relative difference between the two datasets.
3. trade-off: a batch of Cooke-triplet designs on real rays (benchmarks/bench_batched_rays.py: 5 free parameters,
   focal length held, fields 0 and 6 deg): ``solve_numbers`` + ``lens_exact_coefficients`` for the batch, then the
   batch's value and gradient by autograd (the sum of squared coefficients against the parameters); the result: that
   sum, and the largest relative difference of the coefficients between the two.
4. as-built: the as-built Monte Carlo of benchmarks/bench_as_built.py (commercial grade, the paper's E2E design, fast
   numerics, 15 field angles, 27.6 dB): ``as_built_criteria`` of ``--lenses`` lenses (seed 0); the result: the mean
   restored MSE (``mse_r``) and the largest relative difference between the two.

Each piece runs once untimed on a small size on each device first (CUDA context, cuFFT plans, caches). Without a
GPU (or with ``--device cpu``) only the CPU column runs, and the table says so. ``--quick``: tiny sizes (a check of the
script in under a minute on a 2-core CPU; its times mean nothing). No timing is asserted anywhere.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch

from lenssim import FAST_NUMERICS, LensPSF
from lenssim.io.prescription_file import read_lens
from lenssim.io.resources import config_path
from lenssim.model.lens_parameters import parameter_values, parse_parameter
from lenssim.model.tolerances import GRADES
from lenssim.optics.exact_wavefront import lens_exact_coefficients
from lenssim.optics.lens_solves import solve_numbers
from lenssim.tolerancing import as_built_criteria
from lenssim.validate import ModelValidityWarning
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_RHO0
from lenssim_studies.sweep import load_config, run_sweep
from pipeline.blur import PAPER_SCHEME, choose_stride_zones, window_count
from pipeline.scene import resolution_scene
from pipeline.simulate import score_frame, simulate_frame

sys.path.insert(0, str(Path(__file__).parent))
from bench_batched_rays import NAMES, SPREAD  # noqa: E402  the trade-off's designs, as that benchmark draws them

DESIGN = PAPER_DESIGNS["end_to_end_paper"]
FULL_WELL = 3200.0
"""ISO 100's full well (e-), the paper's (as benchmarks/profile_full_frame.py)."""
AS_BUILT_SNR_DB = [27.6]
"""The as-built Monte Carlo's SNR (dB): ISO 100, as benchmarks/bench_as_built.py."""
PARTS = ("frame", "sweep", "tradeoff", "as_built")
"""The pieces of work, in the order they run."""
BUDGET_S = 300.0
"""Seconds after the start past which a part not yet begun is skipped: the defaults' run is ~3.5 min on an H200 with
16 CPU cores (estimated), and the lead's limit is 6 min for the whole call, so a part begun before 300 s ends in it."""
WARM_FRAME_PX = (256, 384)
"""The untimed warm-up frame (rows, columns): one 256 px tile of the PSNR map high, a few seconds on a CPU."""
QUICK = {"frame_px": (256, 384), "cpu_crop_px": (0, 0), "sweep_s_every": 122, "sweep_q_every": 113,
         "tradeoff_designs": 4, "lenses": 1}
"""--quick's sizes: a frame of 384 x 256 (CPU whole), one design of the grid (15 PSFs), 4 designs, 1 lens."""


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def _timed(fn, dev: torch.device):
    """``(result, seconds)`` of ``fn()``, the device synchronised at both ends."""
    _sync(dev)
    t0 = time.perf_counter()
    out = fn()
    _sync(dev)
    return out, time.perf_counter() - t0


def _rel_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest |a - b| over the largest |b| (float64, on the CPU; 0 where both are all zero)."""
    a, b = a.detach().double().cpu(), b.detach().double().cpu()
    scale = float(b.abs().max())
    return float((a - b).abs().max()) / scale if scale > 0 else float((a - b).abs().max())


# -- 1. the frame -----------------------------------------------------------------------------------------------------
def _centre_crop(img: torch.Tensor, rows: int, cols: int) -> torch.Tensor:
    H, W = img.shape[-2:]
    r0, c0 = (H - rows) // 2, (W - cols) // 2
    return img[..., r0:r0 + rows, c0:c0 + cols].contiguous()


def frame_run(ideal_cpu: torch.Tensor, dev: torch.device) -> tuple[float, float, int]:
    """Seconds of ``simulate_frame`` + ``score_frame`` of ``ideal_cpu`` moved to ``dev`` (the move included), the
    restored whole-frame PSNR (dB) and the windows of one pass."""
    def work():
        ideal = ideal_cpu.to(dev)
        psf = LensPSF(PAPER_CAMERA, DESIGN)
        zones = choose_stride_zones(psf, ideal.shape, PAPER_SCHEME)
        frame = simulate_frame(ideal, psf, FULL_WELL, seed=0, sensor=PAPER_CAMERA.sensor, scheme=PAPER_SCHEME,
                               blur_zones=None if zones.uniform else zones)
        return score_frame(ideal, frame, psf.geometry)["psnr_restored_db"]

    psnr, t = _timed(work, dev)
    return t, float(psnr), window_count(ideal_cpu.shape, PAPER_SCHEME)


def columns(use_gpu: bool) -> dict[str, torch.device]:
    """The table's columns and their devices, in the order each part runs them: ``"device"`` (CUDA) where used,
    then ``"cpu"``."""
    return ({"device": torch.device("cuda")} if use_gpu else {}) | {"cpu": torch.device("cpu")}


def bench_frame(a, devs) -> list[dict]:
    H, W = a.frame_px
    ideal = resolution_scene(H, W, geometry=PAPER_CAMERA.geometry)
    crop = tuple(a.cpu_crop_px)
    whole_on_cpu = crop == (0, 0) or crop == (H, W)
    small = _centre_crop(ideal, *WARM_FRAME_PX) if H >= WARM_FRAME_PX[0] and W >= WARM_FRAME_PX[1] else ideal
    for d in devs.values():
        frame_run(small, d)  # warm-up
    label = f"24 MP colour frame {W} x {H}" if (H, W) == (4000, 6000) else f"colour frame {W} x {H}"
    row = {"work": label + ", simulate + restore + score (restored PSNR, dB)"}
    rows = [row]
    gpu, cpu = devs.get("device"), devs["cpu"]
    if gpu is not None:
        t, p, _ = frame_run(ideal, gpu)
        row.update(device_s=t, device_result=p)
        print(f"frame {W} x {H} on {gpu}: {t:.1f} s, restored {p:.2f} dB", flush=True)
    if whole_on_cpu:
        t, p, _ = frame_run(ideal, cpu)
        row.update(cpu_s=t, cpu_result=p)
        print(f"frame {W} x {H} on the CPU: {t:.1f} s, restored {p:.2f} dB", flush=True)
        return rows
    part = _centre_crop(ideal, *crop)
    t, p, n = frame_run(part, cpu)
    scale = window_count(ideal.shape, PAPER_SCHEME) / n
    row.update(cpu_s=t * scale, cpu_estimated=True,
               cpu_note=f"est.: the {crop[1]} x {crop[0]} crop's time x {scale:.2f} (windows), likely a lower bound")
    crow = {"work": f"  the same, centre crop {crop[1]} x {crop[0]} as a frame (both measured; restored PSNR, dB)",
            "cpu_s": t, "cpu_result": p}
    print(f"crop {crop[1]} x {crop[0]} on the CPU: {t:.1f} s, restored {p:.2f} dB (x {scale:.2f} windows to the "
          "whole frame)", flush=True)
    if gpu is not None:
        tg, pg, _ = frame_run(part, gpu)
        crow.update(device_s=tg, device_result=pg)
        print(f"crop {crop[1]} x {crop[0]} on {gpu}: {tg:.1f} s, restored {pg:.2f} dB", flush=True)
    rows.append(crow)
    return rows


# -- 2. the sweep -----------------------------------------------------------------------------------------------------
def _sweep_config(s_every: int, q_every: int):
    """The paper grid on every ``s_every``-th s and ``q_every``-th Q (at least one value each); and its full size."""
    full = load_config(config_path("paper_grid"))
    grid = {}
    for key, every in (("s", s_every), ("Q_back", q_every)):
        start, _, step = full.grid[key]
        picked = full.values(key)[::every]
        grid[key] = (float(picked[0]), float(picked[-1]), step * every)
    cfg = dataclasses.replace(full, grid={**full.grid, **grid})
    angles = len(cfg.lens.field_angles_deg)
    return cfg, cfg.n_designs() * angles, full.n_designs() * angles


def bench_sweep(a, devs) -> list[dict]:
    cfg, n_psf, n_full = _sweep_config(a.sweep_s_every, a.sweep_q_every)
    warm, _, _ = _sweep_config(10**6, 10**6)  # one design: the warm-up
    row = {"work": f"sweep paper_grid: 1 in {a.sweep_s_every} values of s, 1 in {a.sweep_q_every} of Q = {n_psf} "
                   f"PSFs ({n_psf / n_full:.2%} of {n_full}) (mean restored MSE)"}
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for col, d in devs.items():
            run_sweep(warm, Path(tmp) / f"warm_{col}.nc", device=str(d), show_progress=False)
            ds, t = _timed(lambda: run_sweep(cfg, Path(tmp) / f"{col}.nc", device=str(d), show_progress=False), d)
            res = {v: torch.as_tensor(ds[v].values) for v in ds.data_vars if ds[v].dtype.kind == "f"}
            results[col] = res
            key = "mse_r" if "mse_r" in res else sorted(res)[0]
            row["result_name"] = key
            row.update({f"{col}_s": t, f"{col}_result": float(res[key].double().nanmean())})
            print(f"sweep on {d}: {t:.1f} s ({n_psf / t:.0f} PSFs/s); {key} mean {row[f'{col}_result']:.6g}",
                  flush=True)
    if len(results) == 2:
        row["rel_diff"] = max(_rel_diff(results["device"][v].nan_to_num(), results["cpu"][v].nan_to_num())
                              for v in results["cpu"])
    return [row]


# -- 3. the trade-off on real rays --------------------------------------------------------------------------------------
def bench_tradeoff(a, devs) -> list[dict]:
    p = read_lens("cooke_triplet")
    p = dataclasses.replace(p, wavelengths_um=(p.primary_wavelength_um,), fields=(0.0, 6.0))
    pars = [parse_parameter(p, n, aspherize=(6,)) for n in NAMES]
    x0 = torch.tensor([v if v == v else 0.0 for v in parameter_values(p, pars).values()], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    xs = x0 + torch.tensor(SPREAD, dtype=torch.float64) * torch.randn(a.tradeoff_designs, len(NAMES), generator=g,
                                                                       dtype=torch.float64)

    def work(x):
        x = x.clone().requires_grad_(True)
        c = lens_exact_coefficients(solve_numbers(p, pars, x, hold=("efl",)), p.fields, p.wavelengths_um)
        value = (c ** 2).sum()
        (grad,) = torch.autograd.grad(value, x)
        return c.detach(), float(value.detach()), grad

    row = {"work": f"trade-off: {a.tradeoff_designs} Cooke triplets on real rays, value + gradient "
                   f"({len(NAMES)} parameters; sum of squared coefficients)"}
    results = {}
    for col, d in devs.items():
        work(xs[:2].to(d))  # warm-up
        (c, value, grad), t = _timed(lambda: work(xs.to(d)), d)
        results[col] = (c, grad)
        row.update({f"{col}_s": t, f"{col}_result": value})
        print(f"trade-off on {d}: {t:.2f} s ({t / a.tradeoff_designs * 1e3:.2f} ms a design); value {value:.9g}",
              flush=True)
    if len(results) == 2:
        row["rel_diff"] = max(_rel_diff(results["device"][0], results["cpu"][0]),
                              _rel_diff(results["device"][1], results["cpu"][1]))
    return [row]


# -- 4. the as-built Monte Carlo ----------------------------------------------------------------------------------------
def bench_as_built(a, devs) -> list[dict]:
    pert = GRADES["commercial"].sample(a.lenses, seed=0)
    warm = GRADES["commercial"].sample(1, seed=1)
    angles = len(PAPER_CAMERA.lens.field_angles_deg)
    row = {"work": f"as-built Monte Carlo: {a.lenses} lens{'' if a.lenses == 1 else 'es'}, commercial grade, {angles} angles, fast numerics "
                   "(mean mse_r)"}
    results = {}
    for col, d in devs.items():
        def work(q):
            return as_built_criteria(PAPER_CAMERA, DESIGN, q, AS_BUILT_SNR_DB, rho0=PAPER_RHO0, numerics=FAST_NUMERICS,
                                     device=d)["mse_r"]

        work(warm)  # warm-up
        mse, t = _timed(lambda: work(pert), d)
        results[col] = mse
        row.update({f"{col}_s": t, f"{col}_result": float(mse.double().mean())})
        print(f"as-built on {d}: {t:.2f} s ({a.lenses / t:.1f} lenses/s); mean mse_r {row[f'{col}_result']:.6g}",
              flush=True)
    if len(results) == 2:
        row["rel_diff"] = _rel_diff(results["device"], results["cpu"])
    return [row]


# -- the table ----------------------------------------------------------------------------------------------------------
def _fmt(x, spec=".2f") -> str:
    return "-" if x is None else format(x, spec)


def table(rows: list[dict], gpu_name: str | None) -> str:
    dev_col = gpu_name or "device (none: CPU only)"
    lines = [f"| work | {dev_col} [s] | CPU, {torch.get_num_threads()} threads [s] | CPU / device | result, device "
             "| result, CPU | largest relative difference |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        d, c = r.get("device_s"), r.get("cpu_s")
        cpu = _fmt(c, ".1f" if c is not None and c >= 10 else ".2f")
        if r.get("cpu_estimated"):
            cpu = f"{cpu} ({r['cpu_note']})"
        ratio = f"{c / d:.1f}x" if d and c else "-"
        res = ".2f" if "PSNR" in r["work"] else ".6g"
        diff = r.get("rel_diff")
        if diff is None and r.get("device_result") is not None and r.get("cpu_result") is not None:
            diff_s = f"{abs(r['device_result'] - r['cpu_result']):.3f} dB"
        else:
            diff_s = _fmt(diff, ".1e")
        lines.append(f"| {r['work']} | {_fmt(d, '.2f')} | {cpu} | {ratio} | {_fmt(r.get('device_result'), res)} | "
                     f"{_fmt(r.get('cpu_result'), res)} | {diff_s} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--device", default="auto", choices=("auto", "cuda", "cpu"),
                    help="'auto' (default): the device column where CUDA is present; 'cpu': the CPU column only")
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a check of the script; the times mean nothing)")
    ap.add_argument("--frame-px", type=int, nargs=2, default=[4000, 6000], metavar=("ROWS", "COLS"))
    ap.add_argument("--cpu-crop-px", type=int, nargs=2, default=[0, 0], metavar=("ROWS", "COLS"),
                    help="the CPU's centre crop of the frame, its time scaled to the whole frame by the windows' count "
                         "(e.g. 2000 3000, a quarter); default 0 0: the whole frame on the CPU too")
    ap.add_argument("--sweep-s-every", type=int, default=16, help="every N-th s of the paper grid (default 16: 8 of 122)")
    ap.add_argument("--sweep-q-every", type=int, default=1, help="every N-th Q of the paper grid (default 1: all 113)")
    ap.add_argument("--tradeoff-designs", type=int, default=256)
    ap.add_argument("--lenses", type=int, default=64, help="as-built lenses (default 64)")
    ap.add_argument("--skip", nargs="*", default=[], choices=PARTS)
    ap.add_argument("--budget-s", type=float, default=BUDGET_S,
                    help=f"a part not started by then is skipped, and the table says so (default {BUDGET_S:g} s)")
    a = ap.parse_args()
    if a.quick:
        for k, v in QUICK.items():
            setattr(a, k, v)
    H, W = a.frame_px
    crop = tuple(a.cpu_crop_px)
    sensor = (PAPER_CAMERA.sensor.height_px, PAPER_CAMERA.sensor.width_px)
    if not (256 <= H <= sensor[0] and 256 <= W <= sensor[1]) or (
            crop != (0, 0) and not (256 <= crop[0] <= H and 256 <= crop[1] <= W)):
        ap.error(f"--frame-px {H} {W} and --cpu-crop-px {crop[0]} {crop[1]}: at least 256 px each way (one tile of "
                 f"the PSNR map), the frame at most the paper's sensor ({sensor[0]} {sensor[1]}), the crop inside the "
                 "frame (or 0 0)")
    for name in ("sweep_s_every", "sweep_q_every", "tradeoff_designs", "lenses"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} {getattr(a, name)}: at least 1")
    if a.device == "cuda" and not torch.cuda.is_available():
        ap.error("--device cuda: no CUDA device here; use --device auto or cpu")
    use_gpu = a.device != "cpu" and torch.cuda.is_available()
    devs = columns(use_gpu)
    gpu_name = torch.cuda.get_device_name(0) if use_gpu else None
    print(f"devices: {gpu_name or 'no GPU: the CPU column only'}; CPU {torch.get_num_threads()} threads; torch "
          f"{torch.__version__}", flush=True)
    warnings.simplefilter("ignore", ModelValidityWarning)
    t_all = time.perf_counter()
    rows, seconds = [], {}
    for name, fn in zip(PARTS, (bench_frame, bench_sweep, bench_tradeoff, bench_as_built)):
        if name in a.skip:
            continue
        if time.perf_counter() - t_all > a.budget_s:
            rows.append({"work": f"{name}: skipped, the run past its budget of {a.budget_s:g} s"})
            print(f"({name}: skipped: {time.perf_counter() - t_all:.0f} s gone of a budget of {a.budget_s:g} s)")
            continue
        t0 = time.perf_counter()
        rows += fn(a, devs)
        if use_gpu:  # the next part's chunks are sized from the device's free memory: none held back by this one's cache
            torch.cuda.empty_cache()
        seconds[name] = time.perf_counter() - t0
        print(f"({name}: {seconds[name]:.0f} s with warm-ups)", flush=True)
    print()
    if not use_gpu:
        print("No GPU here" + (" (--device cpu)" if a.device == "cpu" else "") + ": the CPU column only.\n")
    print(table(rows, gpu_name))
    total = time.perf_counter() - t_all
    print(f"\n{time.strftime('%Y-%m-%d', time.gmtime())}; {total:.0f} s in all; torch {torch.__version__}; "
          f"{torch.get_num_threads()} CPU threads")
    summary = {"gpu": gpu_name, "cpu_threads": torch.get_num_threads(), "torch": torch.__version__,
               "seconds_total": round(total, 1), "seconds_parts": {k: round(v, 1) for k, v in seconds.items()},
               "rows": [{k: ((float(f"{v:.7g}") if math.isfinite(v) else None) if isinstance(v, float) else v)
                         for k, v in r.items()}
                        for r in rows]}
    if use_gpu:
        summary["gpu_peak_gib"] = round(torch.cuda.max_memory_allocated() / 2**30, 2)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    from pipeline.io import exit_without_teardown

    exit_without_teardown(main())
