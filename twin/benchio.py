"""Results files: ``results/benchmark.json`` (one top-level section per area; each benchmark rewrites only its
own), the ``provenance`` block every results file carries, and atomic writes."""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import platform
import re
import shlex
from pathlib import Path
from typing import Any, Sequence

from .files import read_json

__all__ = ["atomic_write_bytes", "atomic_write_text", "update_benchmark_section", "read_benchmark", "machine_info", "provenance", "PROVENANCE_PACKAGES",
           "peak_rss_kb", "alternate_with_commit", "command_line", "machine_free_path"]

DEFAULT_PATH = Path(__file__).resolve().parent.parent / "results" / "benchmark.json"


# the packages whose version can change a figure: results (numerics, rendering, image processing) or times
PROVENANCE_PACKAGES = ("numpy", "scipy", "mujoco", "opencv-python-headless", "rerun-sdk", "yourdfpy", "figaroh", "pin")


def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def _versions() -> dict[str, str | None]:
    from importlib import metadata

    out: dict[str, str | None] = {}
    for name in PROVENANCE_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def machine_info() -> dict[str, Any]:
    """What the figures were measured on: CPU model and count, Python and the versions of the packages that
    can change a result or a time (``PROVENANCE_PACKAGES``), the 1/5/15-minute load average when written."""
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {
        "cpu_count": os.cpu_count(),
        "cpu_model": _cpu_model(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "packages": _versions(),
        "load_average_1_5_15": load,
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def provenance(load_at_start: tuple[float, float, float] | list[float] | None = None) -> dict[str, Any]:
    """The ``provenance`` block every results file carries: :func:`machine_info` at the time of writing,
    plus the load average the run started under (``load_at_start``, from ``os.getloadavg()``) when given.
    Comparisons of results ignore this block."""
    out = machine_info()
    if load_at_start is not None:
        out["load_average_at_start_1_5_15"] = [round(float(x), 2) for x in load_at_start]
    return out


REPOSITORY = Path(__file__).resolve().parent.parent
OUTSIDE = "OUTSIDE"  # stands for the folders of a path outside the repository in a recorded command
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~-])/[^\s'\"=,;:]+")


def machine_free_path(path: str | os.PathLike, *, root: str | os.PathLike = REPOSITORY) -> str:
    """``path`` as a results file may record it: an absolute path inside the repository ``root`` relative to it, one
    outside (a temporary folder, a home) as ``OUTSIDE/<its name>``; a relative path as given."""
    p = str(path)
    if not p.startswith("/"):
        return p
    resolved, base = Path(os.path.normpath(p)), Path(os.path.normpath(str(root)))
    if resolved == base:
        return "."
    if resolved.is_relative_to(base):
        return resolved.relative_to(base).as_posix()
    return f"{OUTSIDE}/{resolved.name}"


def command_line(program: str, args: Sequence[str], *, root: str | os.PathLike = REPOSITORY) -> str:
    """The command that wrote a results file, for its record: ``program`` and the shell-quoted ``args``, every
    absolute path in them (``--out PATH`` or ``--out=PATH``) made machine-free by
    :func:`machine_free_path`, so that no folder of the machine that ran it is committed."""
    def clean(arg: str) -> str:
        return _ABSOLUTE_PATH.sub(lambda m: machine_free_path(m.group(0), root=root), str(arg))

    return " ".join([program] + [shlex.quote(clean(a)) for a in args])


def peak_rss_kb(pid: int) -> int:
    """Peak resident set of a running process [KiB]: ``VmHWM`` of ``/proc/PID/status`` (0 when it has gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError, ValueError):
        pass
    return 0


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, text.encode())


def read_benchmark(path: str | os.PathLike | None = None) -> dict[str, Any]:
    p = Path(path) if path else DEFAULT_PATH
    if not p.exists():
        return {}
    return read_json(p)


def update_benchmark_section(section: str, data: dict[str, Any], path: str | os.PathLike | None = None) -> Path:
    """Replace ``section`` in the benchmark file (other sections untouched), atomically and under a lock."""
    if not section or not isinstance(section, str):
        raise ValueError(f"section must be a non-empty string, got {section!r}")
    p = Path(path) if path else DEFAULT_PATH
    p.parent.mkdir(parents=True, exist_ok=True)
    lock = p.with_suffix(".lock")
    with open(lock, "w") as lf:
        fcntl.flock(lf, fcntl.LOCK_EX)
        current = read_json(p) if p.exists() else {}
        current[section] = {**data, "machine": machine_info()}
        tmp = p.with_suffix(".tmp")
        tmp.write_text(json.dumps(current, indent=2, sort_keys=True) + "\n")
        os.replace(tmp, p)
    try:
        lock.unlink()
    except FileNotFoundError:
        pass
    return p


def alternate_with_commit(rev: str, rounds: int, run, root: Path) -> tuple[str, str, list[dict[str, Any]]]:
    """A before/after of two codes on this machine: ``run(tree, scratch)`` (a dict of figures) for the commit
    ``rev`` of the repository at ``root`` (its files written by ``git archive`` into a temporary folder) and for the
    working tree ``root``, alternating, ``rounds`` times each; ``scratch`` is a fresh empty folder per run. Returns
    the short hashes of ``rev`` and of HEAD and the runs, each ``{"code": <rev's hash or "current">, **figures}``."""
    import subprocess
    import tempfile

    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    git = dict(check=True, capture_output=True, text=True, cwd=root)
    sha = subprocess.run(["git", "rev-parse", "--short", rev], **git).stdout.strip()
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], **git).stdout.strip()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp) / "tree"
        old.mkdir()
        archive = subprocess.run(["git", "archive", sha], check=True, capture_output=True, cwd=root).stdout
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive, check=True)
        for k in range(rounds):
            for code, tree in ((sha, old), ("current", root)):
                scratch = Path(tmp) / f"run_{code}_{k}"
                scratch.mkdir()
                runs.append({"code": code, **run(tree, scratch)})
                print(runs[-1], flush=True)
    return sha, head, runs
