"""Truth file, image folder and the `twin render` command."""

import json
import tomllib

import numpy as np
import pytest

import cv2

from twin.dataset import read_joints_csv
from twin.kinematics import tool2meas
from twin.transforms import invert_transform
from twin.world import World
from twin.world.truth import write_truth

SMALL = {"render": {"scale": 0.25}, "board": {"texture_px_per_square": 64, "views": 2},
         "preset": "separation_tables_2_4", "seed": 4}


@pytest.fixture(scope="module")
def world():
    w = World.from_config(SMALL)
    yield w
    w.close()


def test_truth_file_round_trips_and_is_consistent(world, tmp_path):
    """truth.json holds the true model, stations and per-pose truth; spheres agree with FK of the true model."""
    q = world.visible_configurations(2, 2, seed=0)
    caps = [world.capture(qq, 2, pose_id=100 + k) for k, qq in enumerate(q)]
    path = world.write_truth(tmp_path / "truth.json", caps)
    t = json.loads(path.read_text())
    assert t["schema_version"] == 1
    names = t["robot"]["parameter_names"]
    assert names == list(world.true_robot.layout.names) and len(t["robot"]["true"]) == len(names)
    st = t["stations"][2]
    b2m = np.array(st["base2meas"])
    model = world.true_robot.with_params(np.array(t["robot"]["true"])).with_frames(base2meas=b2m)
    for row, cap in zip(t["poses"], caps):
        assert row["pose_id"] == cap.pose_id and row["station"] == 2
        T = tool2meas(model, np.array(row["q_actual_rad"]))[0]
        sph = np.array(t["plate"]["spheres_tool_m"]) @ T[:3, :3].T + T[:3, 3]
        assert np.max(np.abs(sph - np.array(row["spheres_meas_m"]))) < 1e-12
    # the measurement frame is the left camera: base2meas = inv(left_cam2world) @ base2world
    expect = invert_transform(np.array(st["left_cam2world"])) @ np.array(t["base2world"])
    assert np.allclose(b2m, expect, atol=1e-12)


def test_true_plate_differs_from_nominal_by_a_small_error(world):
    """The true plate carries a seeded manufacturing error of the configured size inside tool2flange."""
    err = world.true_robot.tool2flange
    assert 0 < np.linalg.norm(err[:3, 3]) < 0.5e-3
    assert np.allclose(world.nominal_robot.tool2flange, np.eye(4))


def test_truth_writer_refuses_nan(tmp_path):
    """A truth dict with a NaN is refused, naming where."""
    with pytest.raises(ValueError, match="poses"):
        write_truth(tmp_path / "t.json", {"schema_version": 1, "poses": [{"x": float("nan")}]})


def test_image_folder_layout(world, tmp_path):
    """write_image_folder produces rig.toml, joints.csv and PNG pairs/board views the instrument can read."""
    q = world.visible_configurations(0, 2, seed=1)
    summary = world.write_image_folder(tmp_path / "img", q, [0, "front"], pose_ids=[7, 9], board_views=2)
    assert summary["pairs"] == 2 and summary["board_views"] == 2
    rig = tomllib.loads((tmp_path / "img" / "rig.toml").read_text())
    assert rig["schema_version"] == 1 and rig["board"]["squares_x"] == 11 and rig["board"]["square_mm"] == 18.0
    assert "fx" not in json.dumps(rig) and "dist" not in json.dumps(rig)
    joints = read_joints_csv(tmp_path / "img" / "joints.csv")
    assert joints.pose_id.tolist() == [7, 9]
    assert np.allclose(joints.q, q, atol=1e-11)
    for name in ("pairs/7_left.png", "pairs/9_right.png", "board/000_left.png", "board/001_right.png"):
        img = cv2.imread(str(tmp_path / "img" / name), cv2.IMREAD_UNCHANGED)
        assert img.shape == (rig["image_height"], rig["image_width"]) and img.dtype == np.uint8


def test_unknown_station_is_refused(world, tmp_path):
    """A station name the config does not have is an error naming it."""
    with pytest.raises(ValueError, match="nowhere"):
        world.write_image_folder(tmp_path / "x", np.zeros((1, 6)), ["nowhere"], board_views=0)


@pytest.mark.slow
def test_render_command_end_to_end(tmp_path):
    """`twin render` writes the image folder, the truth file and a standalone MJCF."""
    from twin.cli import main

    cfg = tmp_path / "w.toml"
    cfg.write_text('[world]\nseed = 2\n[world.render]\nscale = 0.25\n[world.board]\ntexture_px_per_square = 64\n')
    rc = main(["render", str(cfg), "--out", str(tmp_path / "out"), "--per-station", "1", "--board-views", "2", "--quiet"])
    assert rc == 0
    out = tmp_path / "out"
    assert (out / "truth.json").exists() and (out / "mjcf" / "twin.xml").exists()
    assert len(list((out / "images" / "pairs").glob("*_left.png"))) == 4
    t = json.loads((out / "truth.json").read_text())
    assert len(t["poses"]) == 4 and len(t["board_views"]) == 2


def test_render_command_reports_a_bad_config(tmp_path, capsys):
    """A config error ends the command with exit code 2 and a message naming the field."""
    from twin.cli import main

    cfg = tmp_path / "w.toml"
    cfg.write_text("[world]\nrobot = 'r2d2'\n")
    assert main(["render", str(cfg), "--out", str(tmp_path / "o")]) == 2
    assert "r2d2" in capsys.readouterr().err


@pytest.mark.slow
def test_render_command_with_given_joints(world, tmp_path):
    """`twin render --joints` renders the given configurations at the named stations, with their t_s/temp_c."""
    from twin.cli import main
    from twin.dataset import Joints, write_joints_csv

    q = np.concatenate([world.visible_configurations(0, 1, seed=3), world.visible_configurations(3, 1, seed=3)])
    write_joints_csv(tmp_path / "J.csv", Joints(pose_id=np.array([5, 6]), q=q, temp_c=np.array([21.0, 22.5]),
                                                t_s=np.array([0.0, 60.0]), station=np.array(["front", "3"], dtype=object)))
    cfg = tmp_path / "w.toml"
    cfg.write_text('[world]\nseed = 4\npreset = "separation_tables_2_4"\n[world.render]\nscale = 0.25\n'
                   '[world.board]\ntexture_px_per_square = 64\n')
    rc = main(["render", str(cfg), "--out", str(tmp_path / "out"), "--joints", str(tmp_path / "J.csv"),
               "--board-views", "0", "--quiet"])
    assert rc == 0
    t = json.loads((tmp_path / "out" / "truth.json").read_text())
    assert [p["pose_id"] for p in t["poses"]] == [5, 6]
    assert [p["station"] for p in t["poses"]] == [0, 3]
    assert [p["temp_c"] for p in t["poses"]] == [21.0, 22.5] and t["poses"][1]["t_s"] == 60.0
    j = read_joints_csv(tmp_path / "out" / "images" / "joints.csv")
    assert j.t_s is not None and j.station.tolist() == ["0", "3"]
