"""Stereo calibration from ChArUco board views rendered analytically with a known rig."""

import json

import numpy as np
import pytest

from twin.camera import CameraIntrinsics, project_points
from twin.instrument.calibration import (
    BoardSpec,
    StereoCalibration,
    calibrate_stereo,
    calibrate_stereo_views,
    detect_board,
)
from twin.instrument.geometry import pixels_to_rays, triangulate_rays
from twin.instrument.synthetic import add_sensor_noise, look_at_world2cam, render_board
from twin.transforms import invert_transform, make_transform, matrix_to_rotvec, rotvec_to_matrix

# half the MV-EM500M's resolution (f = 3636 px) keeps rendering fast
LEFT = CameraIntrinsics.ideal(1296, 972, 15.225, (-0.05, 0.1, 2e-4, -1e-4, 0.0))
RIGHT = CameraIntrinsics(3640.0, 3637.0, 650.0, 482.0, 1296, 972, (-0.04, 0.05, -1e-4, 2e-4, 0.0))
W2L = look_at_world2cam([-0.125, 0.0, 0.0], [0.0, 0.0, 0.7], up=(0, -1, 0))
W2R = look_at_world2cam([0.125, 0.0, 0.0], [0.0, 0.0, 0.7], up=(0, -1, 0))
L2R = W2R @ invert_transform(W2L)
SPEC = BoardSpec()  # the rig.toml board: 11 x 8 squares of 18 mm, 13.5 mm markers, DICT_5X5_100


def board_pair(rng, z, tilt):
    cvb = SPEC.cv_board()
    centre = np.array([rng.uniform(-0.02, 0.02), rng.uniform(-0.015, 0.015), z])
    Rb = rotvec_to_matrix(np.array([rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-0.3, 0.3)]))
    b2w = make_transform(Rb, centre - Rb @ np.array([11 * 0.009, 8 * 0.009, 0.0]))
    il = add_sensor_noise(render_board(LEFT, W2L @ b2w, cvb), 2.0, rng)
    ir = add_sensor_noise(render_board(RIGHT, W2R @ b2w, cvb), 2.0, rng)
    return il, ir


@pytest.fixture(scope="module")
def board_pairs():
    rng = np.random.default_rng(7)
    return [board_pair(rng, z, 0.55) for z in np.linspace(0.6, 0.95, 12)]


@pytest.fixture(scope="module")
def calib(board_pairs):
    return calibrate_stereo(board_pairs, SPEC)


@pytest.mark.slow
def test_board_corners_found_where_projected(board_pairs):
    """Detected ChArUco corners sit within 0.2 px of their exact projections (board frame convention)."""
    rng = np.random.default_rng(7)
    cvb = SPEC.cv_board()
    centre = np.array([rng.uniform(-0.02, 0.02), rng.uniform(-0.015, 0.015), 0.6])
    Rb = rotvec_to_matrix(np.array([rng.uniform(-0.55, 0.55), rng.uniform(-0.55, 0.55), rng.uniform(-0.3, 0.3)]))
    b2w = make_transform(Rb, centre - Rb @ np.array([11 * 0.009, 8 * 0.009, 0.0]))
    v = detect_board(board_pairs[0][0], SPEC)
    assert v.ok and v.ids.size >= 40
    exact = project_points(v.object_points, W2L @ b2w, LEFT)
    assert np.max(np.linalg.norm(v.corners_px - exact, axis=1)) < 0.2
    del cvb


@pytest.mark.slow
def test_stereo_calibration_recovers_the_rig(calib):
    """Intrinsics, baseline and reprojection RMS of the estimated rig are close to the true ones."""
    assert calib.rms_px < 0.15
    assert calib.n_views_used == 12
    for est, true in ((calib.left, LEFT), (calib.right, RIGHT)):
        assert abs(est.fx / true.fx - 1) < 2e-3 and abs(est.fy / true.fy - 1) < 2e-3
        assert abs(est.cx - true.cx) < 5 and abs(est.cy - true.cy) < 5
    assert abs(calib.baseline / np.linalg.norm(L2R[:3, 3]) - 1) < 2e-3
    rot_err = np.degrees(np.linalg.norm(matrix_to_rotvec(calib.left2right[:3, :3] @ L2R[:3, :3].T)))
    assert rot_err < 0.1


@pytest.mark.slow
def test_estimated_rig_triangulates_the_working_volume(calib):
    """Points triangulated with the estimated rig keep their shape: after one rigid alignment (what the
    estimator's base2meas absorbs) the 3D error stays below 0.02 mm at half resolution."""
    rng = np.random.default_rng(1)
    P = np.stack([rng.uniform(-0.06, 0.06, 300), rng.uniform(-0.05, 0.05, 300), rng.uniform(0.55, 0.95, 300)], 1)
    X = triangulate_rays(
        pixels_to_rays(project_points(P, W2L, LEFT), calib.left),
        pixels_to_rays(project_points(P, W2R, RIGHT), calib.right),
        calib.left2right,
    )
    T = P @ W2L[:3, :3].T + W2L[:3, 3]
    mx, mt = X.mean(0), T.mean(0)
    U, _, Vt = np.linalg.svd((T - mt).T @ (X - mx))
    Rf = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    err = np.linalg.norm((X - mx) @ Rf.T + mt - T, axis=1)
    assert np.sqrt(np.mean(err**2)) < 2e-5


@pytest.mark.slow
def test_corrupt_views_are_rejected_with_reasons(board_pairs):
    """A blank board image and a left/right pair from two different moments are rejected, with the reason,
    and the calibration still succeeds from the others."""
    blank = add_sensor_noise(np.full((972, 1296), 40.0), 2.0, np.random.default_rng(0))
    pairs = list(board_pairs[:8]) + [(board_pairs[8][0], blank), (board_pairs[9][0], board_pairs[10][1])]
    cal = calibrate_stereo(pairs, SPEC)
    v_blank, v_mix = cal.views[8], cal.views[9]
    assert not v_blank.used and v_blank.reason.startswith("right: pattern not found")
    assert not v_mix.used and "outlier" in v_mix.reason
    assert all(v.used for v in cal.views[:8])
    assert cal.rms_px < 0.15


@pytest.mark.slow
def test_calibration_json_round_trip(calib, tmp_path):
    """Saving and loading keeps every number; the file is small and carries its schema version."""
    p = calib.save(tmp_path / "stereo.json")
    back = StereoCalibration.load(p)
    assert p.stat().st_size < 20_000
    assert json.loads(p.read_text())["schema_version"] == 1
    assert back.left == calib.left and back.right == calib.right
    assert np.allclose(back.left2right, calib.left2right, atol=1e-12)
    assert back.views == calib.views and back.board == calib.board


def test_calibration_from_found_corners_is_the_calibration_from_images(board_pairs, calib):
    """calibrate_stereo_views on the corners detect_board finds (as workers hand them over) gives the calibration
    of calibrate_stereo on the images, to the bit."""
    views = [(detect_board(a, SPEC), detect_board(b, SPEC)) for a, b in board_pairs]
    h, w = board_pairs[0][0].shape
    assert calibrate_stereo_views(views, (w, h), SPEC).to_dict() == calib.to_dict()


def test_calibration_is_the_same_bits_on_every_run_whatever_opencvs_threads(board_pairs):
    """Three calibrations from the same corners with OpenCV set to two threads are bit-identical (the calibration
    runs OpenCV on one thread, whose sums keep their order), and OpenCV's thread count is restored after."""
    import cv2

    views = [(detect_board(a, SPEC), detect_board(b, SPEC)) for a, b in board_pairs[:8]]
    h, w = board_pairs[0][0].shape
    n = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        runs = [calibrate_stereo_views(views, (w, h), SPEC).to_dict() for _ in range(3)]
        assert cv2.getNumThreads() == 2
    finally:
        cv2.setNumThreads(n)
    assert runs[0] == runs[1] == runs[2]


def test_calibration_from_corners_refuses_bad_input(board_pairs):
    """Views that are not (left, right) BoardView pairs, or a bad image size, are ValueErrors naming them."""
    views = [(detect_board(a, SPEC), detect_board(b, SPEC)) for a, b in board_pairs[:6]]
    with pytest.raises(ValueError, match=r"views\[2\]"):
        calibrate_stereo_views(views[:2] + [(views[2][0],)] + views[3:], (1296, 972), SPEC)
    with pytest.raises(ValueError, match="image_size"):
        calibrate_stereo_views(views, (0, 972), SPEC)


def test_too_few_views_raise():
    """Fewer views than min_views is a ValueError naming board_pairs."""
    img = np.zeros((972, 1296), np.uint8)
    with pytest.raises(ValueError, match="board_pairs"):
        calibrate_stereo([(img, img)] * 3, SPEC)


def test_all_views_unusable_raise_with_reasons():
    """When no view shows the board, the error lists each view's reason."""
    img = np.zeros((972, 1296), np.uint8)
    with pytest.raises(ValueError, match="pattern not found"):
        calibrate_stereo([(img, img)] * 6, SPEC)


def test_load_refuses_unknown_schema(tmp_path):
    """A calibration file of another schema version is refused, naming the file."""
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"schema_version": 99, "kind": "stereo_calibration"}))
    with pytest.raises(ValueError, match="schema_version"):
        StereoCalibration.load(p)


def test_board_spec_from_rig_table():
    """The rig.toml [board] table (mm) becomes a BoardSpec in metres; a bad dictionary is refused."""
    b = BoardSpec.from_table({"type": "charuco", "squares_x": 11, "squares_y": 8, "square_mm": 18.0,
                              "marker_mm": 13.5, "dictionary": "DICT_5X5_100"})
    assert b == SPEC
    with pytest.raises(ValueError, match="dictionary"):
        BoardSpec(dictionary="DICT_NOPE")
