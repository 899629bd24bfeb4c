"""Benchmark of the diagnosis at scale -> the ``diagnosis_scale`` section of results/benchmark.json.

Target (issue 29): ``twin diagnose`` on 12,000 pose rows in <= 60 s and on 230 rows in <= 5 s on 2 cores, with
the peak memory stated. The dataset is a laser-tracker campaign of a UR10-like arm written here (no rendering, no
real data), with what makes a real tracker campaign of this size costly to diagnose (the UR10 laser-tracker
series A: 11,911 rows, a drift over the campaign, ~200 short pauses and a dozen breaks that start sessions, a dozen
joint terms found):

* the UR10's standard DH table (d1 127.3, a2 -612, a3 -572.3, d4 163.941, d5 115.7, d6 92.2 mm; alpha 90, 0, 0,
  90, -90, 0 deg) with small geometric errors, a probe 93 mm along the flange's z axis, a tracker 2.5 m away;
* the links growing with a slow drift of the cell temperature (23 ppm/K; ``temp_c`` recorded in 0.125 K steps);
* joint-side errors of the drives: harmonics of orders 4.9-46.5 per joint turn and the compliance of joints 2-3
  under gravity (``HARMONICS``, ``COMPLIANCE``);
* 6-DOF poses with 0.02 mm / 0.0001 rad of noise; 2-6 s per pose, now and then a pause of 3-30 min (the same
  session) and more rarely a break of 1-20 h (``t_s``: a gap longer than
  :data:`twin.diagnosis.floor.SESSION_GAP_S` starts a session of the diagnosis, with a step at each start in the
  pool of terms);
* the last 30 % of the rows held out (``set = validation``). The 230-row case is the first 230 rows of the same
  campaign.

Timed per case, in a fresh process each (``twin diagnose DATASET --out DIR --no-plots --no-recording``, the
command a user runs): wall time, CPU time (user and system) and peak resident memory of the process (VmHWM,
polled); the median over ``--runs`` runs. The verdict of one run is recorded beside the figures.

    python experiments/bench_diagnosis_scale.py [--runs 3]
    python experiments/bench_diagnosis_scale.py --write-dataset DIR --rows 12000   # the dataset alone
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from twin.runtime import available_cores, set_process_defaults  # noqa: E402

set_process_defaults()  # one BLAS thread (2 shared cores) before numpy loads, inherited by the timed processes

import numpy as np  # noqa: E402

from twin.benchio import peak_rss_kb, provenance, update_benchmark_section  # noqa: E402
from twin.dataset import write_dataset  # noqa: E402
from twin.diagnosis.floor import SESSION_GAP_S, row_resets  # noqa: E402
from twin.diagnosis.problem import THREADS_MIN_ROWS  # noqa: E402
from twin.estimator.simulate import simulate_dataset  # noqa: E402
from twin.kinematics import RobotModel  # noqa: E402
from twin.transforms import pose6_to_transform, rotvec_to_matrix  # noqa: E402
from twin.units import M_PER_MM, RAD_PER_DEG  # noqa: E402

SECTION = "diagnosis_scale"
CASES = {"rows_230": (230, 5.0), "rows_12000": (12000, 60.0)}  # rows, target [s]

# the UR10's standard DH table [mm, deg]
UR10_DH = {"theta_deg": [0.0] * 6, "d_mm": [127.3, 0.0, 0.0, 163.941, 115.7, 92.2],
           "a_mm": [0.0, -612.0, -572.3, 0.0, 0.0, 0.0], "alpha_deg": [90.0, 0.0, 0.0, 90.0, -90.0, 0.0]}
NOISE_POSITION = 0.02 * M_PER_MM  # [m] per coordinate
NOISE_ORIENTATION = 1e-4  # [rad] per rotation-vector component
THERMAL_PER_K = 23e-6  # [1/K] aluminium links
VALIDATION_FRACTION = 0.3


def ur10_nominal() -> RobotModel:
    """The nominal UR10 (standard DH, ``"dh"``), joint limits +-360 deg."""
    return RobotModel.from_tables(
        "ur10", "dh", theta=np.array(UR10_DH["theta_deg"]) * RAD_PER_DEG, d=np.array(UR10_DH["d_mm"]) * M_PER_MM,
        a=np.array(UR10_DH["a_mm"]) * M_PER_MM, alpha=np.array(UR10_DH["alpha_deg"]) * RAD_PER_DEG,
        q_min=np.full(6, -2 * np.pi), q_max=np.full(6, 2 * np.pi))


def _robot_spec() -> dict:
    return {"name": "ur10", "convention": "dh", **UR10_DH, "q_min_deg": [-360.0] * 6, "q_max_deg": [360.0] * 6}


# joint-side errors of a UR10's drives: harmonics of the strain-wave gears (joint, order per joint turn, amplitude
# [deg], phase) and the compliance of joints 2 and 3 under gravity [rad/Nm]
HARMONICS = ((1, 16.8, 0.016, 0.3), (2, 16.6, 0.015, 1.1), (3, 17.2, 0.015, 2.0), (1, 7.8, 0.014, 0.5),
             (2, 4.86, 0.013, 2.4), (5, 17.0, 0.017, 0.9), (6, 46.5, 0.05, 1.7))
COMPLIANCE = (2e-6, 3e-6)


def joint_errors(q: np.ndarray) -> np.ndarray:
    """The joint errors ``(n, 6)`` [rad] the arm adds to the commanded joints ``q`` ``(n, 6)``: the drives'
    harmonics (``HARMONICS``) and joints 2-3 yielding to the gravity torque of UR10-like link masses
    (``COMPLIANCE``; upper arm 12.9 kg, forearm 3.9 kg, wrist and probe 4.0 kg, in a planar arm's form)."""
    dq = np.zeros_like(q)
    for j, k, amp, ph in HARMONICS:
        dq[:, j - 1] += amp * RAD_PER_DEG * np.sin(k * q[:, j - 1] + ph)
    c2, c23 = np.cos(q[:, 1]), np.cos(q[:, 1] + q[:, 2])
    tau3 = 9.81 * (3.9 * 0.29 * c23 + 4.0 * 0.572 * c23)
    tau2 = 9.81 * (12.9 * 0.306 * c2 + 3.9 * 0.612 * c2 + 4.0 * 0.612 * c2) + tau3
    dq[:, 1] += COMPLIANCE[0] * tau2
    dq[:, 2] += COMPLIANCE[1] * tau3
    return dq


def make_campaign(n: int, seed: int = 0):
    """The synthetic tracker campaign of ``n`` rows (see the module docstring): a :class:`twin.dataset.Dataset`
    of 6-DOF poses with ``t_s``, ``temp_c`` and ``set``. The first rows of a longer campaign of the same seed are
    the same rows."""
    rng = np.random.default_rng(seed)
    nom = ur10_nominal()
    L = nom.layout
    dev = np.zeros(nom.params.size)
    for fam, sd in (("theta", 0.02 * RAD_PER_DEG), ("d", 0.3 * M_PER_MM), ("a", 0.3 * M_PER_MM), ("alpha", 0.02 * RAD_PER_DEG)):
        idx = L.family(fam)
        dev[idx] = rng.normal(0.0, sd, idx.size)
    true = nom.perturbed(dev).with_frames(
        base2meas=pose6_to_transform(np.array([2.36, -1.37, 0.12, 0.3, -0.2, 2.6])),
        tool2flange=pose6_to_transform(np.array([0.4 * M_PER_MM, -0.3 * M_PER_MM, 93.0 * M_PER_MM, 0.002, -0.001, 0.003])))
    m = 20000  # the draws of the longest campaign: a shorter one is its first rows
    lo = np.array([-2.6, -2.3, -1.4, -2.2, 0.35, -3.0])
    hi = np.array([-0.6, -0.9, -0.3, 0.6, 1.5, 3.0])
    q = rng.uniform(lo, hi, (m, 6))
    q[:, 4] *= rng.choice([-1.0, 1.0], m)
    # 2-6 s per pose; the tracker stops now and then (a re-measured reflector, the next grid block): after 1 pose in
    # 60 on average a pause of 3-30 min, shorter than a session gap (series A has ~200 such gaps in 11,911 rows)
    step = rng.uniform(2.0, 6.0, m)
    pause = rng.random(m) < 1.0 / 60.0
    step[pause] += rng.uniform(180.0, 1800.0, int(pause.sum()))
    # and after 1 pose in 1,000 on average a break of 1-20 h (a night, a day off), each the start of a session
    # (series A: 12 gaps over half an hour, up to 21 h); drawn from a stream of their own, so the other draws of
    # the campaign do not depend on them
    brk = np.random.default_rng([seed, 1])
    long_break = brk.random(m) < 1.0 / 1000.0
    long_break[0] = False
    step[long_break] += brk.uniform(3600.0, 72000.0, int(long_break.sum()))
    t_s = np.cumsum(step)
    t_s -= t_s[0]
    # the cell temperature drifts slowly over the campaign (hours), recorded in the instrument's 0.125 K steps
    temp_true = 23.3 + 0.35 * np.sin(2 * np.pi * t_s / 60000.0 + 0.7) - 0.2 * t_s / t_s[-1]
    temp_c = np.round(temp_true / 0.125) * 0.125
    # noise drawn for the longest campaign too (rotation on the left, per rotation-vector component)
    e_pos = rng.normal(0.0, NOISE_POSITION, (m, 3))
    e_rot = rng.normal(0.0, NOISE_ORIENTATION, (m, 3))
    q, t_s, temp_true, temp_c = q[:n], t_s[:n], temp_true[:n], temp_c[:n]
    q_act = q + joint_errors(q)  # the commanded joints are recorded; the arm stands at q_act
    # the links grow with the temperature the arm has (rows grouped on a 0.01 K grid of it)
    grid = np.round(temp_true / 0.01).astype(int)
    pose = np.empty((n, 4, 4))
    lengths = np.concatenate([L.family("d"), L.family("a")])
    for g in np.unique(grid):
        rows = np.flatnonzero(grid == g)
        p = true.params.copy()
        p[lengths] *= 1.0 + THERMAL_PER_K * (g * 0.01 - 23.0)
        _, tr = simulate_dataset(true.with_params(p), q_act[rows], robot_spec=_robot_spec(), nominal=nom, kind="pose")
        pose[rows] = tr["pose"]
    pose[:, :3, 3] += e_pos[:n]
    pose[:, :3, :3] = rotvec_to_matrix(e_rot[:n]) @ pose[:, :3, :3]
    # the dataset's structure and its declared noise; the poses are the ones above
    ds, _ = simulate_dataset(true, q, robot_spec=_robot_spec(), nominal=nom, kind="pose",
                             noise_position=NOISE_POSITION, noise_orientation=NOISE_ORIENTATION,
                             rng=np.random.default_rng(0))
    n_val = int(round(VALIDATION_FRACTION * n))
    sets = np.array(["calibration"] * (n - n_val) + ["validation"] * n_val, dtype=object)
    from dataclasses import replace

    return replace(ds, pose=pose, t_s=t_s, temp_c=temp_c, set=sets, pose_id=np.arange(n),
                   provenance="synthetic UR10 laser-tracker campaign (experiments/bench_diagnosis_scale.py, "
                              f"seed {seed}): geometric errors, thermal growth with temp_c, 6-DOF poses")


def _cli_run(cmd: list[str]) -> dict:
    """One ``twin diagnose`` process: wall, user and system CPU [s] (its rusage), peak RSS [MiB] (VmHWM of
    ``/proc/PID/status`` polled every 20 ms: ``ru_maxrss`` of a forked child starts from this process's)."""
    load0 = [round(x, 2) for x in os.getloadavg()]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    hwm = 0
    while proc.poll() is None:
        hwm = max(hwm, peak_rss_kb(proc.pid))
        time.sleep(0.02)
    wall = time.perf_counter() - t
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited with {proc.returncode}: {err[-2000:]}")
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall_s": round(wall, 2), "user_s": round(ru1.ru_utime - ru0.ru_utime, 2),
            "system_s": round(ru1.ru_stime - ru0.ru_stime, 2), "peak_rss_mb": round(hwm / 1024.0, 1),
            "load_average_start": load0, "load_average_end": [round(x, 2) for x in os.getloadavg()]}


def _library_run(folder: Path) -> dict:
    """``twin.diagnosis.diagnose`` alone on the dataset read from ``folder`` (in this process: no start-up, no
    reading, no writing): wall and CPU [s]."""
    from twin.dataset import read_dataset
    from twin.diagnosis import diagnose

    ds = read_dataset(folder)
    t, c = time.perf_counter(), time.process_time()
    diagnose(ds)
    return {"wall_s": round(time.perf_counter() - t, 2), "cpu_s": round(time.process_time() - c, 2)}


def _case(name: str, rows: int, target_s: float, seed: int, runs: int, work: Path) -> dict:
    ds = make_campaign(rows, seed)
    folder = work / name / "dataset"
    write_dataset(folder, ds)
    twin_exe = shutil.which("twin", path=str(Path(sys.executable).parent)) or "twin"
    out = work / name / "out"
    cmd = [twin_exe, "diagnose", str(folder), "--out", str(out), "--no-plots", "--no-recording"]
    timed = [_cli_run(cmd) for _ in range(runs)]
    walls = [r["wall_s"] for r in timed]
    med = float(np.median(walls))
    d = json.loads((out / "diagnosis.json").read_text())
    gaps = int(np.sum(np.diff(ds.t_s) > 180.0))
    sessions = int(row_resets(ds.n, ds.t_s, gaps=True).sum())
    return {
        "rows": int(ds.n),
        "validation_rows": int(np.sum(ds.set == "validation")),
        "pauses": gaps,
        "sessions": sessions,
        "target_s": target_s,
        "meets_target": bool(med <= target_s),
        "command": f"twin diagnose DATASET --out DIR --no-plots --no-recording ({rows} rows)",
        "wall_s_median": med,
        "wall_s_range": [min(walls), med, max(walls)],
        "user_s_median": float(np.median([r["user_s"] for r in timed])),
        "system_s_median": float(np.median([r["system_s"] for r in timed])),
        "peak_rss_mb_max": max(r["peak_rss_mb"] for r in timed),
        "runs": timed,
        "library_diagnose": _library_run(folder),
        "verdict": {"structured": d["structured"], "effects": d["effects"], "terms": len(d["atoms"]),
                    "model_in_use": d.get("model_in_use"),
                    "candidates_tried": len(d["candidates"]),
                    "before_rms_mm": d["before"]["position_mm"]["rms"], "after_rms_mm": d["after"]["position_mm"]["rms"]},
    }


def section(runs: int = 3, quick: bool = False, seed: int = 0) -> dict:
    """The ``diagnosis_scale`` section: each case of ``CASES`` (``quick``: 2,000 rows instead of 12,000, one run:
    a smoke run, not figures)."""
    load_start = os.getloadavg()
    cases = {"rows_230": (230, CASES["rows_230"][1]),
             "rows_12000": (2000 if quick else 12000, CASES["rows_12000"][1])}
    work = Path(tempfile.mkdtemp(prefix="bench_diagnosis_scale_"))
    try:
        got = {name: _case(name, rows, target, seed, 1 if quick else runs, work) for name, (rows, target) in cases.items()}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return {
        "quick": quick,
        "target": "twin diagnose on 12,000 pose rows <= 60 s and on 230 rows <= 5 s on 2 cores, peak memory stated",
        "meets_target": all(c["meets_target"] for c in got.values()),
        "dataset": {
            "generator": "experiments/bench_diagnosis_scale.py make_campaign (no rendering, no real data)",
            "robot": "UR10 standard DH (d1 127.3, a2 -612, a3 -572.3, d4 163.941, d5 115.7, d6 92.2 mm; "
                     "alpha 90, 0, 0, 90, -90, 0 deg) + N(0, 0.02 deg / 0.3 mm) geometric errors",
            "seed": seed,
            "measurements": "6-DOF probe poses (x y z rx ry rz), tracker 2.5 m away, probe 93 mm along the flange's z",
            "noise": {"position_mm": NOISE_POSITION / M_PER_MM, "orientation_rad": NOISE_ORIENTATION},
            "effects": "link lengths growing 23 ppm/K with the cell temperature (temp_c in 0.125 K steps, drifting "
                       "0.7 K over the session); drive harmonics " + ", ".join(f"joint {j} order {k} {a} deg"
                                                                             for j, k, a, _ in HARMONICS)
                       + f"; joints 2-3 compliance {COMPLIANCE[0]:g}, {COMPLIANCE[1]:g} rad/Nm under gravity",
            "time": "2-6 s per pose, after 1 pose in 60 on average a pause of 3-30 min (the same session), after 1 "
                    f"pose in 1,000 a break of 1-20 h (a gap over {SESSION_GAP_S:.0f} s starts a session)",
            "held_out": f"the last {VALIDATION_FRACTION:.0%} of the rows (set = validation)",
            "rows_230": "the first 230 rows of the same campaign",
        },
        "cases": got,
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "command_threads": available_cores(),
        "note": "wall = the twin process from start to exit (interpreter start-up and imports, ~2 s of CPU, "
                "included); user/system = its CPU time; peak RSS = its VmHWM. The command scores independent places "
                "on command_threads threads (its default: every core) from "
                f"{THREADS_MIN_ROWS} calibration rows on, one thread below; library_diagnose = diagnose() alone in "
                "the benchmark process with the library's default of one thread, one run. Times on a 2-core "
                "machine shared with other jobs: see the load averages of each run.",
        "provenance": provenance(load_start),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="timed runs per case (median recorded)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="2,000 rows instead of 12,000, one run: a smoke run")
    ap.add_argument("--write-dataset", type=Path, default=None, help="only write the campaign of --rows rows here")
    ap.add_argument("--rows", type=int, default=12000)
    ap.add_argument("--no-write", action="store_true", help="print only, do not update results/benchmark.json")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs must be >= 1, got {args.runs}")
    if args.write_dataset is not None:
        if args.rows < 10:
            ap.error(f"--rows must be >= 10, got {args.rows}")
        write_dataset(args.write_dataset, make_campaign(args.rows, args.seed))
        print(f"wrote {args.write_dataset}")
        return 0
    data = section(runs=args.runs, quick=args.quick, seed=args.seed)
    print(json.dumps(data, indent=1))
    if not args.no_write:
        path = update_benchmark_section(SECTION, data)
        for name, c in data["cases"].items():
            print(f"{name}: {c['wall_s_median']:.1f} s wall (median of {len(c['runs'])}), {c['user_s_median']:.1f} s "
                  f"user, peak {c['peak_rss_mb_max']:.0f} MiB; target {c['target_s']:.0f} s")
        print(f"wrote section {SECTION} of {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
