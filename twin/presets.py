"""Preset parameter deviations from the papers: *inputs* of simulations (what is injected), never results.

Each preset is a deviation dict in SI units keyed by parameter names of ``twin.kinematics.ParameterLayout``,
plus the robot it applies to. The papers' identified values and statistics (their *results*) are not here:
they live in ``twin/data/paper_targets_*.toml`` (:mod:`twin.evaluation.targets`) and are only printed beside ours.

* ``separation_tables_2_4``: the separation paper's simulation presets (Tables 2 and 4, IRB-1200, MDH).
  Table 2's theta2 of -0.4 deg is "the sum of delta theta2 and delta theta3"; Table 4 gives them as
  -0.3 and -0.1 deg: they are injected once, as theta2 = -0.3 deg and theta3 = -0.1 deg.
* ``separation_table_6``: the separation paper's identified errors of its real IRB-1200 (Table 6), used as
  the injected truth of the real-robot protocol on the twin.
* ``tmmdh_tables_4_5``: the TM-MDH paper's presets (Tables 4 and 5, BRTIRUS0707A, DH + beta), including the
  base (Delta u) and tool (Delta v) transformation errors; their angles (alpha about z, beta about y, gamma
  about x, eq. 3) become rotation vectors of ``Rz(alpha) Ry(beta) Rx(gamma)``.
"""

from __future__ import annotations

import numpy as np

from .transforms import matrix_from_euler_zyx, matrix_to_rotvec
from .units import M_PER_MM, RAD_PER_DEG

__all__ = ["PRESETS", "preset_deviation", "preset_robot"]


def _rows(table: dict[int, dict[str, float]], scale: dict[str, float]) -> dict[str, float]:
    out: dict[str, float] = {}
    for joint, row in table.items():
        for fam, v in row.items():
            out[f"{fam}{joint}"] = v * scale[fam]
    return out


_SEP_SCALE = {"theta": RAD_PER_DEG, "alpha": RAD_PER_DEG, "beta": RAD_PER_DEG, "d": M_PER_MM, "a": M_PER_MM}
_TM_SCALE = {"theta": 1.0, "alpha": 1.0, "beta": 1.0, "d": M_PER_MM, "a": M_PER_MM}

# Separation paper, Table 2 (angles, deg) and Table 4 (lengths, mm; theta2/theta3 split in deg).
_SEP_T2 = {
    1: {"theta": 0.07, "alpha": 0.1},
    2: {"alpha": 0.4, "beta": 0.1},
    3: {"alpha": -0.5},
    4: {"theta": 0.11, "alpha": 0.2},
    5: {"theta": -0.3, "alpha": 0.4},
    6: {"theta": 0.1, "alpha": -0.5},
}
_SEP_T4 = {
    1: {"d": 0.3, "a": 1.0},
    2: {"theta": -0.3, "a": 0.8},
    3: {"theta": -0.1, "d": -0.8, "a": 0.5},
    4: {"d": -0.1, "a": -1.0},
    5: {"d": -0.3, "a": -0.3},
    6: {"d": 1.0, "a": 1.0},
}
# Separation paper, Table 6 (theta deg, d mm, a mm, alpha deg, beta deg); d2 is not given.
_SEP_T6 = {
    1: {"theta": 0.0335, "d": 0.2975, "a": -0.0772, "alpha": -0.4661},
    2: {"theta": 0.9675, "a": 0.0314, "alpha": 0.5465, "beta": 0.1123},
    3: {"theta": -0.2930, "d": -0.0367, "a": 0.0174, "alpha": -0.8628},
    4: {"theta": -0.2729, "d": 0.2377, "a": -0.0865, "alpha": -0.6019},
    5: {"theta": 0.5736, "d": 0.2872, "a": 0.0424, "alpha": 0.7824},
    6: {"theta": -0.5182, "d": 0.0936, "a": -0.2615, "alpha": -0.3927},
}
# TM-MDH paper, Table 4 (theta rad, d mm, a mm, alpha rad, beta rad).
_TM_T4 = {
    1: {"theta": -0.0035, "d": 0.02, "a": -0.70, "alpha": 0.0},
    2: {"theta": 0.002, "d": -0.05, "a": -0.4, "alpha": 0.0035, "beta": 0.001},
    3: {"theta": 0.001, "d": 0.03, "a": 0.5, "alpha": 0.0014},
    4: {"theta": 0.004, "d": -0.04, "a": 0.5, "alpha": -0.0014},
    5: {"theta": 0.0035, "d": 0.01, "a": -0.1, "alpha": 0.0087},
    6: {"theta": -0.008, "d": -0.06, "a": -0.2, "alpha": -0.001},
}
# TM-MDH paper, Table 5: (x, y, z) mm, (alpha about z, beta about y, gamma about x) rad.
_TM_T5 = {"base": (0.05, 0.07, 0.0, 0.0, 0.001, 0.005), "tool": (0.0, 0.02, 0.0, 0.0, 0.006, 0.0)}


def _frame_dev(prefix: str, xyz_mm_abg: tuple[float, ...]) -> dict[str, float]:
    x, y, z, al, be, ga = xyz_mm_abg
    r = matrix_to_rotvec(matrix_from_euler_zyx(np.array([ga, be, al])))
    return {
        f"{prefix}_x": x * M_PER_MM, f"{prefix}_y": y * M_PER_MM, f"{prefix}_z": z * M_PER_MM,
        f"{prefix}_rx": float(r[0]), f"{prefix}_ry": float(r[1]), f"{prefix}_rz": float(r[2]),
    }


PRESETS: dict[str, tuple[str, dict[str, float]]] = {
    "separation_tables_2_4": ("irb1200", {**_rows(_SEP_T2, _SEP_SCALE), **_rows(_SEP_T4, _SEP_SCALE)}),
    "separation_table_6": ("irb1200", _rows(_SEP_T6, _SEP_SCALE)),
    "tmmdh_tables_4_5": (
        "brtirus0707a",
        {**_rows(_TM_T4, _TM_SCALE), **_frame_dev("base", _TM_T5["base"]), **_frame_dev("tool", _TM_T5["tool"])},
    ),
}


def preset_deviation(name: str) -> dict[str, float]:
    """Deviation dict (SI) of a named preset; ``ValueError`` naming it when unknown."""
    try:
        return dict(PRESETS[name][1])
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None


def preset_robot(name: str) -> str:
    """Name of the robot a preset applies to."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}")
    return PRESETS[name][0]
