"""Stereo measurement of the plate: matching, labelling, triangulation, flags; plate pose and paper frame."""

import numpy as np
import pytest

from twin.camera import CameraIntrinsics
from twin.dataset import Plate, default_plate
from twin.instrument.calibration import StereoCalibration
from twin.instrument.measure import MeasureConfig, format_status, measure_pair
from twin.instrument.plate import (
    label_by_distances,
    paper_euler_zyx_deg,
    paper_frame_from_spheres,
    plate_pose_from_spheres,
)
from twin.instrument.synthetic import add_sensor_noise, look_at_world2cam, render_spheres
from twin.transforms import invert_transform, make_transform, rotvec_to_matrix, rotation_angle_between

LEFT = CameraIntrinsics.ideal(1296, 972, 15.225, (-0.05, 0.1, 2e-4, -1e-4, 0.0))
RIGHT = CameraIntrinsics(3640.0, 3637.0, 650.0, 482.0, 1296, 972, (-0.04, 0.05, -1e-4, 2e-4, 0.0))
W2L = look_at_world2cam([-0.125, 0.0, 0.0], [0.0, 0.0, 0.7], up=(0, -1, 0))
W2R = look_at_world2cam([0.125, 0.0, 0.0], [0.0, 0.0, 0.7], up=(0, -1, 0))
CAL = StereoCalibration(LEFT, RIGHT, W2R @ invert_transform(W2L), 0.0, 0.0, 0.0)  # exact rig
PLATE = default_plate()


def _plate2world(pos, rotvec):
    Rp = rotvec_to_matrix(np.array([np.pi, 0.0, 0.0])) @ rotvec_to_matrix(np.asarray(rotvec, float))
    return make_transform(Rp, np.asarray(pos, float))


def _scene(t2w, seed=0):
    sph = PLATE.spheres_flange @ t2w[:3, :3].T + t2w[:3, 3]
    rng = np.random.default_rng(seed)
    il = add_sensor_noise(render_spheres(LEFT, W2L, sph, 0.0127, supersample=3), 2.0, rng)
    ir = add_sensor_noise(render_spheres(RIGHT, W2R, sph, 0.0127, supersample=3), 2.0, rng)
    truth = sph @ W2L[:3, :3].T + W2L[:3, 3]
    return il, ir, truth


POSES = [([0.01, 0.0, 0.75], [0.1, -0.2, 0.3]), ([-0.02, 0.015, 0.62], [-0.3, 0.2, -1.0]), ([0.02, -0.01, 0.9], [0.2, 0.3, 2.0])]


@pytest.fixture(scope="module")
def scenes():
    return [_scene(_plate2world(p, r), seed=k) for k, (p, r) in enumerate(POSES)]


def test_three_spheres_measured_and_labelled(scenes):
    """All three centres are measured, labelled p0..p2 as on the plate, within 0.03 mm (half resolution)."""
    for il, ir, truth in scenes:
        m = measure_pair(il, ir, CAL, PLATE)
        assert m.complete and m.status == ""
        err = np.linalg.norm(m.centres_array() - truth, axis=1)
        assert err.max() < 3e-5, err


def test_bias_correction_matters(scenes):
    """Without the cone correction the centres are several times further from the truth."""
    ec, eu = [], []
    for il, ir, truth in scenes:
        m = measure_pair(il, ir, CAL, PLATE, bias_correction=False)
        assert all(a is b for a, b in zip(m.centres, m.centres_uncorrected))
        ec.append(np.linalg.norm(np.stack(m.centres_corrected) - truth, axis=1))
        eu.append(np.linalg.norm(np.stack(m.centres_uncorrected) - truth, axis=1))
    rms_c, rms_u = np.sqrt(np.mean(np.square(ec))), np.sqrt(np.mean(np.square(eu)))
    assert rms_u > 3 * rms_c


def test_plate_pose_from_measured_spheres(scenes):
    """The rigid plate fit of the measured centres is within 0.01 deg of the true plate orientation."""
    il, ir, truth = scenes[0]
    m = measure_pair(il, ir, CAL, PLATE)
    fit = m.plate_pose(PLATE)
    t2w = _plate2world(*POSES[0])
    t2l = W2L @ t2w
    assert np.degrees(rotation_angle_between(fit.tool2meas[:3, :3], t2l[:3, :3])) < 0.01
    assert np.linalg.norm(fit.tool2meas[:3, 3] - t2l[:3, 3]) < 5e-5
    assert fit.rms < 3e-5


def test_sphere_out_of_frame_is_flagged_others_kept():
    """A plate pushed so that one sphere leaves the left image: that sphere is empty with a reason, the
    other two are measured, and nothing raises."""
    # the left camera's right image border at 0.7 m is near x = 0.125 - ... in the world; slide the plate
    for x in np.linspace(0.02, 0.12, 11):
        il, ir, truth = _scene(_plate2world([x, 0.0, 0.7], [0.0, 0.0, 0.0]))
        m = measure_pair(il, ir, CAL, PLATE)
        if not m.complete:
            break
    assert not m.complete
    missing = [k for k in range(3) if m.centres[k] is None]
    assert all("out_of_frame" in m.reasons[k] for k in missing), m.reasons
    for k in range(3):
        if m.centres[k] is not None:
            assert np.linalg.norm(m.centres[k] - truth[k]) < 3e-5
    assert m.status == format_status(m.reasons) and "out_of_frame" in m.status


def test_occluded_sphere_is_flagged_others_kept(scenes):
    """A bar painted over one sphere's outline in the right image (the arm) empties only that sphere."""
    il, ir, truth = scenes[0]
    m0 = measure_pair(il, ir, CAL, PLATE)
    u, v = m0.right[2].centre_px
    r = m0.right[2].radius_px
    ir2 = ir.copy()
    ir2[int(v - 1.5 * r): int(v + 1.5 * r), int(u + 0.6 * r): int(u + 0.6 * r) + 60] = 150
    m = measure_pair(il, ir2, CAL, PLATE)
    assert m.centres[2] is None and "occluded" in m.reasons[2], m.reasons
    assert m.centres[0] is not None and m.centres[1] is not None
    assert np.allclose(m.centres[0], m0.centres[0]) and np.allclose(m.centres[1], m0.centres[1])


def test_blank_image_gives_empty_row_not_exception(scenes):
    """A blank left image: no centre at all, every sphere has a reason, no exception."""
    il, ir, _ = scenes[0]
    blank = np.full_like(il, 30)
    m = measure_pair(blank, ir, CAL, PLATE)
    assert not m.measured.any()
    assert all("not_found(left)" in r or "not_matched" in r for r in m.reasons), m.reasons


def test_wrong_extrinsics_fail_the_epipolar_check(scenes):
    """A rig calibration off by 0.3 deg puts the right centres off their epipolar lines: all flagged."""
    il, ir, _ = scenes[0]
    bad = CAL.left2right.copy()
    bad[:3, :3] = rotvec_to_matrix(np.array([np.radians(0.3), 0.0, 0.0])) @ bad[:3, :3]
    cal = StereoCalibration(LEFT, RIGHT, bad, 0.0, 0.0, 0.0)
    m = measure_pair(il, ir, cal, PLATE)
    assert not m.measured.any()
    assert all(r.startswith("epipolar") for r in m.reasons), m.reasons


def test_label_by_distances_recovers_permutation():
    """Shuffled sphere centres (plus a stray point) get their plate labels back."""
    rng = np.random.default_rng(0)
    t = make_transform(rotvec_to_matrix(rng.normal(size=3)), [0.1, 0.0, 0.7])
    pts = PLATE.spheres_flange @ t[:3, :3].T + t[:3, 3]
    order = np.array([2, 0, 1])
    P = np.vstack([pts[order], [[0.3, 0.3, 0.9]]])
    labels, amb = label_by_distances(P, PLATE, 0.004)
    assert labels.tolist() == [2, 0, 1, -1] and amb == []


def test_two_spheres_cannot_be_labelled():
    """Two points alone always fit two labels both ways round: ambiguous, no labels given."""
    labels, amb = label_by_distances(PLATE.spheres_flange[:2], PLATE, 0.004)
    assert labels.tolist() == [-1, -1] and amb == [0, 1]


def test_equally_spaced_plate_is_refused(scenes):
    """A plate with spheres 120 deg apart cannot be labelled by distances: measure_pair says so."""
    ang = np.deg2rad([0.0, 120.0, 240.0])
    sym = Plate(0.0254, np.stack([0.06 * np.cos(ang), 0.06 * np.sin(ang), np.full(3, 0.05)], 1))
    il, ir, _ = scenes[0]
    with pytest.raises(ValueError, match="plate"):
        measure_pair(il, ir, CAL, sym)


def test_plate_pose_round_trip_and_missing_sphere():
    """A known plate transform is recovered exactly; a missing sphere is a ValueError, not a guess."""
    rng = np.random.default_rng(5)
    T = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
    pts = PLATE.spheres_flange @ T[:3, :3].T + T[:3, 3]
    fit = plate_pose_from_spheres(pts, PLATE)
    assert np.allclose(fit.tool2meas, T, atol=1e-12) and fit.rms < 1e-12
    with pytest.raises(ValueError, match="centres"):
        plate_pose_from_spheres([pts[0], None, pts[2]], PLATE)


def test_paper_frame_matches_flange_orientation_for_the_twin_plate():
    """Eq. 38-40 on the twin's plate gives the flange's axes, origin at the circumcentre (0, 0, 50 mm)."""
    rng = np.random.default_rng(6)
    T = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
    pts = PLATE.spheres_flange @ T[:3, :3].T + T[:3, 3]
    F = paper_frame_from_spheres(pts)
    assert np.allclose(F[:3, :3], T[:3, :3], atol=1e-12)
    assert np.allclose(F[:3, 3], T[:3, :3] @ [0, 0, 0.05] + T[:3, 3], atol=1e-12)
    e = paper_euler_zyx_deg(np.eye(4))
    assert np.allclose(e, 0.0)


def test_paper_frame_is_bit_identical_to_eq_38_40_written_with_np_cross():
    """paper_frame_from_spheres returns, to the last bit, eq. 38-40 and the circumcentre computed with np.cross."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        p = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 1)
        X, Z = p[0] - p[1], np.cross(p[0] - p[1], p[2] - p[1])
        Y = np.cross(Z, X)
        a, b = p[0] - p[2], p[1] - p[2]
        axb = np.cross(a, b)
        centre = p[2] + np.cross(np.dot(a, a) * b - np.dot(b, b) * a, axb) / (2.0 * np.dot(axb, axb))
        R = np.stack([X / np.linalg.norm(X), Y / np.linalg.norm(Y), Z / np.linalg.norm(Z)], axis=1)
        F = paper_frame_from_spheres(p)
        assert np.array_equal(F[:3, :3], R) and np.array_equal(F[:3, 3], centre)


def test_measure_config_validates():
    """Non-positive tolerances are refused with the field's name."""
    with pytest.raises(ValueError, match="epipolar_tol_px"):
        MeasureConfig(epipolar_tol_px=0.0)
