"""Tests of the campaign's measurement options (recorded temp_c / t_s, the instrument's bias correction, the
images backend's per-pose noise) and of campaigns with nothing to evaluate after compensation."""

import json
import sys
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _campaign_helpers import SMALL_TOML, reference_full_pose  # noqa: E402

import twin.instrument
from twin.dataset import read_dataset
from twin.runner.campaign import run_campaign, visit_contexts
from twin.runner.config import parse_campaign_config
from twin.runner.measure import ImageBackend, PoseTask, backend_spec_for
from twin.runner.plan import make_plan, pose_seed
from twin.runner.store import PoseStore

IMPL = {"full_pose": reference_full_pose}
THERMAL = [{"name": "thermal", "source": "profile", "temp_start_c": 20.0, "temp_rise_k": 10.0, "tau_s": 300.0}]


def _raw(**measurement):
    raw = tomllib.loads(SMALL_TOML)
    raw["measurement"].update(measurement)
    return raw


def test_record_temp_c_and_t_s_write_the_columns(tmp_path):
    """With record_temp_c / record_t_s on, poses.csv has temp_c and t_s: the world's temperature and the
    time stamp k * seconds_per_pose of each pose in the visit order."""
    raw = _raw(record_temp_c=True, record_t_s=True, seconds_per_pose=7.0)
    raw["world"]["effects"] = THERMAL
    raw["methods"] = []
    cfg = parse_campaign_config(raw)
    run_campaign(cfg, tmp_path)
    ds = read_dataset(tmp_path / "dataset")
    np.testing.assert_allclose(ds.t_s, 7.0 * np.arange(ds.n), rtol=0, atol=1e-6)
    expected_T = 20.0 + 10.0 * (1.0 - np.exp(-ds.t_s / 300.0))
    np.testing.assert_allclose(ds.temp_c, expected_T, rtol=0, atol=1e-6)


def test_temp_c_and_t_s_are_not_recorded_by_default(tmp_path):
    """By default (the papers' instruments) poses.csv has neither a temp_c nor a t_s column."""
    raw = _raw()
    raw["methods"] = []
    run_campaign(parse_campaign_config(raw), tmp_path)
    header = (tmp_path / "dataset" / "poses.csv").read_text().splitlines()[0].split(",")
    assert "temp_c" not in header and "t_s" not in header
    ds = read_dataset(tmp_path / "dataset")
    assert ds.temp_c is None and ds.t_s is None


def test_record_options_are_checked():
    """A non-boolean record option, and bias_correction = false without an instrument, are refused by name."""
    with pytest.raises(ValueError, match="measurement.record_temp_c"):
        parse_campaign_config(_raw(record_temp_c="yes"))
    with pytest.raises(ValueError, match="measurement.bias_correction"):
        parse_campaign_config(_raw(bias_correction=False))  # truth_noise: no instrument
    cfg = parse_campaign_config(_raw(mode="images", bias_correction=False))
    assert cfg.measurement.bias_correction is False and cfg.measurement.record_t_s is False


class _FakePair:
    def __init__(self):
        self.left = self.right = []
        self.centres = [None, None, None]
        self.status = "p0:fake;p1:fake;p2:fake"


@pytest.mark.parametrize("bias_correction", [True, False])
def test_images_backend_passes_bias_correction_and_seeds_noise_publicly(tmp_path, monkeypatch, bias_correction):
    """The images backend hands the config's bias_correction to the instrument's measure_pair, and seeds each
    pair's image noise through World.capture(noise_seed=the pose's seed), never through the world's private
    image counter: the same pose gives the same images whatever was rendered before."""
    raw = _raw(mode="images", bias_correction=bias_correction)
    raw["world"]["render"]["scale"] = 0.15
    cfg = parse_campaign_config(raw)
    backend = ImageBackend(backend_spec_for(cfg, tmp_path))
    backend._calib = SimpleNamespace()  # the stereo calibration is not needed: measure_pair is replaced
    calls = []

    def fake_measure_pair(left, right, calib, plate, **kw):
        calls.append((left.copy(), right.copy(), kw))
        return _FakePair()

    monkeypatch.setattr(twin.instrument, "measure_pair", fake_measure_pair)
    plan = make_plan(cfg)
    ctx = visit_contexts(cfg, plan.q, plan.station)

    def task(i):
        key = f"m/{i:05d}"
        return PoseTask(key, i, plan.q[i], str(plan.station[i]), pose_seed(cfg.seed, key), context=ctx[i])

    counter = backend.world._image_counter
    backend.measure(task(3))
    backend.measure(task(0))
    backend.measure(task(3))
    assert backend.world._image_counter == counter  # the world's private state is not touched
    assert all(c[2] == {"bias_correction": bias_correction} for c in calls)
    np.testing.assert_array_equal(calls[0][0], calls[2][0])
    np.testing.assert_array_equal(calls[0][1], calls[2][1])
    assert not np.array_equal(calls[0][0], calls[1][0])


def _only_calibration_raw():
    raw = tomllib.loads(SMALL_TOML)
    raw["poses"] = raw["poses"][:1]
    return raw


def _no_nan(obj) -> bool:
    if isinstance(obj, dict):
        return all(_no_nan(v) for v in obj.values())
    if isinstance(obj, list):
        return all(_no_nan(v) for v in obj)
    return not (isinstance(obj, float) and not np.isfinite(obj))


def test_campaign_without_validation_rows_reports_absent_statistics(tmp_path):
    """All poses in the calibration set: the campaign finishes; every statistic is None with a reason."""
    run = run_campaign(parse_campaign_config(_only_calibration_raw()), tmp_path, implementations=IMPL)
    assert run.results["counts"]["validation_poses"] == 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert _no_nan(res)
    for source in ("measured", "truth"):
        for unit in ("angle_deg", "position_mm"):
            blk = res["methods"]["full_pose"][source][unit]
            assert blk["before"] is None and blk["after"] is None
            assert "no validation rows" in blk["absent"]["after"]
    assert res["methods"]["full_pose"]["truth"]["absolute_position_mm"]["after"] is None
    assert "absent" in res["methods"]["full_pose"]["truth"]["absolute_position_mm"]
    assert res["parameters"]["full_pose"]  # the identification is still reported
    assert "not computed: angle_deg after: no validation rows" in (tmp_path / "table.txt").read_text()


def test_campaign_whose_compensated_measurements_all_fail_reports_why(tmp_path):
    """Every compensated measurement fails: 'before' statistics stay, 'after' is None with the reason."""
    raw = tomllib.loads(SMALL_TOML)
    raw["outputs"]["figures"] = True  # the figures cope with motions that have no value after compensation
    run = run_campaign(parse_campaign_config(raw), tmp_path, implementations=IMPL,
                       backend_factory="_campaign_helpers:BlindAfterBackend")
    res = json.loads((tmp_path / "results.json").read_text())
    assert _no_nan(res)
    for unit in ("angle_deg", "position_mm"):
        blk = res["methods"]["full_pose"]["measured"][unit]
        assert blk["before"]["mean"] > 0
        assert blk["after"] is None and "every compensated measurement failed" in blk["absent"]["after"]
        assert "improvement_percent" not in blk
    assert run.results["orderings"] == []
    assert (tmp_path / "figure10.png").exists()
    assert PoseStore(tmp_path / "work" / "poses").has("c/full_pose/00024")
