"""URDF robot descriptions: read a serial chain out of a URDF, write a chain back as URDF (and MJCF).

Reading uses `yourdfpy` (pure Python, in the project's main dependencies; Pinocchio is only an optional peer
and the library must not need it). :func:`read_urdf_chain` walks the tree from ``end_link`` up to
``root_link`` and keeps the moving joints (revolute, continuous, prismatic) in order; fixed joints between
two moving joints (or before the first) are folded into the next moving joint's origin, and the fixed joints
after the last one become the chain's constant end transform, so the flange frame is ``end_link``. Each moving
joint carries the mass properties of everything it moves up to the next chain joint (its child link, fixed
descendants and side branches such as a head or fingers held at their zero position), expressed in its own
joint frame, for gravity models.

Writing (:func:`chain_urdf_xml`, :func:`chain_mjcf_xml`) turns any :class:`~twin.kinematics.RobotModel`
(6R conventions included) into a URDF / MJCF of the same forward kinematics: joint offsets and origin errors
are folded into the joint origins, so the file's joint values are the commanded joints.
"""

from __future__ import annotations

import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .kinematics import ChainOp, JointSpec, RobotModel, elementary_transform
from .transforms import euler_zyx_from_matrix, make_transform, matrix_to_quat_wxyz

__all__ = ["UrdfError", "read_urdf_chain", "urdf_links", "chain_urdf_xml", "chain_mjcf_xml", "joint_frames_at_zero"]

_MOVING = ("revolute", "continuous", "prismatic")


class UrdfError(ValueError):
    """A URDF that cannot give the requested chain; the message names the file and the link or joint."""


def _load(path: str | os.PathLike):
    import yourdfpy

    path = Path(path)
    if not path.is_file():
        raise UrdfError(f"{path}: no such URDF file")
    try:
        return yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False, load_collision_meshes=False)
    except Exception as exc:  # yourdfpy raises several types on malformed XML
        raise UrdfError(f"{path}: not a readable URDF ({type(exc).__name__}: {exc})") from None


def urdf_links(path: str | os.PathLike) -> tuple[str, ...]:
    """Names of the links of a URDF file."""
    return tuple(link.name for link in _load(path).robot.links)


def _origin(j) -> np.ndarray:
    return np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)


def _inertial(link) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(mass [kg], centre of mass (3,) [m], inertia about it (3, 3) [kg m^2]) of a link in its own frame."""
    ine = getattr(link, "inertial", None)
    if ine is None or ine.mass is None or not ine.mass > 0:
        return None
    T = np.eye(4) if ine.origin is None else np.asarray(ine.origin, dtype=float)
    Ic = np.zeros((3, 3)) if ine.inertia is None else np.asarray(ine.inertia, dtype=float)
    return float(ine.mass), T[:3, 3].copy(), T[:3, :3] @ Ic @ T[:3, :3].T


def _combine(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> dict | None:
    """Composite mass, centre of mass and inertia (about the composite centre) of parts given in one frame."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return None
    m = sum(p[0] for p in parts)
    c = sum(p[0] * p[1] for p in parts) / m
    inertia = np.zeros((3, 3))
    for mi, ci, Ii in parts:
        r = ci - c
        inertia += Ii + mi * (np.dot(r, r) * np.eye(3) - np.outer(r, r))
    return {"mass": float(m), "com": tuple(float(x) for x in c), "inertia": tuple(map(tuple, inertia.tolist()))}


def read_urdf_chain(path: str | os.PathLike, root_link: str, end_link: str, *, name: str | None = None) -> RobotModel:
    """The serial chain from ``root_link`` to ``end_link`` of a URDF as a ``"urdf"``
    :class:`~twin.kinematics.RobotModel` (see the module docstring). Base and tool are the identity.

    Raises :class:`UrdfError` naming the file and the link when a link is missing, when ``root_link`` is not an
    ancestor of ``end_link``, when a joint on the chain is neither fixed nor revolute/continuous/prismatic, when a
    moving joint on the chain is a ``<mimic>`` of another (the chain's joints are independent), or when the chain has
    no moving joint. A mimic joint off the chain (a gripper's finger) is held at zero with the side branches.
    """
    path = Path(path)
    u = _load(path)
    links = {link.name: link for link in u.robot.links}
    for role, ln in (("root_link", root_link), ("end_link", end_link)):
        if ln not in links:
            near = sorted(links)[:12]
            raise UrdfError(f"{path}: {role} {ln!r} is not a link of this URDF (links include: {', '.join(near)}, ...)")
    by_child = {j.child: j for j in u.robot.joints}
    children: dict[str, list] = {}
    for j in u.robot.joints:
        children.setdefault(j.parent, []).append(j)
    chain = []
    link = end_link
    while link != root_link:
        j = by_child.get(link)
        if j is None:
            raise UrdfError(f"{path}: root_link {root_link!r} is not an ancestor of end_link {end_link!r} (reached the "
                            f"tree's root {link!r})")
        chain.append(j)
        link = j.parent
    chain.reverse()
    for j in chain:
        if j.type not in _MOVING + ("fixed",):
            raise UrdfError(f"{path}: joint {j.name!r} on the chain is of type {j.type!r}; a serial chain takes fixed, "
                            "revolute, continuous and prismatic joints")
    for j in chain:
        mimic = getattr(j, "mimic", None)
        if j.type in _MOVING and mimic is not None:
            m = 1.0 if mimic.multiplier is None else float(mimic.multiplier)
            o = 0.0 if mimic.offset is None else float(mimic.offset)
            raise UrdfError(f"{path}: joint {j.name!r} on the chain mimics joint {mimic.joint!r} (q = {m:g} * "
                            f"q_{mimic.joint} + {o:g}): a chain here has independent joints, each commanded and "
                            "calibrated on its own, and a joint driven by another cannot be one of them; choose "
                            "root_link/end_link so that no mimic joint is on the chain, or write it as an independent "
                            "joint whose position is recorded")
    moving = [j for j in chain if j.type in _MOVING]
    if not moving:
        raise UrdfError(f"{path}: the chain from {root_link!r} to {end_link!r} has no moving joint")
    on_chain_child = {j.child for j in moving}

    def subtree_parts(link_name: str, T_link: np.ndarray) -> list:
        """Mass properties of a link and everything below it except the next chain joint's subtree, in the frame
        that ``T_link`` maps the link's frame into."""
        out = []
        ine = _inertial(links[link_name])
        if ine is not None:
            m, c, inertia = ine
            R = T_link[:3, :3]
            out.append((m, T_link[:3, :3] @ c + T_link[:3, 3], R @ inertia @ R.T))
        for cj in children.get(link_name, []):
            if cj.child in on_chain_child:
                continue
            out += subtree_parts(cj.child, T_link @ _origin(cj))
        return out

    specs = []
    T_acc = np.eye(4)
    for j in chain:
        if j.type == "fixed":
            T_acc = T_acc @ _origin(j)
            continue
        O = T_acc @ _origin(j)
        T_acc = np.eye(4)
        if j.type == "continuous" or j.limit is None or j.limit.lower is None or j.limit.upper is None:
            lo, hi = (-2 * np.pi, 2 * np.pi) if j.type != "prismatic" else (-1.0, 1.0)
        else:
            lo, hi = float(j.limit.lower), float(j.limit.upper)
        if not lo < hi:
            raise UrdfError(f"{path}: joint {j.name!r} has limits [{lo}, {hi}]: lower must be below upper")
        axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=float)
        specs.append(JointSpec(
            name=j.name, kind="prismatic" if j.type == "prismatic" else "revolute",
            xyz=tuple(O[:3, 3]), rpy=tuple(euler_zyx_from_matrix(O[:3, :3])), axis=tuple(axis),
            q_min=lo, q_max=hi, inertial=_combine(subtree_parts(j.child, np.eye(4))),
        ))
    return RobotModel.from_joints(name or u.robot.name or "robot", specs, end_origin=T_acc)


# ------------------------------------------------------------------------------------------------
# Writing a chain
# ------------------------------------------------------------------------------------------------

def _op_matrix(model: RobotModel, i: int, k: int, op: ChainOp, value_q: float = 0.0) -> np.ndarray:
    """Transform of operation ``k`` of joint ``i`` at commanded value ``value_q`` (0 for a fixed operation)."""
    if op.kind in ("R", "P"):
        return op.matrix()
    v = float(model.params[model.layout.index(op.param)])
    if op.joint >= 0:
        v = v + op.sign * value_q
    return elementary_transform(op.kind, op.axis, np.float64(v))


def joint_frames_at_zero(model: RobotModel) -> tuple[list[np.ndarray], list[np.ndarray], list[str], np.ndarray]:
    """The chain as URDF joints: per joint its origin ``(4, 4)`` in the previous joint frame (offsets and origin
    errors folded in, joint value = commanded joint), its unit axis ``(3,)`` in its own frame, its kind, and the
    constant transform ``(4, 4)`` from the last joint frame to the flange."""
    st = model.structure
    origins, axes, kinds = [], [], []
    carry = np.eye(4)
    for i, ops in enumerate(st.ops):
        jk = next(k for k, op in enumerate(ops) if op.joint == i)
        pre = carry.copy()
        for k in range(jk):
            pre = pre @ _op_matrix(model, i, k, ops[k])
        jop = ops[jk]
        # the offset part of the joint operation belongs to the origin; the commanded value moves the joint
        pre = pre @ _op_matrix(model, i, jk, ChainOp(jop.kind, jop.axis, jop.param))
        axis = np.zeros(3)
        axis[jop.axis] = jop.sign
        origins.append(pre)
        axes.append(axis)
        kinds.append(st.joint_kinds[i])
        carry = np.eye(4)
        for k in range(jk + 1, len(ops)):
            carry = carry @ _op_matrix(model, i, k, ops[k])
    for op in st.end:
        carry = carry @ op.matrix()
    return origins, axes, kinds, carry


def _xyz_rpy(T: np.ndarray) -> str:
    xyz = " ".join(f"{v:.12g}" for v in T[:3, 3])
    rpy = " ".join(f"{v:.12g}" for v in euler_zyx_from_matrix(T[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def chain_urdf_xml(model: RobotModel, *, robot_name: str | None = None, tool_points: np.ndarray | None = None) -> str:
    """URDF text of ``model``'s chain: links ``base``, ``link1..N`` (``link<i>`` moves with joint ``i``, named
    after it), ``flange`` and ``tool`` (``tool2flange``; with ``tool_points`` ``(K, 3)`` [m] one fixed child link
    ``point<k>`` per point). The base frame is the robot base (``base2meas`` is not part of the robot). Joint
    values in the file equal the commanded joints [rad, m]."""
    origins, axes, kinds, end = joint_frames_at_zero(model)
    names = model.joint_names
    lo, hi = model.q_min, model.q_max
    out = [f"<robot name={quoteattr(robot_name or model.name)}>", '  <link name="base"/>']
    parent = "base"
    for i, (O, a, kind) in enumerate(zip(origins, axes, kinds)):
        child = f"link{i + 1}"
        out.append(f'  <link name="{child}"/>')
        out.append(f'  <joint name={quoteattr(names[i])} type="{kind}">')
        out.append(f'    <parent link="{parent}"/><child link="{child}"/>')
        out.append(f"    {_xyz_rpy(O)}")
        out.append(f'    <axis xyz="{a[0]:.12g} {a[1]:.12g} {a[2]:.12g}"/>')
        out.append(f'    <limit lower="{lo[i]:.12g}" upper="{hi[i]:.12g}" effort="0" velocity="0"/>')
        out.append("  </joint>")
        parent = child
    for nm, par, T in (("flange", parent, end), ("tool", "flange", model.tool2flange)):
        out.append(f'  <link name="{nm}"/>')
        out.append(f'  <joint name="{nm}_joint" type="fixed"><parent link="{par}"/><child link="{nm}"/>{_xyz_rpy(T)}</joint>')
    if tool_points is not None:
        for k, p in enumerate(np.asarray(tool_points, dtype=float).reshape(-1, 3)):
            out.append(f'  <link name="point{k}"/>')
            out.append(f'  <joint name="point{k}_joint" type="fixed"><parent link="tool"/><child link="point{k}"/>'
                       f'{_xyz_rpy(make_transform(np.eye(3), p))}</joint>')
    out.append("</robot>")
    return "\n".join(out) + "\n"


def chain_mjcf_xml(model: RobotModel, *, model_name: str | None = None, tool_points: np.ndarray | None = None) -> str:
    """MJCF text of ``model``'s chain (bodies ``link1..N``, hinge/slide joints named after the robot's joints,
    sites ``flange``, ``tool`` and ``point<k>``); the robot base is the MJCF world frame and MuJoCo joint values
    equal the commanded joints."""
    origins, axes, kinds, end = joint_frames_at_zero(model)
    names = model.joint_names

    def pq(T):
        q = matrix_to_quat_wxyz(T[:3, :3])
        return (f'pos="{T[0, 3]:.12g} {T[1, 3]:.12g} {T[2, 3]:.12g}" '
                f'quat="{q[0]:.15g} {q[1]:.15g} {q[2]:.15g} {q[3]:.15g}"')

    out = [f"<mujoco model={quoteattr(model_name or model.name)}>", '  <compiler angle="radian"/>', "  <worldbody>"]
    ind = "    "
    for i, (O, a, kind) in enumerate(zip(origins, axes, kinds)):
        out.append(f'{ind}<body name="link{i + 1}" {pq(O)}>')
        typ = "slide" if kind == "prismatic" else "hinge"
        out.append(f'{ind}  <joint name={quoteattr(names[i])} type="{typ}" axis="{a[0]:.12g} {a[1]:.12g} {a[2]:.12g}" '
                   f'range="{model.q_min[i]:.12g} {model.q_max[i]:.12g}" limited="true"/>')
        out.append(f'{ind}  <geom type="sphere" size="0.01" mass="0.1" contype="0" conaffinity="0"/>')
        ind += "  "
    Tt = end @ model.tool2flange
    out.append(f'{ind}<site name="flange" {pq(end)}/>')
    out.append(f'{ind}<site name="tool" {pq(Tt)}/>')
    if tool_points is not None:
        for k, p in enumerate(np.asarray(tool_points, dtype=float).reshape(-1, 3)):
            out.append(f'{ind}<site name="point{k}" {pq(Tt @ make_transform(np.eye(3), p))}/>')
    for i in range(len(origins)):
        ind = ind[:-2]
        out.append(f"{ind}</body>")
    out += ["  </worldbody>", "</mujoco>"]
    return "\n".join(out) + "\n"
