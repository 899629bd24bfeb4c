"""Per instance, what a run of drawn sets moved against another run of the same seeds: the instances whose outcome, rows
after the campaign or named families changed, and each set's totals before and after.

    python -m studies.drawn.compare studies/drawn/results_300 [...]              # against the committed files (HEAD)
    python -m studies.drawn.compare studies/drawn/results_300 --against REV      # against a commit's files
    python -m studies.drawn.compare NEW_FOLDER --old OLD_FOLDER                   # two folders (a scratch run)

An instance *holds* as the tables count it (``studies/drawn/tables.py``): a family's instance named right with its rows
after the campaign within 1.2x the oracle (a clean one: no alarm, and its later rows within 1.2x); a campaign of several
effects named right with its later rows within its goal. An instance moved when it holds on one side only, when its
later rows' after/oracle changed by more than ``--ratio-tol`` (relative, default 2 %), or when the families it names
changed (not their order). A change to what the diagnosis computes is judged on every set with this list: which
instances moved, which way, and the net.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Moved", "SetComparison", "holds", "compare", "main"]

ROOT = Path(__file__).resolve().parents[2]


def holds(instance: dict) -> bool:
    """Whether an instance of a results.json holds (the module docstring): named right and its rows after the campaign
    within 1.2x the oracle, within its goal for a campaign of several effects; an instance that failed never holds."""
    if "error" in instance:
        return False
    test = instance.get("test") or {}
    within = test.get("within_goal") if instance.get("category") == "mixed" else test.get("within_1.2")
    return bool(instance.get("named")) and bool(within)


def _later(instance: dict) -> float | None:
    """The rows after the campaign's after/oracle (None where the instance failed or has none)."""
    return (instance.get("test") or {}).get("after_over_oracle")


@dataclass(frozen=True)
class Moved:
    """One instance that moved: its name, whether it held before and after, its later rows' after/oracle before and
    after (None: not scored) and its named families before and after."""
    name: str
    held_before: bool
    held_after: bool
    later_before: float | None
    later_after: float | None
    effects_before: tuple[str, ...]
    effects_after: tuple[str, ...]

    def line(self) -> str:
        def r(x):
            return "-" if x is None else f"{x:.2f}x"
        fam = "" if sorted(self.effects_before) == sorted(self.effects_after) else \
            f"  named {list(self.effects_before)} -> {list(self.effects_after)}"
        return (f"{self.name:24s} holds {str(self.held_before):5s} -> {str(self.held_after):5s}  later rows "
                f"{r(self.later_before)} -> {r(self.later_after)}{fam}")


@dataclass(frozen=True)
class SetComparison:
    """A set's comparison: the instances of both runs (by name), the effect instances among them (not clean) and how
    many of those held before and after (the tables' totals), the clean instances' alarms before and after, the
    instances in one run only, and those that moved (clean ones included)."""
    n: int
    n_effect: int
    held_before: int
    held_after: int
    alarms_before: int
    alarms_after: int
    only_one_side: tuple[str, ...]
    moved: tuple[Moved, ...]


def _instances(results: dict, what: str) -> dict[str, dict]:
    if not isinstance(results, dict) or not isinstance(results.get("instances"), list):
        raise ValueError(f"{what}: not a drawn set's results.json (no 'instances' list)")
    bad = next((k for k, i in enumerate(results["instances"]) if not isinstance(i, dict) or "name" not in i), None)
    if bad is not None:
        raise ValueError(f"{what}: instances[{bad}] has no 'name'")
    return {i["name"]: i for i in results["instances"]}


def _parse(text: str, what: str) -> dict:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{what}: not JSON ({exc})") from None


def compare(old: dict, new: dict, *, ratio_tol: float = 0.02) -> SetComparison:
    """The instances of ``new`` (a results.json's content) against those of ``old`` of the same names: totals and the
    instances that moved (the module docstring), in name order. ``ratio_tol``: the relative change of the later rows'
    after/oracle that counts as a move."""
    if not (isinstance(ratio_tol, (int, float)) and math.isfinite(ratio_tol) and ratio_tol >= 0):
        raise ValueError(f"ratio_tol must be a finite number >= 0, got {ratio_tol!r}")
    a, b = _instances(old, "old"), _instances(new, "new")
    both = sorted(set(a) & set(b))
    moved = []
    for k in both:
        o, n = a[k], b[k]
        ro, rn = _later(o), _later(n)
        ratio_moved = (ro is None) != (rn is None) or (
            ro is not None and rn is not None and abs(rn - ro) > ratio_tol * max(abs(ro), 1e-12))
        eo, en = tuple(o.get("effects") or ()), tuple(n.get("effects") or ())
        if holds(o) != holds(n) or ratio_moved or sorted(eo) != sorted(en):
            moved.append(Moved(k, holds(o), holds(n), ro, rn, eo, en))

    effect = [k for k in both if b[k].get("category") != "clean"]

    def alarms(side: dict) -> int:
        return sum(1 for k in both if side[k].get("category") == "clean" and "error" not in side[k]
                   and not side[k].get("named"))
    return SetComparison(len(both), len(effect), sum(holds(a[k]) for k in effect), sum(holds(b[k]) for k in effect),
                         alarms(a), alarms(b), tuple(sorted(set(a) ^ set(b))), tuple(moved))


def _read_new(folder: Path) -> dict:
    p = folder / "results.json"
    if not p.is_file():
        raise ValueError(f"new run {folder}: no results.json there")
    return _parse(p.read_text(), str(p))


def _read_old(folder: Path, old: Path | None, against: str) -> dict:
    if old is not None:
        p = old / "results.json"
        if not p.is_file():
            raise ValueError(f"--old {old}: no results.json there")
        return _parse(p.read_text(), str(p))
    rel = (folder.resolve() / "results.json").relative_to(ROOT).as_posix() \
        if folder.resolve().is_relative_to(ROOT) else None
    if rel is None:
        raise ValueError(f"new run {folder}: outside the repository; name the other run with --old")
    try:
        got = subprocess.run(["git", "show", f"{against}:{rel}"], cwd=ROOT, capture_output=True, text=True)
    except OSError as exc:
        raise ValueError(f"--against {against}: git cannot be run here ({exc}); name the other run with --old") \
            from None
    if got.returncode != 0:
        raise ValueError(f"--against {against}: no {rel} in that commit ({got.stderr.strip()})")
    return _parse(got.stdout, f"{against}:{rel}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("new", nargs="+", type=Path, help="folders of the new run, each with its results.json")
    ap.add_argument("--against", default="HEAD", help="the commit whose files of the same folders are the old run")
    ap.add_argument("--old", type=Path, default=None, help="the old run's folder instead (one new folder)")
    ap.add_argument("--ratio-tol", type=float, default=0.02,
                    help="relative change of the later rows' after/oracle that counts as a move (default 0.02)")
    args = ap.parse_args(argv)
    if args.old is not None and len(args.new) != 1:
        ap.error(f"--old compares one new folder, got {len(args.new)}")
    n = ne = hb = ha = ab = aa = 0
    try:
        for folder in args.new:
            c = compare(_read_old(folder, args.old, args.against), _read_new(folder), ratio_tol=args.ratio_tol)
            one = c.only_one_side
            print(f"{folder}: {c.n} instances in both runs; of the {c.n_effect} with an effect holding "
                  f"{c.held_before} -> {c.held_after}; clean alarms {c.alarms_before} -> {c.alarms_after}"
                  + (f"; in one run only: {len(one)}" + (f" ({', '.join(one)})" if len(one) <= 10 else "")
                     if one else ""))
            for m in c.moved:
                print("  " + m.line())
            n, ne, hb, ha = n + c.n, ne + c.n_effect, hb + c.held_before, ha + c.held_after
            ab, aa = ab + c.alarms_before, aa + c.alarms_after
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if len(args.new) > 1:
        print(f"all: {n} instances; of the {ne} with an effect holding {hb} -> {ha} (net {ha - hb:+d}); clean alarms "
              f"{ab} -> {aa}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
