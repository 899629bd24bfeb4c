"""Tests of the diagnosis' workspace (``twin.evaluation.workspace``): the robot's skeleton from the model, the rows
of several stations in one measurement frame, the drawn rows, the colour and arrow scales."""

from __future__ import annotations

import numpy as np
import pytest

from twin.dataset import default_plate
from twin.estimator.calibration import Calibration
from twin.estimator.chain import Chain
from twin.estimator.problem import ParamSpace
from twin.evaluation.workspace import (
    ARROW_LENGTH_SHARE,
    COLOUR_STOPS,
    diagnosis_workspace,
    nice_ceil,
    nice_floor,
    size_colours,
    skeleton_points,
    view_eye,
)
from twin.kinematics import JointSpec, RobotModel, flange2base, tool2meas
from twin.transforms import invert_transform, pose6_to_transform
from twin.units import MM_PER_M


def random_dh_robot(rng: np.random.Generator, n: int) -> RobotModel:
    """A random MDH table of ``n`` revolute joints with a random base2meas and tool."""
    return RobotModel.from_tables(
        "random-mdh", "mdh", theta=rng.uniform(-1, 1, n), d=rng.uniform(-0.3, 0.3, n), a=rng.uniform(-0.4, 0.4, n),
        alpha=rng.uniform(-2, 2, n), base2meas=pose6_to_transform(np.r_[rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3)]),
        tool2flange=pose6_to_transform(np.r_[rng.uniform(-0.1, 0.1, 3), rng.uniform(-1, 1, 3)]))


def random_urdf_robot(rng: np.random.Generator, n: int) -> RobotModel:
    """A random URDF chain of ``n`` joints, revolute and prismatic, oblique axes, random base and tool."""
    axes = [(0, 0, 1), (1, 0, 0), (0.3, -0.5, 0.81), (0, -1, 0)]
    joints = [JointSpec(name=f"j{i}", kind="prismatic" if i % 3 == 1 else "revolute",
                        xyz=tuple(rng.uniform(-0.2, 0.3, 3)), rpy=tuple(rng.uniform(-2, 2, 3)), axis=axes[i % 4],
                        q_min=-0.5, q_max=0.5) for i in range(n)]
    return RobotModel.from_joints(
        "random-urdf", joints, end_origin=pose6_to_transform(np.r_[rng.uniform(-0.05, 0.05, 3), rng.uniform(-1, 1, 3)]),
        base2meas=pose6_to_transform(np.r_[rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3)]),
        tool2flange=pose6_to_transform(np.r_[rng.uniform(-0.1, 0.1, 3), rng.uniform(-1, 1, 3)]))


@pytest.mark.parametrize("make, n_joints", [(random_dh_robot, 6), (random_dh_robot, 4), (random_urdf_robot, 7),
                                             (random_urdf_robot, 3)])
def test_skeleton_runs_from_base_to_the_flange_of_forward_kinematics(make, n_joints):
    """The skeleton has N+1 points: the base origin (base2meas) first, the flange of the forward kinematics last."""
    rng = np.random.default_rng(11 + n_joints)
    model = make(rng, n_joints)
    q = rng.uniform(-0.5, 0.5, (5, n_joints))
    sk = skeleton_points(model, q)
    assert sk.shape == (5, n_joints + 1, 3)
    np.testing.assert_allclose(sk[:, 0], np.broadcast_to(model.base2meas[:3, 3], (5, 3)), atol=1e-12)
    flange_meas = tool2meas(model, q) @ invert_transform(model.tool2flange)
    np.testing.assert_allclose(sk[:, -1], flange_meas[:, :3, 3], atol=1e-12)
    np.testing.assert_allclose(skeleton_points(model, q, frame="base")[:, -1], flange2base(model, q)[:, :3, 3], atol=1e-12)


def test_skeleton_segments_of_a_dh_table_are_its_link_lengths():
    """Between consecutive MDH frames the origin moves by hypot(a_i, d_i), whatever the joints."""
    rng = np.random.default_rng(3)
    model = random_dh_robot(rng, 6)
    sk = skeleton_points(model, rng.uniform(-3, 3, (4, 6)))
    seg = np.linalg.norm(np.diff(sk, axis=1), axis=2)
    np.testing.assert_allclose(seg, np.broadcast_to(np.hypot(model.a, model.d), seg.shape), atol=1e-12)


def test_nice_numbers_follow_the_1_2_5_sequence():
    """nice_ceil/nice_floor round to {1, 2, 5} x 10^k up and down, and keep such numbers as they are."""
    assert [nice_ceil(x) for x in (0.13, 0.2, 3.0, 7.0, 0.0011)] == pytest.approx([0.2, 0.2, 5.0, 10.0, 0.002])
    assert [nice_floor(x) for x in (730.0, 0.07, 2.0, 19.9, 1.0)] == pytest.approx([500.0, 0.05, 2.0, 10.0, 1.0])
    with pytest.raises(ValueError, match="x must be a positive"):
        nice_ceil(0.0)


def test_size_colours_follow_the_stops_and_saturate():
    """0 is the first stop's colour, the maximum and beyond the last's, half way the middle one; NaN is grey."""
    c = size_colours(np.array([0.0, 0.25, 0.5, 0.9, np.nan]), 0.5)
    first, middle, last = (np.array(s[2]) for s in (COLOUR_STOPS[0], COLOUR_STOPS[2], COLOUR_STOPS[-1]))
    np.testing.assert_array_equal(c[0], first)
    np.testing.assert_array_equal(c[1], middle)
    np.testing.assert_array_equal(c[2], last)
    np.testing.assert_array_equal(c[3], last)
    np.testing.assert_array_equal(c[4], [128, 128, 128])
    with pytest.raises(ValueError, match="colour_max_mm"):
        size_colours(np.ones(2), 0.0)


def _two_station_case(rng, n=60, K=3, frac_b=0.4):
    """A calibration of a random 6R robot seen from stations A and B, and a series whose rows' points and residual
    vectors are given in each row's station frame (with the same points and vectors in the base frame)."""
    model = random_dh_robot(rng, 6)
    bases = {s: pose6_to_transform(np.r_[rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3)]) for s in ("A", "B")}
    space = ParamSpace(Chain.of(model), ("A", "B"))
    x = space.from_model(model, bases)
    cal = Calibration(method="test", nominal=model, stations=("A", "B"), x=x, x_nominal=x,
                      status=("identified",) * x.size, covariance=None, plate=default_plate(),
                      spheres_tool=default_plate().spheres_flange, measurement="spheres")
    q = rng.uniform(-2, 2, (n, 6))
    station = np.where(np.arange(n) >= int((1 - frac_b) * n), "B", "A").astype(object)
    p_base = rng.normal(0, 0.5, (n, K, 3))
    v_base = {t: rng.normal(0, s, (n, K, 3)) for t, s in (("before", 2e-4), ("after", 5e-5))}
    p_base[5, 1] = np.nan  # a point not seen
    for t in v_base:
        v_base[t][5, 1] = np.nan
    meas = np.empty_like(p_base)
    vec = {t: np.empty_like(p_base) for t in v_base}
    for k in range(n):
        T = bases[station[k]]
        meas[k] = p_base[k] @ T[:3, :3].T + T[:3, 3]
        for t in v_base:
            vec[t][k] = v_base[t][k] @ T[:3, :3].T
    series = {"dataset_row": np.arange(n) + 100, "q": q, "station": station, "measured_m": meas,
              "residual_vector_m_before": vec["before"], "residual_vector_m_after": vec["after"]}
    return cal, bases, series, p_base, v_base


def test_rows_of_another_station_are_mapped_into_the_first_station_frame():
    """Points, residual vectors and the skeleton of every row are in station A's frame: A's rows as measured, B's
    through base2meas_A @ inv(base2meas_B); the skeleton's flange is A's forward kinematics."""
    rng = np.random.default_rng(5)
    cal, bases, series, p_base, v_base = _two_station_case(rng)
    ws = diagnosis_workspace(series, cal)
    TA = bases["A"]
    assert ws.station == "A"
    np.testing.assert_allclose(ws.measured_m, p_base @ TA[:3, :3].T + TA[:3, 3], atol=1e-12)
    for t in ("before", "after"):
        np.testing.assert_allclose(ws.residual_m[t], v_base[t] @ TA[:3, :3].T, atol=1e-15)
        np.testing.assert_allclose(ws.size_mm[t], np.linalg.norm(v_base[t], axis=2) * MM_PER_M, atol=1e-12)
    flange = (TA @ flange2base(cal.model("A"), series["q"]))[:, :3, 3]
    np.testing.assert_allclose(ws.skeleton_m[:, -1], flange[ws.drawn], atol=1e-12)
    assert any("station 'B'" in note for note in ws.notes)


def test_robot_rows_are_capped_and_the_map_keeps_every_row():
    """With more rows than the cap the robot is drawn on cap rows, evenly spaced, first and last included; the
    points of every row are kept."""
    rng = np.random.default_rng(8)
    cal, _, series, _, _ = _two_station_case(rng, n=500)
    ws = diagnosis_workspace(series, cal, max_robot_rows=40)
    assert ws.drawn.size == 40 and ws.drawn[0] == 0 and ws.drawn[-1] == 499
    assert np.all(np.diff(ws.drawn) >= 12) and np.all(np.diff(ws.drawn) <= 13)
    assert ws.skeleton_m.shape == (40, 7, 3)
    assert ws.measured_m.shape == (500, 3, 3) and np.array_equal(ws.rows, series["dataset_row"])
    assert any("drawn on 40 of the 500" in note for note in ws.notes)
    assert diagnosis_workspace(series, cal, max_robot_rows=1000).drawn.size == 500


def test_arrow_scale_draws_the_typical_residual_at_a_share_of_the_workspace():
    """The 95th percentile of the residual sizes, times the arrow scale, is between 1/2.5 of and the share
    ARROW_LENGTH_SHARE of the workspace extent; the colour map's top is at or above that percentile."""
    rng = np.random.default_rng(9)
    cal, _, series, _, _ = _two_station_case(rng)
    ws = diagnosis_workspace(series, cal)
    seen = np.all(np.isfinite(ws.measured_m), axis=2)
    p95 = np.percentile(np.concatenate([ws.size_mm["before"][seen], ws.size_mm["after"][seen]]), 95)
    drawn_m = p95 / MM_PER_M * ws.arrow_scale
    assert ARROW_LENGTH_SHARE * ws.extent_m / 2.5 <= drawn_m <= ARROW_LENGTH_SHARE * ws.extent_m * (1 + 1e-9)
    assert p95 <= ws.colour_max_mm < 2.5 * p95
    position, target, up = view_eye(ws)
    assert np.linalg.norm(position - target) == pytest.approx(ws.extent_m)
    np.testing.assert_allclose(up, cal.base2meas["A"][:3, 2], atol=1e-12)


def test_workspace_refuses_incomplete_series():
    """A missing key, a station the calibration does not know, or vectors not finite where points are: ValueError."""
    rng = np.random.default_rng(2)
    cal, _, series, _, _ = _two_station_case(rng, n=10)
    with pytest.raises(ValueError, match="series lacks 'residual_vector_m_after'"):
        diagnosis_workspace({k: v for k, v in series.items() if k != "residual_vector_m_after"}, cal)
    with pytest.raises(ValueError, match=r"stations the calibration does not know: \['C'\]"):
        diagnosis_workspace({**series, "station": np.array(["C"] * 10, dtype=object)}, cal)
    bad = series["residual_vector_m_before"].copy()
    bad[2, 0, 1] = np.nan
    with pytest.raises(ValueError, match="finite exactly where"):
        diagnosis_workspace({**series, "residual_vector_m_before": bad}, cal)
    with pytest.raises(ValueError, match="max_robot_rows"):
        diagnosis_workspace(series, cal, max_robot_rows=0)
