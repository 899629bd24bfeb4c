"""Resume for real: `twin campaign` (images mode) killed mid-way and run again re-renders only what is missing."""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _shared import built_once

pytestmark = pytest.mark.slow

TINY = """
schema_version = 1
name = "tiny-resume"
seed = 11
methods = []

[world]
robot = "irb1200"
preset = "separation_tables_2_4"
[world.render]
scale = 0.5
[world.board]
views = 8
[[world.stations]]
name = "front"
target_mm = [500, 0, 550]
elevation_deg = 5

[measurement]
mode = "images"

[sampling]
max_tilt_deg = 20
max_roll_deg = 45
margin_px = 40

[[poses]]
name = "calibration"
set = "calibration"
kind = "motion_pairs"
count = 4

[[poses]]
name = "check"
set = "validation"
kind = "motion_pairs"
count = 1
evaluate = ["angle"]

[outputs]
recording = false
figures = false

[execution]
workers = 1
"""


def _twin(*args):
    return [sys.executable, "-m", "twin.cli", "campaign", *args]


def _renders(out: Path) -> int:
    log = out / "work" / "renders.log"
    return sum(1 for line in log.read_text().splitlines() if line.startswith("render ")) if log.exists() else 0


def _env() -> dict:
    return {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """An uninterrupted run of the tiny campaign, once per test session (the tests read it or copy it, never write
    it)."""
    def build(out: Path) -> None:
        cfg = tmp_path_factory.mktemp("tiny") / "tiny.toml"
        cfg.write_text(TINY)
        subprocess.run(_twin(str(cfg), "--out", str(out)), check=True, env=_env(), capture_output=True, timeout=600)

    return built_once(tmp_path_factory, "tiny_resume_campaign", build)


def test_killed_campaign_resumes_with_the_same_dataset(finished, tmp_path):
    """SIGKILL mid-way, run again: only unfinished poses are rendered, and poses.csv equals an uninterrupted run's."""
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    env = _env()
    ref, res = finished, tmp_path / "res"
    n = _renders(ref)
    assert n == 10
    # the same rig calibration (from a previous session): the test is about the poses, not OpenCV's calibration
    (res / "work").mkdir(parents=True)
    shutil.copy(ref / "work" / "stereo_calibration.json", res / "work" / "stereo_calibration.json")

    proc = subprocess.Popen(_twin(str(cfg), "--out", str(res)), env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    poses = res / "work" / "poses"
    deadline = time.time() + 300
    while time.time() < deadline and len(list(poses.glob("*.json"))) < 4:
        assert proc.poll() is None, "the campaign ended before it could be killed"
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)  # the campaign runs in this one process (workers = 1)
    proc.wait(timeout=30)
    finished = len(list(poses.glob("*.json")))
    assert 4 <= finished < n, f"killed too late or too early ({finished} of {n} poses finished)"
    before = _renders(res)

    subprocess.run(_twin(str(cfg), "--out", str(res)), check=True, env=env, capture_output=True, timeout=600)
    assert _renders(res) - before == n - finished
    assert (res / "dataset" / "poses.csv").read_bytes() == (ref / "dataset" / "poses.csv").read_bytes()


def test_resumed_campaign_keeps_the_true_board_views(finished, tmp_path):
    """A finished campaign run again (nothing left to render) writes truth.json with the board poses its stereo
    calibration came from, as the first run wrote them."""
    import json

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    first = json.loads((out / "truth.json").read_text())["board_views"]
    assert len(first) == 8
    subprocess.run(_twin(str(cfg), "--out", str(out)), check=True, env=_env(), capture_output=True, timeout=600)
    assert json.loads((out / "truth.json").read_text())["board_views"] == first
