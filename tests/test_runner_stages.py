"""Tests of twin.runner.stages: each stage alone over a CampaignState, and the diagnose stage's verdict."""

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _campaign_helpers import reference_full_pose, small_config  # noqa: E402

from twin.dataset import read_dataset  # noqa: E402
from twin.diagnosis import diagnose as diagnose_dataset  # noqa: E402
from twin.runner import stages  # noqa: E402
from twin.runner.campaign import run_campaign  # noqa: E402
from twin.runner.executor import SerialExecutor  # noqa: E402
from twin.runner.measure import backend_spec_for  # noqa: E402
from twin.runner.outputs import term_side  # noqa: E402
from twin.runner.state import CampaignState, Runtime  # noqa: E402
from twin.runner.store import PoseStore  # noqa: E402

IMPL = {"full_pose": reference_full_pose}


def _diagnosed_config():
    return small_config(diagnosis={"enabled": True})


@pytest.fixture(scope="module")
def stepped(tmp_path_factory):
    """The stages run one by one by hand (the states after each), on the small truth-noise campaign with the
    diagnose stage switched on."""
    cfg = _diagnosed_config()
    out = tmp_path_factory.mktemp("stepped")
    rt = Runtime(SerialExecutor(), backend_spec_for(cfg, out / "work"), PoseStore(out / "work" / "poses"),
                 implementations=IMPL)
    states = {"start": CampaignState(cfg, out)}
    state = states["start"]
    for stage in stages.STAGES:
        state = stage(state, rt)
        states[stage.__name__] = state
    return states


def test_each_stage_fills_its_own_fields(stepped):
    """plan fills the plan, measure the dataset, identify the methods, diagnose the verdict, compensate the
    compensated measurements, evaluate the tables, report the files; none clears an earlier stage's field."""
    s = stepped
    assert s["start"].plan is None and s["plan"].plan.n == 40 and s["plan"].dataset is None
    assert s["measure"].dataset.n == 40 and s["measure"].dataset_sha256 and not s["measure"].methods
    assert list(s["identify"].methods) == ["full_pose"] and s["identify"].diagnosis is None
    assert s["diagnose"].diagnosis is not None and not s["diagnose"].after
    assert set(s["compensate"].after["full_pose"]) == set(s["compensate"].plan.pose_id[s["compensate"].val_rows].tolist())
    assert len(s["evaluate"].tables) == 4 and not s["evaluate"].files
    assert {"results", "table"} <= set(s["report"].files)
    final = s["report"]
    assert final.plan is s["plan"].plan and final.dataset is s["measure"].dataset


def test_diagnose_stage_reports_what_twin_diagnose_says_of_the_dataset(stepped):
    """The stage's verdict is the public twin.diagnosis.diagnose on the written dataset (run again here
    independently): structured, p-value, effects, terms, before and after, in results.json and table.txt."""
    final = stepped["report"]
    res = diagnose_dataset(read_dataset(final.out / "dataset"))
    d = json.loads((final.out / "results.json").read_text())["diagnosis"]
    assert d["structured"] == res.structured and d["p_value"] == pytest.approx(res.p_value, rel=1e-9)
    assert d["effects"] == list(res.effects)
    assert [t["text"] for t in d["terms"]] == [a["text"] for a in res.atoms]
    assert d["before"]["position_mm"]["rms"] == pytest.approx(res.before["position_mm"]["rms"], rel=1e-9)
    assert d["after"]["position_mm"]["rms"] == pytest.approx(res.after["position_mm"]["rms"], rel=1e-9)
    table = (final.out / "table.txt").read_text()
    assert "diagnosis of the dataset" in table and f"p = {res.p_value:.3g}" in table
    assert (final.out / "diagnosis" / "diagnosis.json").exists()


def test_a_stage_runs_alone_from_a_state_built_by_hand(stepped):
    """identify on a hand-made state (the measured dataset, nothing else) gives the same identification as in
    the full sequence: a stage reads only its inputs."""
    s = stepped["measure"]
    cfg = s.cfg
    rt = Runtime(SerialExecutor(), backend_spec_for(cfg, s.out / "work"), PoseStore(s.out / "work" / "poses"),
                 implementations=IMPL)
    bare = CampaignState(cfg, s.out / "alone", dataset=s.dataset, dataset_sha256=s.dataset_sha256)
    alone = stages.identify(bare, rt)
    np.testing.assert_array_equal(alone.methods["full_pose"].robot.params,
                                  stepped["identify"].methods["full_pose"].robot.params)


def test_diagnosis_off_by_default_and_outside_the_fingerprint(tmp_path):
    """Without [diagnosis] the stage does nothing (no results key, no folder); switching it on does not change
    the campaign's fingerprint (it measures nothing), so a measured folder is diagnosed without measuring again."""
    plain, diagnosed = small_config(), _diagnosed_config()
    assert plain.fingerprint() == diagnosed.fingerprint() and not plain.diagnosis.enabled
    run = run_campaign(plain, tmp_path, implementations=IMPL)
    assert "diagnosis" not in run.results and not (tmp_path / "diagnosis").exists()
    again = run_campaign(diagnosed, tmp_path, implementations=IMPL)
    assert again.results["counts"]["measured_in_this_run"] == 0 and "diagnosis" in again.results


def test_bad_diagnosis_table_is_named():
    """An unknown key or an alpha outside (0, 0.5) in [diagnosis] is refused, naming it."""
    with pytest.raises(ValueError, match="diagnosis.alpha"):
        small_config(diagnosis={"enabled": True, "alpha": 0.7})
    with pytest.raises(ValueError, match=r"diagnosis\.enable"):
        small_config(diagnosis={"enable": True})


@pytest.mark.parametrize("term, side", [
    ({"place": "field", "target": "meas_field"}, "instrument"),
    ({"place": "scale", "target": "meas"}, "instrument"),
    ({"place": "joint", "target": "base"}, "instrument"),
    ({"place": "joint", "target": "j2"}, "robot"),
    ({"place": "link", "target": "a3"}, "robot"),
])
def test_term_side_is_the_measurement_side_rule(term, side):
    """Terms on a scale or a field of the measurements, or on a station's frame, are the instrument's; others
    the robot's."""
    assert term_side(term) == side


def test_state_copies_keep_earlier_fields():
    """with_timing returns a copy with the timing added and the given fields replaced, the rest kept."""
    s = CampaignState(small_config(), Path("x"), timings={"a": 1.0})
    t = s.with_timing("b", 2.0, dataset_sha256="abc")
    assert t.timings == {"a": 1.0, "b": 2.0} and t.dataset_sha256 == "abc" and s.timings == {"a": 1.0}
    assert replace(t, plan=None).cfg is s.cfg
