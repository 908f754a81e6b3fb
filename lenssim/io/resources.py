"""The built-in configs and named designs, found through ``importlib.resources`` in any install.

In the repository they live in ``configs/`` (the place to read and copy them from); an install
carries them as the package data ``lenssim.configs``. A config is named by a path, or by the
name of a built-in one (``paper_grid``, ``paper_grid_fast``, ``small_grid``, ...). The shipped lens
prescriptions are in ``configs/lenses/`` (:func:`lenses_dir`, :func:`lens_path`).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["builtin_configs", "config_path", "designs_file", "glasses_file", "lenses_dir", "lens_path"]

_PACKAGE = "lenssim.configs"


def _root() -> Path:
    try:
        return Path(str(resources.files(_PACKAGE)))
    except ModuleNotFoundError:  # a source checkout used without installing: configs/ beside the package
        return Path(__file__).resolve().parents[2] / "configs"  # lenssim/io/resources.py -> the repository


def builtin_configs() -> list[str]:
    """Names of the built-in sweep configs."""
    return sorted(p.stem for p in _root().glob("*.toml") if p.stem not in ("designs", "glasses"))


def config_path(spec: str | Path) -> Path:
    """The sweep config ``spec``: an existing file, else a built-in config of that name (``.toml`` optional)."""
    import os

    from .files import check_input_file

    p = Path(spec)
    if p.is_file():
        return p
    name = p.name[:-5] if p.name.endswith(".toml") else p.name
    builtin = p.parent == Path(".") and name in builtin_configs()
    try:
        os.lstat(p)
        there = not (builtin and p.is_dir())  # a folder named like a built-in config (an output folder) is not it
    except FileNotFoundError:
        there = False
    except (OSError, ValueError):  # a name too long, a path through a file, ...: said in words below
        there = True
    if there:  # a link loop, a dangling link, a folder, a pipe or device: check_input_file says which
        return check_input_file(p, "sweep config")
    if builtin:
        return _root() / f"{name}.toml"
    raise FileNotFoundError(f"sweep config {str(spec)!r} does not exist; built-in configs: {', '.join(builtin_configs())}")


def designs_file() -> Path:
    """The built-in named designs file (``configs/designs.toml``)."""
    return _root() / "designs.toml"


def glasses_file() -> Path:
    """The built-in glass catalogue (``configs/glasses.toml``)."""
    return _root() / "glasses.toml"


def lenses_dir() -> Path:
    """The folder of the shipped lens prescriptions (``configs/lenses/``, one ``NAME.toml`` each)."""
    return _root() / "lenses"


def _lens_names() -> list[str]:
    return sorted(p.stem for p in lenses_dir().glob("*.toml"))


def lens_path(spec: str) -> Path:
    """The shipped lens ``spec`` (a bare name, ``.toml`` optional: ``double_gauss``); ``FileNotFoundError`` in one
    line listing the shipped names otherwise."""
    name = str(spec)
    name = name[:-5] if name.endswith(".toml") else name
    names = _lens_names()
    if name not in names:
        raise FileNotFoundError(f"lens {str(spec)!r} is not a shipped lens; shipped lenses: {', '.join(names) or 'none'} "
                                "(or give a .toml or .zmx file)")
    return lenses_dir() / f"{name}.toml"
