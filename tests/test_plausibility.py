"""Refusing what cannot be right: the usual mistakes on a valid dataset, through `twin calibrate`."""

import csv
import json

import numpy as np
import pytest

from twin.cli import main
from twin.dataset import read_dataset
from twin.estimator.plausibility import ImplausibleData, check_joints, check_plate_rows

from _estimator_helpers import write_clean_dataset

Q_COLS = [f"q{j}" for j in range(1, 7)]
P_COLS = [f"p{s}_{c}" for s in range(3) for c in "xyz"]


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """A valid 120-row dataset with calibration and validation rows, written by the library."""
    return write_clean_dataset(tmp_path_factory.mktemp("plaus") / "ds", 120, seed=11)


def _edit(src, dst, fn):
    """Copy the dataset folder, rewriting poses.csv row by row with fn(row_index, row_dict)."""
    dst.mkdir(parents=True)
    (dst / "dataset.toml").write_text((src / "dataset.toml").read_text())
    rows = list(csv.DictReader(open(src / "poses.csv", newline="")))
    for k, r in enumerate(rows):
        fn(k, r)
    with open(dst / "poses.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return dst


def test_joints_written_in_radians_are_refused(clean, tmp_path, capsys):
    """Radians in the degree columns: exit 2, 'joints look like radians', no calibration written."""
    def rad(k, r):
        for c in Q_COLS:
            r[c] = repr(float(r[c]) * np.pi / 180)

    ds = _edit(clean, tmp_path / "rad", rad)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet"]) == 2
    assert "joints look like radians" in capsys.readouterr().err
    assert not (tmp_path / "cal" / "calibration.json").exists()


def test_sphere_centres_in_metres_are_refused(clean, tmp_path, capsys):
    """Metres in the millimetre columns: exit 2, the distance ratio and 'positions in metres?' named."""
    def metres(k, r):
        for c in P_COLS:
            r[c] = repr(float(r[c]) / 1000)

    ds = _edit(clean, tmp_path / "m", metres)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "positions in metres?" in err and "0.001x the plate's" in err
    assert not (tmp_path / "cal").exists()


def test_force_writes_a_marked_calibration(clean, tmp_path):
    """--force writes the calibration anyway and marks it as forced, with the reason."""
    def rad(k, r):
        for c in Q_COLS:
            r[c] = repr(float(r[c]) * np.pi / 180)

    ds = _edit(clean, tmp_path / "rad", rad)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet", "--force"]) == 0
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert any("radians" in f for f in d["details"]["plausibility"]["forced"])


def test_swapped_labels_in_a_validation_row_are_relabelled(clean, tmp_path):
    """Spheres 0 and 2 swapped in one validation row: the row is relabelled, reported, and the validation
    statistics stay those of the clean data."""
    target = 7  # a validation row (every 4th)

    def swap(k, r):
        if k == target:
            for c in "xyz":
                r[f"p0_{c}"], r[f"p2_{c}"] = r[f"p2_{c}"], r[f"p0_{c}"]

    ds = _edit(clean, tmp_path / "swap", swap)
    assert main(["calibrate", str(clean), "--out", str(tmp_path / "ref"), "--quiet"]) == 0
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet"]) == 0
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    ref = json.loads((tmp_path / "ref" / "calibration.json").read_text())
    pid = int(read_dataset(clean).pose_id[target])
    assert d["details"]["plausibility"]["plate"]["relabelled"] == [pid]
    v, v0 = d["residuals"]["validation"]["position_mm"], ref["residuals"]["validation"]["position_mm"]
    assert v["max"] == pytest.approx(v0["max"], rel=1e-6)


def test_a_row_the_instrument_could_not_have_measured_is_left_out(clean, tmp_path):
    """One sphere 2 mm off in one validation row: flagged with its reason and not in the statistics."""
    target = 11

    def off(k, r):
        if k == target:
            r["p1_x"] = repr(float(r["p1_x"]) + 2.0)

    ds = _edit(clean, tmp_path / "off", off)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet"]) == 0
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    pid = int(read_dataset(clean).pose_id[target])
    assert list(d["details"]["plausibility"]["plate"]["flagged"]) == [str(pid)]
    assert pid not in d["rows"]["validation"]
    assert d["residuals"]["validation"]["position_mm"]["max"] < 0.1


def test_check_plate_rows_leaves_a_clean_dataset_alone(clean):
    """No relabelling, no flag, distance ratio 1 on clean data."""
    pc = check_plate_rows(read_dataset(clean))
    assert pc.relabelled == () and pc.flagged == {} and pc.distance_ratio == pytest.approx(1.0, abs=1e-4)


def test_joints_outside_the_limits_are_reported(clean):
    """A joint beyond its limit is named with the rows it occurs in."""
    from dataclasses import replace

    ds = read_dataset(clean)
    q = ds.q.copy()
    q[3, 1] = ds.robot.q_max[1] + 0.1
    notes = check_joints(replace(ds, q=q))
    assert len(notes) == 1 and notes[0].startswith("q2 outside")


def test_implausible_data_is_a_value_error():
    """The CLI's named-error path catches it (it is a ValueError)."""
    assert issubclass(ImplausibleData, ValueError)


def test_rows_of_two_stations_without_their_station_column_are_refused(tmp_path, capsys):
    """Two camera stations' rows with the station column dropped: the calibrated model misses a third of its rows
    by a large fraction of the campaign's motion (whatever the outlier rule left out), refused with the cause named."""
    from test_cli_estimator import _hand_dataset

    _hand_dataset(tmp_path / "h", np.random.default_rng(21), n=40)
    rows = list(csv.DictReader(open(tmp_path / "h" / "poses.csv", newline="")))
    fields = [f for f in rows[0] if f != "station"]
    with open(tmp_path / "h" / "poses.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    assert main(["calibrate", str(tmp_path / "h"), "--out", str(tmp_path / "cal"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "the model cannot fit these data" in err and "without their 'station' column" in err
    assert not (tmp_path / "cal").exists()


def test_swapped_joint_columns_are_still_refused(clean, tmp_path, capsys):
    """q2 and q3 swapped in every row: the calibrated model misses its rows by a large part of their motion; exit 2
    naming the likely cause, nothing written."""
    def swap(k, r):
        r["q2"], r["q3"] = r["q3"], r["q2"]

    ds = _edit(clean, tmp_path / "swap23", swap)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "the model cannot fit these data" in err and "joint columns swapped" in err
    assert not (tmp_path / "cal").exists()


def test_a_robot_with_errors_beyond_its_geometry_calibrates_without_force(tmp_path, capsys):
    """An IRB-1200 whose joints err by a function of the joints, 0.01 mm stated noise: the residual is about 70x the
    noise; `twin calibrate` writes the calibration (exit 0, not forced), says so on stdout and in
    details.beyond_geometry, and points to `twin diagnose`."""
    from dataclasses import replace

    from twin.dataset import write_dataset
    from twin.estimator.simulate import random_configurations, simulate_dataset
    from twin.robots import get_robot

    from _estimator_helpers import camera_base, random_truth

    rng = np.random.default_rng(31)
    truth = random_truth("irb1200", rng)
    q = random_configurations(get_robot("irb1200"), 120, rng)
    q_actual = q + np.deg2rad(0.12) * np.sin(2 * q) + np.deg2rad(0.08) * np.cos(q[:, [1]])
    sets = np.array((["calibration"] * 3 + ["validation"]) * 30, dtype=object)
    ds, _ = simulate_dataset(truth, q_actual, robot_spec="irb1200", base2meas={"0": camera_base(rng)},
                             noise_position=1e-5, rng=rng, set_=sets)
    write_dataset(tmp_path / "ds", replace(ds, q=q))
    assert main(["calibrate", str(tmp_path / "ds"), "--out", str(tmp_path / "cal")]) == 0
    out = capsys.readouterr().out
    assert "the robot has errors the geometric model lacks" in out and "twin diagnose" in out
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert d["details"]["beyond_geometry"]["detected"] and d["details"]["beyond_geometry"]["residual_scale"] > 50
    assert d["details"]["plausibility"]["forced"] == []


def test_a_clean_calibration_says_nothing_is_beyond_its_geometry(clean, tmp_path, capsys):
    """Clean simulated data: details.beyond_geometry.detected is false and stdout has no such note."""
    assert main(["calibrate", str(clean), "--out", str(tmp_path / "cal")]) == 0
    assert "errors the geometric model lacks" not in capsys.readouterr().out
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    bg = d["details"]["beyond_geometry"]
    assert bg["detected"] is False and bg["residual_scale"] < 2 and bg["miss_fraction_of_motion"] < 1e-3


def test_the_reach_is_climbed_to_the_limits_of_the_joints():
    """A chain whose farthest reach needs three slides fully out at once (a telescope): tool_reach finds it to 0.1 %
    (uniform draws seldom take every joint to its limit together and fall short by a per cent or more)."""
    from twin.robots import robot_from_joint_table
    from twin.estimator.plausibility import tool_reach

    slide = {"type": "prismatic", "xyz_mm": [0, 0, 0], "rpy_deg": [0, 0, 0], "axis": [1, 0, 0], "limits": [0, 500]}
    r = robot_from_joint_table({"name": "telescope", "joints": [
        {"name": "turn", "type": "revolute", "xyz_mm": [0, 0, 0], "rpy_deg": [0, 0, 0], "axis": [0, 0, 1],
         "limits": [-170, 170]}] + [{"name": f"slide{k}", **slide} for k in range(3)],
        "end": {"xyz_mm": [200, 0, 0], "rpy_deg": [0, 0, 0]}})
    assert tool_reach(r)[1] == pytest.approx(1.7, rel=1e-3)
    assert tool_reach(r, refine=0)[1] < 0.99 * 1.7


def test_radians_in_degree_columns_are_warned_on_drawn_robots_and_their_degrees_are_not():
    """On drawn robots (4 to 8 joints, a prismatic one on some, limits from +-90 to +-360 deg, 1 to 30 rows), postures
    written in radians with a joint beyond pi rad at a drawn joint are warned naming the largest joint; the same postures
    in degrees are not warned."""
    from twin.estimator.plausibility import radians_warning

    rng = np.random.default_rng(11)
    for _ in range(60):
        N = int(rng.integers(4, 9))
        pris = np.zeros(N, bool)
        if rng.random() < 0.3:
            pris[rng.integers(N)] = True
        half = np.radians(rng.uniform(90.0, 360.0, N))
        q_min, q_max = np.where(pris, -0.5, -half), np.where(pris, 0.5, half)
        n = int(rng.integers(1, 31))
        q = rng.uniform(q_min, q_max, (n, N))  # [rad, m]: the robot's postures
        j = int(rng.choice(np.flatnonzero(~pris & (half > np.pi + 0.1))) if np.any(~pris & (half > np.pi + 0.1))
                else -1)
        if j < 0:
            continue
        q[rng.integers(n), j] = rng.uniform(np.pi + 0.05, half[j]) * rng.choice([-1.0, 1.0])
        names = [f"j{k}" for k in range(N)]
        read = np.where(pris, q, np.radians(q))  # radians written where degrees belong, read as degrees
        words = radians_warning(read, pris, q_min=q_min, q_max=q_max, joint_names=names)
        big = int(np.argmax(np.where(pris, 0.0, np.abs(q)).max(axis=0)))  # the warning names the largest joint
        assert "radians written in the degree columns?" in words and f"({names[big]} reads" in words, words
        assert radians_warning(q, pris, q_min=q_min, q_max=q_max, joint_names=names) == ""
