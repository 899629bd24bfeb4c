"""Data conversions of the peer adapters (URDF, pybotics MDH). `make test` installs the peers (Makefile target
`peers`); where one is missing its tests skip and say which and why."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments.peers.synthetic import make_problem, sample_configurations  # noqa: E402
from experiments.peers.urdf import model_to_urdf  # noqa: E402
from twin.kinematics import tool2base, tool2meas  # noqa: E402
from twin.presets import preset_deviation  # noqa: E402
from twin.robots import brtirus0707a  # noqa: E402

_WHY = "not installed: `make install` installs the peer calibrators (the `peers` extra of uv.lock)"


def _need(module: str):
    """The peer's module, or a skip naming it and how to install it."""
    return pytest.importorskip(module, reason=f"{module} {_WHY}")


def _models():
    pb = make_problem()
    tm = brtirus0707a().perturbed(preset_deviation("tmmdh_tables_4_5"))
    return [pb.nominal, pb.truth, tm]


@pytest.mark.parametrize("with_base", [False, True])
def test_urdf_reproduces_our_forward_kinematics(with_base):
    """Pinocchio on the written URDF gives our tool poses (MDH and DH, with beta, base and tool) to 1e-12."""
    pin = _need("pinocchio")
    rng = np.random.default_rng(7)
    for model in _models():
        urdf = model_to_urdf(model, base2meas=model.base2meas if with_base else None)
        pm = pin.buildModelFromXML(urdf)
        data = pm.createData()
        fid = pm.getFrameId("tool")
        q = rng.uniform(-2.5, 2.5, (10, 6))
        ours = tool2meas(model, q) if with_base else tool2base(model, q)
        for qi, Ti in zip(q, ours):
            pin.framesForwardKinematics(pm, data, qi)
            np.testing.assert_allclose(data.oMf[fid].homogeneous, Ti, atol=1e-12)


def test_urdf_origin_is_exact_at_gimbal_lock():
    """A joint origin at pitch = -90 deg (the IRB-1200's joint 2) is written without losing the yaw."""
    pin = _need("pinocchio")
    model = make_problem().nominal
    pm = pin.buildModelFromXML(model_to_urdf(model))
    data = pm.createData()
    q = np.zeros(6)
    pin.framesForwardKinematics(pm, data, q)
    np.testing.assert_allclose(data.oMf[pm.getFrameId("tool")].homogeneous, tool2base(model, q[None])[0], atol=1e-12)


def test_pybotics_robot_matches_our_model():
    """The pybotics Robot built from our MDH table, world frame and tool point gives our tool positions."""
    _need("pybotics")
    from experiments.peers.pybotics_adapter import build_robot

    pb = make_problem()
    model = pb.nominal.perturbed({"theta2": 0.01, "a3": 0.002, "alpha4": -0.003})
    base2meas = pb.truth.base2meas
    tool = np.array([0.01, -0.02, 0.05])
    robot = build_robot(model, base2meas, tool)
    ref = model.with_frames(base2meas=base2meas, tool2flange=np.block([[np.eye(3), tool[:, None]], [0, 0, 0, 1]]))
    q = sample_configurations(model, 10, np.random.default_rng(0))
    got = np.array([robot.fk(qi)[:3, 3] for qi in q]) / 1e3
    np.testing.assert_allclose(got, tool2meas(ref, q)[:, :3, 3], atol=1e-12)


def test_pybotics_refuses_a_model_with_beta():
    """pybotics has no beta: converting a model with beta2 != 0 raises instead of dropping it."""
    from experiments.peers.pybotics_adapter import mdh_table_mm

    with pytest.raises(ValueError, match="beta"):
        mdh_table_mm(make_problem().truth)


def _beta_free_case():
    """The benchmark problem, a true robot carrying the Tables 2+4 presets without beta (the peers' models have
    none), and 30 calibration / 10 validation configurations."""
    pb = make_problem()
    dev = {k: v for k, v in preset_deviation("separation_tables_2_4").items() if not k.startswith("beta")}
    truth = pb.nominal.perturbed(dev).with_frames(base2meas=pb.truth.base2meas, tool2flange=pb.truth.tool2flange)
    rng = np.random.default_rng(1)
    return pb, truth, sample_configurations(truth, 30, rng), sample_configurations(truth, 10, rng)


@pytest.mark.slow
def test_robotkinecal_recovers_a_noise_free_robot():
    """robotkinecal (on numpy 2) calibrates our URDF to noise-free poses of a perturbed beta-free robot and then
    predicts held-out poses to round-off: the adapter's conversions (URDF, SE3, joints) are consistent. Slow:
    importing robotkinecal (Robotics Toolbox) takes seconds."""
    _need("robotkinecal")
    from experiments.peers.robotkinecal_adapter import calibrate

    pb, truth, q_cal, q_val = _beta_free_case()
    res = calibrate(pb.nominal, q_cal, tool2meas(truth, q_cal), q_val, variant="pose")
    assert res.ok, res.error
    T = tool2meas(truth, q_val)
    assert np.abs(res.positions - T[:, :3, 3]).max() < 1e-9
    assert np.abs(res.rotations - T[:, :3, :3]).max() < 1e-9


@pytest.mark.slow
def test_figaroh_recovers_a_noise_free_robot():
    """FIGAROH (full_params, frames unknown) calibrates our URDF to noise-free poses of a perturbed beta-free
    robot, far from nominal, and then predicts held-out poses to round-off: the adapter's conversions (URDF,
    its CSV of positions and roll-pitch-yaw, joints) are consistent. Slow: importing FIGAROH takes seconds."""
    _need("figaroh")
    _need("pinocchio")
    from experiments.peers.figaroh_adapter import calibrate

    pb, truth, q_cal, q_val = _beta_free_case()
    T = tool2meas(truth, q_val)
    nominal_in_truth_frames = pb.nominal.with_frames(base2meas=truth.base2meas, tool2flange=truth.tool2flange)
    assert np.abs(tool2meas(nominal_in_truth_frames, q_val)[:, :3, 3] - T[:, :3, 3]).max() > 1e-4  # work to do
    res = calibrate(pb.nominal, q_cal, tool2meas(truth, q_cal), q_val, 1e-5, 1e-4, variant="pose")
    assert res.ok, res.error
    assert np.abs(res.positions - T[:, :3, 3]).max() < 1e-9
    assert np.abs(res.rotations - T[:, :3, :3]).max() < 1e-9
