"""measure_folder and `twin measure`: an image folder (analytic renders) in, a valid dataset out."""

import json

import cv2
import numpy as np
import pytest

from test_instrument_calibration import LEFT, RIGHT, W2L, W2R, board_pair
from twin.cli import main
from twin.dataset import Joints, default_plate, read_dataset, write_joints_csv
from twin.instrument.calibration import StereoCalibration
from twin.instrument.folder import CALIBRATION_FILE, measure_folder, measure_to_dataset, read_plate_toml, read_rig_toml
from twin.instrument.synthetic import add_sensor_noise, render_spheres
from twin.transforms import make_transform, rotvec_to_matrix

PLATE = default_plate()
RIG_TOML = """schema_version = 1
image_width = 1296
image_height = 972
[board]
type = "charuco"
squares_x = 11
squares_y = 8
square_mm = 18.0
marker_mm = 13.5
dictionary = "DICT_5X5_100"
"""


def _sphere_pair(pos, rotvec, rng):
    Rp = rotvec_to_matrix(np.array([np.pi, 0.0, 0.0])) @ rotvec_to_matrix(np.asarray(rotvec, float))
    t2w = make_transform(Rp, np.asarray(pos, float))
    sph = PLATE.spheres_flange @ Rp.T + t2w[:3, 3]
    il = add_sensor_noise(render_spheres(LEFT, W2L, sph, 0.0127, supersample=2), 2.0, rng)
    ir = add_sensor_noise(render_spheres(RIGHT, W2R, sph, 0.0127, supersample=2), 2.0, rng)
    return il, ir, sph @ W2L[:3, :3].T + W2L[:3, 3]


@pytest.fixture(scope="module")
def image_folder(tmp_path_factory):
    """rig.toml, joints.csv (with station/set/pair), 8 board views, 4 pose pairs: pose 2 has a sphere out
    of frame, pose 3 has no right image."""
    root = tmp_path_factory.mktemp("images")
    (root / "rig.toml").write_text(RIG_TOML)
    (root / "board").mkdir()
    (root / "pairs").mkdir()
    rng = np.random.default_rng(11)
    for k, z in enumerate(np.linspace(0.6, 0.95, 8)):
        il, ir = board_pair(rng, z, 0.55)
        cv2.imwrite(str(root / "board" / f"{k:03d}_left.png"), il)
        cv2.imwrite(str(root / "board" / f"{k:03d}_right.png"), ir)
    poses = [([0.0, 0.0, 0.72], [0.1, 0.0, 0.2]), ([0.01, 0.01, 0.8], [-0.2, 0.1, -0.5]),
             ([0.05, 0.0, 0.7], [0.0, 0.0, 0.0]), ([0.0, 0.0, 0.75], [0.0, 0.0, 0.0])]
    truth = {}
    for pid, (pos, rv) in zip((10, 11, 12, 13), poses):
        il, ir, t = _sphere_pair(pos, rv, rng)
        truth[pid] = t
        cv2.imwrite(str(root / "pairs" / f"{pid}_left.png"), il)
        if pid != 13:
            cv2.imwrite(str(root / "pairs" / f"{pid}_right.png"), ir)
    q = np.deg2rad(np.arange(24, dtype=float).reshape(4, 6))
    write_joints_csv(root / "joints.csv", Joints(np.array([10, 11, 12, 13]), q, station=np.array(["0"] * 4, dtype=object),
                                                 set=np.array(["calibration"] * 3 + ["validation"], dtype=object)))
    # append a pair column (the format allows it)
    lines = (root / "joints.csv").read_text().splitlines()
    lines = [lines[0] + ",pair"] + [l + f",{p}" for l, p in zip(lines[1:], (1, 1, 2, 2))]
    (root / "joints.csv").write_text("\n".join(lines) + "\n")
    return root, truth


@pytest.mark.slow
def test_measure_folder_writes_a_valid_dataset(image_folder, tmp_path):
    """The folder becomes a dataset that reads back: joints, spheres (mm) near the truth, empty cells with
    a status where a sphere was out of frame or an image missing, optional columns carried over."""
    root, truth = image_folder
    out = tmp_path / "ds"
    s = measure_folder(root, out, plate=PLATE)
    assert s.validation_error == "" and s.n_rows == 4
    ds = read_dataset(out)
    assert ds.pose_id.tolist() == [10, 11, 12, 13]
    assert np.allclose(ds.q, np.deg2rad(np.arange(24, dtype=float).reshape(4, 6)), atol=1e-12)
    assert ds.set.tolist() == ["calibration"] * 3 + ["validation"] and ds.pair.tolist() == [1, 1, 2, 2]
    assert ds.sphere_seen[:2].all() and ds.status[0] == "" and ds.status[1] == ""
    # estimated calibration: compare shapes (distances between spheres), free of the frame's definition
    for k in (0, 1):
        d = np.linalg.norm(ds.spheres[k][:, None] - ds.spheres[k][None], axis=2)
        dt = np.linalg.norm(truth[10 + k][:, None] - truth[10 + k][None], axis=2)
        assert np.max(np.abs(d - dt)) < 1e-4
    assert not ds.sphere_seen[2].all() and "out_of_frame" in ds.status[2]
    assert not ds.sphere_seen[3].any() and "image_missing(right)" in ds.status[3]
    assert (out / CALIBRATION_FILE).exists()
    assert "stereo calibration from 8 board views" in ds.provenance


@pytest.mark.slow
def test_measure_folder_reuses_a_saved_calibration(image_folder, tmp_path):
    """A saved stereo_calibration.json is reused (no board views needed) and gives the same centres."""
    root, _ = image_folder
    a = measure_folder(root, tmp_path / "a", plate=PLATE)
    b = measure_folder(root, tmp_path / "b", plate=PLATE, calib=tmp_path / "a" / CALIBRATION_FILE)
    da, db = read_dataset(tmp_path / "a"), read_dataset(tmp_path / "b")
    assert np.array_equal(da.sphere_seen, db.sphere_seen)
    assert np.allclose(da.spheres[da.sphere_seen], db.spheres[db.sphere_seen], atol=1e-9)
    assert isinstance(b.calibration, StereoCalibration) and b.calibration.rms_px == a.calibration.rms_px


@pytest.mark.slow
def test_cli_measure(image_folder, tmp_path, capsys):
    """`twin measure IMAGES --out DATASET` writes the dataset and prints a JSON summary."""
    root, _ = image_folder
    rc = main(["measure", str(root), "--out", str(tmp_path / "ds"), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    summary = json.loads(out[out.index("{"):])
    assert summary["rows"] == 4 and summary["complete_rows"] == 2
    assert read_dataset(tmp_path / "ds").n == 4


def test_cli_measure_missing_folder_is_a_clear_error(tmp_path, capsys):
    """A folder without rig.toml gives exit code 2 and a message naming the file."""
    rc = main(["measure", str(tmp_path), "--out", str(tmp_path / "ds")])
    assert rc == 2 and "rig.toml" in capsys.readouterr().err


def test_rig_toml_validation(tmp_path):
    """rig.toml with an unknown schema or a missing board is refused, naming the file and field."""
    p = tmp_path / "rig.toml"
    p.write_text(RIG_TOML.replace("schema_version = 1", "schema_version = 7"))
    with pytest.raises(ValueError, match="schema_version"):
        read_rig_toml(p)
    p.write_text("schema_version = 1\nimage_width = 10\nimage_height = 10\n")
    with pytest.raises(ValueError, match=r"\[board\]"):
        read_rig_toml(p)
    p.write_text(RIG_TOML)
    assert read_rig_toml(p).board.squares_x == 11


def test_plate_toml_reader(tmp_path):
    """A [plate] table in mm becomes a Plate in metres; a missing table is refused."""
    p = tmp_path / "plate.toml"
    p.write_text("[plate]\nsphere_diameter_mm = 25.4\nspheres_mm = [[60, 0, 50], [-60, 0, 50], [-20.52, 56.38, 50]]\n")
    pl = read_plate_toml(p)
    assert pl.sphere_diameter == pytest.approx(0.0254) and pl.spheres_flange[0, 0] == pytest.approx(0.06)
    p.write_text("x = 1\n")
    with pytest.raises(ValueError, match="plate"):
        read_plate_toml(p)


def test_measure_to_dataset_in_memory_flags_bad_pairs(tmp_path):
    """In-memory pairs (no image files): a missing and a wrongly sized image leave their rows empty with a
    status; the good row is measured; every row keeps its commanded joints."""
    from test_instrument_measure import CAL

    rng = np.random.default_rng(2)
    il, ir, truth = _sphere_pair([0.0, 0.0, 0.72], [0.1, 0.0, 0.2], rng)
    joints = Joints(np.array([1, 2, 3]), np.deg2rad(np.arange(18, dtype=float).reshape(3, 6)))
    pairs = [(il, ir), (il, None), (il, ir[:100])]
    s = measure_to_dataset(tmp_path / "ds", joints, pairs, CAL, PLATE)
    ds = read_dataset(tmp_path / "ds", max_rows_without_spheres=1.0)
    assert s.n_rows == 3 and s.n_complete == 1 and ds.n == 3
    assert ds.sphere_seen[0].all() and np.max(np.linalg.norm(ds.spheres[0] - truth, axis=1)) < 3e-5
    assert ds.status[1] == "p0:image_missing(right);p1:image_missing(right);p2:image_missing(right)"
    assert "image_size(right)" in ds.status[2] and not ds.sphere_seen[1:].any()
    assert np.allclose(ds.q, joints.q, atol=1e-12)
    assert "too many" in s.validation_error or "rows have fewer than three" in s.validation_error


def test_runner_rows_and_folder_rows_come_from_one_writer(tmp_path):
    """The runner's write_measured_dataset and the folder measurement's MeasuredRowsWriter write the same bytes
    for the same rows, and tally the same summary (rows, complete rows, spheres, reasons by kind, times)."""
    from twin.instrument.folder import MeasuredRowsWriter
    from twin.runner.measure import write_measured_dataset
    from twin.runner.store import PoseResult

    rng = np.random.default_rng(3)
    q = rng.uniform(-1, 1, size=(3, 6))
    c = rng.uniform(-0.1, 0.1, size=(3, 3, 3)) + [0, 0, 0.7]
    spheres = [list(c[0]), [c[1, 0], None, c[1, 2]], [None, None, None]]
    status = ["", "p1:epipolar(3.2px)", "p0:not_found;p1:occluded(left);p2:epipolar(12.0px)"]
    cols = {"set": ["calibration", "validation", "validation"], "station": ["front", "left", "front"],
            "pair": [0, 0, -1], "t_s": [0.0, 10.0, 20.0], "temp_c": [20.0, 20.5, 21.0]}
    results = [PoseResult(key=f"m/{k:05d}", pose_id=k + 1, q=q[k], station=cols["station"][k], spheres=spheres[k],
                          status=status[k], timings={"measure_s": 0.01 * (k + 1)}) for k in range(3)]
    runner = write_measured_dataset(tmp_path / "a", results, q, **cols)
    with MeasuredRowsWriter(tmp_path / "b", columns=list(cols)) as w:
        for k in range(3):
            w.write(k + 1, q[k], spheres[k], status[k], time_s=0.01 * (k + 1), **{n: v[k] for n, v in cols.items()})
    assert (tmp_path / "a" / "poses.csv").read_bytes() == (tmp_path / "b" / "poses.csv").read_bytes()
    header = (tmp_path / "a" / "poses.csv").read_text().splitlines()[0].split(",")
    assert header[-6:] == ["set", "station", "pair", "temp_c", "t_s", "status"]
    for tally in (runner, w):
        assert (tally.n_rows, tally.n_complete, tally.n_spheres) == (3, 1, 5)
        assert dict(tally.reasons) == {"epipolar": 2, "not_found": 1, "occluded(left)": 1}
        assert tally.times == [0.01, 0.02, 0.03]


def test_rows_writer_refuses_values_for_other_columns(tmp_path):
    """A row must give a value for exactly the writer's columns (no column silently left empty)."""
    from twin.instrument.folder import MeasuredRowsWriter

    with MeasuredRowsWriter(tmp_path / "ds", columns=["set"]) as w:
        with pytest.raises(ValueError, match="the writer's columns"):
            w.write(1, np.zeros(6), [None] * 3, "p0:not_found;p1:not_found;p2:not_found", station="front")
