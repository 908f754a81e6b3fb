"""Bad inputs, second round (issue 20), class 5: a full disk (ENOSPC while writing) stops the run with one line and
leaves no partial output.
"""

from __future__ import annotations

import errno

E = ["--design", "end_to_end_paper"]


# class 5: a full disk
def test_a_full_disk_stops_the_run_with_one_line_and_no_partial_output(files, refused, monkeypatch):
    import lenssim_cli.camera as cam

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(cam, "write_image", full)
    refused(["simulate", "ok.png", *E, "--angles", "0", "--crop", "64", "--out", "o"],
            "No space left on device", files)
    assert not list(files.glob(".o.staging-*"))
