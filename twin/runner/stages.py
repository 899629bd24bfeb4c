"""The stages of a campaign: plan -> measure -> identify -> diagnose -> compensate -> evaluate -> report.

Each is a function ``stage(state, runtime) -> state`` over a :class:`~twin.runner.state.CampaignState`
(``docs/runner.md``):

* :func:`plan` -- every commanded configuration with its role (``joints.csv``);
* :func:`measure` -- the world renders and the instrument measures them (the one loop of
  :mod:`twin.runner.measure`): ``dataset/`` (what the estimator sees) and ``truth.json`` (what it must not);
* :func:`identify` -- each method identifies the calibration rows (``calibrations/``);
* :func:`diagnose` -- with ``[diagnosis] enabled``, ``twin diagnose`` on the dataset: is the residual
  structured, which terms explain it (the robot's or the instrument's), the error before and after
  (``diagnosis/``);
* :func:`compensate` -- each method's compensated commands of the validation poses, measured again
  (``after/<method>/``);
* :func:`evaluate` -- the paper's statistics on the measured and on the true centres, the parameters beside
  the injected ones, the paper's claims, the tables;
* :func:`report` -- figures, the Rerun recording, ``results.json`` and ``table.txt``.

Identify, diagnose and compensate read only the dataset, the nominal model and the methods' results; the truth
the state carries goes to evaluate and report alone.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..benchio import atomic_write_text, provenance
from ..dataset import Joints, read_dataset, write_dataset_toml, write_joints_csv
from ..evaluation.evaluate import evaluate_campaign, paper_orderings, parameter_comparison
from ..evaluation.report import comparison_rows, render_parameter_table, render_table, write_results
from ..evaluation.targets import read_targets
from ..files import read_json
from ..transforms import invert_transform
from ..world.effects import contexts_for_sequence
from ..world.truth import write_truth
from .config import CampaignConfig
from .measure import PoseTask, get_backend, measure_tasks, write_measured_dataset
from .methods import MethodUnavailable, compensate as compensate_commands, dataset_fingerprint, identify as identify_method
from .methods import load_method_result, save_method_result
from .outputs import code_version, diagnosis_summary, diagnosis_table, figures, recording
from .plan import make_plan, pose_seed
from .state import CampaignState, Runtime

__all__ = ["STAGES", "MEASURING_STAGES", "plan", "measure", "identify", "diagnose", "compensate", "evaluate", "report",
           "visit_contexts"]


def visit_contexts(cfg: CampaignConfig, q_cmd: np.ndarray, stations) -> list:
    """Effect contexts of the commands ``q_cmd`` ``(n, 6)`` [rad] in the order the robot visits them, at the
    named ``stations``: :func:`twin.world.effects.contexts_for_sequence` (history = every earlier command,
    start at home, ``t_s = k * seconds_per_pose``); pure, so any process and any resume build the same."""
    index = {s.name: k for k, s in enumerate(cfg.stations())}
    st = [index[str(s)] for s in stations]
    t_s = np.arange(len(q_cmd), dtype=float) * cfg.measurement.seconds_per_pose
    return contexts_for_sequence(np.asarray(q_cmd, dtype=float), t_s=t_s, stations=st)


def _recorded(r, channel: str) -> float:
    """What the instrument records of a measurement's ``temp_c`` [°C] / ``t_s`` [s]: the world's value."""
    v = r.truth.get(channel)
    if v is None or not np.isfinite(float(v)):
        raise ValueError(f"pose {r.key}: the backend gave no {channel} to record (measurement.record_{channel})")
    return float(v)


def _write_dataset(folder, state: CampaignState, rows: np.ndarray, results, provenance: str,
                   q: np.ndarray | None = None) -> None:
    """poses.csv + dataset.toml of the plan's ``rows`` (commanded joints, measured spheres, set/station/pair/
    status, and the channels the instrument records)."""
    cfg, p = state.cfg, state.plan
    write_dataset_toml(folder, cfg.robot, cfg.plate, noise_position=state.noise_position,
                       stations_base2meas=dict(state.stations_nominal), provenance=provenance)
    res = [results[int(p.pose_id[i])] for i in rows]
    m = cfg.measurement
    write_measured_dataset(
        folder, res, p.q[rows] if q is None else q, set=p.set[rows], station=p.station[rows], pair=p.pair[rows],
        temp_c=[_recorded(r, "temp_c") for r in res] if m.record_temp_c else None,
        t_s=[_recorded(r, "t_s") for r in res] if m.record_t_s else None,
    )


# ------------------------------------------------------------------------------------------------
# the stages
# ------------------------------------------------------------------------------------------------

def plan(state: CampaignState, rt: Runtime) -> CampaignState:
    """The campaign's poses in measurement order (``joints.csv``), from the config and its seed alone."""
    t = time.perf_counter()
    p = make_plan(state.cfg)
    write_joints_csv(state.out / "joints.csv", Joints(p.pose_id, p.q, station=p.station, set=p.set))
    return state.with_timing("plan_s", time.perf_counter() - t, plan=p)


def measure(state: CampaignState, rt: Runtime) -> CampaignState:
    """Prepare the instrument (stereo calibration, once per campaign), measure every planned pose in the
    robot's visit order (resumable), write ``dataset/`` and ``truth.json`` and read the dataset back."""
    cfg, p, out = state.cfg, state.plan, state.out
    t = time.perf_counter()
    backend = get_backend(rt.spec)
    if cfg.measurement.mode == "images" and not (out / "work" / "stereo_calibration.json").exists():
        rt.log("rendering the board views and calibrating the stereo rig (once per campaign)")
    backend.prepare(rt.executor)
    t_prepare = time.perf_counter() - t
    # Effect contexts in the robot's visit order (docs/runner.md, "Visit order"): the plan's rows first.
    ctx = visit_contexts(cfg, p.q, p.station)
    tasks = [PoseTask(f"m/{pid:05d}", int(pid), p.q[i], str(p.station[i]), pose_seed(cfg.seed, f"m/{pid:05d}"),
                      context=ctx[i])
             for i, pid in enumerate(p.pose_id)]
    t = time.perf_counter()
    n_new = measure_tasks(rt.executor, rt.spec, tasks, rt.store, "measuring", rt.progress)
    t_measure = time.perf_counter() - t
    rt.log(f"measured {n_new} poses ({len(tasks) - n_new} already done)")
    before = {int(task.pose_id): rt.store.read(task.key) for task in tasks}
    state = replace(
        state, before=before, measured_before=n_new, stations_truth=backend.stations_truth(),
        true_robot=backend.true_robot(), noise_position=backend.noise_position(),
        stations_nominal={s.name: invert_transform(s.cameras[0].cam2base) for s in cfg.stations()},
        timings={**state.timings, "prepare_s": t_prepare, "measure_before_s": t_measure},
    )
    _write_dataset(out / "dataset", state, np.arange(p.n), before,
                   f"twin campaign {cfg.name}, seed {cfg.seed}{' (quick)' if cfg.quick else ''}")
    write_truth(out / "truth.json", _with_earlier_board_views(
        backend.truth_record([before[int(i)] for i in p.pose_id]), out / "truth.json"))
    return replace(state, dataset=read_dataset(out / "dataset"), dataset_sha256=dataset_fingerprint(out / "dataset"))


def _with_earlier_board_views(record: dict, path: Path) -> dict:
    """A resumed campaign loads its stereo calibration instead of rendering the board again: the true board poses
    of the views that calibration came from stay those of the run that rendered them (its truth file)."""
    if record.get("board_views") or not path.exists():
        return record
    earlier = read_json(path).get("board_views") or []
    return {**record, "board_views": earlier}


def identify(state: CampaignState, rt: Runtime) -> CampaignState:
    """Each method of the config identifies the dataset's calibration rows; an identification already in
    ``calibrations/`` is reused only for this very dataset (its SHA-256). A method the estimator does not
    provide is reported as unavailable, never faked."""
    found: dict[str, Any] = {}
    unavailable: dict[str, str] = {}
    timings = dict(state.timings)
    for m in state.cfg.methods:
        t = time.perf_counter()
        r = load_method_result(state.out / "calibrations", m, state.dataset_sha256)
        if r is None:
            try:
                r = identify_method(m, state.dataset, seed=state.cfg.seed, implementations=dict(rt.implementations))
            except MethodUnavailable as exc:
                unavailable[m] = str(exc)
                rt.log(f"method {m}: unavailable ({exc})")
                continue
            save_method_result(state.out / "calibrations", r, state.dataset_sha256)
        found[m] = r
        timings[f"identify_{m}_s"] = time.perf_counter() - t
    return replace(state, methods=found, unavailable=unavailable, timings=timings)


def diagnose(state: CampaignState, rt: Runtime) -> CampaignState:
    """With ``[diagnosis] enabled``: ``twin diagnose`` on the campaign's dataset (``twin.diagnosis.diagnose``,
    which reads the dataset alone); its files go to ``diagnosis/``, its verdict to the state."""
    if not state.cfg.diagnosis.enabled:
        return state
    from ..diagnosis import diagnose as run_diagnosis, write_diagnosis

    t = time.perf_counter()
    res = run_diagnosis(state.dataset, alpha=state.cfg.diagnosis.alpha)
    want_fig = state.cfg.outputs.figures if rt.figures is None else rt.figures
    write_diagnosis(res, state.out / "diagnosis", plots=want_fig)
    summary = diagnosis_summary(res)
    rt.log(f"diagnosis: structured={summary['structured']} (p = {summary['p_value']:.3g}); robot terms "
           f"{len(summary['robot_terms'])}, instrument terms {len(summary['instrument_terms'])}")
    return state.with_timing("diagnose_s", time.perf_counter() - t, diagnosis=summary)


def _compensated_commands(state: CampaignState, val_rows: np.ndarray):
    """Per method, the compensated commands of the validation rows and the poses left at their nominal
    command. A motion is compensated as a whole: if either end failed, both keep their nominal command."""
    p, nominal = state.plan, state.cfg.nominal_model()
    q_comp: dict[str, np.ndarray] = {}
    not_converged: dict[str, list[int]] = {}
    for m, r in state.methods.items():
        if not len(val_rows):  # nothing to compensate (no validation rows): evaluation reports why
            q_comp[m], not_converged[m] = np.zeros((0, 6)), []
            continue
        qc, ok = compensate_commands(r, nominal, p.q[val_rows])
        pair_ok: dict[int, bool] = {}
        for k, i in enumerate(val_rows):
            if p.pair[i] >= 0:
                pair_ok[int(p.pair[i])] = pair_ok.get(int(p.pair[i]), True) and bool(ok[k])
        ok = np.array([pair_ok.get(int(p.pair[i]), bool(ok[k])) if p.pair[i] >= 0 else bool(ok[k])
                       for k, i in enumerate(val_rows)])
        q_comp[m] = np.where(ok[:, None], qc, p.q[val_rows])
        not_converged[m] = [int(p.pose_id[i]) for i, c in zip(val_rows, ok) if not c]
    return q_comp, not_converged


def _compensated_tasks(state: CampaignState, val_rows: np.ndarray, q_comp) -> list[PoseTask]:
    """The robot visits the compensated commands after the dataset, method after method (in config order),
    each method's validation rows in plan order: their contexts continue the dataset's history."""
    p, cfg = state.plan, state.cfg
    methods = [m for m in state.methods if len(q_comp[m])]
    if not methods:
        return []
    q_seq = np.vstack([p.q] + [q_comp[m] for m in methods])
    st_seq = np.concatenate([p.station] + [p.station[val_rows] for _ in methods])
    ctx = visit_contexts(cfg, q_seq, st_seq)[p.n:]
    tasks = []
    for j, m in enumerate(methods):
        for k, i in enumerate(val_rows):
            key = f"c/{m}/{int(p.pose_id[i]):05d}"
            tasks.append(PoseTask(key, int(p.pose_id[i]), q_comp[m][k], str(p.station[i]), pose_seed(cfg.seed, key),
                                  context=ctx[j * len(val_rows) + k]))
    return tasks


def compensate(state: CampaignState, rt: Runtime) -> CampaignState:
    """Each method's compensation of the validation poses (iterative inverse on its identified model), measured
    again through the same loop; ``after/<method>/`` in the dataset format."""
    p = state.plan
    groups = {g.name for g in state.cfg.groups if g.evaluate}
    val_rows = np.flatnonzero(np.isin(p.group, list(groups)))
    t = time.perf_counter()
    q_comp, not_converged = _compensated_commands(state, val_rows)
    tasks = _compensated_tasks(state, val_rows, q_comp)
    t_comp = time.perf_counter() - t
    t = time.perf_counter()
    n_new = measure_tasks(rt.executor, rt.spec, tasks, rt.store, "measuring after compensation", rt.progress) if tasks else 0
    t_meas = time.perf_counter() - t
    after = {m: {int(p.pose_id[i]): rt.store.read(f"c/{m}/{int(p.pose_id[i]):05d}") for i in val_rows}
             for m in state.methods}
    for m in state.methods:
        _write_dataset(state.out / "after" / m, state, val_rows, after[m],
                       f"compensated by {m}: validation poses measured again", q=q_comp[m])
    return replace(state, val_rows=val_rows, q_comp=q_comp, not_converged=not_converged, after=after,
                   measured_after=n_new,
                   timings={**state.timings, "compensate_s": t_comp, "measure_after_s": t_meas})


def evaluate(state: CampaignState, rt: Runtime) -> CampaignState:
    """The paper's statistics per method (measured and on the world's truth), the identified parameters beside
    the injected ones, the paper's claims checked, and the tables (ours beside the paper's targets, and the
    diagnosis of the dataset when it ran)."""
    t = time.perf_counter()
    cfg, p = state.cfg, state.plan
    groups = {g.name: g.evaluate for g in cfg.groups if g.evaluate}
    nominal = cfg.nominal_model()
    evals = evaluate_campaign(p, groups, nominal, cfg.plate, {k: v.base2meas for k, v in state.stations_truth.items()},
                              state.before, state.after, {m: r.base2meas for m, r in state.methods.items()})
    summaries = {m: e.summary for m, e in evals.items()}
    targets = None
    try:
        targets = read_targets(rt.targets_path)
    except ValueError as exc:
        rt.log(f"paper targets not read: {exc}")
    true_dev = cfg.true_deviation()
    params = {m: parameter_comparison(nominal, true_dev, r.robot, r.identified) for m, r in state.methods.items()}
    orderings = paper_orderings(summaries) if state.methods else []
    paper_key = ("simulation", "figure10", "figure10") if cfg.outputs.paper == "simulation" else ("real", "figure13", "figure15")
    title = f"{cfg.name} (seed {cfg.seed}{', quick' if cfg.quick else ''}): measured after compensation"
    table = render_table(comparison_rows(summaries, targets, paper_key=paper_key), title)
    absent_notes = sorted({f"{unit} {phase}: {why}" for s in summaries.values() for unit in ("angle_deg", "position_mm")
                           for phase, why in ((s.get("measured", {}).get(unit) or {}).get("absent") or {}).items()})
    if absent_notes:
        table += "\nnot computed: " + "; ".join(absent_notes)
    table_truth = render_table(comparison_rows(summaries, None, source="truth"),
                               "same statistics on the world's truth (no measurement noise)")
    table_params = render_parameter_table(params, targets if cfg.outputs.paper == "simulation" else None,
                                          "identified parameter deviations (Tables 3 and 5 style)")
    tables = (table, table_truth, table_params) + ((diagnosis_table(state.diagnosis),) if state.diagnosis else ())
    results = {"summaries": summaries, "parameters": params, "orderings": orderings, "targets": targets,
               "paper_key": list(paper_key)}
    return state.with_timing("evaluate_s", time.perf_counter() - t, evaluation=evals, results=results, tables=tables)


def report(state: CampaignState, rt: Runtime) -> CampaignState:
    """Figures, the recording, ``results.json`` and ``table.txt``."""
    cfg, p = state.cfg, state.plan
    files: dict[str, Any] = {}
    timings = dict(state.timings)
    want_fig = cfg.outputs.figures if rt.figures is None else rt.figures
    t = time.perf_counter()
    if want_fig and state.evaluation:
        files.update(figures(state.out, state.evaluation, cfg))
    timings["figures_s"] = time.perf_counter() - t
    t = time.perf_counter()
    want_rec = cfg.outputs.recording if rt.recording is None else rt.recording
    if want_rec:
        files["recording"] = recording(state.out / "recording.rrd", state, rt.store)
    timings["recording_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - rt.t_start if rt.t_start else sum(timings.values())
    sums: dict[str, float] = {}
    for r in list(state.before.values()) + [r for d in state.after.values() for r in d.values()]:
        for k, v in r.timings.items():
            sums[k] = sums.get(k, 0.0) + float(v)
    res = state.results
    results = {
        "campaign": cfg.name,
        "description": cfg.description,
        "seed": cfg.seed,
        "quick": cfg.quick,
        "command": rt.command,
        "fingerprint": cfg.fingerprint(),
        "measurement_mode": cfg.measurement.mode,
        "counts": {
            "poses": int(p.n),
            "calibration_poses": int(np.sum(p.set == "calibration")),
            "validation_poses": int(len(state.val_rows)),
            "compensated_measurements": int(len(state.val_rows) * len(state.methods)),
            "rejected_before": int(sum(1 for r in state.before.values() if r.status)),
            "measured_in_this_run": int(state.measured_before + state.measured_after),
        },
        "methods": res["summaries"],
        "methods_unavailable": dict(state.unavailable),
        "compensation_failed": dict(state.not_converged),
        "parameters": res["parameters"],
        "orderings": res["orderings"],
        "paper_targets": res["targets"],
        "paper_key": res["paper_key"],
        **({"diagnosis": dict(state.diagnosis)} if state.diagnosis is not None else {}),
        "timings_s": timings,
        "worker_time_sums_s": sums,
        "config": cfg.raw,
        "code": code_version(),
        "machine": {"cpu_count": os.cpu_count(), "load_average_start": list(rt.load_start),
                    "load_average_end": list(os.getloadavg())},
        "provenance": provenance(rt.load_start),
    }
    if "recording" in files and files["recording"].exists():
        results["recording_mb"] = files["recording"].stat().st_size / 1e6
    files["results"] = write_results(state.out / "results.json", results)
    text = "\n\n".join(state.tables)
    atomic_write_text(state.out / "table.txt", text + "\n")
    files["table"] = state.out / "table.txt"
    return replace(state, timings=timings, files=files, results={**state.results, "results": results, "table": text})


MEASURING_STAGES = (plan, measure, identify, diagnose, compensate)  # run while the executor is open
STAGES = MEASURING_STAGES + (evaluate, report)
