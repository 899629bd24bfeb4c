"""The UR5 laser-tracker study: does `twin diagnose`'s extended model hold on a later block of time?

Run from the repository root::

    .venv/bin/python studies/ur5_laser_tracker/run.py

It imports the committed grid (``data/ur5_laser_tracker``, its column map) into ``work/`` (git-ignored), diagnoses
it with the defaults as the map gives it (the last 25 % of the rows held out), with every 4th row marked
``validation`` (interleaved: the diagnosis holds out the same share at the end instead, and says so) and without a
``set`` column (the last 30 %), and writes ``results/results.json`` (with its ``provenance``) and
``results/table.md``: the geometric and the extended model on the diagnosis' report block (the last rows, used
for nothing else) and on its confirmation block, and every kept term.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from twin.runtime import set_process_defaults

set_process_defaults()  # one BLAS thread before numpy loads (twin.runtime)

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(HERE.parent))

from real_sessions import diagnosis_record, table_rows  # noqa: E402

from twin.benchio import atomic_write_text, provenance  # noqa: E402
from twin.dataset import read_dataset  # noqa: E402
from twin.importers import import_columns  # noqa: E402

MAP = ROOT / "data" / "ur5_laser_tracker" / "ur5_grid.toml"


def main() -> int:
    work = HERE / "work"
    import_columns(MAP, work / "dataset")
    ds = read_dataset(work / "dataset")
    every4 = np.where(np.arange(ds.n) % 4 == 3, "validation", "calibration").astype(object)
    variants = {
        "the map's set: the last 25 % of the rows": ds,
        "every 4th row marked validation (moved to the end by the diagnosis)": replace(ds, set=every4),
        "no set column (the diagnosis holds out the last 30 %)": replace(ds, set=None),
    }
    runs = {name: diagnosis_record(v, work / f"diagnosis_{k}") for k, (name, v) in enumerate(variants.items())}
    out = {"provenance": provenance(), "dataset": str(MAP.relative_to(ROOT)), "rows": int(ds.n), "runs": runs}
    (HERE / "results").mkdir(exist_ok=True)
    atomic_write_text(HERE / "results" / "results.json", json.dumps(out, indent=1) + "\n")
    lines = ["# UR5 laser tracker: the extended model on later blocks of time", "",
             "3-D error of the tool point [mm], mean / RMS / max; `twin diagnose` with default options.", ""]
    lines += table_rows(runs)
    (HERE / "results" / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
