"""Tests of any serial chain (``"urdf"`` convention): FK against an independent URDF library, analytic
Jacobians against finite differences, the batched chain, inverse kinematics and export round trips,
identifiability of the known couplings, and inject -> identify round trips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from twin.estimator import calibrate, compensation, identifiability, simulate_dataset
from twin.estimator.chain import Chain
from twin.kinematics import (
    JointSpec,
    RobotModel,
    flange2base,
    inverse_kinematics_iterative,
    joint_jacobian,
    link_frames,
    point_jacobian,
    pose_error,
    pose_jacobian,
    tool2base,
    tool2meas,
)
from twin.robots import joint_table, robot_from_joint_table
from twin.transforms import pose6_to_transform, rotvec_to_matrix
from twin.urdf import UrdfError, chain_mjcf_xml, chain_urdf_xml, read_urdf_chain

DATA = Path(__file__).resolve().parent.parent / "data" / "tiago_mocap"
URDF = DATA / "tiago_48_schunk.urdf"
END = "wrist_ft_tool_link"


def mixed_chain(rng: np.random.Generator, n: int = 7) -> RobotModel:
    """A random chain: revolute and prismatic joints, negative and oblique axes, arbitrary origins."""
    joints = []
    axes = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, 1, 0), (0.3, -0.5, 0.81)]
    for i in range(n):
        kind = "prismatic" if i in (1, 4) else "revolute"
        lim = (-0.2, 0.3) if kind == "prismatic" else (-2.5, 2.5)
        joints.append(JointSpec(name=f"j{i}", kind=kind, xyz=tuple(rng.uniform(-0.2, 0.3, 3)),
                                rpy=tuple(rng.uniform(-2, 2, 3)), axis=axes[i % len(axes)], q_min=lim[0], q_max=lim[1]))
    end = pose6_to_transform(np.r_[rng.uniform(-0.05, 0.05, 3), rng.uniform(-1, 1, 3)])
    m = RobotModel.from_joints("mixed", joints, end_origin=end,
                               base2meas=pose6_to_transform(np.r_[rng.uniform(-1, 1, 3), rng.uniform(-2, 2, 3)]),
                               tool2flange=pose6_to_transform(np.r_[rng.uniform(-0.1, 0.1, 3), rng.uniform(-1, 1, 3)]))
    dev = np.where(m.layout.is_length, rng.normal(0, 1e-3, m.layout.size), rng.normal(0, 5e-3, m.layout.size))
    return m.perturbed(dev)


def random_q(model: RobotModel, rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(np.maximum(model.q_min, -np.pi), np.minimum(model.q_max, np.pi), (n, model.n_joints))


@pytest.fixture(scope="module")
def tiago() -> RobotModel:
    return read_urdf_chain(URDF, "base_link", END)


def test_urdf_chain_matches_yourdfpy_forward_kinematics(tiago):
    """The folded chain's flange pose equals yourdfpy's own scene-graph FK of the URDF (1e-12 m, rad)."""
    import yourdfpy

    u = yourdfpy.URDF.load(str(URDF), build_scene_graph=True, load_meshes=False, load_collision_meshes=False)
    rng = np.random.default_rng(0)
    q = random_q(tiago, rng, 5)
    F = flange2base(tiago, q)
    for k in range(5):
        u.update_cfg(dict(zip(tiago.joint_names, q[k])))
        T = u.get_transform(END, "base_link")
        assert np.abs(pose_error(T, F[k])).max() < 1e-12


def test_urdf_chain_structure_of_the_tiago_arm(tiago):
    """Eight moving joints (torso prismatic, seven revolute), fixed joints folded, masses read."""
    assert tiago.joint_names == ("torso_lift_joint",) + tuple(f"arm_{i}_joint" for i in range(1, 8))
    assert tiago.joint_kinds[0] == "prismatic" and set(tiago.joint_kinds[1:]) == {"revolute"}
    assert tiago.layout.size == 8 * 7 + 12
    assert all(j.inertial and j.inertial["mass"] > 0.2 for j in tiago.structure.joints)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_pose_jacobian_of_a_mixed_chain_matches_finite_differences(seed):
    """Analytic pose Jacobian (every parameter, measurement frame) equals central differences (1e-7)."""
    rng = np.random.default_rng(seed)
    m = mixed_chain(rng)
    q = random_q(m, rng, 4)
    J = pose_jacobian(m, q)
    T0 = tool2meas(m, q)
    h = 1e-6
    for k in range(m.layout.size):
        dp = np.zeros(m.layout.size)
        dp[k] = h
        Tp, Tm = tool2meas(m.perturbed(dp), q), tool2meas(m.perturbed(-dp), q)
        num_p = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
        num_w = (pose_error(Tp, T0)[:, 3:] - pose_error(Tm, T0)[:, 3:]) / (2 * h)
        assert np.abs(J[:, :3, k] - num_p).max() < 1e-7, m.layout.names[k]
        assert np.abs(J[:, 3:, k] - num_w).max() < 1e-7, m.layout.names[k]


def test_joint_jacobian_of_a_mixed_chain_matches_finite_differences():
    """Joint Jacobian (signs of negative axes, prismatic joints) equals central differences in q (1e-7)."""
    rng = np.random.default_rng(7)
    m = mixed_chain(rng)
    q = random_q(m, rng, 3)
    J = joint_jacobian(m, q, frame="base")
    T0 = tool2base(m, q)
    h = 1e-6
    for j in range(m.n_joints):
        dq = np.zeros(m.n_joints)
        dq[j] = h
        Tp, Tm = tool2base(m, q + dq), tool2base(m, q - dq)
        num = np.concatenate([(Tp[:, :3, 3] - Tm[:, :3, 3]), pose_error(Tp, T0)[:, 3:] - pose_error(Tm, T0)[:, 3:]], axis=1)
        assert np.abs(J[:, :, j] - num / (2 * h)).max() < 1e-7


def test_point_jacobian_of_a_mixed_chain_matches_finite_differences():
    """Jacobian of points fixed in the tool equals central differences (1e-7)."""
    rng = np.random.default_rng(8)
    m = mixed_chain(rng)
    q = random_q(m, rng, 3)
    pts = rng.uniform(-0.1, 0.1, (4, 3))
    J = point_jacobian(m, q, pts)
    h = 1e-6

    def P(model):
        T = tool2meas(model, q)
        return np.einsum("nij,kj->nki", T[:, :3, :3], pts) + T[:, None, :3, 3]

    for k in range(0, m.layout.size, 3):
        dp = np.zeros(m.layout.size)
        dp[k] = h
        num = (P(m.perturbed(dp)) - P(m.perturbed(-dp))) / (2 * h)
        assert np.abs(J[..., k] - num).max() < 1e-7


@pytest.mark.parametrize("seed", [4, 5])
def test_batched_chain_matches_the_foundation_on_a_mixed_chain(seed):
    """Chain.evaluate (poses and Jacobian) equals tool2meas / pose_jacobian for a mixed chain (1e-12)."""
    rng = np.random.default_rng(seed)
    m = mixed_chain(rng)
    q = random_q(m, rng, 6)
    ch = Chain.of(m)
    rt, b = ch.split_full(m.params)
    ev = ch.evaluate(rt, q, base6=b)
    T = tool2meas(m, q)
    assert np.abs(ev.R[0] - T[:, :3, :3]).max() < 1e-12 and np.abs(ev.p[0] - T[:, :3, 3]).max() < 1e-12
    J = pose_jacobian(m, q)
    Jrows = ev.rows()[0]  # (n, 6, P_rt + 6): robot+tool, then base
    lay = m.layout
    order = [lay.index(n) for n in ch.rt_names] + list(range(lay.base_slice.start, lay.base_slice.stop))
    assert np.abs(Jrows - J[:, :, order]).max() < 1e-12


@pytest.mark.parametrize("seed", range(10))
def test_iterative_inverse_of_a_redundant_chain_round_trips(seed, tiago):
    """FK -> IK on the 8-joint arm from a perturbed start reaches the pose to 1e-10 (10 seeds)."""
    rng = np.random.default_rng(seed)
    q = random_q(tiago, rng, 5)
    T = tool2base(tiago, q)
    ik = inverse_kinematics_iterative(tiago, T, q + rng.normal(0, 0.05, q.shape), frame="tool")
    assert ik.converged.all()
    assert np.abs(pose_error(T, tool2base(tiago, ik.q))).max() < 1e-10


def test_joint_table_round_trip_keeps_forward_kinematics(tiago):
    """The joint table (dataset.toml / calibration.json form) rebuilds the same chain (1e-12 m)."""
    again = robot_from_joint_table(joint_table(tiago))
    q = random_q(tiago, np.random.default_rng(3), 10)
    assert np.abs(flange2base(again, q) - flange2base(tiago, q)).max() < 1e-12
    assert again.joint_names == tiago.joint_names and np.allclose(again.q_min, tiago.q_min)
    assert again.structure.joints[3].inertial["mass"] == pytest.approx(tiago.structure.joints[3].inertial["mass"])


@pytest.mark.parametrize("seed", [0, 1])
def test_exported_urdf_reads_back_to_the_same_chain(seed, tmp_path):
    """A perturbed mixed chain written as URDF and read back has the same flange and tool poses (1e-9)."""
    rng = np.random.default_rng(seed)
    m = mixed_chain(rng)
    path = tmp_path / "robot.urdf"
    path.write_text(chain_urdf_xml(m))
    back = read_urdf_chain(path, "base", "tool")
    q = random_q(m, rng, 8)
    assert np.abs(pose_error(tool2base(m, q), flange2base(back, q))).max() < 1e-9


def test_exported_6r_urdf_reads_back(tmp_path):
    """The IRB-1200 (MDH + beta, offsets) exported as URDF gives the same flange poses (1e-9)."""
    from twin.robots import irb1200

    m = irb1200().perturbed({"theta2": 0.01, "beta2": 0.002, "d4": 0.001})
    path = tmp_path / "irb.urdf"
    path.write_text(chain_urdf_xml(m))
    back = read_urdf_chain(path, "base", "flange")
    q = random_q(m, np.random.default_rng(2), 8)
    assert np.abs(pose_error(flange2base(m, q), flange2base(back, q))).max() < 1e-9


def test_exported_mjcf_sites_match_forward_kinematics():
    """MuJoCo loads the exported MJCF; its tool and point sites equal the chain's FK (1e-9 m)."""
    import mujoco

    rng = np.random.default_rng(9)
    m = mixed_chain(rng).with_frames(base2meas=np.eye(4))
    pts = rng.uniform(-0.05, 0.05, (3, 3))
    model = mujoco.MjModel.from_xml_string(chain_mjcf_xml(m, tool_points=pts))
    data = mujoco.MjData(model)
    q = random_q(m, rng, 4)
    for k in range(4):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(model, data)
        T = tool2base(m, q[k : k + 1])[0]
        assert np.abs(data.site("tool").xpos - T[:3, 3]).max() < 1e-9
        assert np.abs(data.site("point2").xpos - (T[:3, :3] @ pts[2] + T[:3, 3])).max() < 1e-9


def test_urdf_without_the_named_link_is_refused():
    """An end link the URDF does not have: UrdfError naming the link and the file."""
    with pytest.raises(UrdfError, match="end_link 'no_such_link' is not a link"):
        read_urdf_chain(URDF, "base_link", "no_such_link")


def test_root_link_that_is_not_an_ancestor_is_refused():
    """A root link on another branch of the tree: UrdfError saying it is not an ancestor."""
    with pytest.raises(UrdfError, match="not an ancestor"):
        read_urdf_chain(URDF, "head_2_link", END)


def _tiago_dataset(model, rng, n, *, kind="spheres", pts=None):
    from twin.dataset import Plate

    q = random_q(model, rng, n)
    plate = Plate(0.0, pts if pts is not None else np.array([[0.06, 0.0, 0.07], [0.08, -0.0, -0.09], [0.17, 0.0, -0.06],
                                                               [0.17, 0.0, 0.05]]))
    nominal = read_urdf_chain(URDF, "base_link", END)
    spec = {"convention": "urdf", **joint_table(nominal)}
    ds, truth = simulate_dataset(model, q, robot_spec=spec, plate=plate, kind=kind, noise_position=0.0, rng=rng,
                                 declare_noise=False)
    return ds


def test_identifiability_names_the_couplings_of_the_tiago_arm(tiago):
    """Joint offsets with base and tool unknown: torso offset ~ base z, arm_1 offset ~ base rz (both vertical axes),
    arm_7 offset ~ tool rotation about the flange axis are named; 17 parameters remain with 4 points."""
    rng = np.random.default_rng(0)
    ds = _tiago_dataset(tiago, rng, 40)
    ida = identifiability(ds, level="offsets", rows="all")
    assert ida.find("torso_lift_joint.offset", "base_z") is not None
    assert ida.find("arm_1_joint.offset", "base_rz") is not None
    assert ida.find("arm_7_joint.offset") is not None and any(n.startswith("tool_r") for n in ida.find("arm_7_joint.offset").names)
    assert ida.rank == 17


def test_identifiability_names_redundant_origin_parameters_of_the_tiago_arm(tiago):
    """Full level: an origin rotation about a joint's own axis is its offset (arm_3_joint.rz ~ arm_3_joint.offset),
    the prismatic lift's origin height is the base's z, consecutive origin translations along one axis line are
    one (arm_4_joint.z ~ arm_3_joint.x); 36 of the 68 parameters remain with 4 points."""
    rng = np.random.default_rng(2)
    ds = _tiago_dataset(tiago, rng, 40)
    ida = identifiability(ds, rows="all")
    assert ida.find("arm_3_joint.rz", "arm_3_joint.offset") is not None
    assert ida.find("torso_lift_joint.z", "base_z") is not None
    assert ida.find("arm_4_joint.z", "arm_3_joint.x") is not None
    assert ida.rank == 36 and len(ida.names) == 68


def test_identifiability_names_in_line_prismatic_and_revolute_axes():
    """A prismatic joint whose axis is the next revolute joint's axis: the prismatic offset, the revolute joint's
    origin z and the base's z are one translation along that line; full-level analysis names the coupling."""
    joints = [JointSpec("lift", "prismatic", (0, 0, 0.3), (0, 0, 0), (0, 0, 1), 0.0, 0.4),
              JointSpec("turn", "revolute", (0, 0, 0.2), (0, 0, 0), (0, 0, 1), -3, 3),
              JointSpec("shoulder", "revolute", (0.1, 0, 0.1), (1.5707963267948966, 0, 0), (0, 0, 1), -2, 2),
              JointSpec("elbow", "revolute", (0.3, 0, 0), (0, 0, 0), (0, 0, 1), -2, 2)]
    m = RobotModel.from_joints("lifter", joints, end_origin=pose6_to_transform(np.array([0.2, 0, 0, 0, 0, 0])))
    rng = np.random.default_rng(1)
    from twin.dataset import Plate

    q = random_q(m, rng, 30)
    spec = {"convention": "urdf", **joint_table(m)}
    ds, _ = simulate_dataset(m, q, robot_spec=spec, plate=Plate(0.0, np.array([[0.0, 0.05, 0.0], [0.0, 0, 0.05],
                                                                              [0.05, 0, 0]])), kind="spheres", rng=rng)
    ida = identifiability(ds, rows="all")
    c = ida.find("lift.offset")
    assert c is not None and "base_z" in c.names
    assert ida.find("turn.z", "base_z") is not None and ida.find("lift.z", "base_z") is not None
    assert ida.find("turn.offset", "base_rz") is not None


@pytest.mark.parametrize("seed", range(10))
def test_inject_identify_round_trip_on_the_tiago_arm(seed, tiago):
    """Random geometric errors (1 mm, 2 mrad, offsets 10 mrad) injected on every parameter; full-level identification
    from noise-free 4-point data predicts new configurations to 1e-6 mm (10 seeds)."""
    rng = np.random.default_rng(100 + seed)
    lay = tiago.layout
    dev = np.where(lay.is_length, rng.normal(0, 1e-3, lay.size), rng.normal(0, 2e-3, lay.size))
    dev[lay.family("offset")] = rng.normal(0, 1e-2, 8) * np.where(tiago.is_prismatic, 0.1, 1.0)
    truth = tiago.perturbed(dev).with_frames(base2meas=pose6_to_transform(np.r_[0.01, 0.2, -0.2, 0.01, 0.02, -0.01]))
    ds = _tiago_dataset(truth, rng, 60)
    ds = ds.__class__(**{**ds.__dict__, "set": np.array(["calibration"] * 60, dtype=object)})
    cal = calibrate(ds, "best", robust=False)
    qn = random_q(tiago, rng, 20)
    pred = cal.predict(qn, np.array(["0"] * 20, dtype=object)).spheres
    T = tool2meas(truth, qn)
    pts = ds.plate.spheres_flange
    true_pts = np.einsum("nij,kj->nki", T[:, :3, :3], pts) + T[:, None, :3, 3]
    assert np.abs(pred - true_pts).max() < 1e-9


def test_compensation_on_the_redundant_arm_reaches_the_targets(tiago):
    """Targets from the nominal arm, compensated on a calibration: the identified model reaches them (1e-9 m)."""
    rng = np.random.default_rng(5)
    lay = tiago.layout
    dev = np.where(lay.is_length, rng.normal(0, 1e-3, lay.size), rng.normal(0, 2e-3, lay.size))
    dev[lay.base_slice] = 0.0
    truth = tiago.perturbed(dev)
    ds = _tiago_dataset(truth, rng, 50)
    cal = calibrate(ds, "best", robust=False, validation_fraction=0.0)
    q = random_q(tiago, rng, 5)
    q = np.clip(q, tiago.q_min + 0.2, tiago.q_max - 0.2)
    q[:, 0] = 0.15
    T = tool2base(tiago, q)
    res = compensation(cal, T, q)
    assert np.abs(pose_error(T, tool2base(cal.robot, res.q))[:, :3]).max() < 1e-9
    assert np.abs(res.q - q).max() < 0.1


def test_link_frames_end_at_the_flange_of_a_chain(tiago):
    """Frames 0..N of a chain: frame N is the flange (end link), frame 0 the base."""
    q = random_q(tiago, np.random.default_rng(4), 3)
    F = link_frames(tiago, q)
    assert F.shape == (3, 9, 4, 4)
    assert np.abs(F[:, -1] - flange2base(tiago, q)).max() < 1e-15


def test_oblique_axis_turns_about_that_axis():
    """A revolute joint with an oblique axis rotates the flange about that axis by the joint angle."""
    a = np.array([0.3, -0.5, 0.81])
    a /= np.linalg.norm(a)
    m = RobotModel.from_joints("one", [JointSpec("j", "revolute", (0, 0, 0), (0, 0, 0), tuple(a), -3, 3)])
    F = flange2base(m, np.array([[0.7]]))[0]
    assert np.abs(F[:3, :3] - rotvec_to_matrix(a * 0.7)).max() < 1e-14


def test_plan_on_the_eight_joint_arm_picks_visible_configurations(tiago):
    """Planning on a chain without a closed-form inverse samples joint space: every chosen configuration of the
    8-joint arm is visible and inside the limits, and the D-optimal plan predicts no worse than random plans."""
    from twin.dataset import Plate
    from twin.estimator.planning import PlanOptions, StereoCamera, plan_measurements, visibility
    from twin.transforms import invert_transform, make_transform

    cam = StereoCamera.from_json_dict({
        "kind": "stereo_camera", "image_width": 1280, "image_height": 1024,
        "left": {"fx_px": 900, "fy_px": 900, "cx_px": 640, "cy_px": 512},
        "right": {"fx_px": 900, "fy_px": 900, "cx_px": 640, "cy_px": 512},
        "left2right": {"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t_mm": [-200.0, 0, 0]}})
    cam2base = make_transform(np.array([[0, 0, -1], [-1, 0, 0], [0, -1, 0]], dtype=float), np.array([1.6, 0.0, 0.9]))
    b2m = invert_transform(cam2base)
    plate = Plate(0.0, np.array([[0.06, 0, 0.07], [0.08, 0, -0.09], [0.17, 0.01, -0.06], [0.17, 0, 0.05]]))
    opts = PlanOptions(depth=(1.0, 2.0), max_tilt=np.deg2rad(80))
    res = plan_measurements(tiago, {"front": b2m}, cam, plate, 25, pool_per_station=120, n_random=4, seed=1,
                            options=opts)
    assert res.q.shape == (25, 8) and tiago.within_limits(res.q).all()
    assert visibility(tiago, res.q, b2m, cam, plate, opts)[0].all()
    assert res.floor_plan <= np.median(res.floor_random)


def _mimic_urdf(path: Path) -> Path:
    """A two-joint arm whose second joint mimics the first (q2 = 0.5 q1 + 0.1), with a finger off the chain that
    mimics joint 2."""
    link = "".join(f'<link name="{n}"/>' for n in ("base", "l1", "l2", "flange", "finger"))
    j = ('<joint name="{n}" type="{t}"><parent link="{p}"/><child link="{c}"/><origin xyz="0 0 0.3" rpy="0 0 0"/>'
         '<axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/>{m}</joint>')
    joints = [j.format(n="j1", t="revolute", p="base", c="l1", m=""),
              j.format(n="j2", t="revolute", p="l1", c="l2", m='<mimic joint="j1" multiplier="0.5" offset="0.1"/>'),
              j.format(n="j3", t="revolute", p="l2", c="flange", m=""),
              j.format(n="finger_joint", t="prismatic", p="l1", c="finger", m='<mimic joint="j2"/>')]
    path.write_text(f'<?xml version="1.0"?><robot name="mimic_arm">{link}{"".join(joints)}</robot>')
    return path


def test_a_mimic_joint_on_the_chain_is_refused_and_one_off_it_is_not(tmp_path):
    """URDF <mimic>: a joint on the chain driven by another (q = m q_ref + o) is refused naming both joints and the
    law; a mimic joint off the chain (a finger) leaves the chain's independent joints as they are."""
    urdf = _mimic_urdf(tmp_path / "arm.urdf")
    with pytest.raises(UrdfError, match=r"joint 'j2' on the chain mimics joint 'j1' \(q = 0.5 \* q_j1 \+ 0.1\)"):
        read_urdf_chain(urdf, "base", "flange")
    assert read_urdf_chain(urdf, "l2", "flange").joint_names == ("j3",)
    assert read_urdf_chain(urdf, "base", "l1").joint_names == ("j1",)
