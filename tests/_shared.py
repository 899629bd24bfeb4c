"""What a test session builds once and its test workers share (pytest-xdist runs a module's tests on either worker,
and a module-scoped fixture runs again on each worker, and again each time a worker comes back to the module).

The first worker to ask builds into the session's temporary folder (the parent of every worker's folder); the others
wait for its 'done' marker (a directory made atomically is the lock) and read what it wrote. Nothing outlives the
session: a fresh clone, CI included, builds everything once per run.
"""

from __future__ import annotations

import os
import pickle
import time
from pathlib import Path
from typing import Callable, TypeVar

_T = TypeVar("_T")
WAIT_S = 900.0  # the longest a worker waits for another's build [s]


def session_root(tmp_path_factory) -> Path:
    """The folder the session's workers share: with workers, the parent of each worker's own; alone, the session's."""
    base = tmp_path_factory.getbasetemp()
    root = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared"
    root.mkdir(exist_ok=True)
    return root


def build_if_unclaimed(tmp_path_factory, name: str, build: Callable[[Path], None]) -> bool:
    """Build ``<session root>/<name>`` as :func:`built_once` does when no worker has claimed it yet, and return
    True; return False at once when another worker has (a worker that would wait builds something else instead)."""
    root = session_root(tmp_path_factory)
    try:
        (root / f"{name}.lock").mkdir()
    except FileExistsError:
        return False
    _build(root, name, build)
    return True


def _build(root: Path, name: str, build: Callable[[Path], None]) -> None:
    try:
        build(root / name)
    except BaseException as e:
        (root / f"{name}.failed").write_text(f"{type(e).__name__}: {e}")
        raise
    (root / f"{name}.done").touch()


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None],
               meanwhile: Callable[[], object] | None = None) -> Path:
    """``<session root>/<name>``, written by ``build(path)`` once per test session whichever worker asks first; a
    build that raised raises again, with its message, in every worker that asks. A worker that finds another
    building it first calls ``meanwhile()`` (e.g. builds what the tests will ask for next), then waits."""
    root = session_root(tmp_path_factory)
    out, done, failed, lock = (root / name, root / f"{name}.done", root / f"{name}.failed", root / f"{name}.lock")
    try:
        lock.mkdir()
    except FileExistsError:
        if meanwhile is not None and not done.exists():
            meanwhile()
        t0 = time.time()
        while not done.exists():
            if failed.exists():
                raise RuntimeError(f"building {name} failed in another test worker: {failed.read_text()}")
            if time.time() - t0 > WAIT_S:
                raise TimeoutError(f"waited {WAIT_S:.0f} s for another test worker to build {out}")
            time.sleep(0.2)
        return out
    _build(root, name, build)
    return out


def value_once(tmp_path_factory, name: str, make: Callable[[], _T]) -> _T:
    """``make()``, computed once per test session (pickled for the other workers)."""
    def build(path: Path) -> None:
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(make()))
        tmp.rename(path)

    return pickle.loads(built_once(tmp_path_factory, f"{name}.pkl", build).read_bytes())
