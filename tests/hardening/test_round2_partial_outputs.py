"""Bad inputs, second round (issue 20), class 6: a run that fails before its first chunk leaves no chunk folder.
"""

from __future__ import annotations


E = ["--design", "end_to_end_paper"]


# class 6: a refused or failed sweep leaves no chunk folder it created
def test_a_sweep_that_fails_before_any_chunk_leaves_no_partial_folder(files, refused):
    refused(["sweep", "grid.toml", "--out", "a.nc", "--max-fft-size", "31", "--quiet"], "a PSF needs an FFT", files)
