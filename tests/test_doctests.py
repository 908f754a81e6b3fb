"""The ``Examples`` sections of the public docstrings run as doctests (numpydoc style)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

PACKAGES = ("lenssim", "pipeline", "lenssim_studies", "lenssim_cli")


def _modules():
    for name in PACKAGES:
        pkg = importlib.import_module(name)
        yield name
        for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{name}."):
            yield info.name


WITH_EXAMPLES = [m for m in _modules() if ">>>" in (importlib.util.find_spec(m).loader.get_source(m) or "")]


def test_some_docstrings_have_examples():
    assert len(WITH_EXAMPLES) >= 2


@pytest.mark.parametrize("module", WITH_EXAMPLES)
def test_examples_run(module):
    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted > 0
