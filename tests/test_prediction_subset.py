"""`twin predict` of a row does not depend on which other rows are in the joints file.

A user predicts a new job list with an extended calibration: each row must get the prediction it gets inside the
campaign's whole file, whether it is alone, in a file that starts later, or in a file with gaps. Checked on the
committed main job (`results/separation`: its extended calibration carries the instrument's terms) and on the
close-loop study's world (`studies/close_loop/close_loop.toml`: a cyclic error, a coupling outside the catalogue
and a link growing with temperature, measured as true centres + noise instead of rendered images, with ``t_s`` and
``temp_c`` recorded), diagnosed, then predicted through the command line."""

from pathlib import Path

import numpy as np
import pytest

from twin.cli import main as twin_main

ROOT = Path(__file__).resolve().parents[1]
COLS = ["pose_id", "q1", "q2", "q3", "q4", "q5", "q6"]


def _write_joints(path: Path, table: dict[str, np.ndarray], rows: np.ndarray) -> Path:
    """A JOINTS.csv of ``rows`` (indices into ``table``'s columns), columns in ``table``'s order."""
    names = list(table)
    lines = [",".join(names)]
    for i in rows:
        lines.append(",".join(str(table[n][i]) for n in names))
    path.write_text("\n".join(lines) + "\n")
    return path


def _predict(cal: Path, joints: Path, out: Path) -> dict[int, np.ndarray]:
    """Run ``twin predict``; per pose_id its predicted sphere centres as read from PRED.csv [mm]."""
    assert twin_main(["predict", str(cal), str(joints), "--out", str(out)]) == 0
    head, *body = out.read_text().splitlines()
    names = head.split(",")
    centre_cols = [k for k, n in enumerate(names) if n.startswith("p") and n[-2:] in ("_x", "_y", "_z")]
    assert centre_cols, f"no sphere-centre columns in {names}"
    return {int(float(r.split(",")[0])): np.array([float(r.split(",")[k]) for k in centre_cols]) for r in body}


def _compare(cal: Path, table: dict[str, np.ndarray], tmp: Path, subsets: dict[str, np.ndarray]) -> None:
    """Every subset's predictions equal the whole file's, row by row (to the file's printed digits)."""
    n = len(table["pose_id"])
    full = _predict(cal, _write_joints(tmp / "all.csv", table, np.arange(n)), tmp / "all_pred.csv")
    for name, rows in subsets.items():
        part = _predict(cal, _write_joints(tmp / f"{name}.csv", table, rows), tmp / f"{name}_pred.csv")
        for pid, p in part.items():
            np.testing.assert_allclose(p, full[pid], rtol=0, atol=1e-6, err_msg=f"{name}: pose_id {pid}")


def _main_job_table() -> dict[str, np.ndarray]:
    import csv

    with open(ROOT / "results/separation/dataset/poses.csv") as f:
        rows = list(csv.DictReader(f))
    out = {c: np.array([r[c] for r in rows]) for c in COLS}
    out["station"] = np.array([r["station"] for r in rows])
    return out


def test_main_job_prediction_of_a_row_alone_equals_its_prediction_in_the_whole_file(tmp_path):
    """The committed main job's extended calibration predicts a row alone, a later-starting file and every 7th
    row exactly as inside its whole campaign file."""
    cal = ROOT / "results/separation/diagnosis/calibration.json"
    table = _main_job_table()
    n = len(table["pose_id"])
    rng = np.random.default_rng(3)
    singles = {f"alone_{i}": np.array([i]) for i in rng.choice(n, 6, replace=False)}
    _compare(cal, table, tmp_path, {**singles, "later_half": np.arange(n // 2, n), "every_7th": np.arange(0, n, 7)})


@pytest.fixture(scope="module")
def close_loop_campaign(tmp_path_factory):
    """The close-loop study's world (no rendering), a plan of 30 visible configurations per station, true centres +
    2 um noise with t_s and temp_c, diagnosed; returns (extended calibration path, joints table, validation rows)."""
    from twin.dataset import write_dataset
    from twin.evaluation.closeloop import plan_poses, synthetic_dataset
    from twin.world import World, load_world_config

    world = World.from_config(load_world_config(str(ROOT / "studies/close_loop/close_loop.toml")))
    plan = plan_poses(world, 30, seed=1)
    ds, _ = synthetic_dataset(world, plan, sigma=2e-6, seed=4, record_temp=True)
    tmp = tmp_path_factory.mktemp("close_loop")
    write_dataset(tmp / "ds", ds)
    assert twin_main(["diagnose", str(tmp / "ds"), "--out", str(tmp / "diag"), "--no-recording"]) == 0
    q_deg = np.degrees(ds.q)
    table = {"pose_id": ds.pose_id}
    table.update({f"q{k + 1}": q_deg[:, k] for k in range(6)})
    table.update({"station": np.asarray(ds.station), "t_s": ds.t_s, "temp_c": ds.temp_c})
    return tmp / "diag" / "calibration.json", table, np.flatnonzero(np.asarray(ds.set) == "validation")


@pytest.mark.slow
def test_close_loop_campaign_has_time_and_temperature_channels(close_loop_campaign):
    """The diagnosed close-loop campaign's extended model keeps a term that reads a per-row channel (the premise of
    the next test: otherwise it would check nothing beyond the geometry)."""
    import json

    cal, _, _ = close_loop_campaign
    effects = json.loads(cal.read_text())["effects"]
    assert any(e.get("family") == "thermal" for e in effects), [e.get("label") for e in effects]


@pytest.mark.slow
def test_close_loop_prediction_of_validation_rows_alone_equals_the_whole_file(close_loop_campaign, tmp_path):
    """The close-loop campaign's extended calibration predicts each validation row alone, the validation rows as a
    file of their own, and a file starting at the campaign's second half, exactly as inside the whole file."""
    cal, table, val = close_loop_campaign
    n = len(table["pose_id"])
    singles = {f"alone_{i}": np.array([i]) for i in val[:: max(1, len(val) // 8)]}
    _compare(cal, table, tmp_path, {**singles, "validation_only": val, "later_half": np.arange(n // 2, n)})
