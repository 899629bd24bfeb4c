"""The diagnosis on any serial chain (the TIAGo's URDF: a prismatic torso and seven revolute joints, four marker
points): gravity loads and carried moments from the URDF masses against finite differences of the potential energy,
the base tilt's parameter directions against finite differences of the prediction, the marker-noise floor and the
session column, selection outcomes over 10 seeds, and FIGAROH's parameter selection against FIGAROH's own result."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import _diagnosis_helpers as H
from twin.dataset import Dataset
from twin.diagnosis import diagnose, noise_floor, row_context
from twin.diagnosis.candidates import carried_moments, gravity_torques, joint_frames
from twin.kinematics import link_frames
from twin.urdf import read_urdf_chain

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data" / "tiago_mocap"
G = np.array([0.0, 0.0, -9.81])
SEEDS = 10


@pytest.fixture(scope="module")
def tiago():
    return read_urdf_chain(DATA / "tiago_48_schunk.urdf", "base_link", "wrist_ft_tool_link")


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The committed campaign imported (its robot, marker set and dataset.toml), the template of the synthetic rows."""
    from twin.dataset import read_dataset
    from twin.importers.mocap import import_mocap

    out = tmp_path_factory.mktemp("tiago") / "ds"
    import_mocap([(DATA / "qualisys_2021-11-30_static_postures.csv", "calibration"),
                  (DATA / "qualisys_2021-11-26_static_postures.csv", "validation")],
                 DATA / "tiago_48_schunk.urdf", "base_link", "wrist_ft_tool_link", out)
    return read_dataset(out)


def _postures(rng, model, n):
    """Postures inside the joint limits (the middle 80 % of each range)."""
    lo, hi = np.asarray(model.q_min), np.asarray(model.q_max)
    wide = hi - lo > 2 * np.pi
    lo, hi = np.where(wide, -2.0, lo), np.where(wide, 2.0, hi)
    m, h = (lo + hi) / 2, 0.4 * (hi - lo)
    return rng.uniform(m - h, m + h, (n, model.n_joints))


def _potential(model, q, bodies=None, pivot=None, axis=None, angle=0.0):
    """Potential energy of the bodies joint k moves (``bodies``: 0-based joints, default all), test-side: each
    body's centre of mass from the link frames and its URDF inertial, optionally every body turned by ``angle``
    about ``axis`` through ``pivot`` (base frame)."""
    from twin.transforms import rotvec_to_matrix

    F = link_frames(model, q)[:, 1:].copy()
    E = np.asarray(model.structure.end_origin, float).reshape(4, 4)
    F[:, -1] = F[:, -1] @ np.linalg.inv(E)
    V = np.zeros(len(q))
    for k, j in enumerate(model.structure.joints):
        if bodies is not None and k not in bodies:
            continue
        c = np.einsum("nij,j->ni", F[:, k, :3, :3], np.asarray(j.inertial["com"])) + F[:, k, :3, 3]
        if axis is not None:
            c = (c - pivot) @ rotvec_to_matrix(np.asarray(axis) * angle).T + pivot
        V += -j.inertial["mass"] * (c @ G)
    return V


def test_gravity_torques_are_minus_the_gradient_of_the_potential_energy(tiago):
    """tau_i = -dV/dq_i (central differences of the potential of the URDF masses) for every joint, the prismatic
    torso's force included, to 1e-6 of the largest load."""
    q = _postures(np.random.default_rng(0), tiago, 20)
    tau = gravity_torques(tiago, q)
    h = 1e-6
    for i in range(tiago.n_joints):
        e = np.zeros(tiago.n_joints)
        e[i] = h
        fd = -(_potential(tiago, q + e) - _potential(tiago, q - e)) / (2 * h)
        np.testing.assert_allclose(tau[:, i], fd, atol=1e-6 * np.abs(tau).max())


@pytest.mark.parametrize("joint", [0, 1, 3])
def test_carried_moment_is_minus_the_gradient_of_a_rotation_about_the_pivot(tiago, joint):
    """The moment of what joint ``joint`` carries (0: the base), about its origin, component a in its origin frame,
    is -dV/dtheta of turning those bodies about that frame's axis a through the origin."""
    q = _postures(np.random.default_rng(1), tiago, 10)
    M = carried_moments(tiago, q, joint)
    if joint == 0:
        o, R = np.zeros((len(q), 3)), np.broadcast_to(np.eye(3), (len(q), 3, 3))
    else:
        F = joint_frames(tiago, q)
        parent = np.broadcast_to(np.eye(4), (len(q), 4, 4)) if joint == 1 else F[:, joint - 2]
        before = parent @ tiago.structure.joints[joint - 1].origin
        o, R = before[:, :3, 3], before[:, :3, :3]
    bodies = set(range(max(joint - 1, 0), tiago.n_joints))
    h = 1e-6
    for a in range(3):
        fd = np.empty(len(q))
        for n in range(len(q)):
            ax = R[n][:, a]
            vp = _potential(tiago, q[n:n + 1], bodies, o[n], ax, h)
            vm = _potential(tiago, q[n:n + 1], bodies, o[n], ax, -h)
            fd[n] = -(vp - vm)[0] / (2 * h)
        np.testing.assert_allclose(M[:, a], fd, atol=1e-6 * np.abs(M).max())


def test_base_tilt_directions_are_a_rotation_of_the_base_about_its_own_axes(tiago):
    """The parameter directions of the base tilt (``tilt_weights``, target ``tilt0``) move the predicted points as
    turning the robot's base about its own x and y axes through its origin does (``base2meas exp([d])``), to first
    order (central differences)."""
    from twin.diagnosis.extend import tilt_weights
    from twin.estimator.chain import Chain
    from twin.estimator.problem import ParamSpace, predict_points
    from twin.transforms import pose6_to_transform, rotvec_to_matrix, transform_to_pose6

    sp = ParamSpace(Chain.of(tiago), ("0",))
    base2meas = pose6_to_transform(np.array([0.1, 0.2, -0.3, 0.4, -0.2, 0.3]))
    x = np.concatenate([tiago.params[: sp.n_rt], transform_to_pose6(base2meas)])
    q = _postures(np.random.default_rng(2), tiago, 5)
    pts = np.array([[0.06, 0.0, 0.07], [0.17, 0.0, -0.06]])
    st = np.zeros(len(q), int)
    W = tilt_weights(sp, x, "tilt0")
    h = 1e-7
    for a in range(2):
        lin = (predict_points(sp, x + h * W[:, a], q, st, pts)[0] - predict_points(sp, x - h * W[:, a], q, st, pts)[0]) / (2 * h)
        T = [base2meas.copy(), base2meas.copy()]
        for s, sign in enumerate((1, -1)):
            T[s][:3, :3] = base2meas[:3, :3] @ rotvec_to_matrix(np.eye(3)[a] * sign * h)
        xs = [np.concatenate([x[: sp.n_rt], transform_to_pose6(t)]) for t in T]
        fd = (predict_points(sp, xs[0], q, st, pts)[0] - predict_points(sp, xs[1], q, st, pts)[0]) / (2 * h)
        np.testing.assert_allclose(lin, fd, atol=1e-7)


def _chain_dataset(template: Dataset, q, spheres, noise, *, sets=None, extra=None) -> Dataset:
    """Rows of joints ``q`` and points ``spheres`` on the imported campaign's robot and marker set."""
    n = len(q)
    return replace(template, pose_id=np.arange(n), q=q, spheres=spheres, sphere_seen=np.all(np.isfinite(spheres), axis=2),
                   pose=np.zeros((n, 4, 4)), pose_seen=np.zeros(n, bool), set=sets, station=None, pair=None, temp_c=None,
                   t_s=None, status=None, noise_position=noise, extra=extra or {})


POINTS = np.array([[0.063, 0.002, 0.070], [0.077, -0.004, -0.088], [0.170, -0.001, -0.057], [0.167, 0.006, 0.050]])


def _simulate(model, q_actual, rng, sigma):
    from twin.kinematics import tool2meas

    T = tool2meas(model, q_actual)
    P = np.einsum("nij,kj->nki", T[:, :3, :3], POINTS) + T[:, None, :3, 3]
    return P + rng.normal(0.0, sigma, P.shape)


def test_marker_noise_column_sets_a_lower_bound_floor_and_bad_values_are_named(tiago, imported):
    """With a marker_std_mm column the floor is its RMS over the rows (the marker set's constant distances give
    nothing), said so and marked as a lower bound; a value that is not a finite number >= 0 is a ValueError naming
    the column and the row."""
    rng = np.random.default_rng(3)
    q = _postures(rng, tiago, 30)
    sph = _simulate(tiago, q, rng, 0.0)
    ms = rng.uniform(0.1, 0.3, 30)
    ds = _chain_dataset(imported, q, sph, None, extra={"marker_std_mm": np.array([f"{v}" for v in ms], dtype=object)})
    f = noise_floor(ds)
    assert f.lower_bound and "marker_std_mm" in f.source
    assert f.sigma == pytest.approx(np.sqrt(np.mean(ms**2)) * 1e-3, rel=1e-12)
    bad = ms.astype(object).astype(str)
    bad[7] = "n/a"
    with pytest.raises(ValueError, match=r"marker_std_mm: row 8 \(pose_id 7\): not a number: 'n/a'"):
        noise_floor(replace(ds, extra={"marker_std_mm": bad}))


def test_a_session_column_restarts_the_history_and_starts_a_session(tiago, imported):
    """Rows where the session column changes start an unknown approach history and a session."""
    q = _postures(np.random.default_rng(4), tiago, 10)
    sess = np.array(["a"] * 6 + ["b"] * 4, dtype=object)
    ds = _chain_dataset(imported, q, _simulate(tiago, q, np.random.default_rng(0), 0.0), 1e-5, extra={"session": sess})
    ctx = row_context(ds)
    assert np.flatnonzero(ctx.history_reset).tolist() == [0, 6]
    assert np.flatnonzero(ctx.session_start).tolist() == [0, 6]


def _approach(q):
    last = np.ones(q.shape[1])
    out = np.empty_like(q)
    prev = q[0]
    for k in range(len(q)):
        d = np.sign(q[k] - prev)
        last = np.where(d != 0, d, last)
        out[k] = last
        prev = q[k]
    return out


def test_compliance_from_the_urdf_masses_and_a_wrist_backlash_are_named_on_a_chain(tiago, imported):
    """A TIAGo-like chain with arm_3 deflecting under its gravity torque (1.5 mrad/Nm, the torque by finite
    differences of the potential, test-side) and arm_6 with a 0.3 deg backlash (test-side approach signs), 0.05 mm
    noise stated: the diagnosis names both at their joints (compliance from the URDF masses) on >= 9 of 10 seeds
    and the extended model's report rows fall below 1.5x the noise's 3-D RMS on >= 9 of 10."""
    out = []
    for seed in H.rate_seeds(range(SEEDS)):
        rng = np.random.default_rng(100 + seed)
        q = _postures(rng, tiago, 160)
        h = 1e-6
        e = np.zeros(tiago.n_joints)
        e[3] = h
        tau3 = -(_potential(tiago, q + e) - _potential(tiago, q - e)) / (2 * h)
        qa = q.copy()
        qa[:, 3] += 1.5e-3 * tau3
        qa[:, 6] += np.deg2rad(0.3) * _approach(q)[:, 6]
        sigma = 5e-5
        sets = np.array(["calibration" if k % 2 == 0 else "validation" for k in range(len(q))], dtype=object)
        ds = _chain_dataset(imported, q, _simulate(tiago, qa, rng, sigma), sigma, sets=sets)
        res = diagnose(ds, generic=False)
        labels = [a["label"] for a in res.atoms if not a["minor"]]
        named = (any(lab.startswith("joint 4 (arm_3_joint) compliance under gravity (the torque") for lab in labels)
                 and any(lab.startswith("joint 7 (arm_6_joint) backlash") for lab in labels))
        after_over_noise = res.after["position_mm"]["rms"] / (np.sqrt(3) * sigma * 1e3)
        out.append({"seed": seed, "named": named, "after_over_noise": after_over_noise,
                    "below": after_over_noise < 1.5})
    H.tally(out, named=(9, SEEDS), below=(9, SEEDS))


def _figaroh_to_ours(model, name):
    """FIGAROH's full-parameter name as our parameter (test-side): its translation d_p<c> along the origin frame's
    axis c is our translation along the parent axis that axis lies on; d_phi<c> our rotation r<c>, or the offset when
    c is the revolute joint's axis; base_* and pEE* our frames."""
    if name.startswith("base_"):
        return {"px": "base_x", "py": "base_y", "pz": "base_z", "phix": "base_rx", "phiy": "base_ry", "phiz": "base_rz"}[name[5:]]
    if name.startswith("pEE"):
        return "tool_" + name[3]
    _, comp, joint = name.split("_", 2)
    j = next(s for s in model.structure.joints if s.name == joint)
    c = "xyz".index(comp[-1])
    if comp.startswith("phi"):
        return f"{joint}.offset" if abs(j.axis[c]) == 1.0 and j.kind == "revolute" else f"{joint}.r{comp[-1]}"
    return f"{joint}.{'xyz'[int(np.argmax(np.abs(j.origin[:3, c])))]}"


def test_figaroh_selection_spans_figaroh_s_own_thirty_parameters(tmp_path):
    """On marker 1 (position only), selection='figaroh' estimates 30 parameters whose directions span exactly those of
    the 30 FIGAROH 1.0.2 estimated when run on the same files (the study's FIGAROH row, mapped to our names: members
    of a coupled set may differ, the span may not) and predicts the other day as FIGAROH did (validation RMSE within
    0.005 mm); our ordered selection estimates 33."""
    from twin.estimator.core import prepare
    from twin.estimator.problem import absolute_residuals

    from twin.dataset import read_dataset
    from twin.estimator import calibrate
    from twin.importers.mocap import import_mocap

    res = json.loads((ROOT / "studies" / "tiago_mocap" / "results" / "results.json").read_text())
    fig = next(r for r in res["rows"] if r.get("tool", "").startswith("FIGAROH full"))
    import_mocap([(DATA / "qualisys_2021-11-30_static_postures.csv", "calibration"),
                  (DATA / "qualisys_2021-11-26_static_postures.csv", "validation")],
                 DATA / "tiago_48_schunk.urdf", "base_link", "wrist_ft_tool_link", tmp_path / "m1", points=[1])
    ds = read_dataset(tmp_path / "m1")
    c = calibrate(ds, "best", level="full", robust=False, selection="figaroh")
    ours = [n for n, s in zip(c.names, c.status) if s == "identified"]
    theirs = [_figaroh_to_ours(ds.robot, n) for n in fig["parameter_names"]]
    assert len(ours) == len(theirs) == 30
    prep = prepare(ds)
    J = absolute_residuals(prep.space, prep.x_nominal, prep.obs_cal).J
    A, B = (J[:, [prep.space.index(n) for n in names]] for names in (ours, theirs))
    A, B = A / np.linalg.norm(A, axis=0), B / np.linalg.norm(B, axis=0)
    for M in (A, B, np.hstack([A, B])):
        sv = np.linalg.svd(M, compute_uv=False)
        assert int(np.sum(sv > 1e-6 * sv[0])) == 30
    v = ds.set == "validation"
    e = np.linalg.norm(c.predict(ds.q, ds.station_ids).spheres - ds.spheres, axis=-1)[v] * 1e3
    assert np.sqrt(np.mean(e**2)) == pytest.approx(fig["validation"]["all"]["rmse"], abs=0.005)
    c0 = calibrate(ds, "best", level="full", robust=False)
    assert sum(s == "identified" for s in c0.status) == 33


def test_the_real_campaign_runs_through_calibrate_diagnose_and_predict(imported, tmp_path, capsys):
    """On the committed TIAGo campaign the user's commands run: twin calibrate, twin diagnose (the floor from the
    rows' marker_std_mm, said so; the wrist's backlash kept, named) and twin predict with the extended calibration,
    whose predictions equal the library's on the same rows (the session column restarts the history where the day
    changes, in both)."""
    import shutil

    from twin.cli import main
    from twin.diagnosis import read_diagnosis
    from twin.diagnosis.apply import predict_extended
    from twin.estimator import Calibration
    from twin.estimator.files import read_pred_csv

    shutil.copytree(imported.path, tmp_path / "ds")
    assert main(["calibrate", str(tmp_path / "ds"), "--out", str(tmp_path / "cal"), "--quiet"]) == 0
    assert main(["diagnose", str(tmp_path / "ds"), "--out", str(tmp_path / "d"), "--catalogue-only", "--no-plots",
                 "--no-recording"]) == 0
    d = read_diagnosis(tmp_path / "d" / "diagnosis.json")
    assert "marker_std" in d["noise_floor"]["components"] and "marker_std_mm" in d["noise_floor"]["source"]
    assert any(a["label"].startswith("joint 7 (arm_6_joint) backlash") for a in d["atoms"])
    assert main(["predict", str(tmp_path / "d" / "calibration.json"), str(tmp_path / "ds" / "poses.csv"), "--out",
                 str(tmp_path / "pred.csv"), "--force"]) == 0
    cli = read_pred_csv(tmp_path / "pred.csv")
    lib = predict_extended(Calibration.load(tmp_path / "d" / "calibration.json"), row_context(imported),
                           imported.station_ids).spheres
    np.testing.assert_allclose(cli["spheres"], lib, atol=1e-8)
