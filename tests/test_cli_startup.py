"""`twin --help` builds its parser without importing numpy, scipy, mujoco, cv2 or rerun (the start-up target, <= 0.5 s, is a benchmark)."""

import subprocess
import sys


def test_parser_imports_no_heavy_module():
    """Building the full parser in a fresh interpreter leaves numpy/scipy/mujoco/cv2/rerun unimported."""
    probe = ("import sys, twin.cli; twin.cli.build_parser(); "
             "print(','.join(m for m in ('numpy', 'scipy', 'mujoco', 'cv2', 'rerun') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""


def test_argument_error_is_reported_without_a_traceback():
    """A missing required argument exits 2 with argparse's usage line, no traceback."""
    r = subprocess.run([sys.executable, "-m", "twin.cli", "calibrate"], capture_output=True, text=True)
    assert r.returncode == 2 and "usage: twin calibrate" in r.stderr and "Traceback" not in r.stderr
