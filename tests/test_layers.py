"""The architecture's import rules, beyond the layer contract that import-linter checks in CI: no import
cycle anywhere (between any two modules of the four packages, function-level imports included), and no
value of the paper's scenario reachable from the core packages."""

from __future__ import annotations

import grimp
import pytest

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
