"""The generated MJCF: body frames follow the numpy kinematic chain; static and composed files load cleanly."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import mujoco

from twin.kinematics import link_frames, tool2meas
from twin.presets import preset_deviation
from twin.resources import model_file, model_names
from twin.robots import get_robot
from twin.transforms import pose6_to_transform, rotation_angle_between
from twin.world.mjcf import joint_geometry, robot_mjcf_xml

N_CONFIGS = 1000


def _perturbed(name: str, preset: str, seed: int):
    """The preset errors plus a random base and tool transform (so base/tool handling is exercised too)."""
    rng = np.random.default_rng(seed)
    r = get_robot(name).perturbed(preset_deviation(preset))
    base = r.base2meas @ pose6_to_transform(np.r_[rng.normal(0, 0.2, 3), rng.normal(0, 0.3, 3)])
    tool = r.tool2flange @ pose6_to_transform(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.02, 3)])
    return r.with_frames(base2meas=base, tool2flange=tool)


def _mujoco_vs_numpy(robot_mj, robot_np, seed: int):
    """Largest position [m] and angle [rad] differences of the plate site and link bodies over random q."""
    m = mujoco.MjModel.from_xml_string(robot_mjcf_xml(robot_mj))
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "plate")
    bodies = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"link{i}") for i in range(1, 7)]
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot_np.q_min, robot_np.q_max, size=(N_CONFIGS, 6))
    T = tool2meas(robot_np, q)
    F = link_frames(robot_np, q, frame="meas")
    dp = dr = 0.0
    for k in range(N_CONFIGS):
        d.qpos[:] = q[k]
        mujoco.mj_kinematics(m, d)  # body and site poses from qpos: nothing dynamic needed
        dp = max(dp, np.linalg.norm(d.site_xpos[site] - T[k, :3, 3]))
        dr = max(dr, rotation_angle_between(d.site_xmat[site].reshape(3, 3), T[k, :3, :3]))
        for i, b in enumerate(bodies):
            dp = max(dp, np.linalg.norm(d.xpos[b] - F[k, i + 1, :3, 3]))
            dr = max(dr, rotation_angle_between(d.xmat[b].reshape(3, 3), F[k, i + 1, :3, :3]))
    return dp, dr


@pytest.mark.parametrize("name,preset", [("irb1200", "separation_tables_2_4"), ("brtirus0707a", "tmmdh_tables_4_5")])
def test_mujoco_plate_pose_equals_numpy_fk(name, preset):
    """Over 1,000 random configurations of a perturbed robot, MuJoCo's plate site and link frames equal the numpy FK."""
    robot = _perturbed(name, preset, seed=1)
    dp, dr = _mujoco_vs_numpy(robot, robot, seed=2)
    assert dp < 1e-9
    assert dr < 1e-9


def test_fk_comparison_detects_a_one_micron_error():
    """The same comparison flags an MJCF built from parameters 1 um off in d4 (so the test above can fail)."""
    robot = _perturbed("irb1200", "separation_tables_2_4", seed=1)
    dp, _ = _mujoco_vs_numpy(robot.perturbed({"d4": 1e-6}), robot, seed=2)
    assert dp > 5e-7


def test_joint_geometry_is_a_unit_hinge_through_the_chain():
    """Each hinge axis is a unit vector and body placement equals the link transform at q = 0."""
    robot = _perturbed("brtirus0707a", "tmmdh_tables_4_5", seed=3)
    from twin.kinematics import link_transforms

    L0 = link_transforms(robot, np.zeros((1, 6)))[0]
    for i, g in enumerate(joint_geometry(robot)):
        assert abs(np.linalg.norm(g.axis) - 1.0) < 1e-12
        assert np.allclose(g.body2parent, L0[i], atol=1e-15)


@pytest.mark.parametrize("name", model_names())
def test_static_scene_files_load(name: str):
    """Every packaged static scene file (models/, installed as twin.models) loads with mujoco.MjModel.from_xml_string."""
    m = mujoco.MjModel.from_xml_string(model_file(name).read_text())
    assert m.ngeom >= 1


def test_static_files_exist():
    """The scene, rig and board files the composer merges are packaged."""
    assert set(model_names()) >= {"scene.xml", "rig.xml", "board.xml"}


def test_model_file_takes_only_bare_names():
    """A packaged model is named by its bare file name; a path or an unknown name is refused, naming it."""
    with pytest.raises(ValueError, match="bare file name"):
        model_file("models/scene.xml")
    with pytest.raises(FileNotFoundError) as e:
        model_file("nope.xml")
    assert e.value.filename == "models/nope.xml"


def test_checkout_reads_the_models_at_the_repository_top():
    """In the checkout's install, the packaged models are the files of the top-level models/ folder (one copy)."""
    top = Path(__file__).resolve().parent.parent / "models"
    for name in model_names():
        assert Path(str(model_file(name))).resolve() == top / name
    assert model_names() == sorted(p.name for p in top.glob("*.xml"))


def test_robot_mass_and_gravity_statics_are_plausible():
    """The arm weighs ~52 kg and mj_forward gives finite gravity torques of tens of N m at the shoulder."""
    robot = get_robot("irb1200")
    m = mujoco.MjModel.from_xml_string(robot_mjcf_xml(robot))
    d = mujoco.MjData(m)
    plate = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "plate")
    arm = sum(m.body_mass[b] for b in range(1, m.nbody) if b != plate)
    assert 51.0 < arm < 53.5
    d.qpos[:] = np.deg2rad([0, 30, 0, 0, 30, 0])
    mujoco.mj_forward(m, d)  # full forward: qfrc_bias (gravity torques) needs the dynamics stages
    assert np.all(np.isfinite(d.qfrc_bias))
    assert 20.0 < abs(d.qfrc_bias[1]) < 400.0
    assert all(w.number == 0 for w in d.warning)


def test_composed_twin_loads_from_disk_without_warnings(tmp_path, capfd):
    """The composed twin written next to a campaign's outputs loads alone, with no MuJoCo warning."""
    from twin.world import World

    w = World.from_config({"render": {"scale": 0.25}, "board": {"texture_px_per_square": 64}})
    path = w.write_mjcf(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = mujoco.MjModel.from_xml_path(str(path))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)  # full forward once: any runtime warning would show in d.warning
    out = capfd.readouterr()
    assert not caught
    assert "WARNING" not in out.out.upper() and "WARNING" not in out.err.upper()
    assert all(w.number == 0 for w in d.warning)
    assert m.ncam == 2 and m.vis.global_.offwidth >= 648
