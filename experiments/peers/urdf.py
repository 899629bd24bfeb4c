"""MDH/DH (+ beta) robot model -> URDF, for the peers that read robots from URDF (FIGAROH via Pinocchio,
robotkinecal via the Robotics Toolbox).

A URDF joint applies a fixed ``origin`` (xyz, then rpy with ``R = Rz(yaw) Ry(pitch) Rx(roll)``) and then the
rotation ``q`` about its ``axis`` (here ``0 0 1``). Joint ``i`` of our chain is
``pre_i RotZ(theta_i + q_i) post_i`` (``docs/conventions.md``: for MDH ``pre = RotX(alpha) TransX(a) TransZ(d)``,
``post = RotY(beta)``; for DH ``pre`` is empty and ``post = TransZ(d) TransX(a) RotX(alpha) RotY(beta)`` with
``TransZ(d)`` commuting with the joint rotation). So URDF joint ``i`` gets the origin
``post_{i-1} pre_i RotZ(theta_i)`` and the fixed ``tool`` joint the origin ``post_6 tool2flange``. An optional
fixed joint from a ``meas`` root link places the robot base with ``base2meas``.

Frames produced: ``base_link`` (robot base), ``link1`` .. ``link6`` (``link6`` is the flange frame), ``tool``
(the measured tool frame), and ``meas`` when ``base2meas`` is given. Joints ``joint1`` .. ``joint6``.
"""

from __future__ import annotations

import numpy as np

from twin.kinematics import N_JOINTS, RobotModel
from twin.transforms import euler_zyx_from_matrix, make_transform, rot_x, rot_y, rot_z

__all__ = ["joint_origins", "model_to_urdf", "write_urdf"]


def _trans(axis: int, v: float) -> np.ndarray:
    T = np.eye(4)
    T[axis, 3] = v
    return T


def _rot(axis: int, v: float) -> np.ndarray:
    return make_transform((rot_x, rot_y, rot_z)[axis](v), np.zeros(3))


def _pre_post(model: RobotModel, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Constant transforms (pre, post) around the joint rotation of joint ``i`` (0-based)."""
    th, d, a, al, be = model.theta[i], model.d[i], model.a[i], model.alpha[i], model.beta[i]
    if model.convention == "mdh":
        pre = _rot(0, al) @ _trans(0, a) @ _trans(2, d) @ _rot(2, th)
        post = _rot(1, be)
    else:  # dh: RotZ(theta+q) TransZ(d) ... ; TransZ(d) commutes with RotZ, keep it after the joint
        pre = _rot(2, th)
        post = _trans(2, d) @ _trans(0, a) @ _rot(0, al) @ _rot(1, be)
    return pre, post


def joint_origins(model: RobotModel) -> tuple[list[np.ndarray], np.ndarray]:
    """The six revolute joints' origin transforms ``(4, 4)`` and the tool joint's origin."""
    origins, prev_post = [], np.eye(4)
    for i in range(N_JOINTS):
        pre, post = _pre_post(model, i)
        origins.append(prev_post @ pre)
        prev_post = post
    return origins, prev_post @ model.tool2flange


def _rpy(R: np.ndarray) -> np.ndarray:
    """URDF (roll, pitch, yaw) of ``R = Rz(yaw) Ry(pitch) Rx(roll)``, exact also at pitch = +-90 deg."""
    if np.hypot(R[2, 1], R[2, 2]) < 1e-9:  # gimbal lock: only yaw -/+ roll matters; take roll = 0
        pitch = np.pi / 2 if -R[2, 0] > 0 else -np.pi / 2
        return np.array([0.0, pitch, np.arctan2(-R[0, 1], R[1, 1])])
    return euler_zyx_from_matrix(R)


def _origin_xml(T: np.ndarray) -> str:
    xyz = " ".join(repr(float(v)) for v in T[:3, 3])
    rpy = " ".join(repr(float(v)) for v in _rpy(T[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


_INERTIAL = (
    '<inertial><mass value="1.0"/><origin xyz="0 0 0" rpy="0 0 0"/>'
    '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
)


def model_to_urdf(model: RobotModel, *, name: str | None = None, base2meas: np.ndarray | None = None) -> str:
    """URDF text of ``model`` (its joints and ``tool2flange``; ``base2meas`` only when given here)."""
    name = name or model.name
    links = ["base_link"] + [f"link{i}" for i in range(1, N_JOINTS + 1)] + ["tool"]
    out = [f'<?xml version="1.0"?>', f'<robot name="{name}">']
    if base2meas is not None:
        out.append(f'  <link name="meas">{_INERTIAL}</link>')
    for ln in links:
        out.append(f'  <link name="{ln}">{_INERTIAL}</link>')
    if base2meas is not None:
        out.append(
            f'  <joint name="meas_to_base" type="fixed"><parent link="meas"/><child link="base_link"/>'
            f"{_origin_xml(np.asarray(base2meas, dtype=float))}</joint>"
        )
    origins, tool_origin = joint_origins(model)
    for i in range(N_JOINTS):
        out.append(
            f'  <joint name="joint{i + 1}" type="revolute"><parent link="{links[i]}"/><child link="{links[i + 1]}"/>'
            f'{_origin_xml(origins[i])}<axis xyz="0 0 1"/>'
            f'<limit lower="{float(model.q_min[i])!r}" upper="{float(model.q_max[i])!r}" effort="100" velocity="3"/>'
            "</joint>"
        )
    out.append(
        f'  <joint name="tool_joint" type="fixed"><parent link="link6"/><child link="tool"/>'
        f"{_origin_xml(tool_origin)}</joint>"
    )
    out.append("</robot>")
    return "\n".join(out) + "\n"


def write_urdf(path, model: RobotModel, **kwargs) -> str:
    """Write :func:`model_to_urdf` to ``path``; returns the path as a string."""
    from pathlib import Path

    p = Path(path)
    p.write_text(model_to_urdf(model, **kwargs))
    return str(p)
