"""Every blind campaign of the five generators (studies/blind): `twin diagnose` against its answer key.

The generators (`studies/blind/generators/generator_a` .. `generator_e`) were written by other sessions from the
public documentation only (they do not import `twin`); the diagnosis was then improved on what they exposed, so
these campaigns are a regression guard, not an exam (the exam scores are the first passes in
`studies/blind/results/`). Each campaign is found by its answer key's name and checked against the targets of its
category, on the diagnosis' report rows (held out and used for nothing else) and on the rows measured after the
campaign: clean -> no structure, no name; catalogue and mixed -> structured, every effect traced, exactly the
key's names, after <= 1.2x the oracle; outside -> structured, traced, no catalogue name, after <= 1.5x; every
effect category <= 1.5x the oracle after the campaign. A campaign that misses a target today is a strict xfail
(KNOWN_MISSES, with the target it misses): when it is fixed the test fails until it is taken off the list.
Campaigns whose extended model reads the order of the moves, a lagged temperature, the motion heat or the row
order also predict every held-out row alone as inside the whole file (except rows flagged as lacking history).
The suite runs every 24th campaign of each batch (``SUITE_EVERY``) as a regression, and its generators write only
those (``--names``); the rate benchmark (``experiments/bench_diagnosis_rates.py``, ``TWIN_FULL_RATES=1``) and
``studies/blind/run.py`` run all of them.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

STUDY = Path(__file__).resolve().parent.parent / "studies" / "blind"
sys.path.insert(0, str(STUDY))
from _diagnosis_helpers import FULL_RATES  # noqa: E402
from _shared import build_if_unclaimed, built_once  # noqa: E402
from blind_scoring import alone_and_in_file, score_campaign  # noqa: E402
from run import GENERATORS  # noqa: E402

from twin.dataset import read_joints_csv  # noqa: E402


def _campaigns():
    """(generator, the key's name, category) of every campaign the committed scores list."""
    out = []
    for gen in GENERATORS:
        res = json.loads((STUDY / "results" / f"batch{gen.upper()}" / "results.json").read_text())
        out += [(gen, c["key_name"], c["category"]) for c in res["campaigns"]]
    return out


CAMPAIGNS = _campaigns()
# campaigns that miss a target with the current diagnosis (studies/blind/results): (generator, key name) -> the
# targets missed
KNOWN_MISSES: dict[tuple[str, str], str] = {
    ('a', 'hA11'): "not traced; extra names ['cyclic', 'tilt']; named ['tilt', 'cyclic']",
    ('a', 'hA15'): "extra names ['backlash']; named ['backlash'] (the key's settling in proportion to the last move is the law of a backlash growing with the last move)",
    ('a', 'hA18'): 'not traced',
    ('a', 'hA19'): "not traced; extra names ['compliance']; named ['compliance']",
    ('b', 'b04'): 'not traced; later rows after/oracle 2.06 > 1.5',
    ('b', 'b12'): 'not structured; report after/oracle 3.08 > 1.5; later rows after/oracle 4.59 > 1.5',
    ('b', 'b22'): "not traced; extra names ['tilt']; named ['tilt']",
    ('c', 'c02'): "named [] not ['cyclic']",
    ('c', 'c05'): 'not structured; report after/oracle 3.84 > 1.5; later rows after/oracle 4.47 > 1.5',
    ('c', 'c06'): "extra names ['cyclic']; named ['compliance', 'cyclic'] not ['compliance']; report after/oracle 2.05 > 1.2; later rows after/oracle 2.31 > 1.5",
    ('c', 'c08'): 'report after/oracle 3.00 > 1.5; later rows after/oracle 2.37 > 1.5',
    ('c', 'c09'): "extra names ['compliance']; named ['backlash', 'compliance'] not ['backlash']; report after/oracle 1.44 > 1.2 (a payload window of joint 4's compliance beside the backlash)",
    ('c', 'c16'): 'report after/oracle 3.18 > 1.5; later rows after/oracle 2.54 > 1.5',
    ('c', 'c17'): 'structured (a false alarm)',
    ('c', 'c23'): "extra names ['plate_geometry']; named ['plate_geometry']; later rows after/oracle 1.66 > 1.5",
    ('c', 'c29'): 'later rows after/oracle 1.56 > 1.5',
    ('d', 'd04'): "not traced; extra names ['tilt']; named ['tilt']; report after/oracle 2.03 > 1.5; later rows after/oracle 2.39 > 1.5",
    ('d', 'd06'): "extra names ['compliance', 'cyclic'] (a plate sagging with the direction of gravity read as a payload hung on at the campaign's start, a harmonic beside it)",
    ('d', 'd09'): "not structured; named [] not ['cyclic']",
    ('d', 'd14'): "not traced; extra names ['thermal']; named ['thermal'] not ['compliance']",
    ('d', 'd18'): "not structured; named [] not ['compliance']",
    ('d', 'd25'): "not traced; extra names ['compliance']; named ['backlash', 'compliance'] not ['backlash']",
    ('d', 'd26'): 'report after/oracle 1.71 > 1.5; later rows after/oracle 3.36 > 1.5',
    ('d', 'd27'): "extra names ['backlash']; named ['plate_geometry', 'backlash'] not ['plate_geometry'] (the ringing arm's lag in proportion to the last step read as a backlash growing with the last move on joint 5, tanh at 58 deg)",
    ('d', 'd28'): 'report after/oracle 1.40 > 1.2',
    ('d', 'd30'): 'not traced',
    ('e', 'e09'): "not traced; extra names ['cyclic']; named ['coupling', 'cyclic'] not ['coupling']",
    ('e', 'e10'): "extra names ['cyclic']; named ['cyclic']",
    ('e', 'e13'): 'report after/oracle 2.09 > 1.5; later rows after/oracle 1.92 > 1.5',
    ('e', 'e19'): "extra names ['tilt']; named ['tilt']",
}


SUITE_EVERY = 24  # the suite runs every 24th campaign of each batch as a regression; the rate benchmark all of them


def _params():
    out = []
    seen: dict[str, int] = {}  # campaigns of each batch so far
    for gen, name, cat in CAMPAIGNS:
        k = seen[gen] = seen.get(gen, -1) + 1
        if not FULL_RATES and k % SUITE_EVERY:
            continue
        marks = [pytest.mark.xfail(strict=True, reason=KNOWN_MISSES[(gen, name)])] if (gen, name) in KNOWN_MISSES else []
        out.append(pytest.param(gen, name, cat, marks=marks, id=f"{gen}-{name}"))
    return out


PARAMS = _params()


def _builder(gen: str):
    """Writes generator ``gen``'s campaigns this session runs (``--names``; every one under ``FULL_RATES``): a
    campaign's bytes depend on the batch's seed and its name only, not on which others are written beside it."""
    names = [p.values[1] for p in PARAMS if p.values[0] == gen]

    def build(out: Path) -> None:
        subset = [] if FULL_RATES else ["--names", *names]
        subprocess.run([sys.executable, str(STUDY / "generators" / f"generator_{gen}" / "make_all.py"), "--out",
                        str(out), "--seed", str(GENERATORS[gen]), *subset], check=True, capture_output=True)

    return build


def _batch(tmp_path_factory, gen: str) -> Path:
    """Generator ``gen``'s batch, written once per test session and shared by the test workers; a worker that finds
    another writing it writes the next batch nobody has claimed meanwhile."""
    def next_batch() -> None:
        for other in list(GENERATORS)[list(GENERATORS).index(gen) + 1:]:
            if build_if_unclaimed(tmp_path_factory, f"blind-batch{other.upper()}", _builder(other)):
                return

    return built_once(tmp_path_factory, f"blind-batch{gen.upper()}", _builder(gen), meanwhile=next_batch)


def _folder(batch: Path, name: str) -> Path:
    found = [p.parent.parent for p in batch.glob("*/key/key.json") if json.loads(p.read_text()).get("name") == name]
    assert len(found) == 1, f"{batch.name}: {len(found)} campaigns named {name!r}"
    return found[0]


ORDERED = ("sign", "play", "lastmove", "stepin", "cartdir", "lag", "heat")


@pytest.mark.slow
@pytest.mark.parametrize("gen,name,category", PARAMS)
def test_blind_campaign_meets_its_category_targets(tmp_path_factory, tmp_path, gen, name, category):
    """The diagnosis meets the targets of the campaign's category (module docstring), and a held-out row predicted
    alone reads what it reads inside the whole file."""
    folder = _folder(_batch(tmp_path_factory, gen), name)
    r = score_campaign(folder, tmp_path, in_process=True)
    assert "error" not in r, r.get("error")
    assert r["category"] == category
    v, t = r["report"], r["test"]
    if category == "clean":
        assert not r["structured"] and r["effects"] == [], (r["effects"], r["terms"])
    else:
        assert r["structured"] and r["trace"]["all_traced"], r["terms"]
        assert r["extra_names"] == [], (r["expected_names"], r["effects"])
        if category in ("catalogue", "mixed"):
            assert r["named_right"], (r["expected_names"], r["effects"])
            assert v["after_over_oracle"] <= 1.2, v
        else:
            assert r["effects"] == [], r["effects"]
            assert v["after_over_oracle"] <= 1.5, v
        # the rows measured after the campaign (the effect continuing in time, the workspace wider)
        assert t["after_over_oracle"] <= 1.5, t
    # prediction does not depend on which other rows are in the file (a row alone, inside the whole sequence)
    cal = json.loads((tmp_path / "diagnosis" / "calibration.json").read_text())
    feats = [f for e in cal.get("effects", []) for f in e["features"]]
    if any(f.get("kind") in ORDERED or f.get("ch") == "row" for f in feats):
        joints = read_joints_csv(tmp_path / "sequence_joints.csv")
        d = json.loads((tmp_path / "diagnosis" / "diagnosis.json").read_text())
        held = np.isin(joints.pose_id, d["rows"]["confirmation"] + d["rows"]["report"])
        got = alone_and_in_file(tmp_path / "diagnosis" / "calibration.json", joints, np.flatnonzero(held))
        same = np.all(np.abs(np.nan_to_num(got["alone"] - got["in_file"])) < 1e-9, axis=(1, 2))
        assert np.all(same | got["flagged"]), f"{int(np.sum(~same & ~got['flagged']))} rows differ unflagged"
        if not any(f.get("kind") in ORDERED[:5] for f in feats):
            assert not got["flagged"].any()  # no order-dependent term: nothing to flag


@pytest.mark.slow
@pytest.mark.parametrize("gen", list(GENERATORS))
def test_a_campaign_written_alone_is_the_campaign_its_batch_holds(tmp_path_factory, tmp_path, gen):
    """A generator's campaign written alone (``--names``) has the bytes of the same campaign written with the others
    of the session's batch: the suite may write only the campaigns it runs."""
    batch = _batch(tmp_path_factory, gen)
    name = [p.values[1] for p in PARAMS if p.values[0] == gen][-1]
    subprocess.run([sys.executable, str(STUDY / "generators" / f"generator_{gen}" / "make_all.py"), "--out",
                    str(tmp_path), "--seed", str(GENERATORS[gen]), "--names", name], check=True, capture_output=True)
    together, alone = _folder(batch, name), _folder(tmp_path, name)
    files = sorted(p.relative_to(together) for p in together.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(alone) for p in alone.rglob("*") if p.is_file())
    assert all((together / f).read_bytes() == (alone / f).read_bytes() for f in files)
