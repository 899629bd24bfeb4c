"""The papers' published numbers: *targets* printed beside ours, never results.

``experiments/paper_targets_separation.toml`` holds the separation paper's Figures 10/11/13/15 statistics and
its Tables 3/5 identified values. This module only reads it; nothing computed by the library is in it.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_SEPARATION_TARGETS", "read_targets"]

DEFAULT_SEPARATION_TARGETS = Path(__file__).resolve().parents[2] / "experiments" / "paper_targets_separation.toml"


def read_targets(path: str | os.PathLike | None = None) -> dict[str, Any]:
    """The targets file as a dict (deg / mm as in the paper). ``ValueError`` naming the file when unusable."""
    p = Path(path) if path is not None else DEFAULT_SEPARATION_TARGETS
    if not p.exists():
        raise ValueError(f"targets file {p} does not exist")
    try:
        data = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML: {exc}") from None
    if data.get("schema_version") != 1:
        raise ValueError(f"{p}: unknown schema_version {data.get('schema_version')!r} (this reader knows 1)")
    return data
