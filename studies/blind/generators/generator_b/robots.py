"""Robot tables used by the generator: the named irb1200 and three inline MDH arms of other sizes."""
from __future__ import annotations

import numpy as np

from kin import DEG, IRB1200


def _inline(name, d1, a3, a4, d4, d6, qmin, qmax):
    return dict(
        name=name,
        alpha=np.array([0.0, -90.0, 0.0, -90.0, 90.0, -90.0]) * DEG,
        a=np.array([0.0, 0.0, a3, a4, 0.0, 0.0]),
        d=np.array([d1, 0.0, 0.0, d4, 0.0, d6]),
        theta=np.array([0.0, -90.0, 0.0, 0.0, 0.0, 0.0]) * DEG,
        beta2=0.0,
        qmin=np.array(qmin, float),
        qmax=np.array(qmax, float),
        inline=True,
    )


ROBOTS = {
    "irb1200": dict(IRB1200, inline=False),
    "arm_k1": _inline("arm_k1", 430.0, 385.0, 30.0, 405.0, 88.0,
                      [-165, -95, -190, -250, -125, -350], [165, 135, 75, 250, 125, 350]),
    "arm_k2": _inline("arm_k2", 352.0, 300.0, 55.0, 318.0, 74.0,
                      [-170, -105, -205, -270, -120, -360], [170, 125, 65, 270, 120, 360]),
    "arm_k3": _inline("arm_k3", 475.5, 420.0, 35.0, 452.0, 95.0,
                      [-160, -90, -185, -240, -130, -330], [160, 140, 70, 240, 130, 330]),
}


def size_factor(robot) -> float:
    """Arm size relative to the IRB 1200 (upper arm + forearm)."""
    return float((robot["a"][2] + robot["d"][3]) / 701.0)


def masses(robot) -> dict:
    """Lumped link masses [kg] for gravity torques (own estimate, scaled with the arm's size^2)."""
    s = size_factor(robot) ** 2
    return dict(upper_arm=7.0 * s, forearm=5.0 * s, wrist=2.5 * s, plate=0.4)


def toml_robot(robot) -> str:
    """The inline [robot] table of docs/formats.md."""
    f = lambda v: "[" + ", ".join(f"{x:.6g}" for x in v) + "]"
    return "\n".join([
        "[robot]",
        f'name = "{robot["name"]}"',
        'convention = "mdh"',
        "beta_joints = [2]",
        f"theta_deg = {f(robot['theta'] / DEG)}",
        f"d_mm = {f(robot['d'])}",
        f"a_mm = {f(robot['a'])}",
        f"alpha_deg = {f(robot['alpha'] / DEG)}",
        "beta_deg = [0]",
        f"q_min_deg = {f(robot['qmin'])}",
        f"q_max_deg = {f(robot['qmax'])}",
    ])
