"""The robots the library knows by name. These nominal tables are contracts: datasets name them.

* ``irb1200``: ABB IRB 1200-7/0.7 in Craig modified DH (the separation paper's eq. 1), with the real
  arm's lengths (the paper's Table 1 leaves d1 and the flange offset at zero and prints -20 deg for the
  last twist; see ``docs/conventions.md``). beta on joint 2 (the parallel pair 2-3).
* ``brtirus0707a``: the TM-MDH paper's Table 3 robot in its standard DH + beta convention, with the
  lost minus signs of the twists restored and the first row read as d1 = 444.5 mm, a1 = 50 mm.

Any other serial chain comes from a URDF (:mod:`twin.urdf`) or from a joint table
(:func:`robot_from_joint_table`, the form ``dataset.toml`` and ``calibration.json`` hold).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .kinematics import RobotModel
from .units import M_PER_MM, RAD_PER_DEG

__all__ = ["irb1200", "brtirus0707a", "get_robot", "ROBOTS", "robot_from_joint_table", "joint_table", "check_robot_fields"]


def irb1200() -> RobotModel:
    """ABB IRB 1200-7/0.7, Craig MDH: (alpha_{i-1} deg, a_{i-1} mm, d_i mm, theta offset deg) per joint."""
    #            alpha   a      d      theta
    table = np.array(
        [
            [0.0, 0.0, 399.1, 0.0],
            [-90.0, 0.0, 0.0, -90.0],
            [0.0, 350.0, 0.0, 0.0],
            [-90.0, 42.0, 351.0, 0.0],
            [90.0, 0.0, 0.0, 0.0],
            [-90.0, 0.0, 82.0, 0.0],
        ]
    )
    limits_deg = np.array([[-170, 170], [-100, 130], [-200, 70], [-270, 270], [-130, 130], [-360, 360]], float)
    return RobotModel.from_tables(
        "irb1200",
        "mdh",
        theta=table[:, 3] * RAD_PER_DEG,
        d=table[:, 2] * M_PER_MM,
        a=table[:, 1] * M_PER_MM,
        alpha=table[:, 0] * RAD_PER_DEG,
        beta={2: 0.0},
        q_min=limits_deg[:, 0] * RAD_PER_DEG,
        q_max=limits_deg[:, 1] * RAD_PER_DEG,
    )


def brtirus0707a() -> RobotModel:
    """BRTIRUS0707A (TM-MDH paper, Table 3), standard DH + beta2: (theta rad, d mm, a mm, alpha rad)."""
    h = np.pi / 2
    #            theta  d      a     alpha
    table = np.array(
        [
            [0.0, 444.5, 50.0, -h],
            [0.0, 0.0, 350.0, 0.0],
            [0.0, 0.0, 41.0, -h],
            [0.0, 364.0, 0.0, h],
            [0.0, 0.0, 0.0, -h],
            [0.0, 117.0, 0.0, 0.0],
        ]
    )
    limits = np.array(
        [[-3.0369, 3.0369], [-2.1817, 2.1817], [-1.0472, 3.0543], [-3.1416, 3.1416], [-2.0944, 2.0944], [-6.2832, 6.2832]]
    )
    return RobotModel.from_tables(
        "brtirus0707a",
        "dh",
        theta=table[:, 0],
        d=table[:, 1] * M_PER_MM,
        a=table[:, 2] * M_PER_MM,
        alpha=table[:, 3],
        beta={2: 0.0},
        q_min=limits[:, 0],
        q_max=limits[:, 1],
    )


ROBOTS: dict[str, Callable[[], RobotModel]] = {"irb1200": irb1200, "brtirus0707a": brtirus0707a}


def get_robot(name: str) -> RobotModel:
    """The nominal model of a robot the library knows; ``ValueError`` naming ``name`` otherwise."""
    try:
        return ROBOTS[name]()
    except KeyError:
        raise ValueError(f"unknown robot name {name!r}; known robots: {', '.join(sorted(ROBOTS))}") from None


# ------------------------------------------------------------------------------------------------
# Chains as tables (dataset.toml, calibration.json): millimetres and degrees at the edge
# ------------------------------------------------------------------------------------------------

def _floats(v, n: int, what: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be {n} numbers, got {v!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be {n} finite numbers, got {v!r}")
    return a


def _transform_from_table(t: dict, what: str) -> np.ndarray:
    from .transforms import make_transform, matrix_from_euler_zyx

    if not isinstance(t, dict):
        raise ValueError(f"{what} must be a table with xyz_mm and rpy_deg, got {t!r}")
    xyz = _floats(t.get("xyz_mm", [0, 0, 0]), 3, f"{what}.xyz_mm") * M_PER_MM
    rpy = _floats(t.get("rpy_deg", [0, 0, 0]), 3, f"{what}.rpy_deg") * RAD_PER_DEG
    return make_transform(matrix_from_euler_zyx(rpy), xyz)


_ROBOT_FIELDS = {  # the fields of each form of an inline robot table (docs/formats.md)
    "urdf file": {"urdf", "root_link", "end_link", "name"},
    "joint table": {"name", "convention", "joints", "end"},
    "dh/mdh table": {"name", "convention", "beta_joints", "theta_deg", "d_mm", "a_mm", "alpha_deg", "beta_deg",
                     "q_min_deg", "q_max_deg"},
}
_JOINT_FIELDS = {"name", "type", "xyz_mm", "rpy_deg", "axis", "limits", "mass_kg", "com_mm", "inertia_kg_m2"}


def check_robot_fields(spec: dict) -> None:
    """``ValueError`` naming the table, the field and the fields its form reads when an inline robot table
    (``docs/formats.md``: a URDF file, a joint table, a DH/MDH table) holds a field its form does not read (a
    misspelt or unsupported one would otherwise be ignored)."""
    form = "urdf file" if "urdf" in spec else "joint table" if spec.get("convention") == "urdf" else "dh/mdh table"
    tables = [("robot", spec, _ROBOT_FIELDS[form])]
    if form == "joint table":
        joints = spec.get("joints") if isinstance(spec.get("joints"), list) else []
        tables += [(f"robot.joints[{k}]", j, _JOINT_FIELDS) for k, j in enumerate(joints) if isinstance(j, dict)]
        if isinstance(spec.get("end"), dict):
            tables.append(("robot.end", spec["end"], {"xyz_mm", "rpy_deg"}))
    for name, table, known in tables:
        unknown = sorted(set(table) - known)
        if unknown:
            hint = (": a DH/MDH table has revolute joints only; a prismatic joint needs a joint table (convention = "
                    "\"urdf\") or a URDF" if form == "dh/mdh table" and any("prism" in u for u in unknown) else "")
            raise ValueError(f"table {name!r} ({form}): unknown field(s) {unknown}; its fields are "
                             f"{sorted(known)}{hint}")


def robot_from_joint_table(spec: dict, where: str = "robot") -> RobotModel:
    """A ``"urdf"`` chain from its table (``docs/formats.md``): ``name``, ``joints`` (each ``name``, ``type``
    ``revolute``/``prismatic``, ``xyz_mm``, ``rpy_deg``, ``axis``, ``limits`` [deg or mm], optional ``mass_kg``,
    ``com_mm``, ``inertia_kg_m2`` ``[ixx, ixy, ixz, iyy, iyz, izz]``), optional ``end`` (``xyz_mm``,
    ``rpy_deg``). ``ValueError`` naming the field."""
    from .kinematics import JointSpec

    joints = spec.get("joints")
    if not isinstance(joints, list) or not joints:
        raise ValueError(f"{where}: field 'joints' must be a non-empty list of joint tables")
    specs = []
    for k, j in enumerate(joints):
        w = f"{where}.joints[{k}]"
        if not isinstance(j, dict):
            raise ValueError(f"{w} must be a table, got {j!r}")
        for key in ("name", "type", "xyz_mm", "rpy_deg", "limits"):
            if key not in j:
                raise ValueError(f"{w} lacks field {key!r}")
        kind = j["type"]
        if kind not in ("revolute", "prismatic"):
            raise ValueError(f"{w}.type must be 'revolute' or 'prismatic', got {kind!r}")
        unit = M_PER_MM if kind == "prismatic" else RAD_PER_DEG
        lim = _floats(j["limits"], 2, f"{w}.limits") * unit
        inertial = None
        if "mass_kg" in j:
            I6 = _floats(j.get("inertia_kg_m2", [0] * 6), 6, f"{w}.inertia_kg_m2")
            inertia = ((I6[0], I6[1], I6[2]), (I6[1], I6[3], I6[4]), (I6[2], I6[4], I6[5]))
            mass = float(_floats([j["mass_kg"]], 1, f"{w}.mass_kg")[0])
            com = tuple(_floats(j.get("com_mm", [0, 0, 0]), 3, f"{w}.com_mm") * M_PER_MM)
            inertial = {"mass": mass, "com": com, "inertia": inertia}
        specs.append(JointSpec(
            name=str(j["name"]), kind=kind,
            xyz=tuple(_floats(j["xyz_mm"], 3, f"{w}.xyz_mm") * M_PER_MM),
            rpy=tuple(_floats(j["rpy_deg"], 3, f"{w}.rpy_deg") * RAD_PER_DEG),
            axis=tuple(_floats(j.get("axis", [0, 0, 1]), 3, f"{w}.axis")),
            q_min=float(lim[0]), q_max=float(lim[1]), inertial=inertial,
        ))
    end = _transform_from_table(spec["end"], f"{where}.end") if "end" in spec else None
    return RobotModel.from_joints(str(spec.get("name", "custom")), specs, end_origin=end)


def joint_table(model: RobotModel) -> dict:
    """The table of a ``"urdf"`` chain's *nominal structure* (what :func:`robot_from_joint_table` reads):
    joints with their nominal origins, axes, limits and mass properties, and the end transform."""
    from .transforms import euler_zyx_from_matrix

    st = model.structure
    if st.convention != "urdf":
        raise ValueError(f"model {model.name!r} is a {st.convention!r} robot: its table is the DH one")
    joints = []
    for j in st.joints:
        unit = M_PER_MM if j.kind == "prismatic" else RAD_PER_DEG
        row = {"name": j.name, "type": j.kind, "xyz_mm": [x / M_PER_MM for x in j.xyz], "rpy_deg": [x / RAD_PER_DEG for x in j.rpy],
               "axis": list(j.axis), "limits": [j.q_min / unit, j.q_max / unit]}
        if j.inertial:
            I = np.asarray(j.inertial["inertia"], dtype=float)
            row.update({"mass_kg": j.inertial["mass"], "com_mm": [c / M_PER_MM for c in j.inertial["com"]],
                        "inertia_kg_m2": [I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]]})
        joints.append(row)
    E = np.asarray(st.end_origin, dtype=float).reshape(4, 4)
    return {"name": model.name, "convention": "urdf", "joints": joints,
            "end": {"xyz_mm": (E[:3, 3] / M_PER_MM).tolist(), "rpy_deg": (euler_zyx_from_matrix(E[:3, :3]) / RAD_PER_DEG).tolist()}}
