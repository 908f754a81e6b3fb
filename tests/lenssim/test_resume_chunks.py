"""The resumable-chunk driver the sweep and the tolerance run share (lenssim_studies.chunks.resume_chunks)."""

import json

import pytest

from lenssim.validate import ResumeWarning
from lenssim_studies.chunks import resume_chunks


def toy(tmp_path, n=4, corrupt_after_write=()):
    paths = [tmp_path / f"chunk_{i}.json" for i in range(n)]
    computed = []

    def read(p, i):
        got = json.loads(p.read_text())
        return got if got == {"i": i, "v": i * i} else "holds other numbers"

    def write(p, chunk, i):
        p.write_text(json.dumps({"i": i, "v": -1} if i in corrupt_after_write else chunk))

    def compute(i, progress):
        computed.append(i)
        progress(1)
        return {"i": i, "v": i * i}

    run = lambda **kw: resume_chunks(paths, kind="toy", read=read, write=write, compute=compute,  # noqa: E731
                                     weight=lambda i: 1, desc="toy", show_progress=False, **kw)
    return paths, computed, run


def test_chunks_resume_verify_and_stop_where_asked(tmp_path):
    paths, computed, run = toy(tmp_path)
    assert run(max_chunks=2) is None and computed == [0, 1]  # stopped with chunks left: nothing returned
    paths[1].write_text(json.dumps({"i": 1, "v": 5}))  # a chunk that no longer verifies
    with pytest.warns(ResumeWarning, match=r"toy chunk .*chunk_1.json' holds other numbers; computing it again"):
        got = run()
    assert computed == [0, 1, 1, 2, 3]  # the good chunk kept, the bad one and the rest computed
    assert got == [{"i": i, "v": i * i} for i in range(4)]
    assert run() == got and computed == [0, 1, 1, 2, 3]  # all there: nothing computed


def test_a_chunk_that_fails_after_it_was_written_stops_the_run(tmp_path):
    _, _, run = toy(tmp_path, corrupt_after_write=(2,))
    with pytest.raises(ValueError, match=r"toy chunk .*chunk_2.json' holds other numbers after it was written"):
        run()
