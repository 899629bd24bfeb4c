"""Shared helpers of the estimator tests: synthetic truths and re-expressing a truth in the estimator's gauge.

Test-side code: it owns the truth it simulates from (the estimator never sees it).
"""

from __future__ import annotations

import numpy as np

from twin.kinematics import RobotModel
from twin.robots import get_robot
from twin.transforms import (
    invert_transform,
    make_transform,
    pose6_to_transform,
    rot_x,
    rot_z,
    transform_to_pose6,
)

MM = 1e-3
DEG = np.pi / 180


def _T(kind: str, v: float) -> np.ndarray:
    if kind == "rx":
        return make_transform(rot_x(v), np.zeros(3))
    if kind == "rz":
        return make_transform(rot_z(v), np.zeros(3))
    t = {"tx": [v, 0, 0], "tz": [0, 0, v]}[kind]
    return make_transform(np.eye(3), np.array(t, float))


def random_truth(robot: str, rng: np.random.Generator, *, zero: tuple[str, ...] = ("d2",), scale=1.0) -> RobotModel:
    """Nominal + random deviations on every structural parameter (lengths ~0.5 mm, angles ~2 mrad) and a
    tool mounting error; deviations on the names in ``zero`` are left at 0 (d2: see module docs)."""
    nom = get_robot(robot)
    lay = nom.layout
    dev = np.zeros(lay.size)
    for k, n in enumerate(lay.names):
        if n.startswith("base_") or n in zero:
            continue
        dev[k] = rng.normal(0, 0.5 * MM if lay.units[k] == "m" else 2e-3) * scale
    return nom.perturbed(dev)


def regauge_frames(truth: RobotModel, nominal: RobotModel, base2meas: dict[str, np.ndarray]):
    """The truth re-expressed in the ``gauge="frames"`` parameterisation: joint 1's base-coupled and the last
    link's tool-coupled parameters at nominal, their effect moved into each ``base2meas`` and the tool.

    MDH: alpha1, a1, d1, theta1 -> base; d6, theta6 -> tool. DH: theta1, d1 -> base; theta6, d6, a6,
    alpha6 -> tool. Returns ``(robot_with_tool, {station: base2meas})`` (robot base = identity).
    """
    t, n = truth, nominal
    p = t.params.copy()
    lay = t.layout
    if t.convention == "mdh":
        pre = lambda m: _T("rx", m.alpha[0]) @ _T("tx", m.a[0]) @ _T("tz", m.d[0]) @ _T("rz", m.theta[0])
        B = {s: T @ pre(t) @ invert_transform(pre(n)) for s, T in base2meas.items()}
        tool = _T("tz", t.d[5] - n.d[5]) @ _T("rz", t.theta[5] - n.theta[5]) @ t.tool2flange
        reset = ["alpha1", "a1", "d1", "theta1", "d6", "theta6"]
    else:
        B = {s: T @ _T("rz", t.theta[0] - n.theta[0]) @ _T("tz", t.d[0] - n.d[0]) for s, T in base2meas.items()}
        post = lambda m: _T("rz", m.theta[5]) @ _T("tz", m.d[5]) @ _T("tx", m.a[5]) @ _T("rx", m.alpha[5])
        tool = invert_transform(post(n)) @ post(t) @ t.tool2flange
        reset = ["theta1", "d1", "theta6", "d6", "a6", "alpha6"]
    for name in reset:
        p[lay.index(name)] = n.param(name)
    p[lay.base_slice] = 0.0
    p[lay.tool_slice] = transform_to_pose6(tool)
    return t.with_params(p), B


def space_vector(cal, robot: RobotModel, bases: dict[str, np.ndarray]) -> np.ndarray:
    """A model + station frames as a vector of ``cal``'s parameter space."""
    return cal.space.from_model(robot, bases)


def camera_base(rng: np.random.Generator) -> np.ndarray:
    """A camera-like ``base2meas`` somewhere in front of the robot."""
    return pose6_to_transform(np.r_[rng.normal(0, 0.3, 3) + [0.0, 0.0, 1.0], rng.normal(0, 1.0, 3)])


def write_clean_dataset(folder, n_rows: int, seed: int):
    """Write a valid single-station IRB-1200 dataset of ``n_rows`` (a multiple of 4: three calibration rows to
    one validation row) simulated at 0.01 mm noise into ``folder``; returns the folder."""
    from twin.dataset import write_dataset
    from twin.estimator.simulate import random_configurations, simulate_dataset

    rng = np.random.default_rng(seed)
    truth = random_truth("irb1200", rng)
    q = random_configurations(get_robot("irb1200"), n_rows, rng)
    sets = np.array((["calibration"] * 3 + ["validation"]) * (n_rows // 4), dtype=object)
    ds, _ = simulate_dataset(truth, q, robot_spec="irb1200", base2meas={"0": camera_base(rng)}, noise_position=1e-5,
                             rng=rng, set_=sets)
    write_dataset(folder, ds)
    return folder
