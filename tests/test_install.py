"""Packaging: a non-editable install (the built wheel) carries the configs and designs and runs from
anywhere; the import layers hold (import-linter)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "lenssim", "pipeline", "lenssim_studies", "lenssim_cli", "configs")


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The project built as a wheel and installed (no dependencies: they are this environment's) into a folder."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info")
    for name in SOURCES:
        p = ROOT / name
        (shutil.copytree(p, src / name, ignore=ignore) if p.is_dir() else shutil.copy(p, src / name))
    pip = [sys.executable, "-m", "pip", "-q", "--disable-pip-version-check"]
    subprocess.run(pip[:4] + ["wheel"] + pip[4:] + ["--no-deps", "--no-build-isolation", str(src), "-w", str(tmp / "dist")],
                   check=True, capture_output=True)
    wheel = next((tmp / "dist").glob("lenssim-*.whl"))
    site = tmp / "site"
    subprocess.run(pip[:4] + ["install"] + pip[4:] + ["--no-deps", "--target", str(site), str(wheel)], check=True,
                   capture_output=True)
    return wheel, site


def _run(site: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site)}
    return subprocess.run([str(site / "bin" / "lenssim"), *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)


def test_the_wheel_carries_the_configs_and_the_command(installed):
    wheel, _ = installed
    names = zipfile.ZipFile(wheel).namelist()
    for cfg in ("paper_grid", "paper_grid_fast", "small_grid", "designs", "lenses/cooke_triplet"):
        assert f"lenssim/configs/{cfg}.toml" in names
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "lenssim = lenssim_cli.main:entry" in entry


def test_the_installed_command_runs_outside_the_repository(installed, tmp_path):
    _, site = installed
    where = subprocess.run([sys.executable, "-c", "import lenssim, lenssim.io.resources as r; print(lenssim.__file__); "
                            "print(r.config_path('paper_grid_fast'))"], cwd=tmp_path, capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(site)}).stdout.split()
    assert where[0].startswith(str(site)) and where[1].startswith(str(site))  # the installed copy, not the repository
    r = _run(site, tmp_path, "reproduce", "--help")
    assert r.returncode == 0 and "paper_grid_fast" in r.stdout
    r = _run(site, tmp_path, "designs")
    assert r.returncode == 0 and "end_to_end_paper" in r.stdout and "mse_s_grid" in r.stdout
    r = _run(site, tmp_path, "evaluate", "--design", "end_to_end_paper", "--snr", "27.6", "--json")
    assert r.returncode == 0, r.stderr
    # the pinned value, to the tolerance of every criterion from the float32 OTF bank (F32_OTF in
    # test_regression_pins.py: float32 FFTs round differently on another CPU, up to 3.1e-7 measured)
    assert json.loads(r.stdout)["mse_r"][0] == pytest.approx(0.03945622863932807, rel=2e-6)
    r = _run(site, tmp_path, "inspect", "paper_singlet", "--json", "--angles", "0")  # a shipped lens, installed
    assert r.returncode == 0 and json.loads(r.stdout)["efl_mm"] == pytest.approx(25.0), r.stderr


def test_import_layers_hold():
    """lenssim never imports pipeline or lenssim_cli; pipeline never imports lenssim_cli; inside lenssim, nothing
    imports back up utilities <- model <- optics <- criteria <- evaluation (pyproject's contracts, all kept)."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("import-linter is not installed (pip install -e '.[test]')")
    r = subprocess.run([exe], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert re.search(r"Contracts: [1-9]\d* kept, 0 broken", r.stdout), r.stdout


def test_example_scripts_end_without_teardown_noise(tmp_path):
    """The example and benchmark scripts end as the console command does (pipeline.io.exit_without_teardown): no
    page of OpenImageIO nanobind "leaked" messages after a run that read and wrote images."""
    script = ROOT / "examples" / "simulate_photo.py"
    r = subprocess.run([sys.executable, str(script), "skimage:camera", "--out", str(tmp_path / "sim")], cwd=tmp_path,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "leaked" not in r.stderr and any((tmp_path / "sim").iterdir())
