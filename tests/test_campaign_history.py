"""Tests of the campaign's effect contexts: the robot's visit order, the full command history (backlash),
one definition of truth (World.true_pose), and the same numbers with two workers and after a resume."""

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _campaign_helpers import SMALL_TOML, reference_full_pose, small_config  # noqa: E402

from twin.dataset import Joints, read_dataset, write_joints_csv
from twin.runner.campaign import run_campaign, visit_contexts
from twin.runner.config import parse_campaign_config
from twin.runner.measure import PoseTask, TruthNoiseBackend, backend_spec_for
from twin.runner.plan import make_plan, pose_seed
from twin.runner.store import PoseStore
from twin.world import World
from twin.world.effects import contexts_for_sequence

IMPL = {"full_pose": reference_full_pose}
STILL_JOINT = 5  # joint 6 stays still between the two poses of every calibration pair
HALF_CLEARANCE_DEG = 0.05


def _backlash_config(tmp: Path, workers: int = 1):
    """The small campaign with a backlash effect; its calibration rows come from a JOINTS.csv in which joint 6
    does not move between the rows of each pair (the approach direction there is only in the history)."""
    plan = make_plan(small_config())
    rows = plan.rows(set="calibration")
    q = plan.q[rows].copy()
    q[1::2, STILL_JOINT] = q[0::2, STILL_JOINT]
    path = tmp / "calibration_joints.csv"
    if not path.exists():
        write_joints_csv(path, Joints(np.arange(len(q)), q, station=plan.station[rows]))
    raw = tomllib.loads(SMALL_TOML)
    raw["world"]["effects"] = [{"name": "backlash", "half_clearance_deg": [HALF_CLEARANCE_DEG] * 6}]
    raw["poses"] = [
        {"name": "calibration", "set": "calibration", "kind": "joints_csv", "path": str(path)},
        {"name": "compensation", "set": "validation", "kind": "motion_pairs", "count": 3, "evaluate": ["angle"]},
    ]
    raw["execution"] = {"workers": workers}
    return parse_campaign_config(raw)


def _visit_sequence(out: Path, cfg):
    """Commands and stations in the order the robot visits them: the plan, then each method's compensated
    validation rows (read back from the campaign's own outputs), and the keys of the stored poses."""
    plan = make_plan(cfg)
    after = read_dataset(out / "after" / "full_pose")
    q = np.vstack([plan.q, after.q])
    val = plan.rows(set="validation")
    stations = np.concatenate([plan.station, plan.station[val]])
    keys = [f"m/{int(p):05d}" for p in plan.pose_id] + [f"c/full_pose/{int(p):05d}" for p in plan.pose_id[val]]
    return q, stations, keys


def _stored_actual(out: Path, keys) -> np.ndarray:
    store = PoseStore(out / "work" / "poses")
    return np.array([store.read(k).truth["q_actual"] for k in keys])


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("history")
    cfg = _backlash_config(tmp)
    run_campaign(cfg, tmp / "serial", implementations=IMPL)
    return tmp, cfg


def test_backlash_gets_the_whole_visit_order(serial_run):
    """Every pose's actual joints (dataset and compensated) equal World.actual_joints on contexts_for_sequence
    over the robot's visit order, also where joint 6 stayed still (only the history tells its approach)."""
    tmp, cfg = serial_run
    q, stations, keys = _visit_sequence(tmp / "serial", cfg)
    world = World.from_config(cfg.world_config())
    index = {n: k for k, n in enumerate(world.station_names)}
    t_s = np.arange(len(q)) * cfg.measurement.seconds_per_pose
    ctxs = contexts_for_sequence(q, t_s=t_s, stations=[index[s] for s in stations], world=world)
    expected = np.array([world.actual_joints(q[k], ctxs[k]) for k in range(len(q))])
    got = _stored_actual(tmp / "serial", keys)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    # the test can tell: at some still pose a one-command history (start, previous, this) gives the other sign
    b = np.deg2rad(HALF_CLEARANCE_DEG)
    still = [k for k in range(2, 24, 2) if k + 1 < len(q)]
    one_step = [np.sign(q[k, STILL_JOINT]) for k in still]  # 0 -> q[k] -> q[k+1] (joint still): sign of q[k]
    true_sign = [np.sign(q[k, STILL_JOINT] - q[k - 1, STILL_JOINT]) for k in still]
    assert any(a != t for a, t in zip(one_step, true_sign))
    for k, t in zip(still, true_sign):
        assert got[k + 1, STILL_JOINT] == pytest.approx(q[k + 1, STILL_JOINT] - t * b, abs=1e-12)


def test_visit_contexts_continue_the_history_across_phases(serial_run):
    """The compensated poses' contexts extend the dataset's: pose index, time stamp and history run on."""
    _, cfg = serial_run
    plan = make_plan(cfg)
    q2 = np.vstack([plan.q, plan.q[:3] + 0.01])
    st2 = np.concatenate([plan.station, plan.station[:3]])
    c = visit_contexts(cfg, q2, st2)
    assert c[plan.n].pose_index == plan.n and c[plan.n].t_s == plan.n * cfg.measurement.seconds_per_pose
    np.testing.assert_array_equal(c[plan.n].q_cmd_history, plan.q)
    np.testing.assert_array_equal(visit_contexts(cfg, plan.q, plan.station)[5].q_cmd_history, c[5].q_cmd_history)


@pytest.mark.slow
def test_two_workers_and_a_resume_give_the_same_actual_joints(serial_run, monkeypatch):
    """The backlash campaign run on 2 worker processes, and killed then resumed, stores the same actual joints
    and the same measured dataset as the serial run."""
    tmp, cfg = serial_run
    q, stations, keys = _visit_sequence(tmp / "serial", cfg)
    ref = _stored_actual(tmp / "serial", keys)
    run_campaign(_backlash_config(tmp, workers=2), tmp / "two", implementations=IMPL)
    monkeypatch.setenv("TWIN_TEST_KILL_AFTER", "20")
    with pytest.raises(KeyboardInterrupt):
        run_campaign(cfg, tmp / "resumed", implementations=IMPL, backend_factory="_campaign_helpers:CountingBackend")
    monkeypatch.delenv("TWIN_TEST_KILL_AFTER")
    run_campaign(cfg, tmp / "resumed", implementations=IMPL, backend_factory="_campaign_helpers:CountingBackend")
    for name in ("two", "resumed"):
        np.testing.assert_array_equal(_stored_actual(tmp / name, keys), ref, err_msg=name)
        for f in ("dataset/poses.csv", "after/full_pose/poses.csv"):
            assert (tmp / name / f).read_bytes() == (tmp / "serial" / f).read_bytes(), (name, f)


def test_truth_noise_truth_is_the_worlds_true_pose(tmp_path):
    """The truth-noise backend's truth and (noise-free) measurement are World.true_pose's, geometry effects
    included (thermal growth: the spheres on the grown arm, not on the cold one)."""
    raw = tomllib.loads(SMALL_TOML)
    raw["world"]["effects"] = [{"name": "thermal", "source": "profile", "temp_start_c": 20.0, "temp_rise_k": 15.0,
                                "tau_s": 600.0}]
    raw["measurement"]["noise_mm"] = 0.0
    cfg = parse_campaign_config(raw)
    plan = make_plan(cfg)
    backend = TruthNoiseBackend(backend_spec_for(cfg, tmp_path))
    backend.prepare()
    i = 30
    ctx = visit_contexts(cfg, plan.q, plan.station)[i]
    task = PoseTask("m/00030", i, plan.q[i], str(plan.station[i]), pose_seed(cfg.seed, "m/00030"), context=ctx)
    r = backend.measure(task)
    k = backend.station_index[task.station]
    cap = backend.world.true_pose(plan.q[i], k, ctx.with_(world=backend.world), i)
    np.testing.assert_array_equal(r.truth["spheres_meas"], cap.spheres_meas)
    np.testing.assert_array_equal(r.truth["tool2meas"], cap.tool2meas)
    np.testing.assert_array_equal(r.truth["params"], cap.params)
    assert r.truth["temp_c"] == pytest.approx(cap.temp_c) and cap.temp_c > 25.0
    seen = [s is not None for s in r.spheres]
    np.testing.assert_array_equal(np.array([s for s in r.spheres if s is not None]), cap.spheres_meas[seen])
    cold = backend.world.true_spheres_meas(cap.q_actual, k)  # the cold arm: what a hand-built truth gave
    assert np.max(np.abs(cold - cap.spheres_meas)) > 1e-5


def test_task_without_context_uses_its_previous_command_and_a_wrong_context_is_refused(tmp_path):
    """A task without a context (benchmarks measuring single poses) takes q_prev as its one-command history
    (backlash works); a context of another station or command is refused, naming the task."""
    cfg = _backlash_config(tmp_path)
    plan = make_plan(cfg)
    backend = TruthNoiseBackend(backend_spec_for(cfg, tmp_path / "work"))
    backend.prepare()
    world = backend.world
    k = backend.station_index[str(plan.station[1])]
    r = backend.measure(PoseTask("m/00001", 1, plan.q[1], str(plan.station[1]), 5, plan.q[0]))
    ctx = contexts_for_sequence(plan.q[:2], stations=[0, k], t_s=[0.0, 10.0], world=world)[1]
    np.testing.assert_allclose(r.truth["q_actual"], world.actual_joints(plan.q[1], ctx), rtol=0, atol=1e-12)
    ctxs = visit_contexts(cfg, plan.q, plan.station)
    other = next(i for i in range(plan.n) if plan.station[i] != plan.station[1])
    with pytest.raises(ValueError, match="m/00001.*station"):
        backend.measure(PoseTask("m/00001", 1, plan.q[1], str(plan.station[1]), 5, context=ctxs[other]))
    same_station = next(i for i in range(2, plan.n) if plan.station[i] == plan.station[1])
    with pytest.raises(ValueError, match="m/00001.*q_cmd"):
        backend.measure(PoseTask("m/00001", 1, plan.q[1], str(plan.station[1]), 5, context=ctxs[same_station]))
