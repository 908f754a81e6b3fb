"""Bad inputs, fourth round (issue 43, class 1): results read back are checked against their own run record, and
every argument is checked before any work.

Read back: a trade-off (tradeoff.nc, its design files, its chunks), a sweep, the tolerance runs' results and the
full-frame checkpoint are damaged as a disk or a hand would damage them (bytes flipped in the data section, found from
the NetCDF-3 header parsed here by hand; a value changed through xarray and the file rewritten without its checksum;
the file truncated; a coordinate swapped; a record that fails no checksum but makes no sense), and each is refused in
one line naming the file, status 2, nothing overwritten (a resumable piece is computed again, with a warning).

Arguments: every numeric flag of ``tradeoff`` (and the flags of ``optimum``, ``tolerance``, ``sweep``, ``study``)
given NaN, infinities, 1e9, -1e9, 1e-320, nothing and repeated values: each is refused in one line, status 2,
nothing written, before the grid starts (the grid's evaluation is replaced by one that raises), or, where the value is
allowed, the run reaches its grid.
"""

from __future__ import annotations

import json
import math
import shutil
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import xarray as xr

import lenssim.tolerancing
import lenssim_studies.tradeoff
import lenssim_studies.study
import lenssim_studies.sweep
import lenssim_studies.tolerance
from lenssim.validate import ResumeWarning
from lenssim_cli.main import main
from lenssim_studies.chunks import dataset_checksum, stamp_result, verify_result

LENS_FILE = str(Path(__file__).parents[1] / "data" / "lenses" / "test_singlet.toml")
TRADEOFF = ["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=-1,0", "--vary", "focus_um=0,10", "--wavefront",
            "third_order", "--levels", "2", "--snr", "21.6", "33.6", "--quiet"]
"""The smallest trade-off of a real lens: 2 x 2 designs, the third-order route at the file's 2 field angles."""


class GridStarted(Exception):
    """Raised by the grid's evaluation in place of any work: the run got past every check."""


def _grid_raises(*args, **kwargs):
    raise GridStarted


# -- a NetCDF-3 header, parsed by hand (not by the library's reader) ------------------------------------------------
NC_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 4, 6: 8}
"""Bytes per value of each NetCDF-3 type (byte, char, short, int, float, double)."""


def data_offsets(raw: bytes) -> dict[str, tuple[int, int]]:
    """``{variable: (begin, vsize)}``: where each variable's data start in a NetCDF-3 file (classic or 64-bit
    offset), from its header."""
    assert raw[:3] == b"CDF" and raw[3] in (1, 2), raw[:4]
    wide = raw[3] == 2
    pos = 8  # magic, numrecs

    def u32():
        nonlocal pos
        pos += 4
        return struct.unpack(">I", raw[pos - 4:pos])[0]

    def name():
        nonlocal pos
        n = u32()
        pos += (n + 3) // 4 * 4
        return raw[pos - (n + 3) // 4 * 4:pos - (n + 3) // 4 * 4 + n].decode()

    def attributes():
        nonlocal pos
        u32()
        for _ in range(u32()):
            name()
            t, k = u32(), u32()
            pos += (k * NC_SIZES[t] + 3) // 4 * 4

    u32()  # NC_DIMENSION or ABSENT
    for _ in range(u32()):
        name()
        u32()
    attributes()
    u32()  # NC_VARIABLE
    out = {}
    for _ in range(u32()):
        v = name()
        ndims = u32()
        pos += 4 * ndims  # their ids
        attributes()
        u32()  # type
        vsize = u32()
        width = 8 if wide else 4
        out[v] = (struct.unpack(">Q" if wide else ">I", raw[pos:pos + width])[0], vsize)
        pos += width
    return out


def test_the_header_parser_finds_every_variable_s_data(tmp_path):
    """The hand-written parser against a file whose bytes are known: each variable's data, big-endian, at its
    offset."""
    ds = xr.Dataset({"a": ("x", np.array([1.5, -2.25])), "b": ("y", np.array([7, 8, 9], dtype=np.int32))},
                    coords={"x": [10.0, 20.0]}, attrs={"title": "t", "n": 3})
    ds.to_netcdf(tmp_path / "f.nc", engine="scipy")
    raw = (tmp_path / "f.nc").read_bytes()
    off = data_offsets(raw)
    for name, dtype, want in (("a", ">f8", [1.5, -2.25]), ("b", ">i4", [7, 8, 9]), ("x", ">f8", [10.0, 20.0])):
        begin, size = off[name]
        assert np.frombuffer(raw[begin:begin + size], dtype)[:len(want)].tolist() == want


# -- the checksum ---------------------------------------------------------------------------------------------------
def _mixed():
    return xr.Dataset({"f": (("x", "y"), np.array([[1.0, np.nan], [-0.0, 1e-300]])),
                       "b": ("x", np.array([True, False])), "i": ("x", np.array([3, -4], dtype=np.int64)),
                       "u": ("x", np.array([0, 127], dtype=np.uint8)), "s": ("x", np.array(["", "why"]))},
                      coords={"x": [0.5, 1.5], "p": ("y", np.array(["S1.conic", "focus_um"]))},
                      attrs={"config": "{}", "config_digest": "44136fa355b3678a"})


def test_a_result_s_checksum_survives_its_file_and_sees_any_change(tmp_path):
    """What NetCDF-3 keeps (booleans, 64-bit and unsigned integers, text, NaN, -0) gives the same checksum read back;
    one value changed, a coordinate swapped or the run record edited is seen."""
    ds = stamp_result(_mixed())
    ds.to_netcdf(tmp_path / "r.nc", engine="scipy")
    back = xr.load_dataset(tmp_path / "r.nc", engine="scipy")
    assert dataset_checksum(back) == ds.attrs["data_sha256"]
    verify_result(back, "r.nc", "test run", "again")
    for edit in (lambda d: d["f"].values.__setitem__((1, 1), 2e-300), lambda d: d["b"].values.__setitem__(1, True),
                 lambda d: d["s"].values.__setitem__(0, "x"), lambda d: d["i"].values.__setitem__(0, 4),
                 lambda d: d.__setitem__("x", ("x", [1.5, 0.5]))):
        e = back.copy(deep=True)
        edit(e)
        with pytest.raises(ValueError, match="'r.nc' fails its checksum: it was modified after the test run wrote"):
            verify_result(e, "r.nc", "test run", "again")
    e = back.copy()
    e.attrs = dict(back.attrs, config='{"rho0": 0.5}')
    with pytest.raises(ValueError, match="its run record"):
        verify_result(e, "r.nc", "test run", "again")


# -- a trade-off read back ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A trade-off folder as `lenssim tradeoff` writes it, and its dataset."""
    out = tmp_path_factory.mktemp("round4") / "t"
    assert main([*TRADEOFF, "--out", str(out)]) == 0
    return out, xr.load_dataset(out / "tradeoff.nc", engine="scipy")


def _refused(argv, capsys, *match):
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert len(err) == 1 and err[0].startswith(f"lenssim {argv[0]}: error: "), err
    assert all(m in err[0] for m in match), err
    return err[0]


def _copy(made, tmp_path, name="c"):
    out, _ = made
    shutil.copytree(out, tmp_path / name)
    return tmp_path / name


def _flip(path: Path, variable: str, at: int = 0):
    """Bytes of ``variable``'s data flipped in place (the header intact): the exponent of its value ``at``."""
    raw = bytearray(path.read_bytes())
    begin, _ = data_offsets(bytes(raw))[variable]
    raw[begin + 8 * at] ^= 0x66
    raw[begin + 8 * at + 1] ^= 0x5A
    path.write_bytes(bytes(raw))


def test_optimum_reads_the_intact_trade_off(made, capsys):
    out, ds = made
    assert main(["optimum", str(out), "--criterion", "mse_r", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["design"]["S1.conic"] in (-1.0, 0.0) and math.isfinite(r["value"])
    assert r["lens_file"] == str(out / "designs" / "mse_r.toml")


@pytest.mark.parametrize("variable, at", [("S1.conic", 0), ("S1.conic", 1), ("focus_um", 1), ("snr", 0),
                                          ("mse_r", 0), ("cost", 2), ("rms_w", 3)])
def test_bytes_flipped_in_the_data_section_are_refused(made, tmp_path, capsys, variable, at):
    """The issue's case: data bytes damaged, the header intact (a conic of -2e181, an SNR of 2e-181 dB)."""
    c = _copy(made, tmp_path)
    _flip(c / "tradeoff.nc", variable, at)
    damaged = xr.load_dataset(c / "tradeoff.nc", engine="scipy")
    assert not np.array_equal(damaged[variable].values, made[1][variable].values, equal_nan=True)
    _refused(["optimum", str(c), "--criterion", "mse_r"], capsys, str(c / "tradeoff.nc"), "fails its checksum")


@pytest.mark.parametrize("cut", [8, 100, 0.5])
def test_a_truncated_trade_off_is_refused(made, tmp_path, capsys, cut):
    c = _copy(made, tmp_path)
    f = c / "tradeoff.nc"
    raw = f.read_bytes()
    f.write_bytes(raw[:len(raw) - cut] if isinstance(cut, int) else raw[:int(len(raw) * cut)])
    _refused(["optimum", str(f), "--criterion", "mse_r"], capsys, str(f), "fails its checksum", "truncated")


def _rewrite(ds, path, edit, *, restamp=False):
    """``ds`` edited (``edit(copy)`` returns the edited dataset) and written to ``path``; ``restamp``: its checksum
    made to fit, so that what is left to see is the sense of its numbers."""
    e = edit(ds.copy(deep=True))
    for v in e.variables.values():
        if v.dtype.kind in "OU":
            v.encoding = {}  # a string's width as the read file had it may not hold the new text
    if restamp:
        stamp_result(e)
    e.to_netcdf(path, engine="scipy")


def _set(name, index, value):
    def edit(d):
        d[name].values[index] = value
        return d
    return edit


EDITS = {
    "mse_r halved": lambda d: d.assign(mse_r=d["mse_r"] * 0.5),
    "a conic swapped": lambda d: d.assign_coords({"S1.conic": d["S1.conic"].values[::-1]}),
    "an SNR moved": lambda d: d.assign_coords(snr=[21.6, 27.6]),
    "a valid design's mse_r NaN": _set("mse_r", (0, 0, 0), np.nan),
    "a negative cost": _set("cost", (0, 0), -1.0),
    "an invalid design scored": lambda d: _set("reason", (0, 0), "the surfaces cross")(_set("valid", (0, 0), False)(d)),
    "valid flags flipped": _set("valid", (1, 1), False),
    "mtf50_capped 7": _set("mtf50_capped", (0, 1), 7),
    "the grid transposed": lambda d: d.assign(rms_w=d["rms_w"].transpose()),
}


@pytest.mark.parametrize("edit", list(EDITS))
def test_a_value_changed_through_xarray_fails_its_checksum(made, tmp_path, capsys, edit):
    c = _copy(made, tmp_path)
    _rewrite(made[1], c / "tradeoff.nc", EDITS[edit])
    _refused(["optimum", str(c), "--criterion", "mse_r"], capsys, "fails its checksum", "was modified after the "
             "trade-off wrote it")


@pytest.mark.parametrize("edit", list(EDITS)[1:])
def test_a_trade_off_whose_checksum_fits_but_which_makes_no_sense_is_refused(made, tmp_path, capsys, edit):
    """Its checksum recomputed for the edited numbers: the grid, the SNRs and the validity are checked against the
    run's record (a coordinate swapped, a valid design not finite, an invalid design scored...)."""
    c = _copy(made, tmp_path)
    _rewrite(made[1], c / "tradeoff.nc", EDITS[edit], restamp=True)
    _refused(["optimum", str(c), "--criterion", "mse_r"], capsys, str(c / "tradeoff.nc"),
             "makes no sense for its run record")


def test_a_trade_off_without_its_checksum_or_with_an_edited_record_is_refused(made, tmp_path, capsys):
    _, ds = made
    bare = ds.copy()
    bare.attrs = {k: v for k, v in ds.attrs.items() if k != "data_sha256"}
    bare.to_netcdf(tmp_path / "bare.nc", engine="scipy")
    _refused(["optimum", str(tmp_path / "bare.nc"), "--criterion", "mse_r"], capsys, "carries no data checksum")
    grid = json.loads(ds.attrs["config"])
    grid["vary"][0][1] = [-2.0, 0.0]  # the record's grid edited, its digest left
    edited = ds.copy()
    edited.attrs = dict(ds.attrs, config=json.dumps(grid, sort_keys=True))
    edited.to_netcdf(tmp_path / "edited.nc", engine="scipy")
    _refused(["optimum", str(tmp_path / "edited.nc"), "--criterion", "mse_r"], capsys, "its run record (config)")


def test_a_rerun_refuses_its_damaged_result_and_leaves_it(made, tmp_path, capsys):
    """`lenssim tradeoff` again on a folder whose tradeoff.nc was damaged: refused, the file untouched (never taken
    for the finished result, never overwritten)."""
    c = _copy(made, tmp_path)
    _flip(c / "tradeoff.nc", "mse_r", 1)
    before = (c / "tradeoff.nc").read_bytes()
    _refused([*TRADEOFF, "--out", str(c)], capsys, str(c / "tradeoff.nc"), "fails its checksum")
    assert (c / "tradeoff.nc").read_bytes() == before
    _rewrite(made[1], c / "tradeoff.nc", EDITS["a valid design's mse_r NaN"], restamp=True)
    _refused([*TRADEOFF, "--out", str(c)], capsys, "makes no sense for its run record")


def test_a_design_file_that_does_not_hold_its_design_is_refused(made, tmp_path, capsys):
    """optimum names designs/NAME.toml as the optimum's lens file only if it holds that design."""
    c = _copy(made, tmp_path)
    f = c / "designs" / "mse_r.toml"
    text = f.read_text()
    assert "thickness_mm = 4.0\n" in text
    f.write_text(text.replace("thickness_mm = 4.0\n", "thickness_mm = 4.5\n", 1))
    _refused(["optimum", str(c), "--criterion", "mse_r"], capsys, str(f), "does not hold the design")
    f.write_text("not = [a lens\n")
    _refused(["optimum", str(c), "--criterion", "mse_r"], capsys, str(f), "does not hold the design")
    f.write_text(text)
    assert main(["optimum", str(c), "--criterion", "mse_r"]) == 0


def test_a_damaged_chunk_is_computed_again(tmp_path, monkeypatch):
    """The trade-off's resumable chunks: one whose bytes are damaged is warned about and computed again; the result
    is the uninterrupted run's."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.numerics import FAST_NUMERICS
    from lenssim_studies.tradeoff import LensTradeoffRun, run_lens_tradeoff

    monkeypatch.setattr(lenssim_studies.tradeoff, "CHUNK_DESIGNS", 1)  # two designs, two chunks
    run = LensTradeoffRun(read_lens(LENS_FILE), LENS_FILE, (("S1.conic", (-1.0, 0.0)),), (27.6,), 0.937, 1.0, "point",
                          FAST_NUMERICS, levels=2, wavefront="third_order")
    out = tmp_path / "t.nc"
    assert run_lens_tradeoff(run, out, show_progress=False, max_chunks=1) is None
    chunk = tmp_path / "t.nc.partial" / "chunk_00000.npz"
    raw = bytearray(chunk.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    chunk.write_bytes(bytes(raw))
    with pytest.warns(ResumeWarning, match="chunk_00000.npz"):
        ds = run_lens_tradeoff(run, out, show_progress=False)
    whole = run_lens_tradeoff(run, tmp_path / "u.nc", show_progress=False)
    for k in whole.data_vars:
        assert np.array_equal(ds[k].values, whole[k].values, equal_nan=ds[k].dtype.kind == "f"), k
    assert ds.attrs["data_sha256"] == whole.attrs["data_sha256"]


# -- other results read back ----------------------------------------------------------------------------------------
def test_a_sweep_that_fits_its_checksum_but_not_its_config_is_refused(files, capsys):
    assert main(["sweep", "grid.toml", "--out", "a.nc", "--quiet"]) == 0
    capsys.readouterr()
    ds = xr.load_dataset(files / "a.nc", engine="scipy")
    _rewrite(ds, files / "swapped.nc", lambda d: d.assign_coords(s=d["s"].values[::-1]), restamp=True)
    _refused(["optimum", "swapped.nc", "--criterion", "mse_r"], capsys, "'swapped.nc' makes no sense", "its s coordinate")
    _rewrite(ds, files / "inf.nc", _set("rms_w", (0, 0), np.inf), restamp=True)
    _refused(["optimum", "inf.nc", "--criterion", "mse_r"], capsys, "its rms_w holds NaN or infinite values")
    _flip(files / "a.nc", "Q_back", 0)
    _refused(["optimum", "a.nc", "--criterion", "mse_r"], capsys, "'a.nc' fails its checksum")
    _refused(["sweep", "grid.toml", "--out", "a.nc"], capsys, "'a.nc' fails its checksum")


def _tolerance_run():
    from lenssim.model.tolerances import GRADES
    from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_RHO0
    from lenssim_studies.tolerance import ToleranceRun

    return ToleranceRun(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"], GRADES["commercial"], (21.6, 27.6),
                        PAPER_RHO0, n_lenses=4, chunk_lenses=2, field_angles_deg=(0.0,))


def test_a_tolerance_result_is_verified_before_it_is_reused(tmp_path):
    from lenssim_studies.tolerance import run_tolerance

    run = _tolerance_run()
    out = tmp_path / "tolerance.nc"
    ds = run_tolerance(run, out, show_progress=False)
    assert run_tolerance(run, out, show_progress=False).attrs["data_sha256"] == ds.attrs["data_sha256"]
    good = out.read_bytes()
    _flip(out, "mse_r", 1)
    with pytest.raises(ValueError, match="tolerance.nc' fails its checksum: it was modified after the tolerance run"):
        run_tolerance(run, out, show_progress=False)
    out.write_bytes(good[:-16])
    with pytest.raises(ValueError, match="fails its checksum: a NetCDF file whose data cannot be read back"):
        run_tolerance(run, out, show_progress=False)
    _rewrite(ds, out, lambda d: d.assign_coords(snr=[21.6, 33.6]), restamp=True)
    with pytest.raises(ValueError, match="makes no sense for its run record: its snr coordinate is not the run's"):
        run_tolerance(run, out, show_progress=False)
    _rewrite(ds, out, _set("mse_r", (0, 0), np.nan), restamp=True)
    with pytest.raises(ValueError, match="its mse_r holds NaN"):
        run_tolerance(run, out, show_progress=False)


def test_a_lens_tolerance_result_is_verified_before_it_is_reused(tmp_path, monkeypatch):
    """The Monte Carlo of any lens: its copies' criteria replaced by numbers drawn here (what is tested is the file
    read back, not the optics: tracing each copy takes minutes on a small machine)."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.numerics import FAST_NUMERICS
    from lenssim.model.tolerances import SurfaceTolerances
    from lenssim.optics.sequential import SequentialLens
    from lenssim.tolerancing import COPY_CRITERIA as CRITERIA
    from lenssim_studies.tolerance import LensToleranceRun, run_tolerance
    from lenssim_studies.tradeoff import sequential_provider

    rng = np.random.default_rng(5)

    def values(snr_db):
        return {k: torch.as_tensor(rng.uniform(0.1, 1.0, len(snr_db)) if k != "rms_w" else rng.uniform(0.1, 1.0))
                for k in CRITERIA}

    monkeypatch.setattr(lenssim.tolerancing, "nominal_criteria",
                        lambda psf, snr_db, **kw: (psf, values(snr_db), values(snr_db)))
    monkeypatch.setattr(lenssim.tolerancing, "copy_criteria", lambda psf, nominal, pert, i, snr_db, **kw:
                        values(snr_db) | {"image_shift_mm": 0.01 * i, "efl_mm": 50.0 + i})
    p = read_lens(LENS_FILE)
    psf = sequential_provider(p, SequentialLens(p), pitch_um=2.0, sampling="point", max_field_deg=3.0, coarse=True)
    run = LensToleranceRun(psf, SurfaceTolerances.grade("commercial"), 3, 0, (21.6, 27.6), 0.937, FAST_NUMERICS,
                           angles_deg=(0.0,), chunk_copies=2)
    out = tmp_path / "tolerance.nc"
    ds = run_tolerance(run, out, show_progress=False)
    assert run_tolerance(run, out, show_progress=False).attrs["data_sha256"] == ds.attrs["data_sha256"]
    _rewrite(ds, out, lambda d: d.assign(efl_mm=d["efl_mm"] * 2.0))
    with pytest.raises(ValueError, match="tolerance.nc' fails its checksum"):
        run_tolerance(run, out, show_progress=False)
    _rewrite(ds, out, lambda d: d.assign_coords(lens=[2, 1, 0]), restamp=True)
    with pytest.raises(ValueError, match="its lens coordinate is not the run's"):
        run_tolerance(run, out, show_progress=False)
    _rewrite(ds, out, _set("mse_r", (1, 1), np.inf), restamp=True)
    with pytest.raises(ValueError, match="its mse_r holds NaN or infinite values"):
        run_tolerance(run, out, show_progress=False)


def test_a_gradient_result_is_verified_before_it_is_reused(tmp_path, monkeypatch):
    """The gradient route's gradient.nc: each descent replaced by an end point made up here (what is tested is the
    file read back)."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.model.numerics import FAST_NUMERICS
    from lenssim_studies.tradeoff import LensGradientRun, run_lens_gradient

    def descend(run, level, j):
        return {"design": np.full(1, -0.5), "start_design": run.start_points()[j].numpy(), "value": np.float64(1 + j),
                "cost": np.float64(0.1 * (j + 1)), "iterations": np.int64(3), "evaluations": np.int64(9),
                "stopped": np.int64(0), "gradient": np.float64(1e-9)}

    monkeypatch.setattr(lenssim_studies.tradeoff, "_descend", descend)
    run = LensGradientRun(read_lens(LENS_FILE), LENS_FILE, (("S1.conic", -1.0, 0.0),), "mse_r", (27.6,), 0.937, 1.0,
                          FAST_NUMERICS, levels=2, starts=2)
    out = tmp_path / "gradient.nc"
    ds = run_lens_gradient(run, out, show_progress=False)
    assert run_lens_gradient(run, out, show_progress=False).attrs["data_sha256"] == ds.attrs["data_sha256"]
    _flip(out, "value", 1)
    with pytest.raises(ValueError, match="gradient.nc' fails its checksum: it was modified after the gradient run"):
        run_lens_gradient(run, out, show_progress=False)
    _rewrite(ds, out, _set("stopped", (0, 1), 7), restamp=True)
    with pytest.raises(ValueError, match="its stopped holds a reason that is not one of gradient, step, steps"):
        run_lens_gradient(run, out, show_progress=False)
    _rewrite(ds, out, _set("cost", (1, 0), np.nan), restamp=True)
    with pytest.raises(ValueError, match="its cost of a descent that was made is not finite"):
        run_lens_gradient(run, out, show_progress=False)
    _rewrite(ds, out, lambda d: d.assign_coords(parameter=["S2.conic"]), restamp=True)
    with pytest.raises(ValueError, match=r"its parameter coordinate is not the run's \(S1.conic\)"):
        run_lens_gradient(run, out, show_progress=False)


def test_a_full_frame_checkpoint_whose_stamp_makes_no_sense_is_computed_again(tmp_path, monkeypatch):
    """The checkpoint's sensor image is checked against its SHA-256 (as before); its stamp's electrons per unit now
    for sense: a damaged number is warned about and the sensor image computed again, never used."""
    import pipeline.simulate
    from lenssim import LensPSF
    from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_SENSOR
    from pipeline.blur import WindowScheme
    from pipeline.simulate import simulate_frame

    ideal = torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.9 + 0.05
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    monkeypatch.setattr(pipeline.simulate, "_restore_frame", lambda *a, resumed, **kw: resumed)
    ck = tmp_path / "ck"
    run = lambda: simulate_frame(ideal, psf, 3200.0, seed=1, scheme=WindowScheme(256, 32, 64), checkpoint=ck,  # noqa: E731
                                 sensor=PAPER_SENSOR)
    assert not run()
    assert run()  # intact: resumed
    stamp = ck / "stamp.json"
    for bad in (math.inf, 0.0, "1e300"):
        good = json.loads(stamp.read_text())  # as the last run wrote it (its sensor image's SHA-256)
        stamp.write_text(json.dumps(good | {"electrons_per_unit": bad}))
        with pytest.warns(ResumeWarning, match="makes no sense"):
            assert not run()
    stamp.write_text("[1, 2]")  # not a stamp at all
    assert not run()
    raw = bytearray((ck / "sensor_linear.exr").read_bytes())
    raw[-100] ^= 0xFF
    (ck / "sensor_linear.exr").write_bytes(bytes(raw))
    with pytest.warns(ResumeWarning, match="does not match its stamp"):
        assert not run()


# -- every argument before any work ---------------------------------------------------------------------------------
HOSTILE = ("nan", "inf", "-inf", "1e9", "-1e9", "1e-320", "")
"""The values each numeric flag is given (as typed: argparse reads them)."""


@pytest.fixture
def no_grid(monkeypatch):
    """Every grid's evaluation replaced by one that raises GridStarted."""
    monkeypatch.setattr(lenssim_studies.tradeoff, "_score", _grid_raises)
    monkeypatch.setattr(lenssim_studies.tradeoff, "_descend", _grid_raises)
    monkeypatch.setattr(lenssim_studies.tolerance, "_compute_chunk", _grid_raises)
    monkeypatch.setattr(lenssim.tolerancing, "nominal_criteria", _grid_raises)
    monkeypatch.setattr(lenssim_studies.sweep, "_compute_chunk", _grid_raises)
    for name in ("white_light_study", "exact_along_tradeoff"):
        monkeypatch.setattr(lenssim_studies.study, name, _grid_raises)


def _checked(argv, out: Path, capsys, allowed: bool):
    """``main(argv)`` either refuses in one line, status 2, before the grid and with nothing written (``allowed``
    False), or gets past every check to its grid (``allowed``)."""
    if allowed:
        with pytest.raises(GridStarted):
            main(argv)
        capsys.readouterr()
        return
    _refused(argv, capsys)
    assert not out.exists(), f"{argv}: a refused run wrote {out}"


GRADIENT = ["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=-1:0", "--wavefront", "third_order", "--optimise",
            "mse_r", "--levels", "2", "--quiet"]
"""The smallest trade-off by gradient descent (--optimise): its flags --seed, --starts and --steps."""
TRADEOFF_FLAGS = {
    # flag: (the command it goes with, the hostile values allowed: an SNR of 1e-320 dB is 0 dB, a seed of 1e9 is one)
    "--snr": ("grid", {"1e-320"}),
    "--pixel-pitch": ("grid", set()),
    "--levels": ("grid", set()),
    "--max-fft-size": ("grid", set()),
    "--seed": ("gradient", {"1e9"}),
    "--starts": ("gradient", set()),
    "--steps": ("gradient", set()),
    "--robust": ("grid", set()),
}


def _as_typed(flag, value):
    """An integer flag's 1e9 typed as a whole number (argparse refuses 1e9 for an int)."""
    if flag in ("--levels", "--max-fft-size", "--seed", "--starts", "--steps", "--robust") and value in ("1e9", "-1e9"):
        return str(int(float(value)))
    return value


@pytest.mark.parametrize("flag", list(TRADEOFF_FLAGS))
@pytest.mark.parametrize("value", HOSTILE)
def test_every_numeric_flag_of_tradeoff_is_checked_before_the_grid(flag, value, tmp_path, capsys, no_grid):
    extra, allowed = TRADEOFF_FLAGS[flag]
    out = tmp_path / "o"
    base = GRADIENT if extra == "gradient" else TRADEOFF
    _checked([*base, flag, _as_typed(flag, value), "--out", str(out)], out, capsys, value in allowed)


@pytest.mark.parametrize("spec", ["S1.conic=nan,0", "S1.conic=0,inf", "S1.conic=-inf:0", "S1.conic=0:1e-320",
                                  "S1.conic=", "S1.conic=0,0", "S1.conic=-1:1:0", "S1.conic=1:-1",
                                  "S1.conic=0:1e9:1e-320", "S1.conic=-1,0,-1", "S1.conic=2:2",
                                  "S1.conic=1e9,-1e9", "S1.conic=1e-320,0"])
def test_vary_values(spec, tmp_path, capsys, no_grid):
    """Grid values: finite, each once (a value twice puts two designs on one coordinate), a range with a step that
    divides it; values far out are designs (kept invalid with the reason if they cannot be made)."""
    out = tmp_path / "o"
    argv = ["tradeoff", "--lens", LENS_FILE, "--vary", spec, "--wavefront", "third_order", "--quiet", "--out", str(out)]
    _checked(argv, out, capsys, spec in ("S1.conic=1e9,-1e9", "S1.conic=1e-320,0", "S1.conic=0:1e-320"))


@pytest.mark.parametrize("argv, match", [
    (["--snr", "27.6", "27.6"], "--snr holds 27.6 more than once"),
    (["--snr", "27.6", "2.76e1"], "more than once"),
    (["--aspherize", "S1", "S1"], "--aspherize names S1 more than once"),
    (["--aspherize", "1", "s1"], "more than once"),
    (["--aspherize", "S9"], "surfaces S1 to S2"),
    (["--aspherize", "Sx"], "surfaces S1 to S2"),
    (["--aspherize", "S\u00b2"], "surfaces S1 to S2"),
    (["--hold", "efl,efl"], "--hold holds efl more than once"),
    (["--vary", "S1.conic=-1:0"], "a free parameter is named twice"),
    (["--pixel-pitch", "10"], "must be below lambda f#"),  # no design of this lens can be point-sampled there
    (["--pixel-pitch", "0.1", "--max-fft-size", "64"], "even an aberration-free design"),
    (["--snr", "5000"], "SNR [5000] dB is not allowed"),
])
def test_repeated_values_and_pixels_no_design_can_use_are_refused(argv, match, tmp_path, capsys, no_grid):
    out = tmp_path / "o"
    err = _refused([*TRADEOFF, *argv, "--out", str(out)], capsys, match)
    assert not out.exists(), err


def test_the_exact_route_checks_its_pixels_before_the_grid(tmp_path, capsys, no_grid):
    """Area samples of pixels far larger than the PSF need a fine grid of thousands of samples per PSF: refused
    before the grid (it asked for 7 GB and more, a design at a time)."""
    out = tmp_path / "o"
    base = ["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=-1,0", "--quiet", "--out", str(out)]
    _refused([*base, "--pixel-pitch", "500"], capsys, "pixels of 500 um (area samples)", "max_fft_size", "raise it")
    assert not out.exists()
    _checked([*base, "--pixel-pitch", "5"], out, capsys, True)
    out = tmp_path / "m"  # the Monte Carlo of any lens: the same rule, before its nominal lens is evaluated
    _refused([*TOLERANCE_LENS, "--pixel-pitch", "500", "--out", str(out)], capsys, "needs an FFT of", "max_fft_size")
    assert not out.exists()
    _checked([*TOLERANCE_LENS, "--pixel-pitch", "5", "--out", str(out)], out, capsys, True)


def test_the_snr_rule_is_evaluate_s(capsys):
    """One rule per quantity: what evaluate refuses, every command refuses, in the same words."""
    from lenssim.optics.image_model import noise_variance
    from lenssim.validate import check_snr_db

    for v in (math.nan, math.inf, -math.inf, 1e9, -1e9, 100.5, -20.5):
        with pytest.raises(ValueError, match=r"SNR \[.*\] dB is not allowed: finite values in \[-20, 100\] dB"):
            noise_variance([v])
        with pytest.raises(ValueError, match=r"^--snr: SNR \[.*\] dB is not allowed"):
            check_snr_db([27.6, v], "--snr")
    for v in (100.0, -20.0, 1e-320):
        with pytest.warns(UserWarning, match="outside"):
            assert check_snr_db([v]) == (v,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_snr_db([10.0, 50.0]) == (10.0, 50.0)
    with pytest.raises(ValueError, match="SNR"):
        check_snr_db([])
    for cmd in (["evaluate", "--design", "end_to_end_paper"], ["tolerance", "--design", "end_to_end_paper", "--out", "o"],
                ["tradeoff", "--lens", LENS_FILE, "--vary", "S1.conic=0,1", "--out", "o"]):
        _refused([*cmd, "--snr", "nan"], capsys, "--snr: SNR [nan] dB is not allowed: finite values in [-20, 100] dB")


@pytest.mark.parametrize("argv, allowed", [
    *[((["--snr", v] if v else ["--snr", ""]), False) for v in ("nan", "inf", "-inf", "1e9", "-1e9", "")],
    (["--snr", "1e-320"], False),  # 0 dB is a number the sweep does not hold: not in this trade-off
    *[((["--max-cost", v]), False) for v in ("nan", "inf", "-inf", "-1e9", "")],
    (["--max-cost", "1e9"], True), (["--max-cost", "1e-320"], True),
])
def test_the_flags_of_optimum(argv, allowed, made, capsys):
    out, _ = made
    full = ["optimum", str(out), "--criterion", "mse_r", *argv]
    if allowed:
        assert main(full) == 0
        capsys.readouterr()
    else:
        _refused(full, capsys)


TOLERANCE = ["tolerance", "--design", "end_to_end_paper", "-n", "4", "--sensitivity-lenses", "0", "--quiet"]
TOLERANCE_LENS = ["tolerance", "--lens", LENS_FILE, "-n", "2", "--quiet"]


@pytest.mark.parametrize("base, flag, allowed", [
    (TOLERANCE, "--snr", {"1e-320"}), (TOLERANCE, "--reference-snr", set()), (TOLERANCE, "--angles", {"1e-320"}),
    (TOLERANCE, "-n", set()), (TOLERANCE, "--seed", {"1e9"}), (TOLERANCE, "--sensitivity-lenses", set()),
    (TOLERANCE, "--workers", set()), (TOLERANCE, "--worker-threads", set()), (TOLERANCE, "--s", {"1e-320"}),
    (TOLERANCE_LENS, "--snr", {"1e-320"}), (TOLERANCE_LENS, "-n", set()), (TOLERANCE_LENS, "--pixel-pitch", set()),
    (TOLERANCE_LENS, "--angles", {"1e-320"}), (TOLERANCE_LENS, "--seed", {"1e9"}),
])
@pytest.mark.parametrize("value", HOSTILE)
def test_the_flags_of_tolerance(base, flag, allowed, value, tmp_path, capsys, no_grid):
    out = tmp_path / "o"
    typed = value if flag not in ("-n", "--seed", "--sensitivity-lenses", "--workers", "--worker-threads") or \
        value not in ("1e9", "-1e9") else str(int(float(value)))
    argv = [*base, flag, typed, "--out", str(out)]
    if flag == "--reference-snr":
        argv += ["--snr", value or "0"] if value not in ("", "1e-320") else []
    _checked(argv, out, capsys, value in allowed)


@pytest.mark.parametrize("flag, allowed", [("--max-fft-size", set()), ("--memory-limit", {"1e9"}),
                                           ("--workers", set()), ("--worker-threads", set())])
@pytest.mark.parametrize("value", HOSTILE)
def test_the_flags_of_sweep(flag, allowed, value, files, capsys, no_grid):
    typed = value if flag == "--memory-limit" or value not in ("1e9", "-1e9") else str(int(float(value)))
    _checked(["sweep", "grid.toml", "--quiet", flag, typed, "--out", "s.nc"], files / "s.nc", capsys,
             value in allowed)


@pytest.mark.parametrize("argv, allowed", [
    *[(["white-light", "--grid-step", v, "0.8"], False) for v in HOSTILE],
    (["white-light", "--grid-step", "0.125", "0.8"], True),
    *[(["white-light", "--evaluations", v], False) for v in ("nan", "1000000000", "-1000000000", "")],
    *[(["white-light", "--wavelengths-per-channel", v, "--spectrum", "Nikon 5100 (NPL)"], False)
      for v in ("1000000000", "0", "")],
    *[(["as-built", "--lenses", v], False) for v in ("1000000000", "-1000000000", "1", "nan", "")],
    *[(["as-built", "--seed", v], False) for v in ("-1", "nan", str(2**63))],
])
def test_the_flags_of_study(argv, allowed, tmp_path, capsys, no_grid, monkeypatch):
    import lenssim_studies.as_built

    monkeypatch.setattr(lenssim_studies.as_built, "as_built_study", _grid_raises)
    out = tmp_path / "o"
    _checked(["study", *argv, "--quiet", "--out", str(out)], out, capsys, allowed)
