"""twin: a digital-twin testbed for kinematic calibration of industrial robots.

Layers (one-way data flow, see docs/architecture.md): world -> instrument -> dataset -> estimator ->
diagnosis -> evaluation. Foundation modules (``transforms``, ``kinematics``, ``robots``, ``camera``)
are pure math and know no truth.
"""

import os as _os

# Offscreen MuJoCo rendering on CPU goes through Mesa's EGL; must be set before mujoco is imported.
_os.environ.setdefault("MUJOCO_GL", "egl")
# Our linear algebra is many small problems: a multi-threaded BLAS only thrashes on a shared 2-core machine
# (a diagnosis run took 30 s with OpenBLAS threads under load, 5 s single-threaded). Only effective when
# twin is imported before numpy; the Makefile exports the same for tests and runs. Override by setting it.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
