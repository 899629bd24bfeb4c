"""Process-wide settings a program that runs the twin chooses before numpy and MuJoCo load.

The library itself never changes its host's environment: importing ``twin`` or any of its modules leaves
``os.environ`` as it was. A program (the ``twin`` command, the test suite, a study's script) sets these
variables itself, before the first ``import numpy`` / ``import mujoco`` of the process, with
:func:`set_process_defaults` or by exporting them:

* ``MUJOCO_GL=egl``: MuJoCo renders off-screen on the CPU through Mesa's EGL; MuJoCo reads it once, when it is
  imported, and without it rendering needs a display (``twin.world``'s images fail with a message saying so).
* ``OPENBLAS_NUM_THREADS=1``, ``OMP_NUM_THREADS=1``, ``MKL_NUM_THREADS=1``: the library solves many small
  linear-algebra problems, where a multi-threaded BLAS only thrashes on a shared two-core machine (a diagnosis
  took 30 s with OpenBLAS threads under load, 5 s single-threaded); BLAS reads them when numpy loads.

A value already set in the environment is kept. Child processes (the campaign's workers) inherit them.

The library starts no thread of its own unless asked: :func:`thread_map` runs independent pieces of numpy work on
``threads`` threads (one by default, as ``twin.diagnosis.diagnose(threads=1)``); the ``twin diagnose`` command asks
for :func:`available_cores`.
"""

from __future__ import annotations

import os
from typing import Callable, MutableMapping, Sequence, TypeVar

_T = TypeVar("_T")
_R = TypeVar("_R")

__all__ = ["PROCESS_DEFAULTS", "available_cores", "set_process_defaults", "thread_map"]

PROCESS_DEFAULTS: dict[str, str] = {
    "MUJOCO_GL": "egl",
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


def set_process_defaults(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Set each of :data:`PROCESS_DEFAULTS` that ``environ`` (default ``os.environ``) lacks; returns the ones set.
    Call it first thing in a program's entry point: the variables act only before numpy and mujoco load."""
    env = os.environ if environ is None else environ
    added = {k: v for k, v in PROCESS_DEFAULTS.items() if k not in env}
    env.update(added)
    return added


def available_cores() -> int:
    """The processor cores this process may run on (its affinity mask where the system has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not every system has affinity masks
        return max(1, os.cpu_count() or 1)


def thread_map(fn: Callable[[_T], _R], items: Sequence[_T], threads: int = 1) -> list[_R]:
    """``[fn(x) for x in items]`` on up to ``threads`` threads, results in the order of ``items``. Worth it where
    ``fn`` spends its time in numpy's array work (which runs outside the interpreter lock) on data the calls only
    read; ``threads <= 1`` (the library's default everywhere) runs them in this thread, one after the other."""
    if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    if threads == 1 or len(items) < 2:
        return [fn(x) for x in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(min(threads, len(items))) as ex:
        return list(ex.map(fn, items))
