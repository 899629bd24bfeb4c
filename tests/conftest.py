"""The test process is a program that runs the twin: it sets the process defaults (off-screen rendering through
EGL, one BLAS thread) before any test module imports numpy or mujoco, as the ``twin`` command does."""

from twin.runtime import set_process_defaults

set_process_defaults()
