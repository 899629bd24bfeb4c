"""twin: a digital-twin testbed for kinematic calibration of industrial robots.

Layers (one-way data flow, see docs/architecture.md): world -> instrument -> dataset -> estimator ->
diagnosis -> evaluation. Foundation modules (``transforms``, ``kinematics``, ``robots``, ``camera``)
are pure math and know no truth.
"""

import os as _os

# Offscreen MuJoCo rendering on CPU goes through Mesa's EGL; must be set before mujoco is imported.
_os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
