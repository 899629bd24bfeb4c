"""What the report stage writes besides results.json: the figures, the Rerun recording, the diagnosis' verdict
(its summary, its table), and the code version a result was produced at."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..evaluation.report import plot_figure10, plot_figure11
from ..instrument.plate import paper_frame_from_spheres
from ..kinematics import link_frames
from ..transforms import invert_transform
from ..units import M_PER_MM, MM_PER_M, DEG_PER_RAD

__all__ = ["code_version", "figures", "recording", "diagnosis_summary", "diagnosis_table", "diagnosis_markdown",
           "term_side"]


def code_version() -> dict[str, Any]:
    """The git commit of the library (and whether the tree had changes), when it runs from a checkout: the git
    work tree whose ``twin/`` is this package's folder (an installed copy inside some other repository has none)."""
    package = Path(__file__).resolve().parent.parent
    try:
        top = subprocess.run(["git", "-C", str(package), "rev-parse", "--show-toplevel"], capture_output=True,
                             text=True, timeout=10).stdout.strip()
        if not top or Path(top).resolve() / "twin" != package:
            return {}
        commit = subprocess.run(["git", "-C", top, "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10).stdout.strip()
        dirty = bool(subprocess.run(["git", "-C", top, "status", "--porcelain", "--", "twin"],
                                    capture_output=True, text=True, timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"git_commit": commit, "twin_modified": dirty} if commit else {}


# ------------------------------------------------------------------------------------------------
# the diagnosis of the campaign's dataset
# ------------------------------------------------------------------------------------------------

def term_side(term: Mapping[str, Any]) -> str:
    """``"instrument"`` for a term on the measurement side (a scale or a field of the measurements, or the
    frame of a station: the instrument or the cell), else ``"robot"``; the rule the diagnosis states in its
    notes."""
    return "instrument" if term.get("place") in ("scale", "field") or term.get("target") == "base" else "robot"


def diagnosis_summary(res) -> dict[str, Any]:
    """The verdict of ``twin.diagnosis.diagnose`` on the campaign's dataset, for results.json: structured and
    its p-value, the noise floor [mm per coordinate], the catalogue effects, every term with its side (robot or
    instrument), and the error before (geometric model) and after (extended model) on the rows the diagnosis
    names in ``held_out`` (its report rows: held out, used neither to choose nor to fit the model)."""
    terms = [{"text": str(a.get("text", a.get("label", ""))), "side": term_side(a)} for a in getattr(res, "atoms", ())]
    return {
        "structured": bool(res.structured),
        "p_value": float(res.p_value),
        "alpha": float(res.alpha),
        "noise_floor_mm": float(res.noise.sigma / M_PER_MM),
        "effects": list(res.effects),
        "terms": terms,
        "robot_terms": [t["text"] for t in terms if t["side"] == "robot"],
        "instrument_terms": [t["text"] for t in terms if t["side"] == "instrument"],
        "before": res.before,
        "after": res.after,
        "held_out": dict(getattr(res, "held_out", None) or {}),
        "notes": list(getattr(res, "notes", ())),
        "files": "diagnosis/diagnosis.json",
    }


def _err(block: Mapping[str, Any] | None) -> str:
    pos = (block or {}).get("position_mm") or {}
    if not pos:
        return "-"
    return f"mean {pos['mean']:.4f}, rms {pos['rms']:.4f}, max {pos['max']:.4f}"


def _rows_said(d: Mapping[str, Any]) -> str:
    """Which rows before/after are measured on, in words."""
    h = d.get("held_out") or {}
    if h.get("before_after_on") == "report":
        return f"on {h.get('n_report_rows', '?')} report rows (held out, used neither to choose nor to fit the model)"
    return f"on the {h.get('before_after_on', 'validation')} rows"


def diagnosis_table(d: Mapping[str, Any]) -> str:
    """The diagnosis block of ``table.txt``."""
    lines = [
        f"diagnosis of the dataset (twin diagnose, alpha {d['alpha']:g}; files in {Path(d['files']).parent}/)",
        f"residual of the geometric model: {'STRUCTURED' if d['structured'] else 'not structured'} "
        f"(p = {d['p_value']:.3g}) against a noise floor of {d['noise_floor_mm']:.5f} mm per coordinate",
        "robot terms: " + ("; ".join(d["robot_terms"]) if d["robot_terms"] else "none"),
        "instrument terms (measurement side: the instrument or the cell, not the robot): "
        + ("; ".join(d["instrument_terms"]) if d["instrument_terms"] else "none"),
        f"catalogue effects: {', '.join(d['effects']) if d['effects'] else 'none'}",
        f"sphere-centre error [mm] {_rows_said(d)}: before (geometric model) {_err(d['before'])}; "
        f"after (extended model) {_err(d['after'])}",
    ]
    return "\n".join(lines)


def diagnosis_markdown(d: Mapping[str, Any]) -> str:
    """The diagnosis' verdict as a Markdown document (the recording's ``diagnosis/verdict``)."""
    lines = ["# Diagnosis of the campaign's dataset", "",
             f"* residual of the geometric model: **{'structured' if d['structured'] else 'not structured'}** "
             f"(p = {d['p_value']:.3g}, alpha = {d['alpha']:g}), noise floor {d['noise_floor_mm']:.5f} mm per coordinate",
             f"* robot terms: **{'; '.join(d['robot_terms']) if d['robot_terms'] else 'none'}**",
             f"* instrument terms (the measurement side): {'; '.join(d['instrument_terms']) if d['instrument_terms'] else 'none'}",
             f"* sphere-centre error {_rows_said(d)}, before (geometric model): {_err(d['before'])} mm",
             f"* after (extended model): {_err(d['after'])} mm"]
    if d.get("notes"):
        lines += ["", "## Notes", ""] + [f"* {n}" for n in d["notes"]]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------
# figures and recording
# ------------------------------------------------------------------------------------------------

def figures(out: Path, evals, cfg) -> dict[str, Path]:
    """Figure 10 (the separation method before and after) and Figure 11 (every method after) in the paper's
    style, measured; for the real-robot protocol ``figure13_15.png`` and ``methods_after.png``."""
    files: dict[str, Path] = {}
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
            cat(ev, "angle", "measured_before", angle_pairs) * DEG_PER_RAD, cat(ev, "angle", "measured_after", angle_pairs) * DEG_PER_RAD,
            cat(ev, "position", "measured_before", pos_pairs) * MM_PER_M, cat(ev, "position", "measured_after", pos_pairs) * MM_PER_M,
            np.concatenate([p.distance for p in pos_pairs]),
            method_label=main, title=f"{cfg.name}: before and after compensation ({main}), measured",
        )
    methods = [m for m in evals if m != "before"]
    if len(methods) > 1 and angle_pairs and pos_pairs:
        files[name11] = plot_figure11(
            out / f"{name11}.png",
            {m: cat(evals[m], "angle", "measured_after", angle_pairs) * DEG_PER_RAD for m in methods},
            {m: cat(evals[m], "position", "measured_after", pos_pairs) * MM_PER_M for m in methods},
            title=f"{cfg.name}: methods after compensation, measured",
        )
    return files


def _residual_series(evals) -> dict[int, dict[str, float]]:
    """The measured residuals at the end pose of every evaluated motion, per method (``before`` once)."""
    series: dict[int, dict[str, float]] = {}
    for m, ev in evals.items():
        for p in ev.pairs:
            for d, scale, unit in ((p.angle, DEG_PER_RAD, "angle_deg"), (p.position, MM_PER_M, "position_mm")):
                for key, vals in d.items():
                    src, phase = key.split("_")
                    if src != "measured":
                        continue
                    name = "before" if phase == "before" else m
                    for pid, v in zip(p.pose_id_end, vals):
                        series.setdefault(int(pid), {})[f"residuals/{name}/{unit}"] = float(v) * scale
    return series


def recording(path: Path, state, store) -> Path:
    """The campaign's Rerun recording (``twin.evaluation.recording``, layout in ``docs/runner.md``): stations,
    the nominal, true and calibrated robots, images, measured centres, residuals per pose, the log and, when the
    diagnose stage ran, its verdict."""
    from ..evaluation import recording as rec_mod  # the only module that imports rerun

    cfg, plan = state.cfg, state.plan
    images_mode = cfg.outputs.recording_images
    views = []
    for name, st in state.stations_truth.items():
        cams = tuple(rec_mod.CameraView(cn, T, K) for cn, (T, K) in st.cameras.items())
        views.append(rec_mod.StationView(name, invert_transform(st.base2meas), cams))
    models = {"nominal": cfg.nominal_model().with_frames(base2meas=np.eye(4)),
              "true": state.true_robot.with_frames(base2meas=np.eye(4))}
    models.update({f"calibrated/{m}": r.robot.with_frames(base2meas=np.eye(4)) for m, r in state.methods.items()})
    series = _residual_series(state.evaluation)
    with rec_mod.CampaignRecording(path, application_id="twin-campaign", recording_id=f"{cfg.name}-{cfg.seed}",
                                   methods=list(state.methods), lossless=cfg.outputs.recording_lossless,
                                   jpeg_quality=cfg.outputs.jpeg_quality, diagnosis=state.diagnosis is not None) as rec:
        rec.log_stations(views)
        if state.diagnosis is not None:
            rec.log_diagnosis(diagnosis_markdown(state.diagnosis))
        for m, ids in state.not_converged.items():
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
                for m in state.after:
                    ra = state.after[m].get(pid)
                    if ra is None:
                        continue
                    ra = store.read(ra.key, with_images=True)
                    if ra.images:
                        rec.log_images({f"compensated_{m}_{c}": b for c, b in ra.images.items()}, image_format=ra.image_format)
    return path
