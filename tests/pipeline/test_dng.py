"""RAW out (pipeline.dng; issue 31): a mosaic written as a DNG is read back by LibRaw (rawpy) with the same digital
numbers, pattern, black and white levels and white balance; bad requests are refused in one line, nothing written."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.cfa import CFA_PATTERNS
from pipeline.dng import write_dng

rawpy = pytest.importorskip("rawpy", reason="rawpy (LibRaw) reads the DNG back: pip install rawpy")


@pytest.mark.parametrize("pattern", CFA_PATTERNS)
def test_libraw_reads_back_what_was_written(tmp_path, pattern):
    rng = np.random.default_rng(7)
    dn = rng.integers(64, 4096, size=(30, 44)).astype(np.float64)
    path = write_dng(tmp_path / "m.dng", torch.from_numpy(dn)[None, None], pattern, black_level=64, white_level=4095,
                     as_shot_neutral=(0.5, 1.0, 0.8))
    with rawpy.imread(str(path)) as r:
        assert np.array_equal(r.raw_image, dn.astype(np.uint16))
        desc = r.color_desc.decode()
        assert "".join(desc[i] for i in r.raw_pattern.reshape(-1)) == pattern
        assert list(r.black_level_per_channel) == [64] * 4 and r.white_level == 4095
        wb = r.camera_whitebalance  # the reciprocal of the as-shot neutral, green 1
        assert wb[:3] == pytest.approx([2.0, 1.0, 1.25], rel=1e-6)


def test_bad_requests_are_refused_and_nothing_is_written(tmp_path):
    raw = torch.full((8, 8), 100.0)
    for kwargs, match in (({"pattern": "RGBX"}, "CFA pattern 'RGBX' is not allowed"),
                          ({"black_level": 5000}, "0 <= black < white"),
                          ({"raw": torch.full((8, 8), 100.5)}, "whole digital numbers"),
                          ({"raw": torch.full((8, 8), 70000.0)}, "whole digital numbers"),
                          ({"as_shot_neutral": (0.0, 1.0, 1.0)}, "three finite values > 0")):
        args = {"raw": raw, "pattern": "RGGB", "black_level": 64, "white_level": 4095} | kwargs
        with pytest.raises(ValueError, match=match):
            write_dng(tmp_path / "x.dng", args.pop("raw"), args.pop("pattern"), **args)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="a name ending .dng"):
        write_dng(tmp_path / "x.tif", raw, "RGGB", black_level=64, white_level=4095)
    write_dng(tmp_path / "x.dng", raw, "RGGB", black_level=64, white_level=4095)
    with pytest.raises(FileExistsError, match="exists"):
        write_dng(tmp_path / "x.dng", raw, "RGGB", black_level=64, white_level=4095)
