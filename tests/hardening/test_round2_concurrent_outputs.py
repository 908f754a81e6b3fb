"""Bad inputs, second round (issue 20), class 4: two runs writing the same output: the second stops with a clear
lock error; the first is untouched; once released the output can be written.
"""

from __future__ import annotations

from lenssim_cli.main import main

E = ["--design", "end_to_end_paper"]


# class 4: two runs writing one output
def test_a_second_run_on_a_locked_output_stops_with_a_clear_error(files, refused):
    from lenssim.io.files import output_lock

    with output_lock(files / "a.nc"):
        refused(["sweep", "grid.toml", "--out", "a.nc"], "another lenssim run is writing", files)
    with output_lock(files / "o"):
        refused(["simulate", "ok.png", *E, "--angles", "0", "--crop", "64", "--out", "o"],
                "another lenssim run is writing", files)
    assert main(["sweep", "grid.toml", "--out", "a.nc", "--quiet"]) == 0  # released: the run goes through
    assert not list(files.glob(".*.lock"))
