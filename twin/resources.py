"""The data files inside the package, found through :mod:`importlib.resources` (never through the current folder
or the location of a checkout): the static MJCF models of the twin's scene (the repository's ``models/``, which the
build maps into the package as ``twin.models``) and the papers' published numbers
(``twin/data/paper_targets_*.toml``). They travel with the installed package (the wheel holds them), so ``twin``
runs the same from a checkout (the editable install) and from any folder of an installed copy.

A file a user names (a config, a dataset, a ``joints_csv`` group's ``path``) is never looked up here: such paths
are relative to the file that names them (``docs/formats.md``).
"""

from __future__ import annotations

from importlib.resources import files
from importlib.resources.abc import Traversable

__all__ = ["data_file", "model_file", "model_names"]

_PACKAGE = "twin"
_MODELS_PACKAGE = "twin.models"  # the repository's models/ folder, mapped into the package by pyproject.toml


def data_file(name: str) -> Traversable:
    """The packaged data file ``twin/data/<name>`` (``name`` may hold ``/``-separated folders); its ``str`` is the
    file's path in an installed package. Whether it exists is the reader's to check (:func:`model_file` does)."""
    if not isinstance(name, str) or not name or name.startswith("/") or ".." in name.split("/"):
        raise ValueError(f"name must be a relative path inside twin/data, got {name!r}")
    return files(_PACKAGE).joinpath("data", *name.split("/"))


def model_file(name: str) -> Traversable:
    """The packaged static MJCF model ``name`` (``scene.xml``, ``rig.xml``, ``board.xml``): a bare file name.
    ``FileNotFoundError`` naming the file when the installed package lacks it (a broken install)."""
    if not isinstance(name, str) or "/" in name or "\\" in name:
        raise ValueError(f"name must be the bare file name of a packaged model ({', '.join(model_names())}), got {name!r}")
    t = files(_MODELS_PACKAGE).joinpath(name)
    if not t.is_file():
        raise FileNotFoundError(2, "packaged MJCF model missing (a broken install: reinstall twin)", f"models/{name}")
    return t


def model_names() -> list[str]:
    """The file names of the packaged static MJCF models, sorted."""
    return sorted(t.name for t in files(_MODELS_PACKAGE).iterdir() if t.name.endswith(".xml"))
