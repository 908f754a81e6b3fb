"""Speed of several fields traced in one ray bundle (issue 46, item 2): the real-ray wavefront tables of shipped lenses
and one manufactured copy's evaluation, each traced node by node (``lenssim.optics.psf_bank.TABLE_TRACE_FIELDS = 1``
and the extent estimate field by field: the baseline, the route before bundles) beside the bundled route, alternated in
one process. Every bundled table is compared with the node-by-node one (they must be equal bit for bit).

    python benchmarks/bench_ray_bundles.py [--lenses cooke_triplet,double_gauss,aspheric_singlet] [--repeats 2]

Prints one line per measurement and a JSON summary on the last line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time

import torch

import lenssim.optics.psf_bank as bank
import lenssim.optics.psf_provider as provider
from lenssim.model.numerics import FAST_NUMERICS
from lenssim.model.tolerances import SurfaceTolerances
from lenssim.optics.psf_provider import SequentialPSF
from lenssim.optics.sequential import Fields
from lenssim.tolerancing import lens_copies

TABLE_FIELDS = ("angles_deg", "opd_waves", "aperture_ratio", "spot_radius_mm", "distortion_mm")


class _OneFieldAtATime:
    """A lens whose ``wavefront`` of several fields traces them one bundle each (the baseline of the extent estimate)."""

    def __init__(self, lens):
        self._lens = lens

    def __getattr__(self, name):
        return getattr(self._lens, name)

    def wavefront(self, field, px, py, *args, **kw):
        if not isinstance(field, Fields):
            return self._lens.wavefront(field, px, py, *args, **kw)
        maps = [self._lens.wavefront(Fields([a]), px, py, *args, **kw) for a in field.values]
        from dataclasses import replace

        return replace(maps[0], **{k: torch.cat([getattr(m, k) for m in maps]) for k in
                                   ("opd_waves", "valid", "chief_mm", "image_mm", "reference_radius_mm",
                                    "aperture_ratio")})


@contextlib.contextmanager
def node_by_node(on: bool):
    """The baseline route while ``on``: one field node a trace."""
    keep = bank.TABLE_TRACE_FIELDS
    if on:
        bank.TABLE_TRACE_FIELDS = 1
    try:
        yield
    finally:
        bank.TABLE_TRACE_FIELDS = keep


def provider_of(name: str) -> SequentialPSF:
    """The lens's provider as ``lenssim tolerance --lens NAME`` makes it (its Nyquist pixels, point samples)."""
    from lenssim_cli.lens import check_lens_arguments, lens_provider, refocused_lens
    from lenssim_cli.main import build_parser

    args = build_parser().parse_args(["tolerance", "--lens", name, "--out", "unused"])
    p = check_lens_arguments(args)
    seq, _ = refocused_lens(p, "file")
    pitch = seq.primary_wavelength_um * seq.paraxial().working_f_number / 2
    return lens_provider(args, p, seq, pitch_um=pitch, width_px=1, height_px=1, max_field_deg=max(p.fields),
                         sampling="point")


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lenses", default="cooke_triplet,double_gauss,aspheric_singlet")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    rows: dict = {"threads": torch.get_num_threads()}
    for name in args.lenses.split(","):
        psf = provider_of(name)
        lams = psf.quadrature()[0]
        times = {True: [], False: [], "extent_base": [], "extent": []}
        tables = {}
        for _ in range(args.repeats):
            for base in (True, False):
                with node_by_node(base):
                    dt, tables[base] = timed(lambda: bank.wavefront_table(psf.lens, lams, psf.max_field_deg,
                                                                          psf.image_scale_mm))
                times[base].append(dt)
                lens = _OneFieldAtATime(psf.lens) if base else psf.lens
                one = provider.SequentialPSF.estimated_extent_px
                dt, ext = timed(lambda: one(_Swap(psf, lens)))
                times["extent_base" if base else "extent"].append(dt)
        same = all(torch.equal(getattr(tables[True], k).nan_to_num(7.0), getattr(tables[False], k).nan_to_num(7.0))
                   for k in TABLE_FIELDS)
        t_base, t_new = min(times[True]), min(times[False])
        e_base, e_new = min(times["extent_base"]), min(times["extent"])
        print(f"{name}: table of {tables[False].angles_deg.numel()} nodes x {len(lams)} wavelengths: node by node "
              f"{t_base:.2f} s, bundled {t_new:.2f} s ({t_base / t_new:.2f}x; equal bit for bit: {same}); extent "
              f"estimate {e_base:.2f} -> {e_new:.2f} s ({e_base / e_new:.2f}x)", flush=True)
        rows[name] = {"nodes": tables[False].angles_deg.numel(), "wavelengths": len(lams), "table_node_by_node_s":
                      t_base, "table_bundled_s": t_new, "table_ratio": t_base / t_new, "bit_for_bit": same,
                      "extent_field_by_field_s": e_base, "extent_bundled_s": e_new}
        if not same:
            raise SystemExit(f"{name}: the bundled table differs from the node-by-node one")
    # one manufactured copy of the Cooke triplet (commercial grade: decentred and tilted, 4 azimuths), evaluated as the
    # tolerance Monte Carlo does (coarse tables: 9 nodes, no bisection)
    psf = provider_of("cooke_triplet")
    tol = SurfaceTolerances.grade("commercial")
    copy_s = {True: [], False: []}
    vals = {}
    for _ in range(args.repeats):
        for base in (True, False):
            bank._TABLES.clear()
            with node_by_node(base):
                copy, _ = lens_copies(psf, tol, 2, seed=0, snr_db=(27.6,), rho0=0.937, numerics=FAST_NUMERICS,
                                      compare_default=False)
                dt, vals[base] = timed(lambda: copy(1))
            copy_s[base].append(dt)
    diff = max(float((torch.as_tensor(vals[True][k]) - torch.as_tensor(vals[False][k])).abs().max()
                     / torch.as_tensor(vals[True][k]).abs().max()) for k in ("mse_s", "mse_r", "mse_r_nominal", "rms_w"))
    c_base, c_new = min(copy_s[True]), min(copy_s[False])
    print(f"one copy of the Cooke triplet (4 azimuths, 4 field angles): tables node by node {c_base:.2f} s, bundled "
          f"{c_new:.2f} s ({c_base / c_new:.2f}x; criteria differ by {diff:.1e} relative; the extent estimate is "
          "bundled in both)", flush=True)
    rows["copy"] = {"node_by_node_s": c_base, "bundled_s": c_new, "ratio": c_base / c_new, "max_rel_diff": diff}
    print(json.dumps(rows))


class _Swap:
    """``psf`` with its lens replaced, for :meth:`SequentialPSF.estimated_extent_px` alone."""

    def __init__(self, psf, lens):
        self._psf, self.lens = psf, lens

    def __getattr__(self, name):
        return getattr(self._psf, name)


if __name__ == "__main__":
    main()
