"""The drawn campaigns' robots: nominal tables, joint limits, mass models, the joint box a campaign's plan is drawn
in, a true geometry off the nominal one, and the ``[robot]`` table the dataset states.

* ``irb1200``: ABB IRB 1200-7/0.7, Craig modified DH with beta on joint 2 (the nominal table of
  ``docs/conventions.md``); a made-up mass model of about 34 kg (the arm's published weight is 52 kg with its base).
* ``ur5``, ``ur10``: Universal Robots' published standard DH tables and their published link masses and centres of
  mass (in the DH frame after each joint), with beta on joints 2 and 3 (axes 2, 3 and 4 are parallel).

A dataset names the IRB 1200 (``robot = "irb1200"``) or states a UR's DH table inline; when a campaign *states the
masses* it writes the chain as a joint table with each link's mass and centre of mass (about 8 % and 8 mm off the
true ones), the form ``docs/formats.md`` documents.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from twin.units import DEG_PER_RAD, MM_PER_M, M_PER_MM, RAD_PER_DEG

from . import kin

__all__ = [
    "Robot", "ROBOTS", "IRB1200", "UR5", "UR10", "true_params", "params_record", "params_from_record", "joint_table",
    "robot_toml"
]


@dataclass(frozen=True)
class Robot:
    """A 6R arm: ``convention`` (``mdh``/``dh``), nominal ``params`` (``theta, d, a, alpha, beta`` ``(6,)`` [m, rad]),
    ``beta_joints`` (1-based), limits [rad], ``bodies`` ``(frame, kg, com [m])``, the joint box a plan is drawn in
    ``box`` ``(6, 2)`` [rad], its rated payload [kg]."""

    name: str
    convention: str
    params: dict
    beta_joints: tuple[int, ...]
    q_min: np.ndarray
    q_max: np.ndarray
    bodies: tuple
    box: np.ndarray
    payload_kg: float
    length_names: tuple[str, ...] = field(default=())

    def frames(self, params: dict, q: np.ndarray, length_scale: np.ndarray | None = None) -> np.ndarray:
        return kin.frames(self.convention, params, q, length_scale)

    def torques(self, F: np.ndarray, bodies=None) -> np.ndarray:
        return kin.gravity_torques(self.convention, F, self.bodies if bodies is None else bodies)


def _params(theta_deg, d_mm, a_mm, alpha_deg, beta_deg=(0,) * 6) -> dict:
    return {"theta": np.asarray(theta_deg, float) * RAD_PER_DEG, "d": np.asarray(d_mm, float) * M_PER_MM,
            "a": np.asarray(a_mm, float) * M_PER_MM, "alpha": np.asarray(alpha_deg, float) * RAD_PER_DEG,
            "beta": np.asarray(beta_deg, float) * RAD_PER_DEG}


def _lengths(p: dict) -> tuple[str, ...]:
    """The names of the link lengths that are not zero (``d1``, ``a3``, ...): what thermal growth can stretch."""
    return tuple(f"{k}{i + 1}" for k in ("d", "a") for i in range(6) if abs(p[k][i]) > 1e-9)


def _deg(x) -> np.ndarray:
    return np.asarray(x, float) * RAD_PER_DEG


IRB1200 = Robot(
    name="irb1200", convention="mdh",
    params=_params([0, -90, 0, 0, 0, 0], [399.1, 0, 0, 351.0, 0, 82.0], [0, 0, 350.0, 42.0, 0, 0],
                   [0, -90, 0, -90, 90, -90]),
    beta_joints=(2,),
    q_min=_deg([-170, -100, -200, -270, -130, -360]), q_max=_deg([170, 130, 70, 270, 130, 360]),
    # (MDH frame, mass [kg], centre of mass in that frame [m]): column, upper arm, elbow, forearm, wrist, flange
    bodies=((1, 13.0, np.array([-0.030, 0.010, -0.110])), (2, 9.5, np.array([0.160, 0.004, 0.045])),
            (3, 5.5, np.array([0.020, -0.035, 0.012])), (4, 3.2, np.array([0.000, 0.003, -0.165])),
            (5, 1.3, np.array([0.000, 0.022, 0.002])), (6, 0.55, np.array([-0.004, 0.012, 0.028]))),
    box=_deg([[-70, 70], [-45, 85], [-95, 45], [-170, 170], [-115, 115], [-180, 180]]),
    payload_kg=7.0,
)

UR5 = Robot(
    name="ur5", convention="dh",
    params=_params([0] * 6, [89.159, 0, 0, 109.15, 94.65, 82.3], [0, -425.0, -392.25, 0, 0, 0], [90, 0, 0, 90, -90, 0]),
    beta_joints=(2, 3),
    q_min=_deg([-360] * 6), q_max=_deg([360] * 6),
    bodies=((1, 3.7, np.array([0.0, -0.02561, 0.00193])), (2, 8.393, np.array([0.2125, 0.0, 0.11336])),
            (3, 2.33, np.array([0.15, 0.0, 0.0265])), (4, 1.219, np.array([0.0, -0.0018, 0.01634])),
            (5, 1.219, np.array([0.0, 0.0018, 0.01634])), (6, 0.1879 + 0.25, np.array([0.0, 0.0, 0.02]))),
    box=_deg([[-70, 70], [-150, -30], [-140, 140], [-200, 20], [-150, 150], [-180, 180]]),
    payload_kg=5.0,
)

UR10 = Robot(
    name="ur10", convention="dh",
    params=_params([0] * 6, [127.3, 0, 0, 163.941, 115.7, 92.2], [0, -612.0, -572.3, 0, 0, 0], [90, 0, 0, 90, -90, 0]),
    beta_joints=(2, 3),
    q_min=_deg([-360] * 6), q_max=_deg([360] * 6),
    bodies=((1, 7.1, np.array([0.021, 0.0, 0.027])), (2, 12.7, np.array([0.38, 0.0, 0.158])),
            (3, 4.27, np.array([0.24, 0.0, 0.068])), (4, 2.0, np.array([0.0, 0.007, 0.018])),
            (5, 2.0, np.array([0.0, 0.007, 0.018])), (6, 0.365 + 0.3, np.array([0.0, 0.0, 0.0]))),
    box=_deg([[-70, 70], [-150, -30], [-140, 140], [-200, 20], [-150, 150], [-180, 180]]),
    payload_kg=10.0,
)

ROBOTS = {r.name: r for r in (IRB1200, UR5, UR10)}
ROBOTS = {k: Robot(**{**r.__dict__, "length_names": _lengths(r.params)}) for k, r in ROBOTS.items()}


def true_params(robot: Robot, rng: np.random.Generator) -> dict:
    """A true geometry: every length off nominal by N(0, 0.2 mm), every angle by N(0, 0.02 deg), beta of the
    declared joints by N(0, 0.015 deg); all clipped at 3 sd."""
    p = {k: v.copy() for k, v in robot.params.items()}
    ls, asd, bsd = 0.2 * M_PER_MM, 0.02 * RAD_PER_DEG, 0.015 * RAD_PER_DEG
    for k, sd in (("d", ls), ("a", ls), ("theta", asd), ("alpha", asd)):
        p[k] = p[k] + np.clip(rng.normal(0, sd, 6), -3 * sd, 3 * sd)
    for j in robot.beta_joints:
        p["beta"][j - 1] += float(np.clip(rng.normal(0, bsd), -3 * bsd, 3 * bsd))
    return p


def params_record(p: dict, beta_joints) -> dict:
    """A geometry in mm / deg for the key (``theta1_deg``, ``d1_mm``, ..., ``beta2_deg``)."""
    out = {}
    for k in ("theta", "d", "a", "alpha"):
        for i in range(6):
            v = p[k][i] * (DEG_PER_RAD if k in ("theta", "alpha") else MM_PER_M)
            out[f"{k}{i + 1}_{'deg' if k in ('theta', 'alpha') else 'mm'}"] = round(float(v), 9)
    for j in beta_joints:
        out[f"beta{j}_deg"] = round(float(p["beta"][j - 1] * DEG_PER_RAD), 9)
    return out


def params_from_record(rec: dict) -> dict:
    """Inverse of :func:`params_record`."""
    p = {k: np.zeros(6) for k in ("theta", "d", "a", "alpha", "beta")}
    for name, v in rec.items():
        stem, unit = name.rsplit("_", 1)
        k, i = stem.rstrip("0123456789"), int(stem[len(stem.rstrip("0123456789")):]) - 1
        p[k][i] = v * (RAD_PER_DEG if unit == "deg" else M_PER_MM)
    return p


def _num(x: float, nd: int = 6) -> str:
    s = f"{x:.{nd}f}".rstrip("0").rstrip(".")
    return "0" if s in ("", "-0") else s


def _vec(v, nd: int = 6) -> str:
    return "[" + ", ".join(_num(float(x), nd) for x in v) + "]"


def _rpy(R: np.ndarray) -> np.ndarray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` -> ``(roll, pitch, yaw)`` [rad]."""
    pitch = np.arcsin(np.clip(-R[2, 0], -1, 1))
    if abs(np.cos(pitch)) > 1e-9:
        return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])
    return np.array([0.0, pitch, np.arctan2(-R[0, 1], R[1, 1])])


def joint_table(robot: Robot, stated_bodies) -> tuple[list, np.ndarray]:
    """The nominal chain as URDF-style joints ``[(xyz [m], rpy [rad], mass [kg], com [m] in the joint's child
    frame)]`` and the end (flange) origin 4x4. mdh: joint i's origin is ``RotX(alpha) TransX(a) TransZ(d)
    RotZ(theta)`` and its child frame is MDH frame i. dh: joint i's origin is the previous joint's
    ``TransZ(d) TransX(a) RotX(alpha)`` then ``RotZ(theta_i)``; its child frame lies ``TransZ(d_i) TransX(a_i)
    RotX(alpha_i)`` before DH frame i, where the published centre of mass is written."""
    p = robot.params
    out = []
    prev = np.eye(4)  # dh: the fixed part after the previous joint
    for i in range(6):
        if robot.convention == "mdh":
            O = np.eye(4)
            O[:3, :3] = kin.rotx(p["alpha"][i]) @ kin.rotz(p["theta"][i])
            O[:3, 3] = kin.rotx(p["alpha"][i]) @ np.array([p["a"][i], 0.0, p["d"][i]])
            child2frame = np.eye(4)
        else:
            Rt = np.eye(4)
            Rt[:3, :3] = kin.rotz(p["theta"][i])
            O = prev @ Rt
            after = np.eye(4)
            after[:3, :3] = kin.rotx(p["alpha"][i])
            after[:3, 3] = np.array([p["a"][i], 0.0, p["d"][i]])
            prev = after
            child2frame = after  # DH frame i = child frame . after
        _, m, c = stated_bodies[i]
        com_child = child2frame[:3, :3] @ c + child2frame[:3, 3]
        out.append((O[:3, 3].copy(), _rpy(O[:3, :3]), float(m), com_child))
    end = prev if robot.convention == "dh" else np.eye(4)
    return out, end


def robot_toml(robot: Robot, stated_bodies=None) -> list[str]:
    """The dataset's robot: a name (IRB 1200), an inline DH table (UR) or, with stated masses, a joint table."""
    if stated_bodies is None:
        if robot.name == "irb1200":
            return ['robot = "irb1200"']
        p = robot.params
        return ["", "[robot]", f'name = "{robot.name}"', 'convention = "dh"',
                f"beta_joints = {list(robot.beta_joints)}",
                f"theta_deg = {_vec(p['theta'] * DEG_PER_RAD)}", f"d_mm = {_vec(p['d'] * MM_PER_M)}",
                f"a_mm = {_vec(p['a'] * MM_PER_M)}", f"alpha_deg = {_vec(p['alpha'] * DEG_PER_RAD)}",
                f"beta_deg = {_vec([0.0] * len(robot.beta_joints))}",
                f"q_min_deg = {_vec(robot.q_min * DEG_PER_RAD, 1)}", f"q_max_deg = {_vec(robot.q_max * DEG_PER_RAD, 1)}"]
    joints, end = joint_table(robot, stated_bodies)
    lines = ["", "[robot]", f'name = "{robot.name}_masses"', 'convention = "urdf"', "joints = ["]
    for i, (xyz, rpy, m, c) in enumerate(joints):
        lim = [robot.q_min[i] * DEG_PER_RAD, robot.q_max[i] * DEG_PER_RAD]
        lines.append(f'  {{ name = "q{i + 1}", type = "revolute", xyz_mm = {_vec(xyz * MM_PER_M, 5)}, '
                     f"rpy_deg = {_vec(rpy * DEG_PER_RAD, 7)}, axis = [0, 0, 1], limits = {_vec(lim, 1)}, "
                     f"mass_kg = {_num(m, 4)}, com_mm = {_vec(c * MM_PER_M, 2)} }},")
    lines += ["]", f"end = {{ xyz_mm = {_vec(end[:3, 3] * MM_PER_M, 5)}, rpy_deg = {_vec(_rpy(end[:3, :3]) * DEG_PER_RAD, 7)} }}"]
    return lines
