"""The built wheel is the whole product: installed with its dependencies at the lock's versions into a clean
virtual environment, it runs `twin --version` and a quick rendered campaign from a folder outside the repository
(the scene's MJCF models and the papers' targets come from the installed package, not from a checkout)."""

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import twin
from twin.runtime import PROCESS_DEFAULTS

ROOT = Path(__file__).resolve().parent.parent

# a small campaign through rendered images: one station, ten board views, quarter resolution with --quick
CONFIG = """\
schema_version = 1
name = "wheel-check"
description = "a small campaign through rendered images, run by the installed wheel outside the repository"
seed = 7
methods = ["separation"]

[world]
robot = "irb1200"
preset = "separation_tables_2_4"

[world.render]
scale = 0.5

[world.board]
views = 10

[[world.stations]]
name = "front"
target_mm = [500, 0, 550]
azimuth_deg = 0
elevation_deg = 5

[sampling]
depth_mm = [600, 800]
max_tilt_deg = 25
margin_px = 40

[[poses]]
name = "calibration"
set = "calibration"
kind = "motion_pairs"
count = 12

[[poses]]
name = "compensation"
set = "validation"
kind = "motion_pairs"
count = 4

[diagnosis]
enabled = false

[outputs]
recording = false
figures = false

[execution]
workers = 1

[quick]
world = { render = { scale = 0.25 } }
poses = { calibration = { count = 10 }, compensation = { count = 3 } }
"""


def _uv() -> str | None:
    pinned = ROOT / ".tools" / "bin" / "uv"  # the project's pinned uv (make install)
    return str(pinned) if pinned.exists() else shutil.which("uv")


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} exited {r.returncode}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def test_wheel_packages_every_subpackage_and_the_models():
    """pyproject.toml names every package folder under twin/ and maps the top-level models/ folder as twin.models."""
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "twin").rglob("__init__.py")}
    assert set(tool["packages"]) == folders | {"twin.models"}
    assert tool["package-dir"] == {"twin.models": "models"}
    assert (ROOT / "models" / "__init__.py").is_file() and "*.xml" in tool["package-data"]["twin.models"]


@pytest.mark.slow
def test_wheel_installs_and_runs_a_campaign_outside_the_repository(tmp_path):
    """uv builds the wheel from the sources alone, installs it into a new venv at the lock's versions, and the
    installed `twin` prints its version and runs `twin campaign CONFIG --quick` in a folder outside the checkout."""
    uv = _uv()
    if uv is None:
        pytest.skip("no uv: make install puts the pinned one in .tools/bin")
    env = {k: v for k, v in os.environ.items() if k not in PROCESS_DEFAULTS and not k.startswith("VIRTUAL_ENV")}
    env["UV_PYTHON_DOWNLOADS"] = "never"
    # the sources only (a copy: the build's scratch folders stay out of the checkout)
    src = tmp_path / "src"
    src.mkdir()
    for f in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / f, src / f)
    for folder in ("twin", "models"):  # models/ is mapped into the package as twin.models by pyproject.toml
        shutil.copytree(ROOT / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    _run([uv, "build", "--wheel", "--out-dir", tmp_path / "dist", src], env=env, timeout=300)
    wheels = list((tmp_path / "dist").glob("twin-*.whl"))
    assert len(wheels) == 1
    # the library's dependencies at the lock's versions, as constraints
    constraints = tmp_path / "constraints.txt"
    _run([uv, "export", "--frozen", "--no-emit-project", "--no-hashes", "--format", "requirements-txt",
          "--output-file", constraints], cwd=ROOT, env=env, timeout=120)
    venv = tmp_path / "venv"
    _run([uv, "venv", venv, "--python", sys.executable], env=env, timeout=120)
    py = venv / "bin" / "python"
    _run([uv, "pip", "install", "--python", py, wheels[0], "--constraint", constraints], env=env, timeout=600)
    # a folder outside the repository, the installed command and nothing of the checkout on the path
    work = tmp_path / "elsewhere"
    work.mkdir()
    assert ROOT not in work.parents
    where = _run([py, "-c", "import twin; print(twin.__file__)"], cwd=work, env=env, timeout=60).stdout.strip()
    assert Path(where).is_relative_to(venv), where
    twin_cmd = venv / "bin" / "twin"
    assert _run([twin_cmd, "--version"], cwd=work, env=env, timeout=60).stdout.strip() == f"twin {twin.__version__}"
    (work / "small.toml").write_text(CONFIG)
    r = _run([twin_cmd, "campaign", "small.toml", "--out", "out", "--quick"], cwd=work, env=env, timeout=600)
    assert "paper targets not read" not in r.stdout + r.stderr
    results = json.loads((work / "out" / "results.json").read_text())
    assert results["paper_targets"]["schema_version"] == 1  # the targets came from the installed package
    rows = (work / "out" / "dataset" / "poses.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * (10 + 3)  # header + the quick plan's motion pairs, all measured
    assert (work / "out" / "table.txt").exists()
