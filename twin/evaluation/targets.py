"""The papers' published numbers: *targets* printed beside ours, never results.

``twin/data/paper_targets_separation.toml`` (package data) holds the separation paper's Figures 10/11/13/15
statistics and its Tables 3/5 identified values; ``twin/data/paper_targets_tmmdh.toml`` the TM-MDH paper's. This
module only reads them; nothing computed by the library is in them.

A target the paper's own text shows to be a slip or synthetic (e.g. the separation paper's Table 5 entries
that are exactly 0.95 x the Table 4 presets) is flagged in an ``[[unscored]]`` entry of the file::

    [[unscored]]
    path = "simulation.table5.d1_mm"     # dotted path into the file; [i] indexes an array (0-based)
    unscored = true
    reason = "exactly 0.95 x the preset ..."

It is still printed (marked), never scored per parameter: :func:`scored_value` returns None for it.
"""

from __future__ import annotations

import os
import re
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, Mapping

from ..files import read_toml
from ..resources import data_file

__all__ = ["DEFAULT_SEPARATION_TARGETS", "DEFAULT_TMMDH_TARGETS", "read_targets", "target_value", "unscored_targets",
           "scored_value"]

DEFAULT_SEPARATION_TARGETS = data_file("paper_targets_separation.toml")
DEFAULT_TMMDH_TARGETS = data_file("paper_targets_tmmdh.toml")

_PART = re.compile(r"^([A-Za-z0-9_']+)((?:\[\d+\])*)$")


def target_value(data: Mapping[str, Any], path: str) -> Any:
    """The entry of a targets dict at a dotted ``path`` (``table6.a[5]``: index 5 of array ``a``).
    ``KeyError`` naming the path when it does not resolve."""
    cur: Any = data
    for part in path.split("."):
        m = _PART.match(part)
        if m is None:
            raise KeyError(f"target path {path!r}: bad component {part!r}")
        try:
            cur = cur[m.group(1)]
            for idx in re.findall(r"\[(\d+)\]", m.group(2)):
                cur = cur[int(idx)]
        except (KeyError, IndexError, TypeError):
            raise KeyError(f"target path {path!r} does not resolve") from None
    return cur


def _check_unscored(data: Mapping[str, Any], p: Path | Traversable) -> None:
    entries = data.get("unscored", [])
    if not isinstance(entries, list):
        raise ValueError(f"{p}: unscored must be an array of tables ([[unscored]])")
    for k, e in enumerate(entries):
        where = f"{p}: unscored[{k}]"
        if not isinstance(e, dict) or set(e) - {"path", "unscored", "reason"}:
            raise ValueError(f"{where}: must be a table with keys path, unscored, reason, got {e!r}")
        if e.get("unscored") is not True:
            raise ValueError(f"{where}: unscored must be true, got {e.get('unscored')!r}")
        if not isinstance(e.get("reason"), str) or not e["reason"].strip():
            raise ValueError(f"{where}: reason must be a non-empty string")
        path = e.get("path")
        if not isinstance(path, str):
            raise ValueError(f"{where}: path must be a string, got {path!r}")
        try:
            v = target_value(data, path)
        except KeyError as exc:
            raise ValueError(f"{where}: {exc.args[0]}") from None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{where}: path {path!r} must name a number, got {v!r}")


def read_targets(path: str | os.PathLike | Traversable | None = None) -> dict[str, Any]:
    """The targets file as a dict (units as in the paper); default the separation paper's (package data).
    ``ValueError`` naming the file when unusable, including an ``[[unscored]]`` entry that is malformed or names
    no number of the file."""
    p = DEFAULT_SEPARATION_TARGETS if path is None else path if isinstance(path, Traversable) else Path(path)
    if not p.is_file():
        raise ValueError(f"targets file {p} does not exist (or is not a file)")
    data = read_toml(p)
    if data.get("schema_version") != 1:
        raise ValueError(f"{p}: unknown schema_version {data.get('schema_version')!r} (this reader knows 1)")
    _check_unscored(data, p)
    return data


def unscored_targets(data: Mapping[str, Any] | None) -> dict[str, str]:
    """Flagged targets of a targets dict: dotted path -> reason (empty when none or ``data`` is None)."""
    if not data:
        return {}
    return {e["path"]: e["reason"] for e in data.get("unscored", [])}


def scored_value(data: Mapping[str, Any], path: str) -> float | None:
    """The number at ``path``, or None when it is flagged unscored (or absent): what a per-parameter score
    may use."""
    if path in unscored_targets(data):
        return None
    try:
        v = target_value(data, path)
    except KeyError:
        return None
    return float(v)
