"""``twin export CALIBRATION.json --out DIR``: the parameter table (CSV, markdown) and an MJCF of the
calibrated robot.

The MJCF is generated here, self-contained (the world's generator in ``twin/world`` had not landed on main
when this was written): one body per joint following the chain exactly. Each joint transform is split at
its variable, ``T_i = pre_i RotZ(q_i) post_i`` with the offset ``theta_i`` folded into ``pre_i``; body ``i``
sits at ``post_{i-1} pre_i`` in body ``i-1`` (``post_0`` = identity: the MJCF world is the robot base frame)
with a hinge about its z axis, so that the MuJoCo joint angle is the commanded joint ``q_i``. Sites mark
the flange, the tool (plate) frame and the three sphere centres; capsules between joint origins are for
looking only (unit density).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from ..estimator import Calibration
from ..transforms import make_transform, matrix_to_quat_wxyz, rot_x, rot_y, rot_z

HELP = "write the calibrated robot as a parameter table (CSV, markdown) and an MJCF model"

_OPS = {
    "mdh": (("r", 0, "alpha"), ("t", 0, "a"), ("t", 2, "d"), ("r", 2, "theta"), ("r", 1, "beta")),
    "dh": (("r", 2, "theta"), ("t", 2, "d"), ("t", 0, "a"), ("r", 0, "alpha"), ("r", 1, "beta")),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", help="calibration.json")
    p.add_argument("--out", required=True, help="output folder (parameters.csv, parameters.md, robot.xml)")


def _elem(kind: str, axis: int, v: float) -> np.ndarray:
    if kind == "t":
        t = np.zeros(3)
        t[axis] = v
        return make_transform(np.eye(3), t)
    return make_transform((rot_x, rot_y, rot_z)[axis](v), np.zeros(3))


def joint_split(model, i: int) -> tuple[np.ndarray, np.ndarray]:
    """``(pre, post)`` ``(4, 4)`` of joint ``i`` (0-based): ``T_i(q) = pre RotZ(q) post``, theta folded into pre."""
    vals = {"theta": model.theta[i], "d": model.d[i], "a": model.a[i], "alpha": model.alpha[i], "beta": model.beta[i]}
    pre, post = np.eye(4), np.eye(4)
    seen = False
    for kind, axis, fam in _OPS[model.convention]:
        if fam == "beta" and (i + 1) not in model.beta_joints:
            continue
        E = _elem(kind, axis, vals[fam])
        if fam == "theta":
            pre = pre @ E
            seen = True
        elif seen:
            post = post @ E
        else:
            pre = pre @ E
    return pre, post


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in np.ravel(v))


def mjcf(cal: Calibration) -> str:
    """MJCF text of the calibrated robot (robot base frame = MJCF world; lengths [m], angles [rad])."""
    m = cal.robot
    splits = [joint_split(m, i) for i in range(6)]
    name = f"{m.name}"
    lines = [
        f'<mujoco model="{name}">',
        f"  <!-- calibrated by twin.estimator, method {cal.method}; dataset {cal.dataset or '(in memory)'} -->",
        '  <compiler angle="radian"/>',
        '  <default><geom rgba="0.8 0.5 0.1 1" density="1000"/></default>',
        "  <worldbody>",
    ]
    for s, T in cal.base2meas.items():
        # where each station's measurement frame is, seen from the robot base (meas2base)
        Ti = np.linalg.inv(T)
        lines.append(f'    <site name="meas_{s}" pos="{_fmt(Ti[:3, 3])}" quat="{_fmt(matrix_to_quat_wxyz(Ti[:3, :3]))}" size="0.01"/>')
    indent = "    "
    post_prev = np.eye(4)
    for i in range(6):
        pre, post = splits[i]
        B = post_prev @ pre
        lines.append(f'{indent}<body name="link{i + 1}" pos="{_fmt(B[:3, 3])}" quat="{_fmt(matrix_to_quat_wxyz(B[:3, :3]))}">')
        ind2 = indent + "  "
        lines.append(f'{ind2}<joint name="joint{i + 1}" type="hinge" axis="0 0 1" limited="true" '
                     f'range="{m.q_min[i]:.12g} {m.q_max[i]:.12g}"/>')
        nxt = post if i == 5 else post @ splits[i + 1][0]
        if np.linalg.norm(nxt[:3, 3]) > 1e-6:
            lines.append(f'{ind2}<geom type="capsule" size="0.02" fromto="0 0 0 {_fmt(nxt[:3, 3])}"/>')
        else:
            lines.append(f'{ind2}<geom type="sphere" size="0.03"/>')
        post_prev = post
        indent = ind2
    fl = post_prev
    lines.append(f'{indent}<site name="flange" pos="{_fmt(fl[:3, 3])}" quat="{_fmt(matrix_to_quat_wxyz(fl[:3, :3]))}" size="0.005"/>')
    tool = fl @ cal.tool2flange
    lines.append(f'{indent}<site name="tool" pos="{_fmt(tool[:3, 3])}" quat="{_fmt(matrix_to_quat_wxyz(tool[:3, :3]))}" size="0.005"/>')
    r = 0.5 * cal.plate.sphere_diameter
    for k, s in enumerate(cal.spheres_tool):
        p = tool[:3, :3] @ s + tool[:3, 3]
        lines.append(f'{indent}<site name="sphere{k}" type="sphere" pos="{_fmt(p)}" size="{r:.6g}"/>')
    for i in range(6, 0, -1):
        lines.append("    " + "  " * (i - 1) + "</body>")
    lines += ["  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)


def run(args) -> int:
    cal = Calibration.load(args.calibration)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = cal.table()
    cols = ["name", "unit", "nominal", "identified", "deviation", "sd", "status"]
    with open(out / "parameters.csv", "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for r in rows:
            w.writerow([r["name"], r["unit"]] + [("" if not math.isfinite(r[c]) else f"{r[c]:.9g}") for c in cols[2:6]] + [r["status"]])
    md = [f"# Calibrated {cal.nominal.name} ({cal.nominal.convention}), method `{cal.method}`", "",
          "| parameter | unit | nominal | identified | deviation | sd | status |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        sd = "" if not math.isfinite(r["sd"]) else f"{r['sd']:.3g}"
        md.append(f"| {r['name']} | {r['unit']} | {r['nominal']:.6f} | {r['identified']:.6f} | {r['deviation']:+.6f} | {sd} | {r['status']} |")
    if cal.combinations:
        md += ["", "Not identifiable from these data (held at nominal or estimated only in combination):", ""]
        md += [f"* {c.describe()}" for c in cal.combinations]
    (out / "parameters.md").write_text("\n".join(md) + "\n")
    (out / "robot.xml").write_text(mjcf(cal))
    print(f"wrote {out / 'parameters.csv'}, {out / 'parameters.md'}, {out / 'robot.xml'}")
    return 0
