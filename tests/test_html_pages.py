"""The self-contained result pages (`index.html` of `simulate` and `reproduce`), rendered in headless
Chromium: every image loads and the tables are there. Skips where Chromium is not installed (.ci/run
installs Debian's `chromium` when missing)."""

from __future__ import annotations

import re
from pathlib import Path
import shutil
import subprocess

import pytest

from lenssim import Camera, Numerics
from lenssim_studies.report import reproduce
from lenssim_studies.sweep import SweepConfig
from lenssim_cli.main import main
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_SENSOR, PAPER_SPECTRUM

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (apt-get install chromium)")


def render(page) -> dict:
    """The page's DOM after load, as Chromium sees it: images loaded / total, tables, text."""
    r = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom", page.as_uri()],
                       capture_output=True, text=True, timeout=120)
    m = re.search(r'<div id="load-check" data-loaded="(-?\d+)" data-total="(-?\d+)" data-tables="(\d+)"', r.stdout)
    assert m, f"the page did not finish loading: {r.stderr[-500:]}"
    return {"loaded": int(m[1]), "total": int(m[2]), "tables": int(m[3]), "dom": r.stdout}


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "out"
    assert main(["simulate", "skimage:camera", "--design", "end_to_end_paper", "--angles", "0", "0.3", "--crop", "48",
                 "--scheme", "128", "32", "64", "--rl", "2", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    cfg = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 7.0, 14.0)), PAPER_SENSOR, PAPER_SPECTRUM),
                      grid={"s": (-1.0, -0.5, 0.25), "Q": (-4.0, 0.0, 1.0)}, numerics=Numerics(min_size=128, oversample=1))
    reproduce(out, cfg, show_progress=False)
    return out


def test_simulate_writes_a_self_contained_page(simulated):
    text = (simulated / "index.html").read_text()
    assert "src=\"data:image/png;base64," in text and "<table>" in text
    assert not re.search(r'src="(?!data:)', text)  # nothing loaded from elsewhere


def test_reproduce_writes_a_self_contained_page(reproduced):
    text = (reproduced / "index.html").read_text()
    assert text.count("data:image/png;base64,") == 4 and "Table 1" in text and "paper&#x27;s claim" in text


@needs_chromium
def test_the_simulate_page_renders_with_every_image(simulated):
    r = render(simulated / "index.html")
    assert r["total"] == 1 + 2 * 4 and r["loaded"] == r["total"]  # mosaic + 2 crops x (ideal, sensor, 2 methods)
    assert r["tables"] == 1 and "Richardson-Lucy" in r["dom"]


@needs_chromium
def test_the_reproduce_page_renders_with_every_image_and_both_tables(reproduced):
    r = render(reproduced / "index.html")
    assert r["total"] == 4 and r["loaded"] == 4 and r["tables"] == 2
    assert "RMS_W optimum" in r["dom"] and "Table 1" in r["dom"]


@pytest.fixture(scope="module")
def traded(tmp_path_factory):
    out = tmp_path_factory.mktemp("trade") / "out"
    lens = Path(__file__).parent / "data" / "lenses" / "test_singlet.toml"
    assert main(["tradeoff", "--lens", str(lens), "--vary", "S1.conic=-1:0:1", "--image", "paraxial", "--pixel-pitch",
                 "5", "--snr", "27.6", "--levels", "3", "--quiet", "--out", str(out)]) == 0
    return out


def test_the_tradeoff_page_is_self_contained(traded):
    text = (traded / "index.html").read_text()
    assert text.count("data:image/png;base64,") == 1 and "<table>" in text
    assert not re.search(r'src="(?!data:)', text)


@needs_chromium
def test_the_tradeoff_page_renders_with_its_figure_and_table(traded):
    r = render(traded / "index.html")
    assert r["total"] == 1 and r["loaded"] == 1 and r["tables"] == 1
    assert "unconstrained optima" in r["dom"] and "S1.conic" in r["dom"]
