"""The newcomer matrix's cases and the README's chain run on each (``tests/test_newcomer.py``).

A case is one draw of the axes below: a robot (its form, joint count and kinds), what the instrument measures, how
the campaign is laid out in files and sets, its time, the lab's CSV dialect, and whether the robot carries an effect
the geometric model lacks. :func:`covering_cases` draws them with a seeded rng so that every value of every axis
appears and every pair of values of the axes in :data:`PAIRS` too (a covering design, not the cross product);
:func:`drawn_case` draws one case at random, every axis uniform (``experiments/bench_newcomer.py`` runs hundreds).

:func:`run_case` writes the files of a case as a user from another lab would (``tests/_newcomer.py``), runs ``twin
import --map`` -> ``calibrate`` -> ``diagnose`` -> ``import`` of a second session -> ``register`` -> ``predict`` ->
``compensate`` -> ``export`` in-process through :func:`twin.cli.main`, and measures the outputs against the
generator's own forward kinematics (the oracle); :func:`check` applies the matrix's checks to its outcome.
:func:`run_corrupted` corrupts a case's CSV or column map one way (:func:`corrupt_csv`, :func:`corrupt_map`) and
asks that import and calibrate either work or refuse naming the file.
"""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import json
import math
import re
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import _newcomer as N
from twin.cli import main
from twin.dataset import read_dataset
from twin.units import M_PER_MM, MM_PER_M, RAD_PER_DEG

AXES = {
    "form": ("dh", "mdh", "table", "urdf"),
    "joints": (3, 4, 5, 6, 7, 8),
    "prismatic": (False, True),
    "measurement": ("points1", "points2", "points3", "pose", "pose_const"),
    "layout": ("no_set", "interleaved", "val_end", "val_only", "sessions_stations"),
    "time": ("none", "seconds", "stamps_gaps_repeats"),
    "dialect": (0, 1, 2),
    "effect": ("none", "backlash"),
    "noise": (True, False),
}
# the pairs of axes whose every pair of values some case takes
PAIRS = (("form", "measurement"), ("measurement", "layout"), ("form", "layout"))
ROWS_A = 48  # rows of the campaign that calibrates
ROWS_B = 24  # rows of the second session (registered, predicted)
REGISTER_ROWS = 12
NOISE_MM = 0.005
NOISE_RAD = 2e-5
BACKLASH_DEG = 0.04
# the matrix's accuracy on an effect-free robot [mm]: the noise is 0.005 mm per coordinate and the injected errors
# move the tool by 1-10 mm, so these are a fifth to a hundredth of the error calibration takes away
ACCURACY_MM = 0.03
# [mm] what a calibration leaves on validation rows at best: the noise's RMS per point (0.005 mm per coordinate,
# 0.0087 mm per point) and a half again for the parameters' own error; a robot whose injected error was small is
# calibrated when it reaches this, not 5 % of that error
FLOOR_MM = 1.5 * np.sqrt(3.0) * NOISE_MM


@dataclass(frozen=True)
class Case:
    form: str
    joints: int
    prismatic: bool
    measurement: str
    layout: str
    time: str
    dialect: int
    effect: str
    noise: bool
    seed: int

    @property
    def name(self) -> str:
        return (f"{self.form}{self.joints}{'p' if self.prismatic else ''}-{self.measurement}-{self.layout}-{self.time}"
                f"-d{self.dialect}-{self.effect}{'' if self.noise else '-nonoise'}")


def allowed(c: dict) -> bool:
    """The combinations a user can have: a DH/MDH table has revolute joints only; one tool orientation over a cube
    needs six joints or more."""
    if c["prismatic"] and c["form"] in ("dh", "mdh"):
        return False
    if c["measurement"] == "pose_const" and c["joints"] < 6:
        return False
    return True


def covering_cases(seed: int = 36, candidates: int = 60) -> list[Case]:
    """Cases that take every value of every axis and every pair of values of the axis pairs in :data:`PAIRS`
    (greedy: each new case the allowed random draw that covers most of what is still uncovered)."""
    rng = np.random.default_rng(seed)
    need = {(a, v) for a, vals in AXES.items() for v in vals}
    need |= {((a, va), (b, vb)) for a, b in PAIRS for va in AXES[a] for vb in AXES[b]}
    need = {n for n in need if _possible(n)}  # what no allowed case can take is not needed
    cases: list[Case] = []
    while need:
        best, gain = None, -1
        for _ in range(candidates):
            c = {a: vals[rng.integers(len(vals))] for a, vals in AXES.items()}
            if not allowed(c):
                continue
            cov = _covers(c)
            g = len(cov & need)
            if g > gain:
                best, gain = c, g
        if gain <= 0:
            continue
        need -= _covers(best)
        cases.append(Case(**{k: (v.item() if hasattr(v, "item") else v) for k, v in best.items()},
                          seed=int(rng.integers(1 << 30))))
    return cases


def drawn_case(seed: int) -> Case:
    """One case drawn at random (every axis uniform over its values, redrawn until :func:`allowed`) from ``seed``:
    the cases a covering design leaves out (the benchmark ``experiments/bench_newcomer.py`` runs hundreds)."""
    rng = np.random.default_rng(seed)
    while True:
        c = {a: vals[rng.integers(len(vals))] for a, vals in AXES.items()}
        if allowed(c):
            break
    return Case(**{k: (v.item() if hasattr(v, "item") else v) for k, v in c.items()}, seed=int(rng.integers(1 << 30)))


def _any() -> dict:
    return {"form": "table", "joints": 7, "prismatic": False, "measurement": "pose", "layout": "no_set",
            "time": "none", "dialect": 0, "effect": "none", "noise": True}


def _possible(n) -> bool:
    """Whether some allowed case takes the value (or the pair of values) ``n``."""
    fixed = [n] if isinstance(n[0], str) else list(n)
    others = [a for a in ("form", "joints", "prismatic", "measurement") if a not in {f[0] for f in fixed}]
    return any(allowed({**_any(), **dict(zip(others, vals)), **dict(fixed)})
               for vals in itertools.product(*(AXES[a] for a in others)))


def _covers(c: dict) -> set:
    out = {(a, c[a]) for a in AXES}
    out |= {((a, c[a]), (b, c[b])) for a, b in PAIRS}
    return out


# ------------------------------------------------------------------------------------------------
# Running the chain
# ------------------------------------------------------------------------------------------------

@dataclass
class Step:
    """One command: its argv, exit code, stdout and stderr."""

    argv: list[str]
    code: int
    out: str
    err: str
    cpu_s: float = 0.0


@dataclass
class Outcome:
    """What a case did: the steps, and the figures the oracle measured (mm)."""

    case: Case
    steps: dict[str, Step] = field(default_factory=dict)
    figures: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    model: Path | None = None


def twin(argv: list[str]) -> Step:
    """``twin ARGV`` in this process, as the console runs it (``twin.cli.main``); stdout and stderr captured."""
    out, err = io.StringIO(), io.StringIO()
    t0 = time.process_time()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return Step([str(a) for a in argv], code, out.getvalue(), err.getvalue(), time.process_time() - t0)


def _time_columns(case: Case, n: int, rng: np.random.Generator, q: np.ndarray, start_s: float) -> tuple[dict, dict]:
    """The time column of a file and the map's ``time`` key: none, seconds, or time stamps with a gap of two hours
    and repeated rows (a command measured twice, a time stamp written twice)."""
    if case.time == "none":
        return {}, {"time": "row"} if case.dialect == 1 else {}
    dt = rng.uniform(20, 40, n)
    dt[n // 2] = 7200.0  # a pause
    same = np.flatnonzero(np.all(np.diff(q, axis=0) == 0, axis=1)) + 1
    dt[same] = rng.choice([0.0, 1.0], same.size)  # a repeated row: at once, or a second later
    t = start_s + np.cumsum(dt)
    if case.time == "seconds":
        return {"Time [s]": np.round(t, 3)}, {"time": {"column": "Time [s]", "format": "seconds"}}
    import datetime as dt_

    t0 = dt_.datetime(2024, 3, 4, 8, 0, 0)
    stamps = np.array([(t0 + dt_.timedelta(seconds=float(int(v)))).strftime("%Y-%m-%d %H:%M:%S") for v in t], dtype=object)
    return {"Timestamp": stamps}, {"time": {"column": "Timestamp", "format": "%Y-%m-%d %H:%M:%S"}}


@dataclass
class World:
    """The generator's truth for a case: the nominal and true robots, the marker points or tool, the frames of the
    campaign's stations and of the second session, and the sessions."""

    robot: N.Robot
    true: N.Robot
    markers: np.ndarray | None
    tool: np.ndarray | None
    frames: dict[str, np.ndarray]
    a_parts: list
    b: N.Session
    b_true: N.Session


def make_world(case: Case) -> World:
    rng = np.random.default_rng(case.seed)
    pri = int(rng.integers(1, case.joints)) if case.prismatic else None
    robot = N.make_robot(rng, case.form, case.joints, prismatic=pri)
    bl = {int(rng.integers(0, min(case.joints, 3))): BACKLASH_DEG * RAD_PER_DEG} if case.effect == "backlash" else None
    true = N.perturbed(robot, rng, backlash=bl)
    markers = tool = None
    if case.measurement.startswith("points"):
        K = int(case.measurement[-1])
        markers = rng.uniform(-80, 80, (K, 3)) * M_PER_MM + np.array([0.0, 0.0, 0.12])
    else:
        tool = N.transform(Rotation.from_rotvec(rng.normal(0, 0.6, 3)).as_matrix(), rng.uniform(-0.05, 0.05, 3)
                           + [0.0, 0.0, 0.1])
    repeats = 4 if case.time == "stamps_gaps_repeats" else 0
    q = N.sample_joints(robot, rng, ROWS_A, repeats=repeats)
    frames = {"T1": N.random_frame(rng), "T2": N.random_frame(rng), "B": N.random_frame(rng)}
    kw = dict(markers=markers, tool2flange=tool, noise_mm=NOISE_MM, noise_rad=0.0 if markers is not None else NOISE_RAD)
    if case.layout == "sessions_stations":
        h = ROWS_A // 2
        parts = [N.measure(true, q[:h], frames["T1"], rng, **kw), N.measure(true, q[h:], frames["T2"], rng, **kw)]
    else:
        parts = [N.measure(true, q, frames["T1"], rng, **kw)]
    if case.measurement == "pose_const":
        qb = N.constant_orientation_joints(robot, rng, ROWS_B, tool)
    else:
        qb = N.sample_joints(robot, rng, ROWS_B)
    b = N.measure(true, qb, frames["B"], rng, **kw)
    b_true = N.measure(true, qb, frames["B"], rng, **{**kw, "noise_mm": 0.0, "noise_rad": 0.0})
    return World(robot, true, markers, tool, frames, parts, b, b_true)


def write_files(case: Case, w: World, folder: Path) -> tuple[Path, Path, list[str]]:
    """The campaign's map and CSVs and the second session's; returns the two maps and the extra arguments of the
    second session's import."""
    rng = np.random.default_rng(case.seed + 1)
    d = N.DIALECTS[case.dialect]
    top: dict = {"description": f"newcomer case {case.name}"}
    parts = []
    t_start = 0.0
    for k, s in enumerate(w.a_parts):
        cols, tkey = _time_columns(case, s.n, rng, s.q, t_start)
        t_start += 86400.0
        top.update(tkey)
        extra: dict = {"__columns__": dict(cols)}
        if case.layout == "interleaved":
            role = np.where(np.arange(s.n) % 4 == 3, "validation", "calibration").astype(object)
            extra["__columns__"]["Role"] = role
            top["set"] = {"column": "Role"}
        elif case.layout == "val_end":
            extra["set"] = {"validation_last_fraction": 0.3}
        elif case.layout == "val_only":
            top["set"] = "calibration"
        elif case.layout == "sessions_stations":
            extra.update(session=("mon", "tue")[k], station=("T1", "T2")[k])
        parts.append((f"campaign_{k + 1}.csv", s, extra))
    noise = NOISE_MM if case.noise else None
    map_a = N.write_campaign(folder / "lab", w.robot, parts, d, top=top, noise_mm=noise)
    cols, tkey = _time_columns(case, w.b.n, rng, w.b.q, 30 * 86400.0)
    b_extra = {"__columns__": dict(cols), "station": "tracker_B", "session": "later"}
    args_b: list[str] = []
    if case.layout == "val_only":
        b_extra["__columns__"]["dummy"] = np.zeros(w.b.n)
        map_b = N.write_campaign(folder / "lab", w.robot, [("session_b.csv", w.b, b_extra)], d, top=tkey,
                                 noise_mm=noise, map_name="session_b.toml")
        # the session's rows as --validation: every row a validation row
        text = map_b.read_text()
        map_b.write_text(text[: text.index("[[files]]")])
        args_b = ["--validation", str(folder / "lab" / "session_b.csv") + ":station=tracker_B,session=later"]
    else:
        map_b = N.write_campaign(folder / "lab", w.robot, [("session_b.csv", w.b, b_extra)], d, top=tkey,
                                 noise_mm=noise, map_name="session_b.toml")
    return map_a, map_b, args_b


def _read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run_case(case: Case, folder: Path) -> Outcome:
    """The README's chain on a case (module docstring); each step's exit code and output in ``steps``, the oracle's
    figures in ``figures``. A step that refuses (exit 2) leaves out the steps that need its output: the geometric
    calibration stands in for the diagnosis' model, a second session not imported is not registered or predicted."""
    from twin.estimator import Calibration

    o = Outcome(case)
    w = make_world(case)
    map_a, map_b, args_b = write_files(case, w, folder)
    ds_a, ds_b = folder / "ds_a", folder / "ds_b"

    def step(name, argv) -> bool:
        o.steps[name] = twin(argv)
        return o.steps[name].code == 0

    if not step("import", ["import", "--map", map_a, "--out", ds_a]):
        return o
    if not step("calibrate", ["calibrate", ds_a, "--out", folder / "cal", "--quiet"]):
        return o
    cal_path = folder / "cal" / "calibration.json"
    res = Calibration.load(cal_path).residuals
    if res.get("validation", {}).get("n_rows"):
        o.figures["calibrate_before_mm"] = res["before_calibration"]["validation"]["position_mm"]["rms"]
        o.figures["calibrate_after_mm"] = res["validation"]["position_mm"]["rms"]
    use = cal_path
    if step("diagnose", ["diagnose", ds_a, "--out", folder / "diag", "--no-plots", "--no-recording", "--threads", "1"]):
        use = folder / "diag" / "calibration.json"
        diag = json.loads((folder / "diag" / "diagnosis.json").read_text())
        o.figures["diagnose_before_mm"] = diag["before"]["position_mm"]["rms"]
        o.figures["diagnose_after_mm"] = diag["after"]["position_mm"]["rms"]
        o.notes.append(f"diagnosis: effects {diag.get('effects')}, model {diag.get('model_in_use')}")
    o.model = use
    b_args = ["--calibration", cal_path] if case.measurement == "pose_const" and case.seed % 2 == 0 else []
    later = np.arange(REGISTER_ROWS, w.b.n)
    if step("import_b", ["import", "--map", map_b, *args_b, "--out", ds_b, *b_args]):
        reg = folder / "registered.json"
        if step("register", ["register", use, ds_b, "--first", REGISTER_ROWS, "--out", reg]):
            # predict the rows the registration did not use, in the session's station frame
            joints = N.write_joints_csv(folder / "joints_b.csv", w.robot, w.b.q, station="tracker_B")
            if step("predict", ["predict", reg, joints, "--out", folder / "pred.csv"]):
                o.figures["predict_mm"] = _prediction_error(_read_csv(folder / "pred.csv"), w, later)
    # compensate targets near the second session's later configurations, in the calibration's base frame
    if step("compensate", _compensate_argv(case, w, folder, use, later)):
        o.figures.update(_compensation_error(case, w, folder, use))
    for name, c in (("export", cal_path), ("export_model", use)):
        step(name, ["export", c, "--out", folder / f"robot_{name}"])
    return o


def _prediction_error(pred: list[dict], w: World, later: np.ndarray) -> float:
    """RMS over the rows ``later`` of the distance between a predicted marker point (the pose origin) and the true
    one [mm]."""
    pred = [pred[k] for k in later]
    if w.markers is not None:
        K = len(w.markers)
        p = np.array([[[float(r[f"p{k}_{a}"]) for a in "xyz"] for k in range(K)] for r in pred])
        t = w.b_true.points[later] * MM_PER_M
    else:
        p = np.array([[[float(r[a]) for a in "xyz"]] for r in pred])
        t = w.b_true.pose[later][:, None, :3, 3] * MM_PER_M
    return float(np.sqrt(np.mean(np.sum((p - t) ** 2, axis=-1))))


def _targets(case: Case, w: World, cal_path: Path, later: np.ndarray) -> tuple[np.ndarray, bool]:
    """Targets [m, base frame of the calibration]: where the calibrated model puts the tool (or the measured point)
    at the later configurations of the second session moved by about 1 deg per joint (a pose the chain reaches);
    position-only for points of one or two markers and every third case, else tool poses."""
    from twin.estimator import Calibration
    from twin.estimator.compensation import point_frame
    from twin.kinematics import tool2base

    cal = Calibration.load(cal_path)
    rng = np.random.default_rng(case.seed + 2)
    q = np.clip(w.b.q[later] + rng.normal(0, 1.0, w.b.q[later].shape) * np.where(w.robot.prismatic, M_PER_MM, RAD_PER_DEG),
                w.robot.lo, w.robot.hi)
    T = tool2base(cal.robot.with_frames(base2meas=np.eye(4)), q)
    position_only = case.measurement in ("points1", "points2") or case.seed % 3 == 0
    if position_only:
        return (T @ point_frame(cal))[:, :3, 3], True
    return T, False


def _compensate_argv(case, w, folder, cal_path, later):
    T, position_only = _targets(case, w, cal_path, later)
    if position_only:
        N.write_targets_csv(folder / "targets.csv", T, position_only=True)
    else:
        N.write_targets_csv(folder / "targets.csv", T)
    N.write_joints_csv(folder / "reference.csv", w.robot, w.b.q[later], np.arange(len(later)))
    (folder / "targets_kind.txt").write_text("position" if position_only else "pose")
    return ["compensate", cal_path, folder / "targets.csv", "--reference", folder / "reference.csv",
            "--out", folder / "corrected.csv"]


def _compensation_error(case: Case, w: World, folder: Path, cal_path: Path) -> dict[str, float]:
    """Where the true robot puts the target point (position-only) or the tool origin at the corrected commands,
    against the target seen in the calibration's first station frame [mm]; the same for the reference commands
    (what an uncalibrated controller would roughly do)."""
    from twin.estimator import Calibration

    cal = Calibration.load(cal_path)
    rows = _read_csv(folder / "corrected.csv")
    names = w.robot.names
    q = np.array([[float(r[c]) for c in names] for r in rows])
    q = q * np.where(w.robot.prismatic, M_PER_MM, RAD_PER_DEG)
    position_only = (folder / "targets_kind.txt").read_text() == "position"
    T_cal, _ = _targets(case, w, cal_path, np.arange(REGISTER_ROWS, w.b.n))
    station = sorted(cal.stations)[0]
    B_cal = cal.base2meas[station]
    B_true = w.frames["T1" if station in ("0", "T1") else "T2"]
    tip = w.markers[0] if w.markers is not None else w.tool[:3, 3]
    F = B_true @ w.true.fk(q, q_start=np.zeros(w.robot.n))  # twin compensate: "commands in file order, start at home"
    got = F[:, :3, :3] @ tip + F[:, :3, 3]
    if position_only:
        want = T_cal @ B_cal[:3, :3].T + B_cal[:3, 3]
    else:
        P = cal.spheres_tool[0] if w.markers is not None else np.zeros(3)
        want = np.einsum("ij,nj->ni", B_cal[:3, :3], np.einsum("nij,j->ni", T_cal[:, :3, :3], P) + T_cal[:, :3, 3]) \
            + B_cal[:3, 3]
    err = np.linalg.norm(got - want, axis=1) * MM_PER_M
    miss = np.array([float(r["miss_mm"]) for r in rows])
    return {"compensate_mm": float(np.sqrt(np.mean(err**2))), "compensate_miss_mm": float(miss.max())}


def _columns(path: Path) -> list[str]:
    with open(path, newline="") as f:
        return next(csv.reader(f))


def refusal_allowed(case: Case, step: str, message: str) -> bool:
    """The named refusals a case may meet: no noise floor (no [noise], too few repeats, fewer than three markers);
    too few coordinates for a diagnosis (one point per row: its three coordinates on the rows that fit, fewer than
    two per parameter of the geometric model, as the message counts them); the compensation of a backlash whose
    commands follow each other too closely (its rows named, its last step of the backlash's size)."""
    if step == "diagnose" and not case.noise and "needs the measurement noise floor" in message:
        return True
    if step == "diagnose" and case.measurement == "points1":
        m = re.search(r"their (\d+) coordinates fit its (\d+) parameters", message)
        if message.startswith("twin diagnose: error: ") and "too few rows for a diagnosis" in message and m:
            return int(m.group(1)) < 2 * int(m.group(2))
    if step == "compensate" and case.effect == "backlash":
        # a command's direction turning over moves its joint by about its correction: the last step is of the
        # backlash's size (a smaller one is a fixed point that has not converged, not a refusal to name)
        m = re.search(r"did not settle in \d+ rounds \(last step ([0-9.e+-]+) rad; still moving: row", message)
        return bool(m) and float(m.group(1)) >= 0.1 * BACKLASH_DEG * RAD_PER_DEG
    return False


def check(o: Outcome, folder: Path) -> None:
    """The matrix's checks on a case's outcome (``folder``: where :func:`run_case` wrote it); AssertionError naming
    what failed. Each step exits 0 with its documented files or refuses with a named error its case explains
    (:func:`refusal_allowed`); the figures are finite; an effect-free robot (or one whose effect the diagnosis took
    in) is calibrated (below ``ACCURACY_MM`` and 5 % of the error before, or the noise: ``FLOOR_MM``), predicted in
    the new session and compensated to ``ACCURACY_MM`` of the oracle's truth."""
    case = o.case
    for name, s in o.steps.items():
        if s.code != 0:
            last = s.err.strip().splitlines()[-1]
            assert s.code == 2 and last.startswith(f"twin {s.argv[0]}: error: "), (name, s.err)
            assert refusal_allowed(case, name, last), f"{name} refused: {last}"
    assert list(o.steps) == ["import", "calibrate", "diagnose", "import_b", "register", "predict", "compensate",
                             "export", "export_model"]
    # the documented outputs
    cols = _columns(folder / "ds_a" / "poses.csv")
    assert ("set" in cols) == (case.layout in ("interleaved", "val_end", "val_only"))  # a set given, or none
    b_cols = _columns(folder / "ds_b" / "poses.csv")
    if case.layout == "val_only":
        with open(folder / "ds_b" / "poses.csv", newline="") as f:
            assert {r["set"] for r in csv.DictReader(f)} == {"validation"}
    else:
        assert "set" not in b_cols
    if o.steps["diagnose"].code == 0:
        assert {p.name for p in (folder / "diag").iterdir()} >= {"diagnosis.json", "calibration.json",
                                                                 "calibration_geometric.json"}
    if o.steps["compensate"].code == 0:
        assert _columns(folder / "corrected.csv")[-2:] == ["miss_mm", "miss_deg"]
        assert o.figures["compensate_miss_mm"] < 1e-3
    for name in ("export", "export_model"):
        assert {p.name for p in (folder / f"robot_{name}").iterdir()} == {"parameters.csv", "parameters.md",
                                                                          "robot.urdf", "robot.xml"}
    f = o.figures
    assert all(math.isfinite(v) for v in f.values())
    if "diagnose_after_mm" in f:
        assert f["diagnose_after_mm"] <= f["diagnose_before_mm"] * 1.001
    # the oracle: an effect-free robot (or one whose effect the diagnosis took in) is known to the noise
    clean = case.effect == "none" or (f.get("diagnose_after_mm", 1.0) < ACCURACY_MM and "backlash" in o.notes[0])
    if case.effect == "none" and "calibrate_after_mm" in f:
        assert f["calibrate_after_mm"] < min(ACCURACY_MM, max(0.05 * f["calibrate_before_mm"], FLOOR_MM)), f
    if clean:
        assert f["predict_mm"] < ACCURACY_MM, f
        if "compensate_mm" in f:
            assert f["compensate_mm"] < ACCURACY_MM, f


# ------------------------------------------------------------------------------------------------
# Files corrupted as files get corrupted: every outcome is an import or a refusal that names the cause
# ------------------------------------------------------------------------------------------------

CORRUPTIONS = ("cell_empty", "cell_nan", "cell_inf", "cell_text", "cell_huge", "cell_comma", "cell_space",
               "drop_column", "dup_row", "truncate", "header_only", "empty", "bom", "crlf", "dup_header",
               "blank_line", "extra_sep", "swap_header", "shuffle_rows", "bad_bytes")


def corrupt_csv(path: Path, kind: str, rng: np.random.Generator, dialect) -> str:
    """Corrupt the CSV ``path`` (written in ``dialect``) one way, ``kind`` of :data:`CORRUPTIONS`: a cell emptied or
    replaced (nan, inf, a word, 1e308, a cell holding the separator, spaces around a number), a column dropped, a
    row doubled, the file cut mid-row or to its header or to nothing, a byte-order mark, CRLF line ends, a header
    name doubled or two swapped, a blank line, a separator closing every line, the rows shuffled, bytes that are no
    UTF-8. Returns what was done, in words."""
    sep, h = dialect.separator, dialect.title_lines
    lines = path.read_text(encoding="utf-8").split("\n")
    if lines and lines[-1] == "":
        lines = lines[:-1]
    body = list(range(h + 1, len(lines)))

    def set_cell(value: str) -> str:
        i = int(rng.choice(body))
        c = lines[i].split(sep)
        j = int(rng.integers(len(c)))
        old, c[j] = c[j], value
        lines[i] = sep.join(c)
        return f"line {i + 1}, cell {j + 1}: {old!r} -> {value!r}"

    cells = {"cell_empty": "", "cell_nan": "nan", "cell_inf": "inf", "cell_text": "abc", "cell_huge": "1e308",
             "cell_comma": "1;2" if sep == "," else "1,2,3", "cell_space": " 12.5 "}
    what = kind
    if kind in cells:
        what = set_cell(cells[kind])
    elif kind == "drop_column":
        j = int(rng.integers(len(lines[h].split(sep))))
        for i in range(h, len(lines)):
            c = lines[i].split(sep)
            lines[i] = sep.join(c[:j] + c[j + 1:])
        what = f"column {j + 1} dropped"
    elif kind == "dup_row":
        i = int(rng.choice(body))
        lines.insert(i, lines[i])
    elif kind == "truncate":
        i = int(rng.choice(body))
        lines = lines[:i] + [lines[i][: len(lines[i]) // 2]]
    elif kind == "header_only":
        lines = lines[: h + 1]
    elif kind == "empty":
        lines = []
    elif kind == "bom":
        lines[0] = "\ufeff" + lines[0]
    elif kind == "crlf":
        lines = [ln + "\r" for ln in lines]
    elif kind == "dup_header":
        c = lines[h].split(sep)
        j = int(rng.integers(1, len(c)))
        c[j] = c[j - 1]
        lines[h] = sep.join(c)
    elif kind == "blank_line":
        lines.insert(int(rng.choice(body)), "")
    elif kind == "extra_sep":
        lines = [ln + sep for ln in lines]
    elif kind == "swap_header":
        c = lines[h].split(sep)
        a, b = rng.choice(len(c), 2, replace=False)
        c[a], c[b] = c[b], c[a]
        lines[h] = sep.join(c)
    elif kind == "shuffle_rows":
        rows = [lines[i] for i in body]
        rng.shuffle(rows)
        lines = lines[: h + 1] + rows
    elif kind == "bad_bytes":
        raw = ("\n".join(lines) + "\n").encode("utf-8")
        path.write_bytes(raw[: len(raw) // 2] + b"\xff\xfe" + raw[len(raw) // 2:])
        return "two bytes that are no UTF-8 in the middle"
    else:
        raise ValueError(f"kind must be one of {CORRUPTIONS}, got {kind!r}")
    path.write_text("\n".join(lines) + ("\n" if lines else ""), encoding="utf-8")
    return what


MAP_CORRUPTIONS = ("map_key_dropped", "map_number_to_word", "map_word_to_number", "map_unit_unknown",
                   "map_header_row_0", "map_header_row_far", "map_separator_empty", "map_decimal_other",
                   "map_joint_column_dropped", "map_file_missing", "map_noise_negative", "map_key_twice",
                   "map_syntax", "map_list_to_number", "map_value_to_list", "map_empty", "map_number_to_bool",
                   "map_word_beyond_ascii", "map_number_huge", "map_noise_zero")


def corrupt_map(path: Path, kind: str, rng: np.random.Generator) -> str:
    """Corrupt the column map ``path`` one way, ``kind`` of :data:`MAP_CORRUPTIONS`: a key dropped or written twice,
    a number made a word or a list or a boolean or 1e308, a word made a number or non-ASCII, a list made a number, a
    unit unknown, the header row 0 or far, the separator empty, the decimal mark another, a joint column dropped, a
    file that does not exist, the noise negative or zero, broken TOML, nothing at all. Returns what was done, or
    ``"-"`` where the map has no line to corrupt that way."""
    lines = path.read_text().split("\n")
    keys = [i for i, ln in enumerate(lines) if re.match(r"^\s*[\w.\"-]+\s*=", ln)]

    def edit(pred, new) -> str:
        cand = [i for i in keys if pred(lines[i])]
        if not cand:
            return "-"
        i = int(rng.choice(cand))
        old = lines[i]
        lines[i] = new(old)
        return f"{old!r} -> {lines[i]!r}"

    def value(v):
        return lambda ln: re.sub(r"=\s*.*$", f"= {v}", ln)

    number = lambda ln: re.search(r"=\s*-?\d", ln) is not None  # noqa: E731
    key = lambda name: (lambda ln: ln.strip().startswith(name))  # noqa: E731
    if kind == "map_key_dropped":
        i = int(rng.choice(keys))
        what = f"{lines.pop(i)!r} dropped"
    elif kind == "map_key_twice":
        i = int(rng.choice(keys))
        lines.insert(i, lines[i])
        what = f"{lines[i]!r} twice"
    elif kind == "map_syntax":
        what = edit(lambda ln: True, lambda ln: ln + " ]]")
    elif kind == "map_empty":
        lines, what = [], "nothing"
    else:
        what = {
            "map_number_to_word": lambda: edit(number, value('"abc"')),
            "map_word_to_number": lambda: edit(lambda ln: re.search(r'=\s*"', ln) is not None, value("3")),
            "map_unit_unknown": lambda: edit(lambda ln: "unit" in ln.split("=")[0], value('"furlong"')),
            "map_header_row_0": lambda: edit(key("header_row"), value("0")),
            "map_header_row_far": lambda: edit(key("header_row"), value("100000")),
            "map_separator_empty": lambda: edit(key("separator"), value('""')),
            "map_decimal_other": lambda: edit(key("decimal"), value('";"')),
            "map_joint_column_dropped": lambda: edit(lambda ln: ln.startswith("columns") and "[" in ln,
                                                     lambda ln: re.sub(r',\s*"[^"]*"\s*\]', "]", ln)),
            "map_file_missing": lambda: edit(key("path"), value('"nowhere.csv"')),
            "map_noise_negative": lambda: edit(key("position_mm"), value("-0.01")),
            "map_noise_zero": lambda: edit(key("position_mm"), value("0.0")),
            "map_list_to_number": lambda: edit(lambda ln: "= [" in ln, lambda ln: re.sub(r"=\s*\[.*$", "= 5", ln)),
            "map_value_to_list": lambda: edit(lambda ln: re.search(r'=\s*[-\d"]', ln) is not None,
                                              lambda ln: re.sub(r"=\s*(.*)$", r"= [\1, \1]", ln)),
            "map_number_to_bool": lambda: edit(number, value("true")),
            "map_word_beyond_ascii": lambda: edit(lambda ln: '"' in ln, lambda ln: ln.replace('"', '"\u00e9\u53f0', 1)),
            "map_number_huge": lambda: edit(number, value("1e308")),
        }.get(kind, lambda: None)()
        if what is None:
            raise ValueError(f"kind must be one of {MAP_CORRUPTIONS}, got {kind!r}")
    path.write_text("\n".join(lines))
    return what


def run_corrupted(seed: int, kind: str, folder: Path) -> dict:
    """A drawn case's campaign (:func:`drawn_case`) with its first CSV (:func:`corrupt_csv`) or its column map
    (:func:`corrupt_map`, ``kind`` in :data:`MAP_CORRUPTIONS`) corrupted, through
    ``twin import`` and, when it imports, ``twin calibrate``: ``outcome`` ``"imported"`` (the dataset reads back and
    calibrate exits 0 or refuses naming the cause), ``"refused"`` (import exits 2 with its error naming the file) or
    ``"defect"`` (another exit code, a traceback, a dataset written that does not read back), with the words of
    each; ``"not_drawable"`` where the generator cannot write the case."""
    case = drawn_case(seed)
    out = {"seed": seed, "kind": kind, "case": case.name}
    try:
        w = make_world(case)
    except RuntimeError as exc:
        return {**out, "outcome": "not_drawable", "message": str(exc)}
    map_a, _, _ = write_files(case, w, folder)
    rng = np.random.default_rng(seed)
    if kind in MAP_CORRUPTIONS:
        out["corruption"] = corrupt_map(map_a, kind, rng)
    else:
        out["corruption"] = corrupt_csv(sorted((folder / "lab").glob("campaign_*.csv"))[0], kind, rng,
                                        N.DIALECTS[case.dialect])
    return {**out, **_import_and_calibrate(["import", "--map", map_a, "--out", folder / "ds"], folder)}


def _import_and_calibrate(argv: list, folder: Path) -> dict:
    """``twin ARGV`` (an import writing ``folder/ds`` from files under ``folder/lab``) and, when it imports, ``twin
    calibrate``: ``outcome`` ``"imported"``, ``"refused"`` or ``"defect"`` as :func:`run_corrupted` says, with the
    last line each command wrote (``folder`` written ``CASE``)."""
    out: dict = {}
    try:
        imp = twin(argv)
    except Exception as exc:  # out of the command's own handling: a traceback for its user
        return {"outcome": "defect", "message": f"import raised {type(exc).__name__}: {exc}"}
    last = imp.err.strip().splitlines()[-1] if imp.err.strip() else ""
    out["import"] = last.replace(str(folder), "CASE")
    if imp.code == 2 and last.startswith("twin import: error: ") and "Traceback" not in imp.err \
            and "CASE/lab/" in out["import"]:  # a refusal names the file it read (and in it the row, the key)
        return {**out, "outcome": "refused"}
    if imp.code != 0 or "Traceback" in imp.err:
        return {**out, "outcome": "defect", "message": f"import exit {imp.code}: {out['import']}"}
    try:
        read_dataset(folder / "ds")
    except Exception as exc:  # a dataset written that does not read back
        return {**out, "outcome": "defect", "message": f"imported, not read back: {exc}".replace(str(folder), "CASE")}
    try:
        cal = twin(["calibrate", folder / "ds", "--out", folder / "cal", "--quiet"])
    except Exception as exc:
        return {**out, "outcome": "defect", "message": f"calibrate raised {type(exc).__name__}: {exc}"}
    last = cal.err.strip().splitlines()[-1] if cal.err.strip() else ""
    out["calibrate"] = last.replace(str(folder), "CASE")
    if cal.code == 0 or (cal.code == 2 and last.startswith("twin calibrate: error: ") and "Traceback" not in cal.err):
        return {**out, "outcome": "imported"}
    return {**out, "outcome": "defect", "message": f"calibrate exit {cal.code}: {out['calibrate']}"}


DATA = Path(__file__).resolve().parent.parent / "data"
# data/'s real campaigns: their folder, the CSV a corruption of a file takes, the column map (None: the FIGAROH CSV
# path, `twin import TRAIN.csv --validation VAL.csv --urdf ...`, as data/tiago_mocap/README.md runs it), the separator
REAL_CAMPAIGNS = {
    "tiago_mocap": ("tiago_mocap", "qualisys_2021-11-30_static_postures.csv", None, ","),
    "ur5_laser_tracker": ("ur5_laser_tracker", "3D_UR5_uncalibrated_grid_cleaned.csv", "ur5_grid.toml", ","),
    "ur10_laser_tracker": ("ur10_laser_tracker", "series_A/measurements_grid.csv", "series_A.toml", ";"),
}


def real_kinds(name: str) -> tuple[str, ...]:
    """The corruptions a real campaign of :data:`REAL_CAMPAIGNS` takes: every CSV one, and every map one where it
    is imported through a column map."""
    return CORRUPTIONS + (MAP_CORRUPTIONS if REAL_CAMPAIGNS[name][2] else ())


def run_real_corrupted(name: str, kind: str, seed: int, folder: Path) -> dict:
    """One of data/'s real campaigns (``name`` of :data:`REAL_CAMPAIGNS`, copied under ``folder/lab``) with its CSV
    (:func:`corrupt_csv`) or its column map (:func:`corrupt_map`) corrupted one way, imported as its README says
    and, where it imports, calibrated: the outcomes of :func:`run_corrupted`."""
    sub, csv_rel, map_rel, sep = REAL_CAMPAIGNS[name]
    if kind not in real_kinds(name):
        raise ValueError(f"kind must be one of {real_kinds(name)} for {name}, got {kind!r}")
    lab = folder / "lab"
    shutil.copytree(DATA / sub, lab)
    rng = np.random.default_rng(seed)
    out = {"seed": seed, "kind": kind, "case": name}
    if kind in MAP_CORRUPTIONS:
        out["corruption"] = corrupt_map(lab / map_rel, kind, rng)
    else:
        out["corruption"] = corrupt_csv(lab / csv_rel, kind, rng, N.Dialect(separator=sep))
    if map_rel is not None:
        argv = ["import", "--map", lab / map_rel]
    else:
        argv = ["import", lab / csv_rel, "--validation", lab / "qualisys_2021-11-26_static_postures.csv",
                "--urdf", lab / "tiago_48_schunk.urdf", "--root", "base_link", "--end", "wrist_ft_tool_link"]
    return {**out, **_import_and_calibrate(argv + ["--out", folder / "ds"], folder)}


def summary(o: Outcome) -> str:
    """One line per case: the steps' exit codes and the figures."""
    codes = " ".join(f"{k}={s.code}({s.cpu_s:.2f}s)" for k, s in o.steps.items())
    figs = " ".join(f"{k}={v:.4g}" for k, v in o.figures.items())
    return f"{o.case.name}: {codes} | {figs}"

# ------------------------------------------------------------------------------------------------
# Rows of two robots mixed in one campaign (tests/test_estimator_mixture.py, studies/mixture)
# ------------------------------------------------------------------------------------------------

MIXED_MARKERS = np.array([[0.05, 0.0, 0.02], [-0.03, 0.04, 0.02], [-0.02, -0.05, 0.03]])  # [m] on the flange
MIXED_NOISE_MM = 0.005


def mixed_campaign(folder, seed: int, *, second: str, blocks: bool = False,
                   share: tuple[float, float] = (0.25, 0.75)) -> tuple[object, np.ndarray]:
    """A campaign of one nominal robot drawn at random (kind, joints) whose rows come from two robots as built
    (``second="robot"``), from one robot seen from two instrument places (``"frame"``: a tripod knocked by ~1 mm and
    ~0.1 deg), from one robot with backlash on a drawn joint (``"backlash"``: the flank each row approaches from) or
    from one robot alone (``"none"``: the labels mark nothing),
    the two kinds of rows interleaved at random in a share drawn uniformly in ``share`` (``blocks``: the second kind's
    rows after the first kind's, a file appended to another); imported with `twin import`. Returns the dataset and whether each row (in
    pose_id order) is of the second kind."""
    if second not in ("robot", "frame", "backlash", "none"):
        raise ValueError(f"second must be 'robot', 'frame', 'backlash' or 'none', got {second!r}")
    rng = np.random.default_rng(seed)
    kind = rng.choice(["dh", "mdh", "urdf"])
    nom = N.make_robot(rng, kind, int(rng.integers(5, 8)))
    n = int(rng.integers(160, 240))
    share = rng.uniform(*share)
    is_b = rng.random(n) < share
    if blocks:
        is_b = np.sort(is_b)
    q = N.sample_joints(nom, rng, n)
    frame = N.random_frame(rng)
    if second == "backlash":
        j = int(rng.integers(0, nom.n))
        true = N.perturbed(nom, rng, backlash={j: float(rng.uniform(0.02, 0.06)) * np.pi / 180})
        s = N.measure(true, q, frame, rng, markers=MIXED_MARKERS, noise_mm=MIXED_NOISE_MM)
    else:
        a = N.perturbed(nom, rng)
        b = N.perturbed(nom, rng) if second == "robot" else a
        frame_b = frame
        if second == "frame":
            knock = N.transform(Rotation.from_rotvec(rng.normal(0, 0.1 * np.pi / 180, 3)).as_matrix(),
                                rng.normal(0, 0.6e-3, 3))
            frame_b = knock @ frame
        sa = N.measure(a, q, frame, rng, markers=MIXED_MARKERS, noise_mm=MIXED_NOISE_MM)
        sb = N.measure(b, q, frame_b, rng, markers=MIXED_MARKERS, noise_mm=MIXED_NOISE_MM)
        s = N.Session(q=q, base2meas=frame, points=np.where(is_b[:, None, None], sb.points, sa.points),
                      markers=MIXED_MARKERS)
    mp = N.write_campaign(Path(folder) / "campaign", nom, [("meas.csv", s, {})], N.Dialect(), noise_mm=MIXED_NOISE_MM)
    step = twin(["import", "--map", mp, "--out", Path(folder) / "ds"])
    if step.code != 0:
        raise RuntimeError(f"twin import of the mixed campaign {seed} failed: {step.err}")
    return read_dataset(Path(folder) / "ds"), is_b


def split_agreement(groups, pose_id, is_b) -> float:
    """The share of a split's rows put with the rows of their own kind (either labelling of the two groups)."""
    b = dict(zip((int(p) for p in pose_id), is_b))
    g0 = np.array([b[p] for p in groups[0]], bool)
    g1 = np.array([b[p] for p in groups[1]], bool)
    right = max((~g0).sum() + g1.sum(), g0.sum() + (~g1).sum())
    return float(right / max(g0.size + g1.size, 1))
