"""A campaign end to end: plan -> world -> instrument -> dataset -> estimator -> compensation -> evaluation.

:func:`run_campaign` is what ``twin campaign CONFIG --out DIR`` runs; :func:`run_repeats` runs it for several
seeds on an executor and aggregates the statistics. Output folder (``docs/runner.md``)::

    DIR/
      results.json            statistics per method, the paper's targets beside them, parameters, timings
      table.txt               the comparison table
      figure10.png            Figure 10 style (separation method: before / after)
      figure11.png            Figure 11 style (all methods after compensation)
      recording.rrd           the Rerun recording (git-ignored)
      joints.csv              the plan (JOINTS.csv format)
      dataset/                poses.csv + dataset.toml: what the estimator sees
      truth.json              what the world knew (evaluation only)
      calibrations/           one identification per method (+ the estimator's calibration.json)
      after/<method>/         the compensated poses measured again (dataset format)
      work/                   per-pose results (resume state), renders.log; images under work/poses/images/

Resume: every measured pose is written atomically as soon as it is finished (:mod:`twin.runner.store`);
running the same command again measures only what is missing. The dataset CSV is assembled from the
per-pose files in plan order, so a resumed run writes the same bytes as an uninterrupted one. A different
config in the same folder is refused (``work/campaign.json`` holds the config's fingerprint).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..dataset import DatasetWriter, Joints, PoseRow, read_dataset, write_dataset_toml, write_joints_csv
from ..kinematics import link_frames
from ..transforms import invert_transform
from ..world.effects import contexts_for_sequence
from ..world.truth import write_truth
from .config import CampaignConfig
from ..evaluation.evaluate import evaluate_campaign, paper_orderings, parameter_comparison
from ..evaluation.statistics import aggregate
from .executor import SerialExecutor, open_executor, run_tasks, worker_identity
from .methods import (Identify, MethodUnavailable, compensate, dataset_fingerprint, identify, load_method_result,
                      save_method_result)
from .measure import PoseTask, backend_spec_for, get_backend, measure_pose
from .plan import CampaignPlan, make_plan, pose_seed
from ..evaluation.report import comparison_rows, plot_figure10, plot_figure11, render_parameter_table, render_table, write_results
from ..instrument.plate import paper_frame_from_spheres
from ..benchio import atomic_write_text
from .store import PoseResult, PoseStore
from ..evaluation.targets import read_targets

__all__ = ["CampaignRun", "run_campaign", "run_repeats", "visit_contexts", "Progress"]

Progress = Callable[[str, int, int], None]  # (phase, done, total)


@dataclass
class CampaignRun:
    """What :func:`run_campaign` returns: the results dict (as in results.json), the table text, paths."""

    out_dir: Path
    results: dict[str, Any]
    table: str
    files: dict[str, Path] = field(default_factory=dict)


def _code_version() -> dict[str, Any]:
    """The git commit of the library (and whether the tree had changes), when it runs from a checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10).stdout.strip()
        dirty = bool(subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "twin"],
                                    capture_output=True, text=True, timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"git_commit": commit, "twin_modified": dirty} if commit else {}


def _check_fingerprint(work: Path, cfg: CampaignConfig) -> None:
    work.mkdir(parents=True, exist_ok=True)
    marker = work / "campaign.json"
    fp = cfg.fingerprint()
    if marker.exists():
        old = json.loads(marker.read_text()).get("fingerprint")
        if old != fp:
            raise ValueError(
                f"{work.parent} holds another campaign (fingerprint {old}, this config {fp}): "
                "use another --out folder or delete it"
            )
        return
    atomic_write_text(marker, json.dumps({"fingerprint": fp, "name": cfg.name, "seed": cfg.seed, "quick": cfg.quick}))


def _stored_for(store: PoseStore, task: PoseTask) -> bool:
    """True when the store holds a result of ``task.key`` measured at the task's commanded joints."""
    if not store.has(task.key):
        return False
    q_stored = np.asarray(store.read(task.key).q, dtype=float)
    return q_stored.shape == np.shape(task.q) and bool(np.all(np.abs(q_stored - np.asarray(task.q, dtype=float)) <= 1e-12))


def _measure(
    executor: cf.Executor, spec, tasks: Sequence[PoseTask], store: PoseStore, phase: str, progress: Progress | None
) -> int:
    """Measure the tasks not yet in the store; every result is written as soon as it arrives.

    A stored result is reused only when it was measured at the task's own command: a compensated pose whose
    command changed (the identification was redone on a re-measured dataset) is measured again, so a command
    is never paired with spheres measured at another one."""
    pending = [t for t in tasks if not _stored_for(store, t)]
    done = len(tasks) - len(pending)
    if progress:
        progress(phase, done, len(tasks))
    counter = {"n": done}

    def on_done(task: PoseTask, res: PoseResult) -> None:
        store.write(res)
        counter["n"] += 1
        if progress:
            progress(phase, counter["n"], len(tasks))

    run_tasks(executor, measure_pose, pending, args=(spec,), on_done=on_done)
    return len(pending)


def _write_dataset(folder: Path, plan: CampaignPlan, rows: np.ndarray, results: Mapping[int, PoseResult], cfg,
                   stations_nominal: Mapping[str, np.ndarray], noise: float | None, provenance: str,
                   q_override: np.ndarray | None = None) -> None:
    """poses.csv + dataset.toml in plan order (commanded joints, measured spheres, set/station/pair/status)."""
    write_dataset_toml(folder, cfg.robot, cfg.plate, noise_position=noise, stations_base2meas=dict(stations_nominal),
                       provenance=provenance)
    rec_T, rec_t = cfg.measurement.record_temp_c, cfg.measurement.record_t_s
    optional = ("set", "station", "pair", "status") + (("temp_c",) if rec_T else ()) + (("t_s",) if rec_t else ())
    with DatasetWriter(folder, spheres=True, optional=optional) as w:
        for k, i in enumerate(rows):
            r = results[int(plan.pose_id[i])]
            w.write(PoseRow(
                pose_id=int(plan.pose_id[i]),
                q=plan.q[i] if q_override is None else q_override[k],
                spheres=list(r.spheres),
                set=str(plan.set[i]),
                station=str(plan.station[i]),
                pair=None if plan.pair[i] < 0 else int(plan.pair[i]),
                status=r.status,
                temp_c=_recorded(r, "temp_c") if rec_T else None,
                t_s=_recorded(r, "t_s") if rec_t else None,
            ))


def _recorded(r: PoseResult, channel: str) -> float:
    """What the instrument records of a measurement's ``temp_c`` [°C] / ``t_s`` [s]: the world's value."""
    v = r.truth.get(channel)
    if v is None or not np.isfinite(float(v)):
        raise ValueError(f"pose {r.key}: the backend gave no {channel} to record (measurement.record_{channel})")
    return float(v)


def visit_contexts(cfg: CampaignConfig, q_cmd: np.ndarray, stations: Sequence[str]) -> list:
    """Effect contexts of the commands ``q_cmd`` ``(n, 6)`` [rad] in the order the robot visits them, at the
    named ``stations``: :func:`twin.world.effects.contexts_for_sequence` (history = every earlier command,
    start at home, ``t_s = k * seconds_per_pose``); pure, so any process and any resume build the same."""
    index = {s.name: k for k, s in enumerate(cfg.stations())}
    st = [index[str(s)] for s in stations]
    t_s = np.arange(len(q_cmd), dtype=float) * cfg.measurement.seconds_per_pose
    return contexts_for_sequence(np.asarray(q_cmd, dtype=float), t_s=t_s, stations=st)


def _evaluated_groups(cfg: CampaignConfig) -> dict[str, tuple[str, ...]]:
    return {g.name: g.evaluate for g in cfg.groups if g.evaluate}


def run_campaign(
    cfg: CampaignConfig,
    out_dir: str | os.PathLike,
    *,
    executor: cf.Executor | None = None,
    backend_factory: str | None = None,
    implementations: Mapping[str, Identify] | None = None,
    progress: Progress | None = None,
    log: Callable[[str], None] | None = None,
    targets_path: str | os.PathLike | None = None,
    command: str = "",
    recording: bool | None = None,
    figures: bool | None = None,
) -> CampaignRun:
    """Run (or resume) the campaign ``cfg`` into ``out_dir``; returns the results and the table.

    ``executor``: where poses are measured (default: ``cfg.workers`` local processes, or in-process for one
    worker). ``backend_factory``: a ``module:callable`` measurement backend instead of ``cfg.measurement.mode``
    (tests use cheap fakes). ``implementations``: identification functions per method instead of the
    estimator's. A method the estimator does not provide is reported as unavailable, not faked.
    """
    say = log or (lambda s: None)
    t_start = time.perf_counter()
    load_start = os.getloadavg()
    timings: dict[str, float] = {}
    out = Path(out_dir)
    work = out / "work"
    _check_fingerprint(work, cfg)
    store = PoseStore(work / "poses")

    t = time.perf_counter()
    plan = make_plan(cfg)
    write_joints_csv(out / "joints.csv", Joints(plan.pose_id, plan.q, station=plan.station, set=plan.set))
    timings["plan_s"] = time.perf_counter() - t

    spec = backend_spec_for(cfg, work, backend_factory)
    t = time.perf_counter()
    backend = get_backend(spec)
    if cfg.measurement.mode == "images" and not (work / "stereo_calibration.json").exists():
        say("rendering the board views and calibrating the stereo rig (once per campaign)")
    backend.prepare()
    timings["prepare_s"] = time.perf_counter() - t
    stations_truth = backend.stations_truth()
    base2meas_true = {k: v.base2meas for k, v in stations_truth.items()}
    stations_nominal = {s.name: invert_transform(s.cameras[0].cam2base) for s in cfg.stations()}

    own_ex = executor is None
    ex_ctx = (open_executor("process", cfg.workers) if cfg.workers > 1 else nullcontext(SerialExecutor())) if own_ex else nullcontext(executor)
    with ex_ctx as ex:
        # --- 1. the campaign's own poses -----------------------------------------------------------
        # Effect contexts in the robot's visit order (docs/runner.md, "Visit order"): the plan's rows first.
        ctx_before = visit_contexts(cfg, plan.q, plan.station)
        tasks = [PoseTask(f"m/{pid:05d}", int(pid), plan.q[i], str(plan.station[i]), pose_seed(cfg.seed, f"m/{pid:05d}"),
                          context=ctx_before[i])
                 for i, pid in enumerate(plan.pose_id)]
        t = time.perf_counter()
        n_new = _measure(ex, spec, tasks, store, "measuring", progress)
        timings["measure_before_s"] = time.perf_counter() - t
        say(f"measured {n_new} poses ({len(tasks) - n_new} already done)")
        before = {int(t_.pose_id): store.read(t_.key) for t_ in tasks}
        rows = np.arange(plan.n)
        noise = backend.noise_position()
        _write_dataset(out / "dataset", plan, rows, before, cfg, stations_nominal, noise,
                       f"twin campaign {cfg.name}, seed {cfg.seed}{' (quick)' if cfg.quick else ''}")
        write_truth(out / "truth.json", backend.truth_record([before[int(p)] for p in plan.pose_id]))
        dataset = read_dataset(out / "dataset")
        dataset_sha256 = dataset_fingerprint(out / "dataset")

        # --- 2. identification per method ------------------------------------------------------------
        method_results: dict[str, Any] = {}
        unavailable: dict[str, str] = {}
        for m in cfg.methods:
            t = time.perf_counter()
            r = load_method_result(out / "calibrations", m, dataset_sha256)  # only for this very dataset
            if r is None:
                try:
                    r = identify(m, dataset, seed=cfg.seed, implementations=dict(implementations or {}))
                except MethodUnavailable as exc:
                    unavailable[m] = str(exc)
                    say(f"method {m}: unavailable ({exc})")
                    continue
                save_method_result(out / "calibrations", r, dataset_sha256)
            method_results[m] = r
            timings[f"identify_{m}_s"] = time.perf_counter() - t

        # --- 3. compensation and measurement after compensation ------------------------------------
        groups = _evaluated_groups(cfg)
        val_rows = np.flatnonzero(np.isin(plan.group, list(groups)))
        q_comp: dict[str, np.ndarray] = {}
        comp_tasks: list[PoseTask] = []
        not_converged: dict[str, list[int]] = {}
        t = time.perf_counter()
        for m, r in method_results.items():
            if not len(val_rows):  # nothing to compensate (no validation rows): evaluation reports why
                q_comp[m], not_converged[m] = np.zeros((0, 6)), []
                continue
            qc, ok = compensate(r, cfg.nominal_model(), plan.q[val_rows])
            # A motion is compensated as a whole: if either end failed, both keep their nominal command.
            pair_ok = {}
            for k, i in enumerate(val_rows):
                if plan.pair[i] >= 0:
                    pair_ok[int(plan.pair[i])] = pair_ok.get(int(plan.pair[i]), True) and bool(ok[k])
            ok = np.array([pair_ok.get(int(plan.pair[i]), bool(ok[k])) if plan.pair[i] >= 0 else bool(ok[k])
                           for k, i in enumerate(val_rows)])
            qc = np.where(ok[:, None], qc, plan.q[val_rows])
            not_converged[m] = [int(plan.pose_id[i]) for i, c in zip(val_rows, ok) if not c]
            q_comp[m] = qc
        # The robot visits the compensated commands after the dataset, method after method (in config order),
        # each method's validation rows in plan order: their contexts continue the dataset's history.
        comp_methods = [m for m in method_results if len(q_comp[m])]
        if comp_methods:
            q_seq = np.vstack([plan.q] + [q_comp[m] for m in comp_methods])
            st_seq = np.concatenate([plan.station] + [plan.station[val_rows] for _ in comp_methods])
            ctx_after = visit_contexts(cfg, q_seq, st_seq)[plan.n:]
            for j, m in enumerate(comp_methods):
                for k, i in enumerate(val_rows):
                    key = f"c/{m}/{int(plan.pose_id[i]):05d}"
                    comp_tasks.append(PoseTask(key, int(plan.pose_id[i]), q_comp[m][k], str(plan.station[i]),
                                               pose_seed(cfg.seed, key), context=ctx_after[j * len(val_rows) + k]))
        timings["compensate_s"] = time.perf_counter() - t
        t = time.perf_counter()
        n_new_after = 0
        if comp_tasks:
            n_new_after = _measure(ex, spec, comp_tasks, store, "measuring after compensation", progress)
        timings["measure_after_s"] = time.perf_counter() - t
        after = {m: {int(plan.pose_id[i]): store.read(f"c/{m}/{int(plan.pose_id[i]):05d}") for i in val_rows}
                 for m in method_results}
        for m in method_results:
            _write_dataset(out / "after" / m, plan, val_rows, after[m], cfg, stations_nominal, noise,
                           f"compensated by {m}: validation poses measured again", q_override=q_comp[m])

    # --- 4. evaluation ---------------------------------------------------------------------------
    t = time.perf_counter()
    nominal = cfg.nominal_model()
    evals = evaluate_campaign(plan, groups, nominal, cfg.plate, base2meas_true, before, after,
                              {m: r.base2meas for m, r in method_results.items()})
    summaries = {m: e.summary for m, e in evals.items()}
    targets = None
    try:
        targets = read_targets(targets_path)
    except ValueError as exc:
        say(f"paper targets not read: {exc}")
    true_dev = cfg.true_deviation()
    params = {m: parameter_comparison(nominal, true_dev, r.robot, r.identified) for m, r in method_results.items()}
    orderings = paper_orderings(summaries) if method_results else []
    paper_key = ("simulation", "figure10", "figure10") if cfg.outputs.paper == "simulation" else ("real", "figure13", "figure15")
    rows_tab = comparison_rows({m: s for m, s in summaries.items()}, targets, paper_key=paper_key)
    title = f"{cfg.name} (seed {cfg.seed}{', quick' if cfg.quick else ''}): measured after compensation"
    table = render_table(rows_tab, title)
    absent_notes = sorted({f"{unit} {phase}: {why}" for s in summaries.values() for unit in ("angle_deg", "position_mm")
                           for phase, why in ((s.get("measured", {}).get(unit) or {}).get("absent") or {}).items()})
    if absent_notes:
        table += "\nnot computed: " + "; ".join(absent_notes)
    rows_truth = comparison_rows({m: s for m, s in summaries.items()}, None, source="truth")
    table_truth = render_table(rows_truth, "same statistics on the world's truth (no measurement noise)")
    table_params = render_parameter_table(params, targets if cfg.outputs.paper == "simulation" else None,
                                          "identified parameter deviations (Tables 3 and 5 style)")
    timings["evaluate_s"] = time.perf_counter() - t

    files: dict[str, Path] = {}
    want_fig = cfg.outputs.figures if figures is None else figures
    t = time.perf_counter()
    if want_fig and evals:
        files.update(_figures(out, evals, cfg))
    timings["figures_s"] = time.perf_counter() - t
    t = time.perf_counter()
    want_rec = cfg.outputs.recording if recording is None else recording
    if want_rec:
        files["recording"] = _recording(out / "recording.rrd", cfg, plan, store, before, after, evals, method_results,
                                        stations_truth, backend, not_converged)
    timings["recording_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t_start

    worker_times = [r.timings for r in before.values()] + [r.timings for d in after.values() for r in d.values()]
    sums: dict[str, float] = {}
    for wt in worker_times:
        for k, v in wt.items():
            sums[k] = sums.get(k, 0.0) + float(v)
    results = {
        "campaign": cfg.name,
        "description": cfg.description,
        "seed": cfg.seed,
        "quick": cfg.quick,
        "command": command,
        "fingerprint": cfg.fingerprint(),
        "measurement_mode": cfg.measurement.mode,
        "counts": {
            "poses": int(plan.n),
            "calibration_poses": int(np.sum(plan.set == "calibration")),
            "validation_poses": int(len(val_rows)),
            "compensated_measurements": int(len(val_rows) * len(method_results)),
            "rejected_before": int(sum(1 for r in before.values() if r.status)),
            "measured_in_this_run": int(n_new + n_new_after),
        },
        "methods": summaries,
        "methods_unavailable": unavailable,
        "compensation_failed": not_converged,
        "parameters": params,
        "orderings": orderings,
        "paper_targets": targets,
        "paper_key": list(paper_key),
        "timings_s": timings,
        "worker_time_sums_s": sums,
        "config": cfg.raw,
        "code": _code_version(),
        "machine": {"cpu_count": os.cpu_count(), "load_average_start": list(load_start),
                    "load_average_end": list(os.getloadavg())},
    }
    if "recording" in files and files["recording"].exists():
        results["recording_mb"] = files["recording"].stat().st_size / 1e6
    files["results"] = write_results(out / "results.json", results)
    atomic_write_text(out / "table.txt", table + "\n\n" + table_truth + "\n\n" + table_params + "\n")
    files["table"] = out / "table.txt"
    return CampaignRun(out, results, table + "\n\n" + table_truth + "\n\n" + table_params, files)


def _figures(out: Path, evals, cfg: CampaignConfig) -> dict[str, Path]:
    files: dict[str, Path] = {}
    deg = 180.0 / np.pi
    angle_pairs = [p for p in next(iter(evals.values())).pairs if p.angle]
    pos_pairs = [p for p in next(iter(evals.values())).pairs if p.position and np.isfinite(p.distance).any()]
    if not pos_pairs:
        pos_pairs = [p for p in next(iter(evals.values())).pairs if p.position]

    def cat(ev, attr, key, pairs_sel):
        names = {p.group for p in pairs_sel}
        arrs = [getattr(p, attr).get(key) for p in ev.pairs if p.group in names]
        arrs = [a for a in arrs if a is not None]
        return np.concatenate(arrs) if arrs else np.zeros(0)

    main = "separation" if "separation" in evals else next(iter(evals))
    ev = evals[main]
    real = cfg.outputs.paper == "real"
    name10, name11 = ("figure13_15", "methods_after") if real else ("figure10", "figure11")
    if angle_pairs and pos_pairs and main != "before":
        files[name10] = plot_figure10(
            out / f"{name10}.png",
            cat(ev, "angle", "measured_before", angle_pairs) * deg, cat(ev, "angle", "measured_after", angle_pairs) * deg,
            cat(ev, "position", "measured_before", pos_pairs) * 1e3, cat(ev, "position", "measured_after", pos_pairs) * 1e3,
            np.concatenate([p.distance for p in pos_pairs]),
            method_label=main, title=f"{cfg.name}: before and after compensation ({main}), measured",
        )
    methods = [m for m in evals if m != "before"]
    if len(methods) > 1 and angle_pairs and pos_pairs:
        files[name11] = plot_figure11(
            out / f"{name11}.png",
            {m: cat(evals[m], "angle", "measured_after", angle_pairs) * deg for m in methods},
            {m: cat(evals[m], "position", "measured_after", pos_pairs) * 1e3 for m in methods},
            title=f"{cfg.name}: methods after compensation, measured",
        )
    return files


def _recording(path: Path, cfg, plan, store, before, after, evals, method_results, stations_truth, backend, not_converged) -> Path:
    from ..evaluation import recording as rec_mod  # the only module that imports rerun

    images_mode = cfg.outputs.recording_images
    views = []
    for name, st in stations_truth.items():
        cams = tuple(rec_mod.CameraView(cn, T, K) for cn, (T, K) in st.cameras.items())
        views.append(rec_mod.StationView(name, invert_transform(st.base2meas), cams))
    nominal = cfg.nominal_model().with_frames(base2meas=np.eye(4))
    true_model = backend.true_robot().with_frames(base2meas=np.eye(4))
    models = {"nominal": nominal, "true": true_model}
    models.update({f"calibrated/{m}": r.robot.with_frames(base2meas=np.eye(4)) for m, r in method_results.items()})
    # residual series at the end pose of every evaluated pair
    series: dict[int, dict[str, float]] = {}
    for m, ev in evals.items():
        for p in ev.pairs:
            for quantity, d, scale, unit in (("angle", p.angle, 180 / np.pi, "angle_deg"), ("position", p.position, 1e3, "position_mm")):
                for key, vals in d.items():
                    src, phase = key.split("_")
                    if src != "measured":
                        continue
                    name = "before" if phase == "before" else m
                    for pid, v in zip(p.pose_id_end, vals):
                        series.setdefault(int(pid), {})[f"residuals/{name}/{unit}"] = float(v) * scale
    with rec_mod.CampaignRecording(path, application_id="twin-campaign", recording_id=f"{cfg.name}-{cfg.seed}",
                                   methods=list(method_results), lossless=cfg.outputs.recording_lossless,
                                   jpeg_quality=cfg.outputs.jpeg_quality) as rec:
        rec.log_stations(views)
        for m, ids in not_converged.items():
            if ids:
                rec.log_text(f"{m}: no compensated command for poses {ids} (did not converge or left the joint limits); "
                             "their motions kept the nominal commands", "WARN")
        for i, pid in enumerate(plan.pose_id):
            pid = int(pid)
            r = store.read(f"m/{pid:05d}", with_images=images_mode != "none")
            rec.set_pose(pid)
            if r.images:
                rec.log_images(r.images, image_format=r.image_format, overlays=r.overlays)
            s, seen = r.spheres_array()
            plate = paper_frame_from_spheres(s) if seen.all() else None
            rec.log_measurement(r.station, s, seen, plate)
            q_act = np.asarray(r.truth.get("q_actual", plan.q[i]), dtype=float)
            frames = {name: link_frames(mdl, plan.q[i] if name != "true" else q_act)[0] for name, mdl in models.items()}
            rec.log_robot(frames)
            if r.status:
                rec.log_text(f"pose {pid} ({plan.group[i]}, station {r.station}): not measured: {r.status}", "WARN")
            if pid in series:
                rec.log_scalars(series[pid])
            if images_mode == "all":
                for m in after:
                    ra = after[m].get(pid)
                    if ra is None:
                        continue
                    ra = store.read(ra.key, with_images=True)
                    if ra.images:
                        rec.log_images({f"compensated_{m}_{c}": b for c, b in ra.images.items()}, image_format=ra.image_format)
    return path


# ------------------------------------------------------------------------------------------------
# Monte-Carlo: several seeds on an executor
# ------------------------------------------------------------------------------------------------

def _one_seed(raw: dict, source: str | None, quick: bool, seed: int, out_dir: str, backend_factory: str | None,
              implementations: Mapping[str, Identify] | None = None) -> dict[str, Any]:
    """Worker: one whole campaign for ``seed`` (poses measured in this process), its statistics, and where it ran."""
    from .config import parse_campaign_config

    raw = {**raw, "outputs": {**raw.get("outputs", {}), "recording": False, "figures": False}}  # no images kept
    cfg = parse_campaign_config(raw, source=Path(source) if source else None, _quick_applied=quick).with_seed(seed)
    run = run_campaign(cfg, out_dir, executor=SerialExecutor(), backend_factory=backend_factory,
                       implementations=implementations, recording=False, figures=False)
    return {
        "seed": seed,
        "methods": run.results["methods"],
        "orderings": run.results["orderings"],
        "parameters": run.results["parameters"],
        "worker": worker_identity(),
        "timings_s": run.results["timings_s"],
    }


def run_repeats(
    cfg: CampaignConfig,
    out_dir: str | os.PathLike,
    seeds: Sequence[int],
    executor: cf.Executor,
    *,
    backend_factory: str | None = None,
    implementations: Mapping[str, Identify] | None = None,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Run the campaign once per seed (each in its own ``out_dir/seed_<n>`` folder, resumable) on
    ``executor`` and aggregate every statistic into mean and spread; ordering claims into the fraction of
    seeds where they hold."""
    out = Path(out_dir)
    items = [int(s) for s in seeds]
    done = {"n": 0}

    def on_done(_item, _res):
        done["n"] += 1
        if progress:
            progress("seeds", done["n"], len(items))

    if progress:
        progress("seeds", 0, len(items))
    per_seed = run_tasks(
        executor,
        _seed_task,
        [(cfg.raw, str(cfg.source) if cfg.source else None, cfg.quick, s, str(out / f"seed_{s}"), backend_factory,
          dict(implementations) if implementations else None) for s in items],
        on_done=on_done,
    )
    stats = aggregate([{"methods": r["methods"]} for r in per_seed])
    claims: dict[str, dict[str, Any]] = {}
    for r in per_seed:
        for c in r["orderings"]:
            e = claims.setdefault(c["claim"], {"holds": 0, "n": 0})
            e["n"] += 1
            e["holds"] += int(bool(c["holds"]))
    for e in claims.values():
        e["fraction"] = e["holds"] / e["n"] if e["n"] else float("nan")
    return {"seeds": items, "statistics": stats, "orderings": claims, "per_seed": per_seed}


def _seed_task(args: tuple) -> dict[str, Any]:
    return _one_seed(*args)
