"""twin: a digital-twin testbed for kinematic calibration of industrial robots.

Layers (one-way data flow, see docs/architecture.md): world -> instrument -> dataset -> estimator ->
diagnosis -> evaluation. Foundation modules (``transforms``, ``kinematics``, ``robots``, ``camera``)
are pure math and know no truth.

Importing the library changes nothing in its host's environment. A program that renders sets ``MUJOCO_GL=egl``
(and one BLAS thread, for speed) before numpy and mujoco load: :func:`twin.runtime.set_process_defaults` does
both, as the ``twin`` command does.
"""

__version__ = "0.1.0"
