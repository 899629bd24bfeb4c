"""The campaign's adapter to the estimator: identification methods and compensation behind one small API.

Campaign method names map to the estimator's (``twin.estimator.calibrate``):

=============  ==============  ====================================================================
campaign       estimator       what
=============  ==============  ====================================================================
``distance``   ``distance``    distance constraints only (separation paper, Figure 11)
``full_pose``  ``fullpose``    full-pose constraint (separation paper, Figure 11)
``separation`` ``separation``  angles from orientation changes, then lengths from distances (eq. 21-36)
``separation_paper``            the same, paper-literal: d2 held, nominal tool, given base rotation (eq. 42)
``default``    ``best``        our default estimator
=============  ==============  ====================================================================

:func:`identify` returns a :class:`MethodResult` whose ``robot`` is the identified model with its base frame
at the identity (what compensation inverts); :func:`compensate` turns commanded joints into the joints that
make the identified model reach the nominal model's pose (the paper's section 2.4 iterative inverse). Tests
and experiments may pass their own implementations (``Identify`` callables) instead of the estimator's.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..dataset import Dataset
from ..files import read_json
from ..kinematics import RobotModel, UnreachableError, inverse_kinematics_iterative, tool2base

__all__ = [
    "ESTIMATOR_METHODS",
    "MethodUnavailable",
    "MethodResult",
    "Identify",
    "identify",
    "compensate",
    "save_method_result",
    "load_method_result",
    "dataset_fingerprint",
]

ESTIMATOR_METHODS = {"distance": "distance", "full_pose": "fullpose", "separation": "separation",
                     "separation_paper": "separation_paper", "default": "best"}


class MethodUnavailable(ValueError):
    """The estimator (or one of its methods) is not available in this installation."""


@dataclass(frozen=True, eq=False)
class MethodResult:
    """An identification: ``robot`` (identified, base frame = identity), ``base2meas`` per station when the
    method estimates them, the names of the identified parameters, free-form ``info`` (iterations, time,
    residuals) and the estimator's calibration object when there is one (saved as ``calibration.json``)."""

    method: str
    robot: RobotModel
    base2meas: dict[str, np.ndarray] = field(default_factory=dict)
    identified: tuple[str, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)
    calibration: Any = None


Identify = Callable[[Dataset, int], MethodResult]


def _estimator_identify(method: str) -> Identify:
    try:
        from ..estimator import calibrate  # type: ignore[attr-defined]
    except ImportError as exc:
        raise MethodUnavailable(f"method {method!r} needs twin.estimator, which is not available here ({exc})") from None

    est_name = ESTIMATOR_METHODS[method]

    def run(dataset: Dataset, seed: int) -> MethodResult:
        try:
            cal = calibrate(dataset, est_name, seed=seed)
        except ValueError as exc:
            if f"{est_name!r}" in str(exc) and "method must be one of" in str(exc):
                raise MethodUnavailable(f"the estimator has no method {est_name!r} yet: {exc}") from None
            raise
        robot = cal.robot
        identified = tuple(n for n, s in zip(cal.names, cal.status) if s == "identified")
        info = {"residuals": getattr(cal, "residuals", {}), "notes": list(getattr(cal, "notes", ()))}
        return MethodResult(method, robot, dict(cal.base2meas), identified, info, cal)

    return run


def identify(method: str, dataset: Dataset, seed: int = 0, implementations: dict[str, Identify] | None = None) -> MethodResult:
    """Identify ``dataset`` (its calibration rows) with the campaign ``method``."""
    if method not in ESTIMATOR_METHODS and not (implementations and method in implementations):
        raise ValueError(f"method must be one of {sorted(ESTIMATOR_METHODS)}, got {method!r}")
    fn = (implementations or {}).get(method) or _estimator_identify(method)
    return fn(dataset, seed)


def compensate(
    result: MethodResult, nominal: RobotModel, q_cmd: np.ndarray, *, max_iter: int = 100
) -> tuple[np.ndarray, np.ndarray]:
    """Compensated joints ``(n, 6)`` [rad] and a mask ``(n,)`` of targets that were compensated.

    Target: the nominal model's tool pose at the commanded joints, in the robot base frame. With the
    estimator's calibration, its :func:`twin.estimator.compensation` (the separation paper's section 2.4:
    nominal closed-form start, Newton iteration on the identified model, joint limits checked) per target;
    otherwise the same iteration here (:func:`twin.kinematics.inverse_kinematics_iterative`). A target that
    does not converge or whose command leaves the joint limits is reported in the mask (its row of ``q`` is
    then the commanded one).
    """
    q = np.asarray(q_cmd, dtype=float).reshape(-1, 6)
    if not len(q):  # no validation rows: nothing to compensate (the solvers refuse an empty batch)
        return q.copy(), np.zeros(0, dtype=bool)
    nominal_b = nominal.with_frames(base2meas=np.eye(4))
    target = tool2base(nominal_b, q)
    cal = result.calibration
    if cal is not None:
        from ..estimator import compensation

        try:
            return compensation(cal, target, q, max_iter=max_iter).q, np.ones(len(q), dtype=bool)
        except UnreachableError:
            out, ok = q.copy(), np.zeros(len(q), dtype=bool)
            for k in range(len(q)):
                try:
                    out[k] = compensation(cal, target[k:k + 1], q[k:k + 1], max_iter=max_iter).q[0]
                    ok[k] = True
                except UnreachableError:
                    pass
            return out, ok
    robot = result.robot.with_frames(base2meas=np.eye(4))
    res = inverse_kinematics_iterative(robot, target, q, frame="tool", tol_position=1e-10, tol_rotation=1e-10,
                                       max_iter=max_iter)
    ok = res.converged & robot.within_limits(res.q)
    return np.where(ok[:, None], res.q, q), ok


def dataset_fingerprint(folder: str | os.PathLike) -> str:
    """SHA-256 over a dataset folder's ``poses.csv`` and ``dataset.toml`` (what an identification depends on)."""
    h = hashlib.sha256()
    for name in ("poses.csv", "dataset.toml"):
        path = Path(folder) / name
        if not path.exists():
            raise ValueError(f"folder: {folder} has no {name}: not a dataset")
        h.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def save_method_result(folder: str | os.PathLike, result: MethodResult, dataset_sha256: str | None = None) -> Path:
    """``<folder>/<method>.json``: the identified parameter vector (and the estimator's calibration.json).

    ``dataset_sha256``: fingerprint of the dataset the method was identified on (:func:`dataset_fingerprint`);
    :func:`load_method_result` reuses the result only for the same dataset."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if result.calibration is not None and hasattr(result.calibration, "save"):
        result.calibration.save(folder / f"{result.method}.calibration.json")
    d = {
        "method": result.method,
        "dataset_sha256": dataset_sha256,
        "robot": {
            "name": result.robot.name,
            "convention": result.robot.convention,
            "beta_joints": list(result.robot.beta_joints),
            "params": [float(x) for x in result.robot.params],
            "q_min": [float(x) for x in result.robot.q_min],
            "q_max": [float(x) for x in result.robot.q_max],
        },
        "base2meas": {k: np.asarray(v, dtype=float).tolist() for k, v in result.base2meas.items()},
        "identified": list(result.identified),
        "info": json.loads(json.dumps(result.info, default=str)),
    }
    path = folder / f"{result.method}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(d, indent=1))
    os.replace(tmp, path)
    return path


def load_method_result(folder: str | os.PathLike, method: str, dataset_sha256: str | None = None) -> MethodResult | None:
    """The saved result of ``method`` in ``folder``, or ``None`` when there is none.

    With ``dataset_sha256`` given, a result identified on another dataset (or saved without a fingerprint) is
    not reused either (``None``): a re-measured dataset must be identified again, never paired with a stale
    identification."""
    path = Path(folder) / f"{method}.json"
    if not path.exists():
        return None
    d = read_json(path)
    if dataset_sha256 is not None and d.get("dataset_sha256") != dataset_sha256:
        return None
    r = d["robot"]
    robot = RobotModel(
        name=r["name"], convention=r["convention"], params=np.array(r["params"]), beta_joints=tuple(r["beta_joints"]),
        q_min=np.array(r["q_min"]), q_max=np.array(r["q_max"]),
    )
    cal = None
    cal_path = Path(folder) / f"{method}.calibration.json"
    if cal_path.exists():
        from ..estimator import Calibration

        cal = Calibration.load(cal_path)
    return MethodResult(
        method=d["method"],
        robot=robot,
        base2meas={k: np.array(v) for k, v in d["base2meas"].items()},
        identified=tuple(d["identified"]),
        info=d["info"],
        calibration=cal,
    )
