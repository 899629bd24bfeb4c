"""DH and MDH tables of any length in dataset.toml: read, evaluated, calibrated (a 7-joint arm), and a 7-joint arm
whose errors are not geometric calibrated without --force."""

import json

import numpy as np
import pytest

from twin.cli import main
from twin.dataset import DatasetError, read_dataset, robot_from_spec, write_dataset
from twin.estimator import Calibration
from twin.estimator.chain import Chain
from twin.estimator.simulate import random_configurations, simulate_dataset
from twin.kinematics import pose_jacobian, tool2base, tool2meas
from twin.transforms import matrix_to_rotvec, pose6_to_transform

DEG = np.pi / 180
ARM7 = {"name": "arm7", "convention": "dh", "theta_deg": [0, 0, 0, 0, 0, 0, 0],
        "d_mm": [340, 10, 400, 5, 400, 8, 126], "a_mm": [20, 30, 25, 15, 10, 12, 0],
        "alpha_deg": [-90, 90, 90, -90, -90, 90, 0],
        "q_min_deg": [-170, -120, -170, -120, -170, -120, -175], "q_max_deg": [170, 120, 170, 120, 170, 120, 175]}
ARM7_MDH = {**ARM7, "convention": "mdh", "alpha_deg": [0, -90, 90, 90, -90, -90, 90], "beta_joints": [3],
            "beta_deg": [0.0]}


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _tr(x, z):
    T = np.eye(4)
    T[0, 3], T[2, 3] = x, z
    return T


def _truth(nominal, rng):
    """Nominal + random deviations of every structural parameter (0.5 mm, 2 mrad) and a tool."""
    dev = np.zeros(nominal.layout.size)
    for k, n in enumerate(nominal.layout.names):
        if not n.startswith("base_"):
            dev[k] = rng.normal(0, 0.5e-3 if nominal.layout.units[k] == "m" else 2e-3)
    dev[nominal.layout.tool_slice] += [0.0, 0.0, 0.05, 0.0, 0.0, 0.0]
    return nominal.perturbed(dev)


def _write(folder, truth, q, rng, *, q_actual=None, noise_mm=0.01):
    """A dataset of the 7-joint arm measured at ``q_actual`` (default ``q``), commanded ``q``; every 4th row
    validation; the noise stated in dataset.toml."""
    B = pose6_to_transform(np.array([1.0, 0.2, 0.3, 0.1, -0.2, 0.3]))
    sets = np.where(np.arange(q.shape[0]) % 4 == 0, "validation", "calibration")
    ds, _ = simulate_dataset(truth, q if q_actual is None else q_actual, robot_spec=ARM7, base2meas={"0": B},
                             noise_position=noise_mm * 1e-3, rng=rng, set_=sets)
    from dataclasses import replace

    write_dataset(folder, replace(ds, q=q))
    return folder


def test_a_seven_joint_dh_table_is_read_with_columns_q1_to_q7():
    """dataset.toml's DH keys with 7 entries: a 7-joint robot, joint columns q1..q7, parameters theta1..alpha7."""
    r = robot_from_spec(ARM7)
    assert r.n_joints == 7 and r.joint_names == tuple(f"q{j}" for j in range(1, 8))
    assert r.layout.size == 4 * 7 + 12 and "alpha7" in r.layout.names
    assert np.allclose(r.q_max, np.array(ARM7["q_max_deg"]) * DEG)


@pytest.mark.parametrize("spec", [ARM7, ARM7_MDH, {**ARM7, "theta_deg": [5], "d_mm": [100], "a_mm": [50],
                                                   "alpha_deg": [30], "q_min_deg": [-90], "q_max_deg": [90]}])
def test_forward_kinematics_of_a_dh_table_is_the_product_of_its_joint_transforms(spec):
    """FK of a DH (7 joints), an MDH (7 joints, a beta) and a 1-joint table equals the product written out here."""
    r = robot_from_spec(spec)
    rng = np.random.default_rng(4)
    q = random_configurations(r, 5, rng)
    th, d, a, al = (np.asarray(spec[k], float) * f for k, f in (("theta_deg", DEG), ("d_mm", 1e-3),
                                                                 ("a_mm", 1e-3), ("alpha_deg", DEG)))
    for k in range(q.shape[0]):
        T = np.eye(4)
        for i in range(r.n_joints):
            if spec["convention"] == "dh":
                T = T @ _rz(th[i] + q[k, i]) @ _tr(a[i], d[i]) @ _rx(al[i])
            else:
                T = T @ _rx(al[i]) @ _tr(a[i], 0) @ _tr(0, d[i]) @ _rz(th[i] + q[k, i])
        assert np.allclose(tool2base(r, q[k:k + 1])[0], T, atol=1e-12)


def test_pose_jacobian_of_a_seven_joint_dh_arm_matches_central_differences():
    """Every column of the pose Jacobian of a perturbed 7-joint MDH arm (beta included) equals central
    differences of its FK, and the estimator's batched chain gives the same poses."""
    rng = np.random.default_rng(5)
    nom = robot_from_spec(ARM7_MDH)
    m = nom.perturbed(np.r_[rng.normal(0, 1e-2, nom.layout.size - 12), rng.normal(0, 0.3, 12)])
    q = random_configurations(m, 4, rng)
    J = pose_jacobian(m, q, frame="meas")
    h = 1e-6
    for k, name in enumerate(m.layout.names):
        e = np.zeros(m.layout.size)
        e[k] = h
        Tp, Tm = tool2meas(m.with_params(m.params + e), q), tool2meas(m.with_params(m.params - e), q)
        assert np.allclose(J[:, :3, k], (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h), atol=2e-8), name
        dw = matrix_to_rotvec(Tp[:, :3, :3] @ np.swapaxes(Tm[:, :3, :3], 1, 2)) / (2 * h)
        assert np.allclose(J[:, 3:, k], dw, atol=2e-8), name
    ch = Chain.of(m)
    rt, base = ch.split_full(m.params)
    ev = ch.evaluate(rt, q, base6=base)
    assert np.abs(ev.p[0] - tool2meas(m, q)[:, :3, 3]).max() < 1e-13


@pytest.mark.parametrize("edit,match", [
    ({"d_mm": [340, 10, 400, 5, 400, 8]}, "robot.theta_deg has 7 entries but robot.d_mm has 6"),
    ({"beta_joints": [8], "beta_deg": [0.0]}, r"beta_joints \[8\] are not joint numbers of this 7-joint table"),
    ({"q_min_deg": [-170] * 6}, "robot.q_min_deg must be 7 finite numbers"),
    ({"theta_deg": []}, "robot.theta_deg must be a list of N >= 1 finite numbers"),
])
def test_an_inconsistent_dh_table_is_refused_with_the_field_named(edit, match):
    """Tables of unequal lengths, a beta joint beyond the table, limits of another length, an empty table."""
    with pytest.raises(DatasetError, match=match):
        robot_from_spec({**ARM7, **edit})


def test_a_seven_joint_dh_arm_is_calibrated_and_its_parameters_recovered(tmp_path):
    """`twin calibrate` on a simulated 7-joint DH arm (200 rows, 0.01 mm): every identified structural parameter
    within 4.5 sd of the truth, the validation RMS at the noise; the calibration file reads back as 7 joints."""
    rng = np.random.default_rng(3)
    nom = robot_from_spec(ARM7)
    truth = _truth(nom, rng)
    ds = _write(tmp_path / "ds", truth, random_configurations(nom, 200, rng), rng)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal"), "--quiet"]) == 0
    cal = Calibration.load(tmp_path / "cal" / "calibration.json")
    assert cal.nominal.n_joints == 7 and cal.nominal.convention == "dh"
    # frames gauge: theta1, d1 go into the base and the last link's theta7, d7, a7, alpha7 into the tool
    assert {n for n, s in zip(cal.names, cal.status) if s == "fixed"} == {"theta1", "d1", "theta7", "d7", "a7",
                                                                         "alpha7"}
    checked = 0
    for k, (n, s) in enumerate(zip(cal.names, cal.status)):
        if s == "identified" and n in nom.layout.names[:28]:
            assert abs(cal.x[k] - truth.param(n)) < 4.5 * cal.std[k], n
            checked += 1
    assert checked == 22
    assert cal.residuals["validation"]["position_mm"]["rms"] < 0.03
    assert cal.residuals["before_calibration"]["validation"]["position_mm"]["rms"] > 1.0


def test_a_seven_joint_dh_arm_with_a_70x_residual_calibrates_without_force(tmp_path, capsys):
    """A 7-joint DH arm whose joints err by a function of the joints (not geometric) at 0.01 mm stated noise: the
    residual is about 70x the noise; `twin calibrate` writes the calibration without --force, says the robot has
    errors the geometric model lacks (stdout and details.beyond_geometry) and points to `twin diagnose`."""
    rng = np.random.default_rng(8)
    nom = robot_from_spec(ARM7)
    truth = _truth(nom, rng)
    q = random_configurations(nom, 200, rng)
    q_actual = q + 0.07 * DEG * np.sin(3 * q) + 0.05 * DEG * np.cos(q[:, [1]] - q[:, [3]])
    ds = _write(tmp_path / "ds", truth, q, rng, q_actual=q_actual)
    assert main(["calibrate", str(ds), "--out", str(tmp_path / "cal")]) == 0
    out = capsys.readouterr().out
    assert "the robot has errors the geometric model lacks" in out and f"twin diagnose {ds}" in out
    d = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    bg = d["details"]["beyond_geometry"]
    assert bg["detected"] and 40 < bg["residual_scale"] < 120
    assert d["details"]["plausibility"]["forced"] == []
    assert read_dataset(ds).robot.n_joints == 7
