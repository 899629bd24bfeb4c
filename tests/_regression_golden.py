"""Golden values of the 6R kinematics and estimator (IRB-1200, BRTIRUS0707A) through the public paths.

``compute()`` evaluates forward kinematics, Jacobians, inverse kinematics, the batched chain, calibrations of a
committed campaign dataset (``tests/golden/separation_dataset``, a copy of the separation campaign's measured
dataset) and of seeded simulated datasets with every method, prediction, compensation, identifiability,
planning and export. ``python tests/_regression_golden.py`` writes ``tests/golden/regression_golden.json``;
``tests/test_regression_golden.py`` recomputes and requires every number to be bit-identical, so a change of the
kinematic model that alters a 6R result by one unit in the last place fails.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
GOLDEN = HERE / "golden" / "regression_golden.json"
DATASET = HERE / "golden" / "separation_dataset"
MM = 1e-3


def _arr(a):
    return np.asarray(a, dtype=float).tolist()


def _kinematics(out: dict) -> None:
    from twin import kinematics as K
    from twin.estimator.chain import Chain
    from twin.robots import get_robot
    from twin.transforms import pose6_to_transform

    for name in ("irb1200", "brtirus0707a"):
        nom = get_robot(name)
        rng = np.random.default_rng(11)
        dev = np.where(nom.layout.is_length, rng.normal(0, 0.5 * MM, nom.layout.size), rng.normal(0, 2e-3, nom.layout.size))
        true = nom.perturbed(dev).with_frames(
            base2meas=pose6_to_transform(np.array([0.3, -0.2, 0.9, 0.4, -1.2, 0.7])),
            tool2flange=pose6_to_transform(np.array([0.01, -0.02, 0.05, 0.1, 0.2, -0.3])),
        )
        q = rng.uniform(np.maximum(nom.q_min, -np.pi), np.minimum(nom.q_max, np.pi), (12, 6))
        pts = np.array([[0.06, 0.0, 0.05], [-0.02, 0.056, 0.05]])
        d = out.setdefault("kinematics", {}).setdefault(name, {})
        for tag, m in (("nominal", nom), ("perturbed", true)):
            d[f"{tag}.tool2meas"] = _arr(K.tool2meas(m, q))
            d[f"{tag}.link_frames_meas_sha256"] = _digest(K.link_frames(m, q, frame="meas"))
            d[f"{tag}.pose_jacobian_meas_sha256"] = _digest(K.pose_jacobian(m, q, frame="meas"))
            d[f"{tag}.pose_jacobian_base_sha256"] = _digest(K.pose_jacobian(m, q, frame="base"))
            d[f"{tag}.point_jacobian_sha256"] = _digest(K.point_jacobian(m, q, pts))
            d[f"{tag}.joint_jacobian_sha256"] = _digest(K.joint_jacobian(m, q))
        sols = K.inverse_kinematics_closed_form(nom, K.flange2base(nom, q))
        d["ik_closed.q"] = _arr(sols.q)
        d["ik_closed.valid"] = _arr(sols.valid)
        d["ik_closed.within"] = _arr(sols.within_limits)
        q0 = K.closest_branch(sols, q, require_limits=False)
        ik = K.inverse_kinematics_iterative(true, K.tool2base(true, q), q0, frame="tool")
        d["ik_iter.q"] = _arr(ik.q)
        d["ik_iter.iterations"] = ik.iterations
        ch = Chain(nom.convention, nom.beta_joints)
        rt, b = ch.split_full(np.stack([nom.params, true.params]))
        ev = ch.evaluate(rt, q, base6=b, jacobian=True)
        d["chain.R"] = _arr(ev.R)
        d["chain.p"] = _arr(ev.p)
        d["chain.J_sha256"] = _digest(ev.J)


def _digest(a) -> str:
    """sha256 of the float64 bytes of ``a`` (a bit-exact fingerprint of a large array)."""
    return hashlib.sha256(np.ascontiguousarray(np.asarray(a, dtype=np.float64)).tobytes()).hexdigest()


def _cal_summary(cal) -> dict:
    return {
        "names": list(cal.names),
        "x": _arr(cal.x),
        "x_nominal": _arr(cal.x_nominal),
        "status": list(cal.status),
        "covariance_diag": None if cal.covariance is None else _arr(np.diag(cal.covariance)),
        "covariance_sha256": None if cal.covariance is None else _digest(cal.covariance),
        "residuals": cal.residuals,
        "identifiability": cal.identifiability,
        "noise": cal.noise,
        "rows": cal.rows,
        "unidentifiable": [c.describe() for c in cal.combinations],
    }


def _pred_summary(pred) -> dict:
    return {
        "spheres": _arr(pred.spheres),
        "pose": _arr(pred.pose),
        "frame": [str(f) for f in pred.frame],
        "sd_spheres": None if pred.sd_spheres is None else _arr(pred.sd_spheres),
        "sd_pose": None if pred.sd_pose is None else _arr(pred.sd_pose),
    }


def _simulated():
    from twin.estimator import simulate_dataset
    from twin.robots import get_robot
    from twin.transforms import pose6_to_transform

    out = {}
    rng = np.random.default_rng(5)
    nom = get_robot("brtirus0707a")
    dev = np.where(nom.layout.is_length, rng.normal(0, 0.3 * MM, nom.layout.size), rng.normal(0, 1e-3, nom.layout.size))
    dev[nom.layout.index("d2")] = 0.0
    true = nom.perturbed(dev).with_frames(tool2flange=pose6_to_transform(np.array([0.001, -0.002, 0.003, 0.01, 0.02, -0.01])),
                                          base2meas=pose6_to_transform(np.array([0.002, 0.001, -0.003, 0.002, -0.001, 0.003])))
    q = rng.uniform(np.maximum(nom.q_min, -np.pi), np.minimum(nom.q_max, np.pi), (60, 6))
    out["brt_pose"], _ = simulate_dataset(true, q, robot_spec="brtirus0707a", kind="pose", noise_position=2e-5,
                                          noise_orientation=2e-4, rng=rng)
    nom = get_robot("irb1200")
    dev = np.where(nom.layout.is_length, rng.normal(0, 0.3 * MM, nom.layout.size), rng.normal(0, 1e-3, nom.layout.size))
    dev[nom.layout.index("d2")] = 0.0
    dev[nom.layout.base_slice] = 0.0
    true = nom.perturbed(dev).with_frames(tool2flange=pose6_to_transform(np.array([0.0005, -0.0004, 0.0003, 0.002, 0.001, -0.003])))
    q = rng.uniform(np.maximum(nom.q_min, -np.pi), np.minimum(nom.q_max, np.pi), (80, 6))
    bases = {"a": pose6_to_transform(np.array([0.1, 0.2, 1.2, 0.5, 1.0, -0.4])),
             "b": pose6_to_transform(np.array([-0.2, 0.3, 1.1, 1.4, 0.3, 0.2]))}
    st = np.where(np.arange(80) % 2 == 0, "a", "b")
    sets = np.where(np.arange(80) % 5 == 0, "validation", "calibration")
    out["irb_spheres"], _ = simulate_dataset(true, q, robot_spec="irb1200", kind="spheres", noise_position=1e-5,
                                             base2meas=bases, station=st, set_=sets, rng=rng)
    return out


def _estimator(out: dict) -> None:
    from twin.dataset import read_dataset
    from twin.estimator import calibrate, compensation, identifiability, predict
    from twin.kinematics import tool2base

    ds = read_dataset(DATASET)
    sim = _simulated()
    cals = {}
    runs = [("sep", ds, m, {}) for m in ("best", "distance", "fullpose", "separation", "lm", "clm")]
    runs += [("brt_pose", sim["brt_pose"], "best", {}), ("brt_pose", sim["brt_pose"], "best", {"gauge": "structure"}),
             ("brt_pose", sim["brt_pose"], "lm", {"error_model": "structural"}), ("brt_pose", sim["brt_pose"], "clm", {}),
             ("irb_spheres", sim["irb_spheres"], "best", {}), ("irb_spheres", sim["irb_spheres"], "distance", {})]
    for tag, d, m, opts in runs:
        key = f"{tag}.{m}" + "".join(f".{k}={v}" for k, v in opts.items())
        cal = calibrate(d, m, **opts)
        cals[key] = cal
        out.setdefault("calibrations", {})[key] = _cal_summary(cal)
    rng = np.random.default_rng(21)
    for key in ("sep.best", "brt_pose.best", "irb_spheres.best"):
        cal = cals[key]
        nom = cal.nominal
        q = rng.uniform(np.maximum(nom.q_min, -np.pi) * 0.5, np.minimum(nom.q_max, np.pi) * 0.5, (8, 6))
        st = np.array([cal.stations[0]] * 4 + ["elsewhere"] * 4, dtype=object)
        out.setdefault("predict", {})[key] = {"station": _pred_summary(predict(cal, q, st)),
                                              "default": _pred_summary(predict(cal, q))}
        T = tool2base(nom, q)
        T[:, :3, 3] += 1e-3
        res = compensation(cal, T, q)
        out.setdefault("compensate", {})[key] = {"q": _arr(res.q), "q_nominal": _arr(res.q_nominal),
                                                 "position_error": _arr(res.position_error), "iterations": res.iterations}
    for part in ("full", "position", "orientation"):
        ida = identifiability(ds, part=part)
        out.setdefault("identifiability", {})[part] = ida.summary()
    out["export"] = _export(cals["sep.best"])
    out["plan"] = _plan(ds)


def _export(cal) -> dict:
    from twin.commands.export import mjcf
    from twin.estimator.calibration import parameter_table

    table = json.dumps([{k: (v if not isinstance(v, float) else repr(v)) for k, v in r.items()} for r in parameter_table(cal)])
    return {"table_sha256": hashlib.sha256(table.encode()).hexdigest(),
            "mjcf_sha256": hashlib.sha256(mjcf(cal).encode()).hexdigest()}


def _plan(ds) -> dict:
    from twin.estimator.planning import StereoCamera, plan_measurements

    cam = StereoCamera.from_json_dict({
        "kind": "stereo_camera", "image_width": 2592, "image_height": 1944,
        "left": {"fx_px": 7272.7, "fy_px": 7272.7, "cx_px": 1295.5, "cy_px": 971.5},
        "right": {"fx_px": 7272.7, "fy_px": 7272.7, "cx_px": 1295.5, "cy_px": 971.5},
        "left2right": {"R": [[0.9396926, 0.0, 0.3420201], [0.0, 1.0, 0.0], [-0.3420201, 0.0, 0.9396926]],
                       "t_mm": [-246.0, 0.0, 43.0]},
    })
    stations = {k: v for k, v in list(ds.stations_base2meas.items())[:2]}
    res = plan_measurements(ds.robot, stations, cam, ds.plate, 14, pool_per_station=60, n_random=3, seed=3)
    return {"q": _arr(res.q), "station": [str(s) for s in res.station], "floor_plan": res.floor_plan,
            "floor_random": _arr(res.floor_random), "identifiable": list(res.identifiable)}


def compute() -> dict:
    out: dict = {}
    _kinematics(out)
    _estimator(out)
    return json.loads(json.dumps(out, default=_default))


def _default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


if __name__ == "__main__":
    import subprocess

    data = compute()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE).stdout.strip()
    GOLDEN.write_text(json.dumps({"commit": commit, "values": data}) + "\n")
    print(f"wrote {GOLDEN.relative_to(HERE.parent)} at commit {commit} ({GOLDEN.stat().st_size / 1e6:.1f} MB)")
    sys.exit(0)
