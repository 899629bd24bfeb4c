"""The subcommands of ``twin`` (one module each, see :mod:`twin.cli`) and what they share."""

from __future__ import annotations

import sys

__all__ = ["warn_forced", "check_joints_file"]


def warn_forced(path, reasons: list[str]) -> None:
    """Print, on stderr, that a calibration was written with ``twin calibrate --force`` and why (nothing when
    ``reasons`` is empty)."""
    for r in reasons:
        print(f"warning: {path} was written by `twin calibrate --force` past: {r}; results from it may be wrong",
              file=sys.stderr)


def check_joints_file(path, q, pose_id, robot, force: bool, what: str) -> None:
    """Joints ``q`` ``(n, N)`` [rad, m] read from the JOINTS.csv ``path`` against ``robot``'s limits and a radians
    reading (:func:`twin.estimator.plausibility.check_joint_values`): a ``ValueError`` naming the file and the
    cause, or with ``force`` a warning on stderr (``what``: what the command does anyway, e.g. "predicted"); a file
    too short for the radians refusal whose joints all lie within pi degrees of zero, or any whose joints all lie
    within 2 pi degrees of zero while the limits span far more: a warning on stderr."""
    from ..estimator.plausibility import ImplausibleData, check_joint_values, radians_warning

    few = radians_warning(q, robot.is_prismatic, q_min=robot.q_min, q_max=robot.q_max,
                          joint_names=robot.joint_names)
    if few:
        print(f"warning: {path}: {few}", file=sys.stderr)
    try:
        six_r = robot.n_joints == 6 and tuple(robot.joint_names) == tuple(f"q{j}" for j in range(1, 7))
        names = None if six_r else robot.joint_names
        problems = check_joint_values(q, pose_id, robot.q_min, robot.q_max, where="JOINTS.csv", joint_names=names,
                                      prismatic=None if six_r else robot.is_prismatic)
        if problems:
            unit = "degrees" if six_r or not robot.is_prismatic.any() else "degrees, millimetres for a prismatic joint,"
            raise ImplausibleData(f"{'; '.join(problems)}: the robot cannot take these joints ({unit} expected)")
    except ImplausibleData as exc:
        if not force:
            raise ValueError(f"{path}: {exc}; nothing written (--force goes on anyway)") from None
        print(f"warning: {path}: {exc} (--force: {what} anyway)", file=sys.stderr)
