"""The architecture's import rules, beyond the layer contracts that import-linter checks in CI: no import
cycle anywhere (between any two modules of the four packages, function-level imports included), no import back
up the layers inside lenssim (pyproject's contract, checked here on the same graph, so also where import-linter
is not installed), and no value of the paper's scenario reachable from the core packages."""

from __future__ import annotations

import textwrap
import tomllib
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]

PACKAGES = ("lenssim", "pipeline", "lenssim_studies", "lenssim_cli")


@pytest.fixture(scope="module")
def graph():
    return grimp.build_graph(*PACKAGES)


def test_no_import_cycle_between_any_two_modules(graph):
    cycles = []
    for importer in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(importer)):
            if importer.startswith(imported + ".") or imported.startswith(importer + "."):
                continue  # a package and its own modules (an __init__ re-exporting them)
            back = graph.find_shortest_chain(importer=imported, imported=importer)
            if back:
                cycles.append(" -> ".join((importer,) + tuple(back)))
    assert not cycles, "import cycles:\n" + "\n".join(cycles[:10])


def _lenssim_contract() -> dict:
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    (contract,) = [c for c in contracts if c.get("containers") == ["lenssim"]]
    return contract


def _layer(spec: str) -> grimp.Layer:
    """import-linter's notation: ``"a | b"`` independent siblings, ``"a : b"`` siblings that may import each other."""
    sep = "|" if "|" in spec else ":"
    return grimp.Layer(*(t.strip() for t in spec.split(sep)), independent=sep == "|")


def test_no_import_runs_back_up_the_layers_inside_lenssim(graph):
    """utilities <- model <- optics <- criteria <- evaluation (pyproject's contract, the one list of the layers):
    no module imports one of a higher layer, at module or function level, and every module of lenssim is in a
    layer."""
    contract = _lenssim_contract()
    layers = [_layer(spec) for spec in contract["layers"]]
    placed = {f"lenssim.{tail}" for layer in layers for tail in layer.module_tails}
    ignored = {f"lenssim.{m}" for m in contract.get("exhaustive_ignores", [])}
    missing = sorted(graph.find_children("lenssim") - placed - ignored)
    assert not missing, f"modules of lenssim in no layer of the contract: {missing}"
    illegal = graph.find_illegal_dependencies_for_layers(layers, containers={"lenssim"})
    routes = sorted(" -> ".join(("|".join(sorted(r.heads)), *r.middle, "|".join(sorted(r.tails))))
                    for d in illegal for r in d.routes)
    assert not routes, "imports back up the layers:\n" + "\n".join(routes)


def test_the_import_graph_counts_function_level_imports(tmp_path, monkeypatch):
    """What the cycle test and the layer contracts rely on: grimp (and so import-linter) sees an import inside a
    function as an import."""
    pkg = tmp_path / "layers_probe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "low.py").write_text(textwrap.dedent("""
        def f():
            from . import high
            return high
    """))
    (pkg / "high.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    probe = grimp.build_graph("layers_probe", cache_dir=None)
    assert probe.direct_import_exists(importer="layers_probe.low", imported="layers_probe.high")
    assert probe.find_illegal_dependencies_for_layers(["high", "low"], containers={"layers_probe"})


def test_the_core_never_imports_the_paper_scenario(graph):
    for core in ("lenssim", "pipeline"):
        chain = graph.find_shortest_chain(importer=core, imported="lenssim_studies.paper", as_packages=True)
        assert chain is None, f"{core} reaches the paper's scenario: {' -> '.join(chain)}"


def test_the_paper_s_numbers_are_no_defaults_of_the_core():
    """The core's objects have no paper defaults: a Lens, Sensor, Camera and Spectrum must be given their values,
    and the criteria need the SNR and the image model."""
    from lenssim import Camera, Lens, Sensor, Spectrum, evaluate

    for cls in (Lens, Sensor, Camera, Spectrum):
        with pytest.raises(TypeError):
            cls()
    with pytest.raises(TypeError):
        evaluate(None, None)
