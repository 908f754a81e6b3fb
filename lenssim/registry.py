"""Registries (name -> entry) and the plug-in packages that fill them: one mechanism for the design criteria
(:mod:`lenssim.criteria`) and the restoration methods (:mod:`pipeline.restoration`)."""

from __future__ import annotations

import importlib
import pkgutil

__all__ = ["Registry", "import_plugins"]


class Registry(dict):
    """A ``dict`` of entries by their ``name``; ``noun`` names an entry in messages (e.g. ``"criterion"``)."""

    def __init__(self, noun: str):
        super().__init__()
        self.noun = noun

    def register(self, entry):
        """Add ``entry`` under ``entry.name`` (a name may be registered once); returns it."""
        if entry.name in self:
            raise ValueError(f"{self.noun} {entry.name!r} is registered already")
        self[entry.name] = entry
        return entry

    def validate(self, name: str):
        """The entry ``name``; ``ValueError`` listing the valid names otherwise."""
        if name not in self:
            from .validate import listed, quoted

            raise ValueError(f"{self.noun} {quoted(name)} is not known; valid: {listed(self, near=[name])}")
        return self[name]


def import_plugins(package: str, path, first=()) -> None:
    """Import every module of ``package`` (its ``__path__``): those of ``first`` in that order, then the others
    by name (a module whose name starts with ``_`` is not a plug-in)."""
    for name in first:
        importlib.import_module(f"{package}.{name}")
    for info in sorted(pkgutil.iter_modules(path), key=lambda i: i.name):
        if info.name not in first and not info.name.startswith("_"):
            importlib.import_module(f"{package}.{info.name}")
