"""The description of a serial chain (pure data, no kinematics): its elementary operations (:class:`ChainOp`),
the joints of a ``"urdf"`` chain (:class:`JointSpec`), its structure (:class:`ChainStructure`), the names, units and
positions of its parameter vector (:class:`ParameterLayout`) and the arm itself (:class:`RobotModel`).

The conventions (``"mdh"``, ``"dh"``, ``"urdf"``) and the parameter vector are described in :mod:`twin.kinematics`,
which computes on these types and re-exports every name of this module.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from .transforms import make_transform, matrix_from_euler_zyx, pose6_to_transform, rotvec_to_matrix, transform_to_pose6

__all__ = [
    "Convention",
    "N_JOINTS",
    "URDF_FAMILIES",
    "ChainOp",
    "JointSpec",
    "ChainStructure",
    "ParameterLayout",
    "RobotModel",
]

Convention = Literal["mdh", "dh", "urdf"]
# The joint count of the papers' 6R conventions ("mdh", "dh"); a chain's own count is RobotModel.n_joints.
N_JOINTS = 6
_POSE_NAMES = ("x", "y", "z", "rx", "ry", "rz")
# Parameter families of a "urdf" chain, in vector order (family-major).
URDF_FAMILIES = ("offset", "x", "y", "z", "rx", "ry", "rz")

# Elementary operations per joint, in order of application, for each 6R convention:
# (kind, axis index, parameter family). kind 'r' rotates about the local axis, 't' translates along it.
_OPS: dict[str, tuple[tuple[str, int, str], ...]] = {
    "mdh": (("r", 0, "alpha"), ("t", 0, "a"), ("t", 2, "d"), ("r", 2, "theta"), ("r", 1, "beta")),
    "dh": (("r", 2, "theta"), ("t", 2, "d"), ("t", 0, "a"), ("r", 0, "alpha"), ("r", 1, "beta")),
}


# ------------------------------------------------------------------------------------------------
# Chain structure
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ChainOp:
    """One elementary operation of a chain.

    ``kind``: ``"r"`` rotation about local axis ``axis`` (0, 1, 2 = x, y, z) by the value of parameter
    ``param`` [rad]; ``"t"`` translation along it [m]; ``"R"`` the constant rotation ``const`` (a row-major
    9-tuple); ``"P"`` the constant translation ``const`` (3-tuple) [m]. ``joint`` (0-based, -1 for none): the
    commanded joint value ``q[joint]`` enters the value as ``param + q`` (``sign`` +1) or ``param - q`` (-1).
    """

    kind: Literal["r", "t", "R", "P"]
    axis: int = 0
    param: str | None = None
    joint: int = -1
    sign: float = 1.0
    const: tuple[float, ...] | None = None

    def matrix(self) -> np.ndarray:
        """The constant transform ``(4, 4)`` of an ``"R"`` / ``"P"`` operation."""
        T = np.eye(4)
        if self.kind == "R":
            T[:3, :3] = np.asarray(self.const, dtype=float).reshape(3, 3)
        elif self.kind == "P":
            T[:3, 3] = np.asarray(self.const, dtype=float)
        else:
            raise ValueError(f"operation {self.kind!r} has no constant transform")
        return T


@dataclass(frozen=True)
class JointSpec:
    """One joint of a ``"urdf"`` chain in SI: ``origin`` as ``xyz`` [m] and ``rpy`` [rad] (URDF's
    ``R = Rz(yaw) Ry(pitch) Rx(roll)``) relative to the previous joint's frame (fixed joints before it folded
    in), unit ``axis`` (3,) in the joint frame, ``kind`` ``"revolute"`` or ``"prismatic"``, limits
    ``q_min``/``q_max`` [rad or m]. ``inertial``: optional mass properties of the link the joint moves (its
    child link plus fixed descendants up to the next joint): ``{"mass": kg, "com": (3,) [m], "inertia": (3, 3)
    [kg m^2]}`` in the joint frame."""

    name: str
    kind: Literal["revolute", "prismatic"]
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    q_min: float = -np.pi
    q_max: float = np.pi
    inertial: dict | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("revolute", "prismatic"):
            raise ValueError(f"joint {self.name!r}: kind must be 'revolute' or 'prismatic', got {self.kind!r}")
        for attr in ("xyz", "rpy", "axis"):
            v = np.asarray(getattr(self, attr), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"joint {self.name!r}: {attr} must be 3 finite numbers, got {getattr(self, attr)!r}")
            object.__setattr__(self, attr, tuple(float(x) for x in v))
        n = float(np.linalg.norm(self.axis))
        if not n > 1e-9:
            raise ValueError(f"joint {self.name!r}: axis must be a non-zero vector, got {self.axis!r}")
        object.__setattr__(self, "axis", tuple(float(x) / n for x in self.axis))
        if not (np.isfinite(self.q_min) and np.isfinite(self.q_max) and self.q_min < self.q_max):
            raise ValueError(f"joint {self.name!r}: limits must be finite with q_min < q_max, got "
                             f"[{self.q_min!r}, {self.q_max!r}]")
        if not self.name or "." in self.name or "@" in self.name or "," in self.name:
            raise ValueError(f"joint name {self.name!r} must be non-empty without '.', '@' or ','")

    @property
    def origin(self) -> np.ndarray:
        """The origin transform ``(4, 4)``: joint frame in the previous joint's frame at ``q = 0``."""
        return make_transform(matrix_from_euler_zyx(np.array(self.rpy)), np.array(self.xyz))


def _axis_ops(axis: tuple[float, float, float]) -> tuple[int, float, np.ndarray | None]:
    """(local axis index, sign, constant rotation taking z onto the axis or None) of a unit joint axis."""
    a = np.asarray(axis, dtype=float)
    k = int(np.argmax(np.abs(a)))
    if abs(abs(a[k]) - 1.0) < 1e-12:
        return k, float(np.sign(a[k])), None
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, a)
    ang = np.arctan2(np.linalg.norm(v), a[2])
    R = rotvec_to_matrix(v / np.linalg.norm(v) * ang)
    return 2, 1.0, R


@dataclass(frozen=True, eq=False)
class ChainStructure:
    """The structure of a serial chain: joints (names, kinds), their elementary operations and the names,
    units, families and joints of its structural parameters (base and tool excluded).

    ``ops[i]`` are joint ``i``'s operations in order of application; ``end`` the constant operations after the
    last joint (the flange is the frame they end in). ``convention`` ``"mdh"``, ``"dh"`` (the 6R papers'
    tables) or ``"urdf"`` (``joints`` holds the :class:`JointSpec` table it was built from, ``end_origin`` the
    constant end transform ``(4, 4)``).
    """

    convention: str
    joint_names: tuple[str, ...]
    joint_kinds: tuple[str, ...]
    ops: tuple[tuple[ChainOp, ...], ...]
    end: tuple[ChainOp, ...]
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    param_families: tuple[str, ...]
    param_joints: tuple[int, ...]
    beta_joints: tuple[int, ...] = ()
    joints: tuple[JointSpec, ...] = ()
    end_origin: tuple[float, ...] | None = None

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def joint_params(self) -> tuple[str, ...]:
        """The parameter each joint's commanded value adds to (``theta_i`` / ``<joint>.offset``)."""
        out = []
        for i, ops in enumerate(self.ops):
            out.append(next(op.param for op in ops if op.joint == i))
        return tuple(out)

    @property
    def joint_signs(self) -> np.ndarray:
        """``(N,)`` +1 / -1: how each commanded joint enters its operation."""
        return np.array([next(op.sign for op in ops if op.joint == i) for i, ops in enumerate(self.ops)])

    @staticmethod
    def six_r(convention: str, beta_joints: tuple[int, ...], n_joints: int = N_JOINTS) -> "ChainStructure":
        """The structure of a DH table (``"mdh"`` / ``"dh"``) of ``n_joints`` revolute joints (the papers' 6R arms
        by default; joint columns ``q1..qN``) with beta on ``beta_joints`` (1-based, in ``1..n_joints``). One
        object per distinct structure."""
        return _dh_structure(str(convention), tuple(int(j) for j in beta_joints), int(n_joints))

    @staticmethod
    def _build_dh(convention: str, beta_joints: tuple[int, ...], n_joints: int) -> "ChainStructure":
        if convention not in _OPS:
            raise ValueError(f"convention must be 'mdh' or 'dh', got {convention!r}")
        n_joints = int(n_joints)
        if n_joints < 1:
            raise ValueError(f"n_joints must be at least 1, got {n_joints}")
        bad = [j for j in beta_joints if not 1 <= int(j) <= n_joints]
        if bad:
            raise ValueError(f"beta_joints must be joint numbers in 1..{n_joints}, got {list(beta_joints)}")
        names: list[str] = []
        for fam in ("theta", "d", "a", "alpha"):
            names += [f"{fam}{i}" for i in range(1, n_joints + 1)]
        names += [f"beta{j}" for j in beta_joints]
        ops = []
        for i in range(n_joints):
            jops = []
            for kind, axis, fam in _OPS[convention]:
                if fam == "beta" and (i + 1) not in beta_joints:
                    continue
                jops.append(ChainOp(kind, axis, f"{fam}{i + 1}", joint=i if fam == "theta" else -1))
            ops.append(tuple(jops))
        units = tuple("m" if n.rstrip("0123456789") in ("d", "a") else "rad" for n in names)
        return ChainStructure(
            convention=convention,
            joint_names=tuple(f"q{i}" for i in range(1, n_joints + 1)),
            joint_kinds=("revolute",) * n_joints,
            ops=tuple(ops),
            end=(),
            param_names=tuple(names),
            param_units=units,
            param_families=tuple(n.rstrip("0123456789") for n in names),
            param_joints=tuple(int(n[len(n.rstrip("0123456789")):]) for n in names),
            beta_joints=tuple(beta_joints),
        )

    @staticmethod
    def from_joints(joints: tuple[JointSpec, ...] | list[JointSpec], end_origin: np.ndarray | None = None) -> "ChainStructure":
        """A ``"urdf"`` chain from its joints and the constant transform ``(4, 4)`` after the last one."""
        joints = tuple(joints)
        if not joints:
            raise ValueError("joints: a chain needs at least one joint")
        names = [j.name for j in joints]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"joints: duplicate joint names {dup}")
        pnames, units, fams, pj = [], [], [], []
        for fam in URDF_FAMILIES:
            for i, j in enumerate(joints):
                pnames.append(f"{j.name}.{fam}")
                fams.append(fam)
                pj.append(i + 1)
                if fam == "offset":
                    units.append("m" if j.kind == "prismatic" else "rad")
                else:
                    units.append("m" if fam in ("x", "y", "z") else "rad")
        ops = []
        for i, j in enumerate(joints):
            jops = [ChainOp("t", 0, f"{j.name}.x"), ChainOp("t", 1, f"{j.name}.y"), ChainOp("t", 2, f"{j.name}.z")]
            R = matrix_from_euler_zyx(np.array(j.rpy))
            if not np.array_equal(R, np.eye(3)):
                jops.append(ChainOp("R", const=tuple(R.reshape(-1).tolist())))
            jops += [ChainOp("r", 0, f"{j.name}.rx"), ChainOp("r", 1, f"{j.name}.ry"), ChainOp("r", 2, f"{j.name}.rz")]
            k, sign, Ra = _axis_ops(j.axis)
            if Ra is not None:
                jops.append(ChainOp("R", const=tuple(Ra.reshape(-1).tolist())))
            jops.append(ChainOp("r" if j.kind == "revolute" else "t", k, f"{j.name}.offset", joint=i, sign=sign))
            if Ra is not None:
                jops.append(ChainOp("R", const=tuple(Ra.T.reshape(-1).tolist())))
            ops.append(tuple(jops))
        E = np.eye(4) if end_origin is None else np.asarray(end_origin, dtype=float)
        if E.shape != (4, 4) or not np.all(np.isfinite(E)):
            raise ValueError(f"end_origin must be a finite (4, 4) transform, got shape {E.shape}")
        end = []
        if np.any(E[:3, 3] != 0):
            end.append(ChainOp("P", const=tuple(E[:3, 3].tolist())))
        if not np.array_equal(E[:3, :3], np.eye(3)):
            end.append(ChainOp("R", const=tuple(E[:3, :3].reshape(-1).tolist())))
        return ChainStructure(
            convention="urdf",
            joint_names=tuple(names),
            joint_kinds=tuple(j.kind for j in joints),
            ops=tuple(ops),
            end=tuple(end),
            param_names=tuple(pnames),
            param_units=tuple(units),
            param_families=tuple(fams),
            param_joints=tuple(pj),
            joints=joints,
            end_origin=tuple(E.reshape(-1).tolist()),
        )

    def nominal_params(self) -> np.ndarray:
        """Structural parameter values of a ``"urdf"`` chain's nominal joints ``(P_s,)`` (origin translations,
        zero offsets and origin rotation errors)."""
        if self.convention != "urdf":
            raise ValueError("nominal_params: only a 'urdf' chain carries its nominal values in its joints")
        v = np.zeros(len(self.param_names))
        for k, (fam, j) in enumerate(zip(self.param_families, self.param_joints)):
            if fam in ("x", "y", "z"):
                v[k] = self.joints[j - 1].xyz["xyz".index(fam)]
        return v


@functools.lru_cache(maxsize=None)
def _dh_structure(convention: str, beta_joints: tuple[int, ...], n_joints: int) -> ChainStructure:
    return ChainStructure._build_dh(convention, beta_joints, n_joints)


@dataclass(frozen=True)
class ParameterLayout:
    """Names, units and positions of the entries of a model's parameter vector: the chain's structural
    parameters, then ``base_*`` and ``tool_*``. ``ParameterLayout(beta_joints)`` is the papers' 6R layout;
    ``ParameterLayout(structure=...)`` any chain's."""

    beta_joints: tuple[int, ...] = ()
    structure: ChainStructure | None = None
    names: tuple[str, ...] = field(init=False)
    units: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        st = self.structure
        if st is None:
            st = ChainStructure.six_r("mdh", tuple(self.beta_joints))
            object.__setattr__(self, "structure", st)
        else:
            object.__setattr__(self, "beta_joints", tuple(st.beta_joints))
        names = list(st.param_names)
        names += [f"base_{c}" for c in _POSE_NAMES]
        names += [f"tool_{c}" for c in _POSE_NAMES]
        unit_of = dict(zip(st.param_names, st.param_units))
        units = [unit_of.get(n) or self._frame_unit(n) for n in names]
        object.__setattr__(self, "names", tuple(names))
        object.__setattr__(self, "units", tuple(units))
        object.__setattr__(self, "_unit_of", {**unit_of, **{n: u for n, u in zip(names, units)}})
        object.__setattr__(self, "_fam_of", dict(zip(st.param_names, st.param_families)))

    @staticmethod
    def _frame_unit(name: str) -> str:
        if name.startswith(("d", "a")) and not name.startswith("alpha"):
            return "m"
        if name in ("base_x", "base_y", "base_z", "tool_x", "tool_y", "tool_z"):
            return "m"
        return "rad"

    def _unit(self, name: str) -> str:
        """Unit (``"m"`` or ``"rad"``) of parameter ``name``."""
        u = self._unit_of.get(name)  # type: ignore[attr-defined]
        return u if u is not None else self._frame_unit(name)

    def family_of(self, name: str) -> str:
        """Family of a parameter name: ``theta``/``d``/``a``/``alpha``/``beta``, ``offset``/``x``/...``rz`` of a
        ``"urdf"`` chain, or ``base``/``tool``."""
        name = name.split("@")[0]
        if name.startswith(("base_", "tool_")):
            return name.split("_")[0]
        fam = self._fam_of.get(name)  # type: ignore[attr-defined]
        return fam if fam is not None else name.rstrip("0123456789")

    @property
    def size(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Position of parameter ``name``; ``ValueError`` naming it when unknown."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown parameter name {name!r}; known: {', '.join(self.names)}") from None

    def indices(self, names) -> np.ndarray:
        return np.array([self.index(n) for n in names], dtype=int)

    def family(self, fam: str) -> np.ndarray:
        """Indices of one family: 'theta', 'd', 'a', 'alpha', 'beta' (6R), 'offset', 'x', ..., 'rz' ("urdf"),
        'base', 'tool'."""
        if fam in ("base", "tool"):
            return np.array([i for i, n in enumerate(self.names) if n.startswith(fam + "_")], dtype=int)
        return np.array(
            [i for i, n in enumerate(self.names[: len(self.structure.param_names)]) if self.family_of(n) == fam],
            dtype=int,
        )

    @property
    def is_length(self) -> np.ndarray:
        """Boolean mask of parameters in [m]."""
        return np.array([u == "m" for u in self.units])

    @property
    def base_slice(self) -> slice:
        i = self.index("base_x")
        return slice(i, i + 6)

    @property
    def tool_slice(self) -> slice:
        i = self.index("tool_x")
        return slice(i, i + 6)


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A serial arm: convention, absolute parameter vector (SI), joint limits.

    ``params`` ``(P,)`` follows :class:`ParameterLayout`. ``q_min``/``q_max`` ``(N,)`` [rad, or m for prismatic
    joints] bound the commanded joints ``q``. ``convention`` ``"mdh"``/``"dh"`` (six revolute joints ``q1..q6``,
    ``beta_joints``) or ``"urdf"`` (``structure`` required: :meth:`ChainStructure.from_joints`).
    """

    name: str
    convention: Convention
    params: np.ndarray
    beta_joints: tuple[int, ...] = ()
    q_min: np.ndarray | None = None
    q_max: np.ndarray | None = None
    structure: ChainStructure | None = None

    def __post_init__(self) -> None:
        if self.convention in _OPS:
            given = self.structure
            if isinstance(given, ChainStructure) and given.convention == self.convention:
                st = given
            else:  # a DH table's joint count follows from its parameter count: 4 N + betas + base + tool
                extra = np.size(self.params) - len(self.beta_joints) - 12
                n = extra // 4 if extra >= 4 and extra % 4 == 0 else N_JOINTS
                st = ChainStructure.six_r(self.convention, tuple(int(j) for j in self.beta_joints), n)
        elif self.convention == "urdf":
            if not isinstance(self.structure, ChainStructure) or self.structure.convention != "urdf":
                raise ValueError("convention 'urdf' needs structure=ChainStructure.from_joints(...)")
            st = self.structure
        else:
            raise ValueError(f"convention must be 'mdh', 'dh' or 'urdf', got {self.convention!r}")
        object.__setattr__(self, "structure", st)
        object.__setattr__(self, "beta_joints", tuple(st.beta_joints) if self.convention == "urdf" else tuple(self.beta_joints))
        p = np.array(self.params, dtype=float).reshape(-1)
        six_r = self.convention != "urdf" and st.n_joints == N_JOINTS
        layout = ParameterLayout(tuple(self.beta_joints)) if six_r else ParameterLayout(structure=st)
        if p.shape != (layout.size,):
            raise ValueError(f"params must have {layout.size} entries for this chain, got {p.size}")
        if not np.all(np.isfinite(p)):
            bad = [layout.names[i] for i in np.flatnonzero(~np.isfinite(p))]
            raise ValueError(f"params contain non-finite values at {bad}")
        p.setflags(write=False)
        object.__setattr__(self, "params", p)
        nj = st.n_joints
        for attr, default in (("q_min", -np.pi), ("q_max", np.pi)):
            raw = getattr(self, attr)
            if raw is None:
                if self.convention == "urdf":
                    raw = [getattr(j, attr) for j in st.joints]
                else:
                    raw = np.full(nj, default)
            v = np.array(raw, dtype=float).reshape(nj)
            v.setflags(write=False)
            object.__setattr__(self, attr, v)
        object.__setattr__(self, "_layout", layout)
        object.__setattr__(self, "_pindex", tuple(
            tuple(layout.index(op.param) if op.param is not None else -1 for op in ops) for ops in st.ops))

    # --- construction -------------------------------------------------------------------------
    @classmethod
    def from_tables(
        cls,
        name: str,
        convention: Convention,
        *,
        theta: np.ndarray,
        d: np.ndarray,
        a: np.ndarray,
        alpha: np.ndarray,
        beta: dict[int, float] | None = None,
        base2meas: np.ndarray | None = None,
        tool2flange: np.ndarray | None = None,
        q_min: np.ndarray | None = None,
        q_max: np.ndarray | None = None,
    ) -> "RobotModel":
        """A DH-table model (``convention`` ``"mdh"``/``"dh"``) of N revolute joints from per-joint tables in SI
        (``theta``/``alpha`` [rad], ``d``/``a`` [m], ``(N,)`` each, N >= 1; the papers' 6R arms have N = 6);
        ``beta``: ``{joint (1-based): tilt [rad]}``."""
        beta = {int(j): float(v) for j, v in dict(beta or {}).items()}
        beta_joints = tuple(sorted(beta))
        tables = [np.asarray(x, dtype=float).reshape(-1) for x in (theta, d, a, alpha)]
        n = tables[0].size
        if n < 1 or any(t.size != n for t in tables):
            raise ValueError(f"theta, d, a, alpha must have the same length N >= 1, got "
                             f"{[t.size for t in tables]}")
        base = np.zeros(6) if base2meas is None else transform_to_pose6(base2meas)
        tool = np.zeros(6) if tool2flange is None else transform_to_pose6(tool2flange)
        params = np.concatenate(tables + [np.array([beta[j] for j in beta_joints], dtype=float), base, tool])
        kw = {"structure": ChainStructure.six_r(convention, beta_joints, n)} if convention in _OPS else {}
        if q_min is not None:
            kw["q_min"] = q_min
        if q_max is not None:
            kw["q_max"] = q_max
        return cls(name=name, convention=convention, params=params, beta_joints=beta_joints, **kw)

    @classmethod
    def from_joints(
        cls,
        name: str,
        joints: list[JointSpec] | tuple[JointSpec, ...],
        *,
        end_origin: np.ndarray | None = None,
        base2meas: np.ndarray | None = None,
        tool2flange: np.ndarray | None = None,
    ) -> "RobotModel":
        """A ``"urdf"`` chain from its joints (nominal: zero offsets and origin errors), the constant transform
        ``(4, 4)`` after the last joint (flange = end link) and optional base and tool ``(4, 4)``."""
        st = ChainStructure.from_joints(joints, end_origin)
        base = np.zeros(6) if base2meas is None else transform_to_pose6(base2meas)
        tool = np.zeros(6) if tool2flange is None else transform_to_pose6(tool2flange)
        params = np.concatenate([st.nominal_params(), base, tool])
        return cls(name=name, convention="urdf", params=params, structure=st)

    def with_params(self, params: np.ndarray, name: str | None = None) -> "RobotModel":
        """Same structure, new parameter vector ``(P,)``."""
        return replace(self, params=np.asarray(params, dtype=float), name=name or self.name)

    def perturbed(self, deviation: dict[str, float] | np.ndarray, name: str | None = None) -> "RobotModel":
        """Add a deviation (by name, SI units, or as a full ``(P,)`` vector) to the parameters."""
        p = self.params.copy()
        if isinstance(deviation, dict):
            for k, v in deviation.items():
                p[self.layout.index(k)] += float(v)
        else:
            dev = np.asarray(deviation, dtype=float)
            if dev.shape != p.shape:
                raise ValueError(f"deviation must have shape {p.shape}, got {dev.shape}")
            p += dev
        return self.with_params(p, name)

    def with_frames(self, base2meas: np.ndarray | None = None, tool2flange: np.ndarray | None = None) -> "RobotModel":
        """Replace the base and/or tool transforms ``(4, 4)``."""
        p = self.params.copy()
        if base2meas is not None:
            p[self.layout.base_slice] = transform_to_pose6(base2meas)
        if tool2flange is not None:
            p[self.layout.tool_slice] = transform_to_pose6(tool2flange)
        return self.with_params(p)

    # --- views ---------------------------------------------------------------------------------
    @property
    def layout(self) -> ParameterLayout:
        return self._layout  # type: ignore[attr-defined]

    @property
    def n_joints(self) -> int:
        """Number of joints N."""
        return self.structure.n_joints  # type: ignore[union-attr]

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names (``q1..q6`` for the 6R conventions): the joint columns of datasets."""
        return self.structure.joint_names  # type: ignore[union-attr]

    @property
    def joint_kinds(self) -> tuple[str, ...]:
        """``"revolute"`` or ``"prismatic"`` per joint."""
        return self.structure.joint_kinds  # type: ignore[union-attr]

    @property
    def is_prismatic(self) -> np.ndarray:
        """``(N,)`` mask of prismatic joints (commanded in [m]; revolute ones in [rad])."""
        return np.array([k == "prismatic" for k in self.joint_kinds])

    def _family(self, fam: str) -> np.ndarray:
        if self.convention == "urdf" and fam in ("theta", "d", "a", "alpha", "beta"):
            raise ValueError(f"model {self.name!r} is a 'urdf' chain: it has no DH parameter {fam!r}")
        return self.params[self.layout.family(fam)]

    @property
    def theta(self) -> np.ndarray:
        """Joint angle offsets ``(N,)`` [rad] (DH conventions)."""
        return self._family("theta")

    @property
    def d(self) -> np.ndarray:
        """Link offsets ``(N,)`` [m] (DH conventions)."""
        return self._family("d")

    @property
    def a(self) -> np.ndarray:
        """Link lengths ``(N,)`` [m] (DH conventions)."""
        return self._family("a")

    @property
    def alpha(self) -> np.ndarray:
        """Link twists ``(N,)`` [rad] (DH conventions)."""
        return self._family("alpha")

    @property
    def beta(self) -> np.ndarray:
        """Parallel-axis tilts ``(N,)`` [rad], zero for joints without beta (DH conventions)."""
        out = np.zeros(self.n_joints)
        for j, v in zip(self.beta_joints, self._family("beta")):
            out[j - 1] = v
        return out

    @property
    def base2meas(self) -> np.ndarray:
        """Base-to-measurement transform ``(4, 4)`` (``p_meas = base2meas @ p_base``)."""
        return pose6_to_transform(self.params[self.layout.base_slice])

    @property
    def tool2flange(self) -> np.ndarray:
        """Tool(plate)-to-flange transform ``(4, 4)``."""
        return pose6_to_transform(self.params[self.layout.tool_slice])

    def param(self, name: str) -> float:
        return float(self.params[self.layout.index(name)])

    def within_limits(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Mask ``(n,)`` of configurations ``(n, N)`` inside the joint limits."""
        q = np.atleast_2d(q)
        return np.all((q >= self.q_min - tol) & (q <= self.q_max + tol), axis=-1)
