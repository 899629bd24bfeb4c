"""Tests of twin.dataset: the dataset folder's reader and writer, and JOINTS.csv."""

import numpy as np
import pytest

from twin.dataset import (
    DatasetError,
    DatasetWriter,
    Joints,
    PoseRow,
    default_plate,
    read_dataset,
    read_joints_csv,
    read_noise_table,
    write_dataset,
    write_dataset_toml,
    write_joints_csv,
)
from twin.transforms import pose6_to_transform
from twin.units import M_PER_MM


def _write_small(folder, rng, n=6, missing=()):
    write_dataset_toml(folder, "irb1200", default_plate(), noise_position=5e-6, provenance="test")
    q = rng.uniform(-1, 1, (n, 6))
    sph = rng.normal(0, 0.2, (n, 3, 3))
    with DatasetWriter(folder, optional=["set", "status", "temp_c"], extra=["operator"]) as w:
        for k in range(n):
            spheres = [None if (k, s) in missing else sph[k, s] for s in range(3)]
            status = ";".join(f"p{s}:occluded" for s in range(3) if (k, s) in missing)
            w.write(PoseRow(k, q[k], spheres, set="calibration" if k % 2 else "validation", status=status,
                            temp_c=20.5 + k, extra={"operator": "ann"}))
    return q, sph


def test_round_trip_keeps_values_masks_and_unknown_columns(tmp_path):
    """Write then read: joints to 1e-12 rad, spheres to 1 nm, missing spheres masked, extra columns kept."""
    rng = np.random.default_rng(0)
    q, sph = _write_small(tmp_path, rng, missing={(2, 1)})
    ds = read_dataset(tmp_path)
    assert ds.n == 6 and ds.robot.name == "irb1200"
    assert np.abs(ds.q - q).max() < 1e-12
    ok = ds.sphere_seen
    assert not ok[2, 1] and ok.sum() == 17
    assert np.abs(ds.spheres[ok] - sph[ok]).max() < 1e-9
    assert ds.extra["operator"].tolist() == ["ann"] * 6
    assert ds.status[2] == "p1:occluded"
    assert ds.noise_position == pytest.approx(5e-6)
    assert np.allclose(ds.plate.spheres_flange, default_plate().spheres_flange)
    out = tmp_path / "copy"
    write_dataset(out, ds)
    assert (out / "poses.csv").read_text() == (tmp_path / "poses.csv").read_text()


def test_pose_columns_round_trip(tmp_path):
    """A 6-DOF pose dataset (the TM-MDH paper's kind) round-trips position to 1 nm and rotation to 1e-12 rad."""
    write_dataset_toml(tmp_path, "brtirus0707a", default_plate())
    rng = np.random.default_rng(1)
    poses = pose6_to_transform(np.concatenate([rng.normal(0, 0.5, (4, 3)), rng.normal(0, 1, (4, 3))], axis=1))
    with DatasetWriter(tmp_path, spheres=False, pose=True) as w:
        for k in range(4):
            w.write(PoseRow(k, np.zeros(6), pose=poses[k]))
    ds = read_dataset(tmp_path)
    assert ds.has_poses and not ds.has_spheres
    assert np.abs(ds.pose[:, :3, 3] - poses[:, :3, 3]).max() < 1e-9
    assert np.abs(ds.pose[:, :3, :3] - poses[:, :3, :3]).max() < 1e-11


def _edit_csv(folder, old, new):
    p = folder / "poses.csv"
    p.write_text(p.read_text().replace(old, new, 1))


def test_non_numeric_joint_names_file_row_and_column(tmp_path):
    """A non-numeric joint value is refused with the file, the row, the pose_id and the column."""
    _write_small(tmp_path, np.random.default_rng(2))
    lines = (tmp_path / "poses.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[2] = "abc"
    lines[3] = ",".join(cells)
    (tmp_path / "poses.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"poses.csv: row 3 \(pose_id 2\), column 'q2': not a number: 'abc'"):
        read_dataset(tmp_path)


@pytest.mark.parametrize("cell,column", [(2, "q2"), (8, "p0_y")])
def test_a_reading_beyond_any_robot_or_instrument_names_file_row_and_column(tmp_path, cell, column):
    """A joint or a coordinate of 1e308 (a typing or export error) is refused with the file, the row, the pose_id, the
    column and the value, not met as an overflow in a fit."""
    _write_small(tmp_path, np.random.default_rng(2))
    lines = (tmp_path / "poses.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[cell] = "1e308"
    lines[3] = ",".join(cells)
    (tmp_path / "poses.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=rf"poses.csv: row 3 \(pose_id 2\), column '{column}': 1e\+308 is beyond any"):
        read_dataset(tmp_path)


def test_a_pose_id_beyond_the_ids_a_dataset_holds_is_named(tmp_path):
    """A pose_id of 20 digits (beyond a 64-bit id) is refused naming the row and the value, not an overflow."""
    _write_small(tmp_path, np.random.default_rng(2))
    lines = (tmp_path / "poses.csv").read_text().splitlines()
    lines[3] = "12345678901234567890" + lines[3][lines[3].index(","):]
    (tmp_path / "poses.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"row 3, column 'pose_id': '12345678901234567890' is beyond the ids"):
        read_dataset(tmp_path)


def test_missing_column_and_unknown_robot_are_refused(tmp_path):
    """A missing q column and an unknown robot name each give an error naming them."""
    _write_small(tmp_path, np.random.default_rng(3))
    _edit_csv(tmp_path, "q5,", "qq5,")
    with pytest.raises(DatasetError, match=r"missing required columns \['q5'\]"):
        read_dataset(tmp_path)
    _edit_csv(tmp_path, "qq5,", "q5,")
    toml = tmp_path / "dataset.toml"
    toml.write_text(toml.read_text().replace('robot = "irb1200"', 'robot = "irb9999"'))
    with pytest.raises(DatasetError, match="unknown robot name 'irb9999'"):
        read_dataset(tmp_path)


def test_too_many_rows_without_three_spheres_is_an_error(tmp_path):
    """When most rows lack a sphere the dataset is refused, pointing at the status column."""
    missing = {(k, 0) for k in range(5)}
    _write_small(tmp_path, np.random.default_rng(4), missing=missing)
    with pytest.raises(DatasetError, match="fewer than three spheres"):
        read_dataset(tmp_path)


def test_bad_set_value_is_refused(tmp_path):
    """A 'set' value outside {calibration, validation} names the row and the value."""
    _write_small(tmp_path, np.random.default_rng(5))
    _edit_csv(tmp_path, "validation", "holdout")
    with pytest.raises(DatasetError, match=r"row 1 \(pose_id 0\), column 'set': 'holdout'"):
        read_dataset(tmp_path)


def test_writer_refuses_nan_sphere_instead_of_writing_it(tmp_path):
    """A NaN centre is never written: the caller must pass None and a status."""
    with DatasetWriter(tmp_path) as w:
        with pytest.raises(ValueError, match="not finite"):
            w.write(PoseRow(0, np.zeros(6), [np.array([np.nan, 0, 0]), None, None]))


def test_inline_robot_table(tmp_path):
    """An inline robot table in dataset.toml builds the same model as the named irb1200."""
    spec = {
        "name": "irb_inline", "convention": "mdh", "beta_joints": [2],
        "theta_deg": [0, -90, 0, 0, 0, 0], "d_mm": [399.1, 0, 0, 351, 0, 82],
        "a_mm": [0, 0, 350, 42, 0, 0], "alpha_deg": [0, -90, 0, -90, 90, -90], "beta_deg": [0.0],
    }
    write_dataset_toml(tmp_path, spec, default_plate())
    with DatasetWriter(tmp_path) as w:
        w.write(PoseRow(0, np.zeros(6), [np.zeros(3)] * 3))
    from twin.robots import irb1200

    ds = read_dataset(tmp_path)
    assert np.allclose(ds.robot.params, irb1200().params)


def test_joints_csv_round_trip(tmp_path):
    """JOINTS.csv keeps ids, joints and the temperature channel in order."""
    j = Joints(np.array([3, 1, 2]), np.deg2rad([[1, 2, 3, 4, 5, 6], [0] * 6, [-10] * 6]), temp_c=np.array([20.0, 21, 22]))
    write_joints_csv(tmp_path / "J.csv", j)
    r = read_joints_csv(tmp_path / "J.csv")
    assert r.pose_id.tolist() == [3, 1, 2]
    assert np.allclose(r.q, j.q) and np.allclose(r.temp_c, j.temp_c)


def test_a_joints_csv_joint_beyond_any_robot_is_named(tmp_path):
    """JOINTS.csv with a joint of 1e308 deg: DatasetError naming the row, the pose_id, the column and the value."""
    j = Joints(np.array([3, 1, 2]), np.deg2rad([[1, 2, 3, 4, 5, 6], [0] * 6, [-10] * 6]))
    write_joints_csv(tmp_path / "J.csv", j)
    p = tmp_path / "J.csv"
    lines = p.read_text().splitlines()
    cells = lines[2].split(",")
    cells[3] = "1e308"
    lines[2] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"row 2 \(pose_id 1\), column '\w+': 1e\+308 is beyond any reading"):
        read_joints_csv(p)


def test_a_joints_csv_pose_id_of_twenty_digits_is_named_beyond_the_ids(tmp_path):
    """JOINTS.csv with a pose_id of 20 digits: DatasetError naming the row, the column and the cell as beyond the ids
    a dataset holds (the same words as poses.csv's reader), not an overflow."""
    write_joints_csv(tmp_path / "J.csv", Joints(np.array([3, 1, 2]), np.zeros((3, 6))))
    lines = (tmp_path / "J.csv").read_text().splitlines()
    lines[2] = "12345678901234567890" + lines[2][lines[2].index(","):]
    (tmp_path / "J.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"J.csv: row 2, column 'pose_id': '12345678901234567890' is beyond the ids"):
        read_joints_csv(tmp_path / "J.csv")


def test_noise_table_reads_si_and_refuses_bad_entries(tmp_path):
    """[noise] gives (m, rad) or None per key; an unknown key or a value that is not positive is refused, named."""
    assert read_noise_table({"position_mm": 0.02, "orientation_rad": 1e-4}, "x") == (0.02 * M_PER_MM, 1e-4)
    assert read_noise_table(None, "x") == (None, None) and read_noise_table({"position_mm": 5}, "x") == (5e-3, None)
    with pytest.raises(DatasetError, match=r"^map.toml: \[noise\]: unknown key\(s\) \['position_m'\]"):
        read_noise_table({"position_m": 0.02}, "map.toml")
    for bad in (0, -1.0, float("nan"), "0.02", True):
        with pytest.raises(DatasetError, match=r"^d.toml: noise.position_mm: must be a positive number"):
            read_noise_table({"position_mm": bad}, "d.toml")


def test_a_noise_beyond_any_instrument_is_refused_naming_the_key():
    """[noise] of 1e308 rad or 2 m (a unit or typing error, whose weights would vanish) is refused, named."""
    with pytest.raises(DatasetError, match=r"^m.toml: noise.orientation_rad: 1e\+308 is beyond any instrument's noise"):
        read_noise_table({"orientation_rad": 1e308}, "m.toml")
    with pytest.raises(DatasetError, match=r"^m.toml: noise.position_mm: 2000.0 is beyond"):
        read_noise_table({"position_mm": 2000.0}, "m.toml")


def test_dataset_refuses_a_bad_noise_value_naming_the_file(tmp_path):
    """A dataset.toml whose [noise] position_mm is not a positive number is refused naming the file and the key."""
    _write_small(tmp_path, np.random.default_rng(1))
    toml = tmp_path / "dataset.toml"
    toml.write_text(toml.read_text().replace("position_mm = 0.005", "position_mm = -0.005"))
    with pytest.raises(DatasetError, match=r"dataset.toml: noise.position_mm: must be a positive number, got -0.005"):
        read_dataset(tmp_path)
