"""The UR10 laser-tracker study: does `twin diagnose`'s extended model hold on a later block and in another session?

Run from the repository root::

    .venv/bin/python studies/ur10_laser_tracker/run.py [--skip-a]

It imports the committed series (``data/ur10_laser_tracker``, its column maps) into ``work/`` (git-ignored) and
writes ``results/results.json`` (with its ``provenance``) and ``results/table.md``:

1. series A alone (its last 30 % in time held out): `twin diagnose` with default options, the geometric and the
   extended model on the report block (the last rows, used for nothing else) and the confirmation block; then
   series B, months later with the tracker placed elsewhere, as a new session: each model keeps its robot, the
   tracker's frame (and, second, the probe's frame) is registered on B's first 50 rows (`twin register`), and the
   other 1445 rows are predicted, by each model and by the model `twin register` takes for the session (judged on
   those 50 rows, series A's terms that they do not bear out dropped);
2. series A and B in one dataset (``ur10_A_to_B.toml``: A fits, B's first 50 rows register its tracker, B's other
   rows confirm the terms and report): the terms must hold on the other session to be kept.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from twin.runtime import set_process_defaults

set_process_defaults()  # one BLAS thread before numpy loads (twin.runtime)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(HERE.parent))

from real_sessions import diagnosis_record, table_rows  # noqa: E402

from twin.benchio import atomic_write_text, provenance  # noqa: E402
from twin.dataset import read_dataset  # noqa: E402
from twin.estimator import Calibration  # noqa: E402
from twin.diagnosis.apply import new_session_errors  # noqa: E402
from twin.importers import import_columns  # noqa: E402

DATA = ROOT / "data" / "ur10_laser_tracker"


def _fmt(e: dict) -> str:
    p = e["position_mm"]
    return f"{p['mean']:.3f} / {p['rms']:.3f} / {p['max']:.3f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--skip-a", action="store_true", help="keep the committed series-A run (it takes the longest)")
    a = ap.parse_args()
    work = HERE / "work"
    res_path = HERE / "results" / "results.json"
    old = json.loads(res_path.read_text()) if res_path.exists() else {}
    out = {"provenance": provenance(), "runs": dict(old.get("runs", {})), "new_session": old.get("new_session", {}),
           "same_session": old.get("same_session", {})}
    for name in ("series_A", "series_B", "ur10_A_to_B"):
        import_columns(DATA / f"{name}.toml", work / name)
    ds_b = read_dataset(work / "series_B")
    name_a = "series A, its last 30 % in time held out"
    if not a.skip_a:
        ds_a = read_dataset(work / "series_A")
        out["runs"][name_a] = diagnosis_record(ds_a, work / "diagnosis_A")
        geo = Calibration.load(work / "diagnosis_A" / "calibration_geometric.json")
        ext = Calibration.load(work / "diagnosis_A" / "calibration.json")  # the model to use
        out["new_session"] = {f"tool {'re-registered' if tool else 'kept'}": new_session_errors(geo, ext, ds_b, tool=tool)
                              for tool in (False, True)}
        # the same judgement on series A's own first 50 rows (the session the models were fitted on): nothing there
        # should be dropped that the rest of series A bears out
        out["same_session"] = new_session_errors(geo, ext, ds_a)
    ds_ab = read_dataset(work / "ur10_A_to_B")
    out["runs"]["series A fits, series B confirms and reports (its first 50 rows register its tracker)"] = \
        diagnosis_record(ds_ab, work / "diagnosis_AB")
    (HERE / "results").mkdir(exist_ok=True)
    atomic_write_text(res_path, json.dumps(out, indent=1) + "\n")
    lines = ["# UR10 laser tracker: the extended model on a later block and in another session", "",
             "3-D error of the probe's position [mm], mean / RMS / max; `twin diagnose` with default options.", ""]
    lines += table_rows(out["runs"])
    lines += ["", "## Series B as a new session of series A's models", "",
              "Each model keeps its robot; the tracker's frame (and the probe's) registered on B's first 50 rows "
              "(`twin register`), B's other rows predicted.", "",
              "| registration | rows | geometric | extended | extended / geometric (RMS) | model `twin register` takes "
              "(judged on the 50 rows: RMS [mm] of each block predicted by the others' registration) | that model | "
              "its RMS / geometric |", "|---|---|---|---|---|---|---|---|"]
    for k, v in out["new_session"].items():
        e, m = v["rows"], v["session_model"]
        cv = v["cv_position_rms_mm"]
        judged = f"{v['chosen']} ({', '.join(f'{n} {x:.3f}' for n, x in cv.items())})"
        lines.append(f"| base, {k} | {e['n_rows']} | {_fmt(e['geometric'])} | {_fmt(e['extended'])} | "
                     f"{e['rms_ratio']:.3f} | {judged} | {_fmt(m['extended'])} | {m['rms_ratio']:.3f} |")
    if out["same_session"]:
        v = out["same_session"]
        m = v["session_model"]
        lines.append(f"| series A's own first 50 rows (the session the models were fitted on), tool kept | {m['n_rows']} | "
                     f"{_fmt(v['rows']['geometric'])} | {_fmt(v['rows']['extended'])} | {v['rows']['rms_ratio']:.3f} | "
                     f"{v['chosen']} ({', '.join(f'{n} {x:.3f}' for n, x in v['cv_position_rms_mm'].items())}) | "
                     f"{_fmt(m['extended'])} | {m['rms_ratio']:.3f} |")
    for k, v in out["new_session"].items():
        if v["dropped"]:
            lines.append(f"\nTerms `twin register` dropped for session B (base, {k}), in the order dropped: "
                         + "; ".join(v["dropped"]) + ".")
    (HERE / "results" / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
