"""The drawn families' tables in studies/drawn/README.md and docs/diagnosis.md are made from the sets' results."""

import json
import shutil
from pathlib import Path

from studies.drawn.tables import SETS, tables

ROOT = Path(__file__).resolve().parent.parent


def test_the_committed_tables_are_the_ones_the_committed_results_make():
    """Every cell the tables take from a results.json is that file's figure (run `python -m studies.drawn.tables`)."""
    for path, (old, new) in tables().items():
        assert old == new, f"{path.relative_to(ROOT)}: its drawn table differs from the results: run python -m studies.drawn.tables"


def test_a_changed_result_changes_its_cell(tmp_path):
    """One family's count changed in one set's results.json changes both tables (the check can fail)."""
    for rel in ["studies/drawn/README.md", "docs/diagnosis.md"] + [f"studies/drawn/{d}/results.json" for d, _ in SETS]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    p = tmp_path / "studies" / "drawn" / "results_300" / "results.json"
    res = json.loads(p.read_text())
    res["summary"]["compliance"]["named_and_test_within_1.2"] -= 1
    p.write_text(json.dumps(res))
    assert all(old != new for old, new in tables(tmp_path).values())


def test_a_changed_total_changes_its_sets_row_and_not_an_earlier_codes(tmp_path):
    """A set's totals changed in its results.json change that set's row of the README's totals table; the row of an
    earlier code's run on the same seeds stays as written."""
    for rel in ["studies/drawn/README.md", "docs/diagnosis.md"] + [f"studies/drawn/{d}/results.json" for d, _ in SETS]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    p = tmp_path / "studies" / "drawn" / "results_300" / "results.json"
    res = json.loads(p.read_text())
    res["totals"]["named"] -= 1
    p.write_text(json.dumps(res))
    old, new = tables(tmp_path)[tmp_path / "studies" / "drawn" / "README.md"]
    changed = [(a, b) for a, b in zip(old.splitlines(), new.splitlines()) if a != b]
    assert len(changed) == 1 and changed[0][0].startswith("| 300-319 | ")
    assert f"| 300-319 | {res['totals']['named']}/280 |" in changed[0][1]
    assert [ln for ln in old.splitlines() if ln.startswith("| 300-319 with older code")] == \
        [ln for ln in new.splitlines() if ln.startswith("| 300-319 with older code")]
