"""The robots the library knows by name. These nominal tables are contracts: datasets name them.

* ``irb1200``: ABB IRB 1200-7/0.7 in Craig modified DH (the separation paper's eq. 1), with the real
  arm's lengths (the paper's Table 1 leaves d1 and the flange offset at zero and prints -20 deg for the
  last twist; see ``docs/conventions.md``). beta on joint 2 (the parallel pair 2-3).
* ``brtirus0707a``: the TM-MDH paper's Table 3 robot in its standard DH + beta convention, with the
  lost minus signs of the twists restored and the first row read as d1 = 444.5 mm, a1 = 50 mm.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .kinematics import RobotModel

__all__ = ["irb1200", "brtirus0707a", "get_robot", "ROBOTS"]

_MM = 1e-3
_DEG = np.pi / 180.0


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
        theta=table[:, 3] * _DEG,
        d=table[:, 2] * _MM,
        a=table[:, 1] * _MM,
        alpha=table[:, 0] * _DEG,
        beta={2: 0.0},
        q_min=limits_deg[:, 0] * _DEG,
        q_max=limits_deg[:, 1] * _DEG,
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
        d=table[:, 1] * _MM,
        a=table[:, 2] * _MM,
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
