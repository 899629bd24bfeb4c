"""``results/benchmark.json``: one top-level section per area; each benchmark rewrites only its own."""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import platform
from pathlib import Path
from typing import Any

__all__ = ["update_benchmark_section", "read_benchmark", "machine_info"]

DEFAULT_PATH = Path(__file__).resolve().parent.parent / "results" / "benchmark.json"


def machine_info() -> dict[str, Any]:
    """What the figures were measured on."""
    return {
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def read_benchmark(path: str | os.PathLike | None = None) -> dict[str, Any]:
    p = Path(path) if path else DEFAULT_PATH
    if not p.exists():
        return {}
    return json.loads(p.read_text())


def update_benchmark_section(section: str, data: dict[str, Any], path: str | os.PathLike | None = None) -> Path:
    """Replace ``section`` in the benchmark file (other sections untouched), atomically and under a lock."""
    if not section or not isinstance(section, str):
        raise ValueError(f"section must be a non-empty string, got {section!r}")
    p = Path(path) if path else DEFAULT_PATH
    p.parent.mkdir(parents=True, exist_ok=True)
    lock = p.with_suffix(".lock")
    with open(lock, "w") as lf:
        fcntl.flock(lf, fcntl.LOCK_EX)
        current = json.loads(p.read_text()) if p.exists() else {}
        current[section] = {**data, "machine": machine_info()}
        tmp = p.with_suffix(".tmp")
        tmp.write_text(json.dumps(current, indent=2, sort_keys=True) + "\n")
        os.replace(tmp, p)
    try:
        lock.unlink()
    except FileNotFoundError:
        pass
    return p
