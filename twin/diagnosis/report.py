"""Writing a diagnosis: ``diagnosis.json`` (the one writer; format in ``docs/formats.md``), the extended and
the geometric-only ``calibration.json`` files, and plots of the residual against the most telling variables."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..units import M_PER_MM
from .apply import STATE_BLOCKS, block_errors, prediction_states
from ..files import read_json
from .candidates import EFFECT_VOCABULARY
from .diagnose import DiagnosisResult
from .structure import StructureTest

__all__ = ["DIAGNOSIS_SCHEMA_VERSION", "diagnosis_dict", "write_diagnosis", "read_diagnosis", "blocked_summary"]

DIAGNOSIS_SCHEMA_VERSION = 2
# the models fitted on the calibration rows only (before/after and the block figures are theirs)
BLOCKED_FILES = {"geometric": "calibration_geometric_blocked.json", "extended": "calibration_blocked.json"}


def _test(t: StructureTest | None) -> dict | None:
    if t is None:
        return None
    return {
        "statistic": t.statistic,
        "dof": t.dof,
        "p_value": t.p_value,
        "distribution": t.distribution,
        "whitened_rms": t.whitened_rms,
    }


def _clean(o: Any) -> Any:
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    if isinstance(o, (np.floating, float)):
        x = float(o)
        return x if math.isfinite(x) else None
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def prediction_states_dict(res: DiagnosisResult, calibration: str = "calibration.json") -> dict[str, Any]:
    """Per block of rows a prediction serves (the report rows, the rows measured after the campaign, a new session),
    the model it uses and the state each of its terms reads (:func:`twin.diagnosis.apply.term_state`)."""
    rep = res.calibrations_blocked.get("extended") if res.held_out.get("before_after_on") == "report" else None
    out = {}
    for block in STATE_BLOCKS:
        cal = res.calibration if block != "report_rows" else (rep if rep is not None else res.calibration)
        model = calibration if block != "report_rows" else BLOCKED_FILES["extended"]
        out[block] = {"model": model, "terms": prediction_states(cal, block) if cal.effects else []}
    return out


def diagnosis_dict(res: DiagnosisResult, calibration: str = "calibration.json",
                   calibration_geometric: str = "calibration_geometric.json") -> dict[str, Any]:
    """The content of ``diagnosis.json``."""
    return _clean({
        "schema_version": DIAGNOSIS_SCHEMA_VERSION,
        "structured": res.structured,
        "p_value": res.p_value,
        "alpha": res.alpha,
        "test": {
            "description": "validation residuals of the geometric fit against the noise floor: "
                           "T = r^T (I + J C J^T)^-1 r (whitened), chi2(m) with a stated floor, "
                           "(T/m) ~ F(m, nu) with a floor from nu repeat degrees of freedom; "
                           "structured when p < alpha (the false-alarm rate)",
            "before": _test(res.test_before),
            "after": _test(res.test_after),
            "rows": "confirmation",
            "report": {"before": _test(res.test_report.get("before")), "after": _test(res.test_report.get("after")),
                       "rows": res.held_out.get("before_after_on", "confirmation")},
        },
        "effects": list(res.effects),
        "explained": res.explained,
        "explained_fraction": res.explained_fraction,
        "vocabulary": list(EFFECT_VOCABULARY),
        "model_in_use": res.model_in_use,
        "adoption": None if res.adoption is None else {k: v for k, v in res.adoption.items() if k != "note"},
        "atoms": list(res.atoms),
        "candidate_terms": list(res.candidate_terms),
        "unnamed": list(res.unnamed),
        "changes": list(res.changes),
        "alternatives": list(res.alternatives),
        "effect_parameters": res.effect_parameters,
        "before": {k: v for k, v in res.before.items() if k in ("position_mm", "orientation_deg", "n_rows")},
        "after": {k: v for k, v in res.after.items() if k in ("position_mm", "orientation_deg", "n_rows")},
        "noise_floor": {
            "position_mm": res.noise.sigma / M_PER_MM,
            "dof": None if math.isinf(res.noise.dof) else res.noise.dof,
            "source": res.noise.source,
            "components": res.noise.components,
        },
        "held_out": res.held_out,
        "sampling": res.sampling,  # [configurations]
        "rows": res.rows,
        "unexplained": res.unexplained,
        "two_groups": res.two_groups,
        "candidates": [
            {
                "round": s.round,
                "name": s.name,
                "dimension": s.dim,
                "delta_chi2_calibration": s.delta_chi2,
                "p_adjusted": s.p_adjusted,
                "z_validation": s.z_validation,
                "z_configurations": s.z_configurations,  # [configurations]
                "decision": s.decision,
            }
            for s in res.scores
        ],
        "calibration": calibration,
        "calibration_geometric": calibration_geometric,
        "calibration_candidate": "calibration_candidate.json" if res.calibration_candidate is not None else None,
        "calibrations_blocked": {k: BLOCKED_FILES[k] for k in res.calibrations_blocked},
        "prediction_states": prediction_states_dict(res, calibration),
        "notes": list(res.notes),
    })


def write_diagnosis(res: DiagnosisResult, out_dir: str | os.PathLike, *, plots: bool = True) -> dict[str, Path]:
    """Write ``diagnosis.json``, ``calibration.json`` (extended; equal to the geometric one when no effect
    explains the residual), ``calibration_geometric.json`` and, with ``plots``, PNG figures."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "calibration": res.calibration.save(out / "calibration.json"),
        "calibration_geometric": res.calibration_geometric.save(out / "calibration_geometric.json"),
    }
    if res.calibration_candidate is not None:
        paths["calibration_candidate"] = res.calibration_candidate.save(out / "calibration_candidate.json")
    for k, c in res.calibrations_blocked.items():
        paths[f"{k}_blocked"] = c.save(out / BLOCKED_FILES[k])
    d = diagnosis_dict(res)
    p = out / "diagnosis.json"
    tmp = p.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(d, indent=2) + "\n")
    os.replace(tmp, p)
    paths["diagnosis"] = p
    if plots:
        paths.update(plot_diagnosis(res, out))
    return paths


def read_diagnosis(path: str | os.PathLike) -> dict[str, Any]:
    """Read ``diagnosis.json``; ``ValueError`` naming the file when it is not one."""
    path = Path(path)
    d = read_json(path)
    if not isinstance(d, dict):
        raise ValueError(f"{path}: not a diagnosis (a JSON object expected)")
    if d.get("schema_version") != DIAGNOSIS_SCHEMA_VERSION:
        raise ValueError(f"{path}: schema_version {d.get('schema_version')!r} is not supported")
    for k in ("structured", "p_value", "effects", "before", "after", "calibration", "calibration_geometric"):
        if k not in d:
            raise ValueError(f"{path}: missing field {k!r}")
    return d


def plot_diagnosis(res: DiagnosisResult, out: Path) -> dict[str, Path]:
    """Residual RMS per validation row against joints, approach direction and time/temperature."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = res.series
    if not s:
        return {}
    before = s["residual_rms_mm_before"]
    after = s["residual_rms_mm_after"]
    floor = res.noise.sigma / M_PER_MM
    paths: dict[str, Path] = {}
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), sharey=True)
    for j, ax in enumerate(axes.flat):
        ax.scatter(s["q_deg"][:, j], before, s=9, label="geometric only", color="tab:red", alpha=0.7)
        if res.atoms:
            ax.scatter(s["q_deg"][:, j], after, s=9, label="extended", color="tab:blue", alpha=0.7)
        ax.axhline(floor, color="k", lw=0.8, ls="--", label="noise floor (per coordinate)")
        ax.set_xlabel(f"q{j + 1} [deg]")
        if j % 3 == 0:
            ax.set_ylabel("validation residual RMS per coordinate [mm]")
    axes.flat[0].legend(fontsize=8)
    names = list(res.effects) + [f"unnamed ({a['channel']} on {a['target']})" for a in res.unnamed]
    title = f"structured={res.structured} (p={res.p_value:.2g}); terms: {', '.join(names) or 'none'}"
    fig.suptitle(title)
    fig.tight_layout()
    p = out / "residual_vs_joints.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    paths["residual_vs_joints"] = p

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    sign = s["approach_sign"]
    for j in range(6):
        for sg, mk in ((-1, "v"), (1, "^")):
            sel = sign[:, j] == sg
            axes[0].scatter(np.full(sel.sum(), j + 1) + 0.15 * sg, before[sel], s=8, marker=mk, alpha=0.6)
    axes[0].set_xlabel("joint (markers: approach direction - / +)")
    axes[0].set_ylabel("residual RMS [mm] (geometric only)")
    if "temp_c" in s or "t_s" in s:
        key = "temp_c" if "temp_c" in s else "t_s"
        axes[1].scatter(s[key], before, s=9, color="tab:red", label="geometric only")
        if res.atoms:
            axes[1].scatter(s[key], after, s=9, color="tab:blue", label="extended")
        axes[1].set_xlabel(key)
        axes[1].legend(fontsize=8)
    else:
        axes[1].plot(before, ".", color="tab:red", label="geometric only")
        if res.atoms:
            axes[1].plot(after, ".", color="tab:blue", label="extended")
        axes[1].set_xlabel("validation row (measurement order)")
        axes[1].legend(fontsize=8)
    axes[1].axhline(floor, color="k", lw=0.8, ls="--")
    fig.tight_layout()
    p = out / "residual_vs_history.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    paths["residual_vs_history"] = p
    return paths


def blocked_summary(res: DiagnosisResult, dataset, blocks: dict | None = None) -> dict[str, Any]:
    """What a diagnosis says on blocks of time: the geometric and the extended model as fitted on the calibration
    rows (``res.calibrations_blocked``; the candidate terms' model when it was not adopted) on the confirmation and
    the report block and on any further named ``blocks`` of ``dataset``'s rows
    (:func:`twin.diagnosis.apply.block_errors`), with how the rows were chosen, the model in use, the adoption
    figures and every term in words."""
    pid = np.asarray(dataset.pose_id)
    named = {"confirmation": np.isin(pid, res.rows.get("confirmation", [])),
             "report": np.isin(pid, res.held_out.get("report_pose_ids", []))}
    named.update(blocks or {})
    blocked = res.calibrations_blocked
    geo = blocked.get("geometric", res.calibration_geometric)
    ext = res.calibration_candidate if res.calibration_candidate is not None else blocked.get("extended", res.calibration)
    terms = [{"text": a["text"], "family": a["family"], "minor": bool(a.get("minor"))}
             for a in (res.atoms or res.candidate_terms)]
    return _clean({"model_in_use": res.model_in_use, "adoption": None if res.adoption is None else
                   {k: v for k, v in res.adoption.items() if k != "note"},
                   "held_out_rows": res.held_out.get("held_out_rows"), "blocks_rule": res.held_out.get("blocks"),
                   "structured": res.structured, "effects": list(res.effects), "terms": terms,
                   "errors": block_errors(geo, ext, dataset, named),
                   "notes": list(res.notes)})
