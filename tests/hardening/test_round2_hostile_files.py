"""Bad inputs, second round (issue 20), class 3: hostile files: a PNG header claiming 100,000 x 100,000 px, a
truncated JPEG, a NaN EXR, a folder given as a photo, and sweep files edited by hand for `optimum`.
"""

from __future__ import annotations

import math

import pytest

from lenssim_cli.main import main

E = ["--design", "end_to_end_paper"]


# class 3: hostile files
@pytest.mark.parametrize("photo, match", [("huge.png", "cannot read photo"), ("trunc.jpg", "cannot read photo"),
                                          ("nan.exr", "NaN or infinite"), ("adir", "is not a file")])
def test_hostile_photos_are_refused(photo, match, files, refused):
    refused(["simulate", photo, *E, "--out", "o"], match, files)


def test_a_sweep_file_edited_by_hand_is_refused_by_optimum(files, capsys, refused):
    """The sweep writes a SHA-256 of its data; optimum (and a rerun that would reuse the file) checks it, so a
    number changed by hand never becomes an optimum."""
    import xarray as xr

    assert main(["sweep", "grid.toml", "--out", "a.nc", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["optimum", "a.nc", "--criterion", "mse_r"]) == 0
    good = capsys.readouterr().out
    ds = xr.load_dataset(files / "a.nc", engine="scipy")
    for name, edit in (("lower.nc", lambda d: d["mse_r"].values.__imul__(0.5)),
                       ("nan.nc", lambda d: d["mse_r"].values.__setitem__((0, 0, 0), math.nan))):
        e = ds.copy(deep=True)
        edit(e)
        e.to_netcdf(files / name, engine="scipy")
        refused(["optimum", name, "--criterion", "mse_r"], "was modified after the sweep wrote it", files)
    assert "best mse_r" in good
    del ds.attrs["data_sha256"]
    ds.to_netcdf(files / "bare.nc", engine="scipy")
    refused(["optimum", "bare.nc", "--criterion", "mse_r"], "carries no data checksum", files)
    refused(["sweep", "grid.toml", "--out", "lower.nc"], "was modified after the sweep wrote it", files)
