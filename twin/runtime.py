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
"""

from __future__ import annotations

import os
from typing import MutableMapping

__all__ = ["PROCESS_DEFAULTS", "set_process_defaults"]

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
