"""The library leaves its host's environment alone; the twin command sets the process defaults itself."""

import json
import os
import subprocess
import sys

import pytest

from twin.runtime import PROCESS_DEFAULTS, set_process_defaults

# imported before the snapshot: their own import-time effects are theirs (OpenCV's loader sets LD_LIBRARY_PATH)
THIRD_PARTY = ("numpy", "scipy", "cv2", "mujoco", "matplotlib", "rerun", "rich", "yourdfpy")

_PROBE = """
import importlib, json, os, pkgutil, sys
for name in sys.argv[1].split(","):
    if name:
        importlib.import_module(name)
before = dict(os.environ)
import twin
names = [] if sys.argv[2] == "bare" else sorted(m.name for m in pkgutil.walk_packages(twin.__path__, "twin."))
for name in names:
    importlib.import_module(name)
after = dict(os.environ)
changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
print(json.dumps({"modules": len(names), "changed": changed}))
"""


def _probe(preload: tuple[str, ...], what: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in PROCESS_DEFAULTS and k != "PYOPENGL_PLATFORM"}
    out = subprocess.run([sys.executable, "-c", _PROBE, ",".join(preload), what], env=env, capture_output=True,
                         text=True, timeout=300, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_import_twin_leaves_environ_unchanged():
    """`import twin` in a fresh process (none of the process defaults set) changes no environment variable."""
    assert _probe((), "bare")["changed"] == []


def test_importing_every_module_leaves_environ_unchanged():
    """Importing every module of the package (the world, the renderer and the recording included) sets nothing:
    MUJOCO_GL and the BLAS thread counts stay unset."""
    res = _probe(THIRD_PARTY, "all")
    assert res["modules"] > 50
    assert res["changed"] == []


def test_set_process_defaults_keeps_values_already_set():
    """set_process_defaults fills only the variables the environment lacks, and says which."""
    env = {"MUJOCO_GL": "osmesa", "OMP_NUM_THREADS": "4"}
    added = set_process_defaults(env)
    assert env["MUJOCO_GL"] == "osmesa" and env["OMP_NUM_THREADS"] == "4"
    assert added == {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    assert {k: env[k] for k in added} == added


def test_console_entry_sets_the_defaults_before_running():
    """The installed command's entry point (twin.cli:console) sets MUJOCO_GL=egl and one BLAS thread."""
    code = ("import os, sys\nfrom twin.cli import console\nsys.argv = ['twin', '--version']\n"
            "try:\n    console()\nexcept SystemExit:\n    pass\n"
            "print({k: os.environ.get(k) for k in ('MUJOCO_GL', 'OPENBLAS_NUM_THREADS')})")
    env = {k: v for k, v in os.environ.items() if k not in PROCESS_DEFAULTS}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.splitlines()[0].startswith("twin ")
    assert out.stdout.splitlines()[-1] == str({"MUJOCO_GL": "egl", "OPENBLAS_NUM_THREADS": "1"})


def test_thread_map_keeps_the_order_of_its_items():
    """thread_map on two threads returns fn of each item in the items' order, as the plain loop does."""
    import time

    from twin.runtime import thread_map

    def slow_first(x: int) -> int:  # earlier items finish later: completion order differs from the items' order
        time.sleep(0.002 * (5 - x % 5))
        return x * x

    items = list(range(40))
    assert thread_map(slow_first, items, 2) == [x * x for x in items]
    assert thread_map(slow_first, items, 1) == [x * x for x in items]


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_thread_map_refuses_a_thread_count_that_is_not_a_positive_integer(bad):
    """thread_map names ``threads`` and the value when it is not a positive integer."""
    from twin.runtime import thread_map

    with pytest.raises(ValueError, match=r"threads must be a positive integer, got"):
        thread_map(abs, [1, 2], bad)
