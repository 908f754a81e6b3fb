"""Class 4 (issue 9): every resumed piece is checked (checksum and coordinates); a bad piece is
reported by name and recomputed; temporaries of a killed run are removed."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
import torch

from lenssim import Camera, Design, LensPSF, Numerics

from lenssim_studies.paper import PAPER_CAMERA
from lenssim_studies.sweep import SweepConfig, run_sweep
from lenssim.validate import ResumeWarning
from pipeline import resolution_scene, simulate_frame, write_image
from pipeline.blur import WindowScheme
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_SENSOR, PAPER_SPECTRUM

CFG = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 10.0)), PAPER_SENSOR, PAPER_SPECTRUM), grid={"s": (-1.0, -0.5, 0.25), "Q": (-3.0, 0.0, 1.5)},
                  snr_db=(27.6,), numerics=Numerics(min_size=64, oversample=1))


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "ref.nc"
    run_sweep(CFG, out, show_progress=False)
    return out.read_bytes()


def _partial(tmp_path):
    out = tmp_path / "s.nc"
    assert run_sweep(CFG, out, show_progress=False, max_chunks=2) is None
    return out, tmp_path / "s.nc.partial"


@pytest.mark.parametrize("damage, reason", [
    (lambda p: p.write_bytes(p.read_bytes()[:100]), "cannot be read"),
    (lambda p: p.write_bytes(b""), "cannot be read"),
    (lambda p: shutil.copy(p.with_name("chunk_00001.npz"), p), "holds the chunk of s = -0.75 (index 1), not s = -1"),
])
def test_a_bad_sweep_chunk_is_reported_and_recomputed(tmp_path, reference, damage, reason):
    out, part = _partial(tmp_path)
    damage(part / "chunk_00000.npz")
    with pytest.warns(ResumeWarning, match=re.escape(f"chunk_00000.npz' {reason}")):
        run_sweep(CFG, out, show_progress=False)
    assert out.read_bytes() == reference


def test_a_chunk_with_changed_numbers_fails_its_checksum(tmp_path, reference):
    out, part = _partial(tmp_path)
    p = part / "chunk_00001.npz"
    with np.load(p) as z:
        data = {k: z[k] for k in z.files}
    data["mse_r"] = data["mse_r"] * 1.01
    with open(p, "wb") as fh:
        np.savez(fh, **data)
    with pytest.warns(ResumeWarning, match="fails its checksum"):
        run_sweep(CFG, out, show_progress=False)
    assert out.read_bytes() == reference


def test_temporaries_of_a_killed_run_are_removed(tmp_path, reference):
    out, part = _partial(tmp_path)
    (part / ".chunk_00002.x1y2.npz").write_bytes(b"half")
    (tmp_path / ".s.abcd.nc").write_bytes(b"half")
    run_sweep(CFG, out, show_progress=False)
    assert out.read_bytes() == reference
    assert not list(tmp_path.glob(".*"))


def test_a_replaced_checkpoint_image_is_not_trusted(tmp_path):
    ideal = resolution_scene(600, 900, seed=3, geometry=PAPER_CAMERA.geometry)[..., :300, :400]
    psf = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4))
    scheme = WindowScheme(256, 32, 64)
    first = simulate_frame(ideal, psf, 3200.0, seed=1, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)
    other = torch.rand_like(first.sensor)
    write_image(tmp_path / "sensor_linear.exr", other, bits="float")  # same size, other pixels
    with pytest.warns(ResumeWarning, match="does not match its stamp"):
        again = simulate_frame(ideal, psf, 3200.0, seed=1, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)
    assert not again.resumed and torch.equal(again.sensor, first.sensor) and torch.equal(again.restored, first.restored)
    resumed = simulate_frame(ideal, psf, 3200.0, seed=1, scheme=scheme, checkpoint=tmp_path, sensor=PAPER_SENSOR)
    assert resumed.resumed and torch.equal(resumed.restored, first.restored)
