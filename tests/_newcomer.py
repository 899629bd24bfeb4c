"""A newcomer's robots and campaigns, written as a user from another lab writes them: a robot given as a DH or MDH
table, a joint table or a URDF; a laser tracker's or a motion-capture system's CSV in the lab's own dialect (its
column names, separator, decimal mark, units, a title line); a column map (``docs/formats.md``, "Column map")
that tells ``twin import`` how to read them; the JOINTS.csv and TARGETS.csv a user writes for ``twin predict`` and
``twin compensate``.

The measured values come from this module's own forward kinematics (a few lines per convention, with scipy's
rotations), never from the library's simulators: the library is tested against an independent oracle. The robot
that measures (``true``) is the nominal one with small errors in every parameter and, optionally, a joint with
backlash; the user's files give the nominal one only.
"""

from __future__ import annotations

import functools
import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from twin.units import DEG_PER_RAD, M_PER_MM, MM_PER_M, RAD_PER_DEG

__all__ = ["Robot", "make_robot", "perturbed", "sample_joints", "constant_orientation_joints", "Session", "measure",
           "Dialect", "DIALECTS", "write_campaign", "write_joints_csv", "write_targets_csv", "transform"]


# ------------------------------------------------------------------------------------------------
# Forward kinematics, independent of the library
# ------------------------------------------------------------------------------------------------

def transform(R: np.ndarray | None = None, p=None) -> np.ndarray:
    """A 4x4 (or (n, 4, 4)) homogeneous transform from rotations ``R`` and translations ``p`` [m]."""
    R = np.eye(3) if R is None else np.asarray(R, float)
    p = np.zeros(3) if p is None else np.asarray(p, float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def _rot(axis, angle) -> np.ndarray:
    """Rotations ``(n, 3, 3)`` about the unit ``axis`` by ``angle`` ``(n,)`` [rad]."""
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    return Rotation.from_rotvec(np.asarray(angle, float)[:, None] * u).as_matrix()


def _rpy(rpy) -> np.ndarray:
    """URDF's ``rpy``: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return Rotation.from_euler("xyz", rpy).as_matrix()


def _to_rpy(R: np.ndarray) -> np.ndarray:
    """``(roll, pitch, yaw)`` [rad] of a rotation (at pitch +-90 deg scipy picks one of the equal answers)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(R).as_euler("xyz")


@dataclass(frozen=True)
class Robot:
    """A serial chain of N joints in one of four user forms: ``dh``/``mdh`` (per joint ``theta, d, a, alpha`` [rad,
    m]; revolute), ``table``/``urdf`` (per joint ``xyz`` [m], ``rpy`` [rad], ``axis``, ``prismatic``; ``end`` the
    flange after the last joint). ``offset`` ``(N,)``: added to each commanded joint (zero on the nominal robot);
    ``backlash`` ``(N,)`` [rad, m]: half the clearance of each joint, taken up towards the side the joint last
    moved from. Joint limits ``lo, hi`` ``(N,)`` [rad, m]."""

    kind: str
    theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    d: np.ndarray = field(default_factory=lambda: np.zeros(0))
    a: np.ndarray = field(default_factory=lambda: np.zeros(0))
    alpha: np.ndarray = field(default_factory=lambda: np.zeros(0))
    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    axis: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    prismatic: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    end: np.ndarray = field(default_factory=lambda: np.eye(4))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(0))
    backlash: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lo: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hi: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mass: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n(self) -> int:
        return int(self.lo.size)

    @functools.cached_property
    def _origins(self) -> list[np.ndarray]:
        """A joint table's constant origins ``T(xyz) R(rpy)``."""
        return [transform(_rpy(self.rpy[j]), self.xyz[j]) for j in range(self.n)]

    @property
    def names(self) -> list[str]:
        """The dataset's joint columns: ``q1..qN`` for a DH/MDH table, the joint names for a chain."""
        return [f"q{j + 1}" for j in range(self.n)] if self.kind in ("dh", "mdh") else [f"joint_{j + 1}" for j in range(self.n)]

    def actual(self, q: np.ndarray, q_start: np.ndarray | None = None) -> np.ndarray:
        """The joints the robot takes at the commands ``q`` ``(n, N)`` in this order: offsets and backlash (each
        joint on the side it last moved from; from ``q_start`` to the first row, or +1 when None)."""
        q = np.atleast_2d(np.asarray(q, float))
        out = q + self.offset
        if not self.backlash.any():
            return out
        prev = np.vstack([q[:1] if q_start is None else np.asarray(q_start, float)[None], q[:-1]])
        side = np.ones(self.n)
        for k in range(len(q)):
            step = np.sign(q[k] - prev[k])
            side = np.where(step != 0, step, side)
            out[k] += side * self.backlash
        return out

    def fk(self, q: np.ndarray, q_start: np.ndarray | None = None) -> np.ndarray:
        """Flange poses in the base frame ``(n, 4, 4)`` at the commands ``q`` ``(n, N)`` [rad, m], rows in the order
        measured (backlash depends on it; ``q_start``: where the robot stood before the first row)."""
        qa = self.actual(q, q_start)
        n = len(qa)
        T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        for j in range(self.n):
            if self.kind == "dh":  # Rz(theta + q) Tz(d) Tx(a) Rx(alpha)
                L = transform(_rot([0, 0, 1], self.theta[j] + qa[:, j]))
                L = L @ transform(None, [self.a[j], 0.0, self.d[j]])
                L = L @ transform(_rot([1, 0, 0], np.full(n, self.alpha[j])))
            elif self.kind == "mdh":  # Rx(alpha) Tx(a) Tz(d) Rz(theta + q)
                L = transform(_rot([1, 0, 0], np.full(n, self.alpha[j]))) @ transform(None, [self.a[j], 0.0, self.d[j]])
                L = L @ transform(_rot([0, 0, 1], self.theta[j] + qa[:, j]))
            else:  # T(xyz) R(rpy) Joint(q)
                L = np.broadcast_to(self._origins[j], (n, 4, 4))
                if self.prismatic[j]:
                    u = self.axis[j] / np.linalg.norm(self.axis[j])
                    L = L @ transform(None, qa[:, j, None] * u)
                else:
                    L = L @ transform(_rot(self.axis[j], qa[:, j]))
            T = T @ L
        return T @ self.end if self.kind in ("table", "urdf") else T

    # -- what the user writes -----------------------------------------------------------------------------------

    def joint_units(self, unit_rev: str = "deg", unit_pri: str = "mm") -> list[str]:
        return [unit_pri if p else unit_rev for p in self.prismatic]

    def to_user(self, q: np.ndarray, unit_rev: str = "deg", unit_pri: str = "mm") -> np.ndarray:
        """Joints ``(n, N)`` [rad, m] in the user's units."""
        s = np.where(self.prismatic, MM_PER_M if unit_pri == "mm" else 1.0, DEG_PER_RAD if unit_rev == "deg" else 1.0)
        return np.asarray(q, float) * s

    def table(self) -> dict:
        """The ``[robot]`` table of a column map (or a ``dataset.toml``) for a DH/MDH table or a joint table."""
        lim_r = DEG_PER_RAD
        if self.kind in ("dh", "mdh"):
            return {"name": f"newcomer_{self.kind}{self.n}", "convention": self.kind,
                    "theta_deg": (self.theta * DEG_PER_RAD).tolist(), "d_mm": (self.d * MM_PER_M).tolist(),
                    "a_mm": (self.a * MM_PER_M).tolist(), "alpha_deg": (self.alpha * DEG_PER_RAD).tolist(),
                    "q_min_deg": (self.lo * lim_r).tolist(), "q_max_deg": (self.hi * lim_r).tolist()}
        joints = []
        for j in range(self.n):
            s = MM_PER_M if self.prismatic[j] else DEG_PER_RAD
            row = {"name": self.names[j], "type": "prismatic" if self.prismatic[j] else "revolute",
                   "xyz_mm": (self.xyz[j] * MM_PER_M).tolist(), "rpy_deg": (self.rpy[j] * DEG_PER_RAD).tolist(),
                   "axis": self.axis[j].tolist(), "limits": [self.lo[j] * s, self.hi[j] * s]}
            if self.mass.size:
                row.update(mass_kg=float(self.mass[j]), com_mm=[0.0, 0.0, 40.0])
            joints.append(row)
        end_rpy = _to_rpy(self.end[:3, :3]) * DEG_PER_RAD
        return {"name": f"newcomer_chain{self.n}", "convention": "urdf", "joints": joints,
                "end": {"xyz_mm": (self.end[:3, 3] * MM_PER_M).tolist(), "rpy_deg": end_rpy.tolist()}}

    def urdf(self) -> str:
        """The chain as a URDF file (m, rad) with a fixed joint folded between joints 1 and 2 (a spacer link) and a
        fixed joint to the end link ``tool0``; every link with a mass."""
        def origin(T):
            r = _to_rpy(T[:3, :3])
            return (f'<origin xyz="{T[0, 3]:.9f} {T[1, 3]:.9f} {T[2, 3]:.9f}" '
                    f'rpy="{r[0]:.12f} {r[1]:.12f} {r[2]:.12f}"/>')

        spacer = transform(_rpy([0.1, -0.2, 0.3]), [0.011, -0.007, 0.031])
        links = ["base_link"] + [f"link_{j + 1}" for j in range(self.n)]
        out = ['<?xml version="1.0"?>', f'<robot name="newcomer_urdf{self.n}">']
        for name in links + ["spacer", "tool0"]:
            m = 0.5 if name in ("spacer", "tool0") else 2.0
            out.append(f'  <link name="{name}"><inertial><origin xyz="0 0 0.04" rpy="0 0 0"/><mass value="{m}"/>'
                       '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>')
        for j in range(self.n):
            O = transform(_rpy(self.rpy[j]), self.xyz[j])
            parent = links[j]
            if j == 1:  # a fixed joint before joint 2: its origin is folded into joint 2's
                out.append(f'  <joint name="spacer_joint" type="fixed"><parent link="link_1"/><child link="spacer"/>'
                           f'{origin(spacer)}</joint>')
                parent, O = "spacer", np.linalg.inv(spacer) @ O
            kind = "prismatic" if self.prismatic[j] else "revolute"
            ax = self.axis[j]
            out.append(f'  <joint name="{self.names[j]}" type="{kind}"><parent link="{parent}"/>'
                       f'<child link="{links[j + 1]}"/>{origin(O)}<axis xyz="{ax[0]} {ax[1]} {ax[2]}"/>'
                       f'<limit lower="{self.lo[j]:.9f}" upper="{self.hi[j]:.9f}" effort="100" velocity="1"/></joint>')
        out.append(f'  <joint name="flange_joint" type="fixed"><parent link="{links[-1]}"/><child link="tool0"/>'
                   f'{origin(self.end)}</joint>')
        out.append("</robot>")
        return "\n".join(out) + "\n"


def make_robot(rng: np.random.Generator, kind: str, n: int, *, prismatic: int | None = None) -> Robot:
    """A nominal robot of ``n`` joints in the form ``kind`` with unusual link lengths and offsets (a long link, a
    negative offset, a zero, twists that are not multiples of 90 deg). ``prismatic``: the (0-based) joint that slides
    (a joint table or URDF only)."""
    if kind in ("dh", "mdh"):
        if prismatic is not None:
            raise ValueError("a DH/MDH table has revolute joints only")
        theta = rng.choice([0.0, 90.0, -90.0, 37.5, -12.0], n) * RAD_PER_DEG
        d = rng.choice([0.0, 0.0, 85.0, 312.7, -140.0, 1150.0], n) * M_PER_MM
        a = rng.choice([0.0, 42.0, 425.0, -392.25, 880.0], n) * M_PER_MM
        alpha = rng.choice([90.0, -90.0, 0.0, 90.0, -90.0, 63.0], n) * RAD_PER_DEG
        # no two consecutive parallel axes at the start (a planar chain of 3 is fine but dull): tilt joint 1's
        alpha[0] = rng.choice([90.0, -90.0]) * RAD_PER_DEG
        lim = rng.uniform(120.0, 350.0, n) * RAD_PER_DEG
        return Robot(kind, theta=theta, d=d, a=a, alpha=alpha, prismatic=np.zeros(n, bool), offset=np.zeros(n),
                     backlash=np.zeros(n), lo=-lim, hi=lim)
    if kind not in ("table", "urdf"):
        raise ValueError(f"kind must be dh, mdh, table or urdf, got {kind!r}")
    axes = np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, -1], [0, 0.6, 0.8], [0, -1, 0]], float)
    ax = axes[rng.integers(0, len(axes), n)]
    ax[0] = [0, 0, 1]
    xyz = rng.choice([0.0, 0.0, 55.0, 240.0, -130.0, 610.0], (n, 3)) * M_PER_MM
    xyz[np.arange(n), rng.integers(0, 3, n)] += rng.uniform(80.0, 400.0, n) * M_PER_MM  # no zero-length link
    rpy = rng.choice([0.0, 0.0, 90.0, -90.0, 30.0], (n, 3)) * RAD_PER_DEG
    pri = np.zeros(n, bool)
    if prismatic is not None:
        pri[prismatic] = True
    lim = rng.uniform(120.0, 300.0, n) * RAD_PER_DEG
    lo, hi = -lim, lim.copy()
    lo[pri], hi[pri] = 0.0, rng.uniform(250.0, 600.0, pri.sum()) * M_PER_MM
    end = transform(_rpy(rng.choice([0.0, 90.0, 180.0], 3) * RAD_PER_DEG), [0.0, 0.0, rng.uniform(30, 120) * M_PER_MM])
    return Robot(kind, xyz=xyz, rpy=rpy, axis=ax, prismatic=pri, end=end, offset=np.zeros(n), backlash=np.zeros(n),
                 lo=lo, hi=hi, mass=np.full(n, 3.0) if kind == "table" else np.zeros(0))


def perturbed(robot: Robot, rng: np.random.Generator, *, length_mm: float = 0.4, angle_deg: float = 0.08,
              backlash: dict[int, float] | None = None) -> Robot:
    """The robot as built: every length off by about ``length_mm``, every angle and joint offset by ``angle_deg``
    (1-sigma); ``backlash``: ``{joint (0-based): half clearance [rad, m]}``."""
    L, A = length_mm * M_PER_MM, angle_deg * RAD_PER_DEG
    n = robot.n
    bl = np.zeros(n)
    for j, b in (backlash or {}).items():
        bl[j] = b
    off = np.where(robot.prismatic, rng.normal(0, L, n), rng.normal(0, A, n))
    if robot.kind in ("dh", "mdh"):
        return replace(robot, d=robot.d + rng.normal(0, L, n), a=robot.a + rng.normal(0, L, n),
                       alpha=robot.alpha + rng.normal(0, A, n), offset=off, backlash=bl)
    end = robot.end @ transform(Rotation.from_rotvec(rng.normal(0, A, 3)).as_matrix(), rng.normal(0, L, 3))
    return replace(robot, xyz=robot.xyz + rng.normal(0, L, (n, 3)), rpy=robot.rpy + rng.normal(0, A, (n, 3)),
                   end=end, offset=off, backlash=bl)


def sample_joints(robot: Robot, rng: np.random.Generator, n: int, *, repeats: int = 0) -> np.ndarray:
    """``n`` commanded joint rows [rad, m] within 0.8 of each joint's range; ``repeats`` of them measured again
    right after themselves (a repeated row: the same command twice in a row)."""
    mid, half = 0.5 * (robot.lo + robot.hi), 0.4 * (robot.hi - robot.lo)
    q = mid + rng.uniform(-1.0, 1.0, (n - repeats, robot.n)) * half
    for k in sorted(rng.choice(np.arange(1, len(q)), repeats, replace=False), reverse=True):
        q = np.insert(q, k, q[k - 1], axis=0)
    return q


def _pose_error(T, target):
    e = np.zeros(6)
    e[:3] = target[:3, 3] - T[:3, 3]
    e[3:] = Rotation.from_matrix(target[:3, :3] @ T[:3, :3].T).as_rotvec()
    return e


def constant_orientation_joints(robot: Robot, rng: np.random.Generator, n: int, tool: np.ndarray, *,
                                side_mm: float = 120.0) -> np.ndarray:
    """``n`` commands [rad] that hold the tool at one orientation while its origin visits the corners and the inside
    of a cube (an ISO 9283 cube) of side ``side_mm`` (halved up to twice where the chain cannot), solved on ``robot``
    (the nominal one: what a user commands) by damped least squares from configurations inside the ranges. Needs
    N >= 6 joints."""
    if robot.n < 6:
        raise ValueError("a constant orientation over a cube needs 6 joints or more")
    mid = 0.5 * (robot.lo + robot.hi)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    unit = np.vstack([corners, rng.uniform(-1, 1, (max(n - 8, 0), 3))])[:n]
    for side in (side_mm, side_mm / 2, side_mm / 4):
        for _ in range(20):
            q0 = mid + rng.uniform(-0.3, 0.3, robot.n) * (robot.hi - robot.lo)
            T0 = (robot.fk(q0[None]) @ tool)[0]
            out, q = [], q0.copy()
            for o in unit * 0.5 * side * M_PER_MM:
                target = T0.copy()
                target[:3, 3] += o
                for _ in range(30):
                    T = (robot.fk(q[None]) @ tool)[0]
                    e = _pose_error(T, target)
                    if np.abs(e).max() < 1e-10:
                        break
                    J = _jacobian(robot, q, tool)
                    q = q + J.T @ np.linalg.solve(J @ J.T + 1e-10 * np.eye(6), e)
                if np.abs(e).max() > 1e-8 or np.any(q < robot.lo) or np.any(q > robot.hi):
                    break
                out.append(q.copy())
            if len(out) == n:
                return np.array(out)
    raise RuntimeError("no constant-orientation cube found for this robot")


def _jacobian(robot: Robot, q: np.ndarray, tool: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """The tool pose's Jacobian ``(6, N)`` by forward differences (rows: position, the small rotation's vector)."""
    T = robot.fk(np.vstack([q, q + h * np.eye(robot.n)])) @ tool
    dR = T[1:, :3, :3] @ T[0, :3, :3].T
    w = 0.5 * np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0], dR[:, 1, 0] - dR[:, 0, 1]], axis=1)
    return np.hstack([T[1:, :3, 3] - T[0, :3, 3], w]).T / h


# ------------------------------------------------------------------------------------------------
# A session: commands, what the instrument read
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Session:
    """What one session measured: commands ``q`` ``(n, N)`` [rad, m] in the order measured, the measurement
    frame ``base2meas``, and the readings: ``points`` ``(n, K, 3)`` [m] of K markers (``markers`` ``(K, 3)`` on the
    flange), or a 6-DOF ``pose`` ``(n, 4, 4)`` of the tool ``tool2flange``."""

    q: np.ndarray
    base2meas: np.ndarray
    points: np.ndarray | None = None
    pose: np.ndarray | None = None
    markers: np.ndarray | None = None
    tool2flange: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(len(self.q))


def measure(true: Robot, q: np.ndarray, base2meas: np.ndarray, rng: np.random.Generator, *,
            markers: np.ndarray | None = None, tool2flange: np.ndarray | None = None, noise_mm: float = 0.0,
            noise_rad: float = 0.0) -> Session:
    """The instrument's readings of the robot ``true`` at the commands ``q``: the marker points (``markers`` ``(K,
    3)`` [m] on the flange) or the tool pose (``tool2flange``), in the frame ``base2meas``, with Gaussian noise."""
    F = base2meas @ true.fk(q)
    if markers is not None:
        P = np.einsum("nij,kj->nki", F[:, :3, :3], markers) + F[:, None, :3, 3]
        P = P + rng.normal(0, noise_mm * M_PER_MM, P.shape)
        return Session(q=q, base2meas=base2meas, points=P, markers=markers)
    T = F @ tool2flange
    T[:, :3, 3] += rng.normal(0, noise_mm * M_PER_MM, (len(q), 3))
    if noise_rad:
        T[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, noise_rad, (len(q), 3))).as_matrix() @ T[:, :3, :3]
    return Session(q=q, base2meas=base2meas, pose=T, tool2flange=tool2flange)


def random_frame(rng: np.random.Generator, distance_m: float = 3.0) -> np.ndarray:
    """``base2meas`` of an instrument somewhere in the cell, ``distance_m`` from the robot base, its z axis (the line
    of sight of a tracker or a camera) towards the base, turned about it at random."""
    c = rng.normal(0, 1, 3)
    c = distance_m * c / np.linalg.norm(c)  # the instrument in the base frame
    z = -c / np.linalg.norm(c)
    x = np.cross(rng.normal(0, 1, 3), z)
    x /= np.linalg.norm(x)
    meas2base = transform(np.column_stack([x, np.cross(z, x), z]), c)
    return np.linalg.inv(meas2base)


# ------------------------------------------------------------------------------------------------
# The user's files
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Dialect:
    """How a lab's software writes its CSV: separator, decimal mark, title lines above the header, the units of the
    joints (revolute, prismatic) and of the lengths, the Euler sequence and unit of a pose's angles."""

    separator: str = ","
    decimal: str = "."
    title_lines: int = 0
    joint_unit: str = "deg"
    prismatic_unit: str = "mm"
    length_unit: str = "mm"
    euler: str = "XYZ"
    angle_unit: str = "deg"


DIALECTS = (
    Dialect(),
    Dialect(separator=";", decimal=",", title_lines=1, joint_unit="rad", prismatic_unit="m", euler="zyx"),
    Dialect(separator="\t", length_unit="m", euler="ZYZ", angle_unit="rad"),
)


def _toml_value(v) -> str:
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    return repr(float(v)) if isinstance(v, (float, np.floating)) else str(v)


def _num(v: float, dialect: Dialect) -> str:
    s = f"{v:.10g}"
    return s.replace(".", ",") if dialect.decimal == "," else s


def write_csv(path: Path, header: list[str], rows: list[list], dialect: Dialect) -> Path:
    """A CSV in the dialect: title lines, the header, the rows (numbers with the dialect's decimal mark)."""
    lines = [f"exported by the lab's tracker software, run {k + 1}" for k in range(dialect.title_lines)]
    lines.append(dialect.separator.join(header))
    for r in rows:
        lines.append(dialect.separator.join(c if isinstance(c, str) else _num(c, dialect) for c in r))
    path.write_text("\n".join(lines) + "\n")
    return path


def session_columns(robot: Robot, s: Session, dialect: Dialect) -> tuple[list[str], np.ndarray, dict]:
    """The CSV columns of a session's joints and readings in the dialect, and the map's ``[joints]`` and
    ``[measurement]`` tables."""
    jcols = [f"Axis {j + 1}" for j in range(robot.n)]
    q = robot.to_user(s.q, dialect.joint_unit, dialect.prismatic_unit)
    lscale = MM_PER_M if dialect.length_unit == "mm" else 1.0
    units = robot.joint_units(dialect.joint_unit, dialect.prismatic_unit)
    joints = {"columns": jcols, "unit": units if robot.prismatic.any() else dialect.joint_unit}
    if s.points is not None:
        K = s.points.shape[1]
        cols = [f"{c}{k + 1}" for k in range(K) for c in "XYZ"]
        vals = s.points.reshape(len(s.q), -1) * lscale
        meas = {"kind": "points", "unit": dialect.length_unit,
                "points": [{"x": f"X{k + 1}", "y": f"Y{k + 1}", "z": f"Z{k + 1}"} for k in range(K)]}
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # gimbal lock: scipy picks one of the equal answers
            ang = Rotation.from_matrix(s.pose[:, :3, :3]).as_euler(dialect.euler)
        ang = ang * (DEG_PER_RAD if dialect.angle_unit == "deg" else 1.0)
        cols = ["Pos X", "Pos Y", "Pos Z", "Angle A", "Angle B", "Angle C"]
        vals = np.hstack([s.pose[:, :3, 3] * lscale, ang])
        meas = {"kind": "pose", "unit": dialect.length_unit, "position": cols[:3], "rotation": cols[3:],
                "rotation_unit": dialect.angle_unit, "euler": dialect.euler}
    return jcols + cols, np.hstack([q, vals]), {"joints": joints, "measurement": meas}


def write_campaign(folder: Path, robot: Robot, parts: list[tuple[str, Session, dict]], dialect: Dialect, *,
                   top: dict | None = None, noise_mm: float | None = None, frames: dict | None = None,
                   map_name: str = "map.toml") -> Path:
    """Write a campaign's CSVs (``parts``: ``(file name, session, per-file columns and [[files]] keys)``; the
    per-file columns: ``{"__columns__": {name: (n,) values or labels}}``) and its column map; returns the map's path.
    ``top``: top-level keys of the map (``set``, ``time``, ``session``, ...); ``frames``: the map's ``[frames]``."""
    folder.mkdir(parents=True, exist_ok=True)
    spec_keys = None
    files = []
    for name, s, extra in parts:
        header, vals, spec_keys = session_columns(robot, s, dialect)
        cols = dict(extra.get("__columns__", {}))
        header = header + list(cols)
        rows = []
        for i in range(s.n):
            rows.append([*vals[i], *[c[i] if isinstance(c[i], str) else float(c[i]) for c in cols.values()]])
        write_csv(folder / name, header, rows, dialect)
        entry = {"path": name, **{k: v for k, v in extra.items() if k != "__columns__"}}
        files.append(entry)
    lines = ["# a newcomer's column map", "schema_version = 1"]
    for k, v in (top or {}).items():
        lines.append(f"{k} = {_toml_value(v)}")
    if robot.kind == "urdf":
        (folder / "robot.urdf").write_text(robot.urdf())
        lines.append('robot = { urdf = "robot.urdf", root_link = "base_link", end_link = "tool0" }')
    else:
        tab = robot.table()
        lines.append("[robot]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in tab.items()]
    sep = "\\t" if dialect.separator == "\t" else dialect.separator
    lines += ["[csv]", f"separator = {json.dumps(sep)}", f"decimal = {json.dumps(dialect.decimal)}",
              f"header_row = {dialect.title_lines + 1}"]
    lines += ["[joints]"] + [f"{k} = {_toml_value(v)}" for k, v in spec_keys["joints"].items()]
    lines += ["[measurement]"] + [f"{k} = {_toml_value(v)}" for k, v in spec_keys["measurement"].items()]
    if frames:
        lines += ["[frames]"] + [f"{k} = {_toml_value(v)}" for k, v in frames.items()]
    if noise_mm is not None:
        lines += ["[noise]", f"position_mm = {noise_mm!r}"]
        if spec_keys["measurement"]["kind"] == "pose":
            lines.append("orientation_rad = 2e-5")
    for e in files:
        lines += ["[[files]]"] + [f"{k} = {_toml_value(v)}" for k, v in e.items()]
    path = folder / map_name
    path.write_text("\n".join(lines) + "\n")
    return path


def write_joints_csv(path: Path, robot: Robot, q: np.ndarray, pose_id: np.ndarray | None = None, *,
                     station: str | None = None) -> Path:
    """A JOINTS.csv (``docs/formats.md``): ``pose_id``, the robot's joint columns [deg, mm] and the ``station``."""
    pid = np.arange(len(q)) if pose_id is None else pose_id
    v = robot.to_user(q, "deg", "mm")
    st = [] if station is None else [station]
    lines = [",".join(["pose_id", *robot.names] + (["station"] if st else []))]
    lines += [",".join([str(int(p)), *(f"{x:.9f}" for x in r), *st]) for p, r in zip(pid, v)]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_targets_csv(path: Path, tool2base: np.ndarray, *, position_only: bool = False) -> Path:
    """A TARGETS.csv: ``pose_id, x, y, z`` [mm] and ``qw qx qy qz`` of the tool poses ``(n, 4, 4)`` in the
    calibration's base frame, or with ``position_only`` the positions ``(n, 3)`` [m] alone."""
    head = ["pose_id", "x", "y", "z"] + ([] if position_only else ["qw", "qx", "qy", "qz"])
    lines = [",".join(head)]
    for k, T in enumerate(tool2base):
        p = T if position_only else T[:3, 3]
        row = [str(k), *(f"{v * MM_PER_M:.6f}" for v in p)]
        if not position_only:
            x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
            row += [f"{v:.12f}" for v in (w, x, y, z)]
        lines.append(",".join(row))
    path.write_text("\n".join(lines) + "\n")
    return path
