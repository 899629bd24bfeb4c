"""Tests of twin.runner.campaign: a small seeded campaign end to end, resume, and the executors."""

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _campaign_helpers import reference_full_pose, small_config  # noqa: E402

from twin.dataset import read_dataset
from twin.runner.campaign import run_campaign, run_repeats
from twin.evaluation.statistics import aggregate
from twin.runner.executor import SerialExecutor, open_executor, run_tasks, worker_identity

IMPL = {"full_pose": reference_full_pose}
COUNTING = "_campaign_helpers:CountingBackend"


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("small")
    return run_campaign(small_config(), out, implementations=IMPL)


def test_campaign_writes_dataset_truth_and_results(small_run):
    """The run writes a readable dataset (calibration + validation rows), truth.json and results.json."""
    out = small_run.out_dir
    ds = read_dataset(out / "dataset")
    assert ds.n == small_run.results["counts"]["poses"] == 2 * (12 + 4 + 4)
    assert set(ds.set) == {"calibration", "validation"}
    assert (out / "truth.json").exists() and (out / "after" / "full_pose" / "poses.csv").exists()
    res = json.loads((out / "results.json").read_text())
    assert res["schema_version"] == 1 and "full_pose" in res["methods"]
    assert res["paper_targets"]["simulation"]["figure10"]["angle_deg"]["after"]["mean"] == 0.0197


def test_compensation_reduces_the_papers_errors(small_run):
    """With a working identification, the measured angle and moved-distance errors drop after compensation."""
    m = small_run.results["methods"]["full_pose"]["measured"]
    assert m["angle_deg"]["after"]["mean"] < 0.3 * m["angle_deg"]["before"]["mean"]
    assert m["position_mm"]["after"]["mean"] < 0.3 * m["position_mm"]["before"]["mean"]
    truth = small_run.results["methods"]["full_pose"]["truth"]
    assert truth["absolute_aligned_position_mm"]["after"]["mean"] < truth["absolute_aligned_position_mm"]["before"]["mean"]


def test_identified_parameters_are_reported_beside_the_injected_ones(small_run):
    """results.json lists, per parameter, the injected and the identified deviation (Tables 3/5 style)."""
    p = small_run.results["parameters"]["full_pose"]
    assert p["theta2_plus_theta3_deg"]["true"] == pytest.approx(-0.4)
    assert abs(p["theta2_plus_theta3_deg"]["identified"] - (-0.4)) < 0.05
    assert p["a1_mm"]["true"] == pytest.approx(1.0)


def test_unavailable_method_is_reported_not_faked(tmp_path):
    """A method without an implementation is listed as unavailable, with no statistics invented for it."""
    cfg = small_config(methods=["separation"])
    run = run_campaign(cfg, tmp_path, implementations={}, backend_factory=None)
    if "separation" in run.results["methods"]:  # the estimator is installed: then it must have real numbers
        assert run.results["methods"]["separation"]["measured"]["angle_deg"]["after"] is not None
    else:
        assert "separation" in run.results["methods_unavailable"]


def test_other_campaign_in_the_same_folder_is_refused(tmp_path):
    """Resuming into a folder that holds another campaign (different config) raises, naming both."""
    run_campaign(small_config(methods=[]), tmp_path)
    with pytest.raises(ValueError, match="holds another campaign"):
        run_campaign(small_config(methods=[], seed=8), tmp_path)


def test_resume_measures_only_unfinished_poses_and_gives_the_same_dataset(tmp_path, monkeypatch):
    """Killed after 15 poses and resumed, the campaign measures only the rest; poses.csv is byte-identical."""
    cfg = small_config(methods=[])
    ref = run_campaign(cfg, tmp_path / "ref", backend_factory=COUNTING)
    n = ref.results["counts"]["poses"]
    monkeypatch.setenv("TWIN_TEST_KILL_AFTER", "15")
    with pytest.raises(KeyboardInterrupt):
        run_campaign(cfg, tmp_path / "res", backend_factory=COUNTING)
    assert len(list((tmp_path / "res" / "work" / "poses").glob("*.json"))) == 15
    monkeypatch.delenv("TWIN_TEST_KILL_AFTER")
    (tmp_path / "res" / "work" / "count.txt").write_text("0")
    run_campaign(cfg, tmp_path / "res", backend_factory=COUNTING)
    assert int((tmp_path / "res" / "work" / "count.txt").read_text()) == n - 15
    assert (tmp_path / "res" / "dataset" / "poses.csv").read_bytes() == (tmp_path / "ref" / "dataset" / "poses.csv").read_bytes()


def test_run_tasks_returns_in_order_and_propagates_errors():
    """run_tasks keeps item order, calls on_done per item, and re-raises the first error."""
    seen = []
    out = run_tasks(SerialExecutor(), pow, [1, 2, 3], args=(2,), on_done=lambda i, r: seen.append(i))
    assert out == [2, 4, 8] and seen == [1, 2, 3]
    with pytest.raises(ZeroDivisionError):
        run_tasks(SerialExecutor(), divmod, [1, 0], args=(1,))


def test_worker_identity_outside_dask_does_not_import_distributed(monkeypatch):
    """Where distributed is not imported, worker_identity names no Dask worker without importing it."""
    asked = []

    class Recorder:
        @staticmethod
        def find_spec(name, path=None, target=None):
            if name.split(".")[0] == "distributed":
                asked.append(name)
            return None

    monkeypatch.delitem(sys.modules, "distributed", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Recorder()] + sys.meta_path)
    ident = worker_identity()
    assert ident["dask_worker"] is None and ident["pid"] == os.getpid()
    assert asked == [] and "distributed" not in sys.modules


def test_aggregate_gives_mean_and_spread():
    """Aggregation over repeats gives n, mean, sample std, min, max per numeric leaf."""
    agg = aggregate([{"a": {"b": 1.0}}, {"a": {"b": 3.0}}, {"a": {"b": 2.0, "c": "text"}}])
    assert agg["a.b"] == {"n": 3, "mean": 2.0, "std": 1.0, "min": 1.0, "max": 3.0}
    with pytest.raises(ValueError, match="empty"):
        aggregate([])


@pytest.mark.slow
def test_process_pool_gives_the_same_repeats_as_serial(tmp_path):
    """Two seeds on local processes aggregate to exactly what the in-process executor gives."""
    cfg = small_config()
    serial = run_repeats(cfg, tmp_path / "s", [1, 2], SerialExecutor(), implementations=IMPL)
    with open_executor("process", 2) as ex:
        procs = run_repeats(cfg, tmp_path / "p", [1, 2], ex, implementations=IMPL)
    assert serial["statistics"] == procs["statistics"]
    assert {r["worker"]["pid"] for r in procs["per_seed"]}.isdisjoint({os.getpid()})


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_aggregate_and_runs_on_its_workers(tmp_path):
    """A two-worker Dask LocalCluster aggregates to the local executor's results, and the seeds ran on its workers."""
    distributed = pytest.importorskip("distributed")
    cfg = small_config()
    seeds = [1, 2, 3, 4]
    local = run_repeats(cfg, tmp_path / "local", seeds, SerialExecutor(), implementations=IMPL)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        worker_addresses = set(client.scheduler_info()["workers"])
        worker_pids = set(client.run(os.getpid).values())
        with open_executor("dask", address=client) as ex:
            remote = run_repeats(cfg, tmp_path / "dask", seeds, ex, implementations=IMPL)
    assert remote["statistics"] == local["statistics"]
    ran_on = [r["worker"] for r in remote["per_seed"]]
    assert all(w["dask_worker"] in worker_addresses for w in ran_on)
    assert {w["pid"] for w in ran_on} <= worker_pids and os.getpid() not in {w["pid"] for w in ran_on}
    assert len({w["dask_worker"] for w in ran_on}) == 2  # both workers took seeds


def test_a_motion_is_compensated_as_a_whole(tmp_path):
    """When one end of a motion cannot be compensated (joint limit), both ends keep their nominal commands."""
    import dataclasses

    from twin.runner.plan import make_plan
    from twin.runner.store import PoseStore

    cfg = small_config()
    plan = make_plan(cfg)
    val = np.flatnonzero(plan.set == "validation")
    # joint-3 limit just below one end pose's command: that end (and only it) cannot be compensated
    end = val[1]
    limit = plan.q[end, 2] - 1e-4

    def narrow(dataset, seed):
        r = reference_full_pose(dataset, seed)
        q_max = r.robot.q_max.copy()
        q_max[2] = limit
        return dataclasses.replace(r, robot=dataclasses.replace(r.robot, q_max=q_max))

    run = run_campaign(cfg, tmp_path, implementations={"full_pose": narrow})
    failed = set(run.results["compensation_failed"]["full_pose"])
    assert {int(plan.pose_id[val[0]]), int(plan.pose_id[end])} <= failed
    store = PoseStore(tmp_path / "work" / "poses")
    for i in (val[0], end):
        np.testing.assert_array_equal(store.read(f"c/full_pose/{int(plan.pose_id[i]):05d}").q, plan.q[i])
    ok_rows = [i for i in val if int(plan.pose_id[i]) not in failed]
    assert ok_rows and not np.allclose(store.read(f"c/full_pose/{int(plan.pose_id[ok_rows[0]]):05d}").q, plan.q[ok_rows[0]])


def test_identification_is_reused_only_for_the_same_dataset(tmp_path):
    """Saved identifications are reused on resume, but never paired with a different (re-measured) dataset."""
    calls = []

    def counted(dataset, seed):
        calls.append(seed)
        return reference_full_pose(dataset, seed)

    impl = {"full_pose": counted}
    run_campaign(small_config(), tmp_path / "a", implementations=impl)
    assert len(calls) == 1
    run_campaign(small_config(), tmp_path / "a", implementations=impl)  # resume: same dataset, reused
    assert len(calls) == 1
    # a folder holding committed calibrations of another dataset (e.g. a fresh clone re-measuring)
    (tmp_path / "b").mkdir()
    import shutil

    shutil.copytree(tmp_path / "a" / "calibrations", tmp_path / "b" / "calibrations")
    run_campaign(small_config(seed=8), tmp_path / "b", implementations=impl)
    assert len(calls) == 2
    a = json.loads((tmp_path / "a" / "calibrations" / "full_pose.json").read_text())
    b = json.loads((tmp_path / "b" / "calibrations" / "full_pose.json").read_text())
    assert a["dataset_sha256"] != b["dataset_sha256"] and a["robot"]["params"] != b["robot"]["params"]


def test_compensated_pose_is_measured_again_when_its_command_changed(tmp_path):
    """Resumed with another identification, the compensated poses are re-measured at their new commands."""
    cfg = small_config()
    run_campaign(cfg, tmp_path, implementations={"full_pose": lambda ds, seed: reference_full_pose(ds, seed, 8)},
                 backend_factory=COUNTING)
    (tmp_path / "calibrations" / "full_pose.json").unlink()  # e.g. identified again by changed code
    (tmp_path / "work" / "count.txt").write_text("0")
    run = run_campaign(cfg, tmp_path, implementations={"full_pose": lambda ds, seed: reference_full_pose(ds, seed, 1)},
                       backend_factory=COUNTING)
    n_after = len(read_dataset(tmp_path / "after" / "full_pose").q)
    assert int((tmp_path / "work" / "count.txt").read_text()) == n_after > 0
    after = read_dataset(tmp_path / "after" / "full_pose")
    from twin.runner.store import PoseStore

    store = PoseStore(tmp_path / "work" / "poses")
    for pid, q in zip(after.pose_id, after.q):  # the spheres of each row were measured at that row's command
        np.testing.assert_allclose(store.read(f"c/full_pose/{int(pid):05d}").q, q, atol=1e-8)
