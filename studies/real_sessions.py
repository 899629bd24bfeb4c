"""What the real-robot studies share: one diagnosis of a real campaign, recorded on its blocks of time, and its
rows in a markdown table. (Imported by the studies' scripts; not part of ``twin``.)"""

from __future__ import annotations

from pathlib import Path

from twin.diagnosis import diagnose, write_diagnosis
from twin.diagnosis.report import blocked_summary


def diagnosis_record(ds, out: Path, blocks: dict | None = None, **options) -> dict:
    """``twin diagnose``'s result on ``ds`` (written to ``out``) as :func:`twin.diagnosis.report.blocked_summary`
    gives it, on its confirmation and report blocks and the further named ``blocks``."""
    res = diagnose(ds, **options)
    write_diagnosis(res, out, plots=False)
    return blocked_summary(res, ds, blocks)


def _fmt(e: dict) -> str:
    p = e["position_mm"]
    return f"{p['mean']:.3f} / {p['rms']:.3f} / {p['max']:.3f}"


def table_rows(runs: dict) -> list[str]:
    """Markdown rows: per run and block, the geometric and the extended model's errors, their RMS ratio, the model
    in use and the terms."""
    out = ["| hold-out | block | rows | geometric | extended | extended / geometric (RMS) | model to use |",
           "|---|---|---|---|---|---|---|"]
    for name, r in runs.items():
        for block, e in r["errors"].items():
            out.append(f"| {name} | {block} | {e['n_rows']} | {_fmt(e['geometric'])} | {_fmt(e['extended'])} | "
                       f"{e['rms_ratio']:.3f} | {r['model_in_use']} |")
    for name, r in runs.items():
        out += ["", f"**{name}**: {r['held_out_rows']}; {r['blocks_rule']}.", ""]
        out += [f"* {t['text']}" + (" (minor)" if t["minor"] else "") for t in r["terms"]] or ["* no term"]
    return out
