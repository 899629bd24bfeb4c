"""Rates over seeds of the diagnosis' judging on configurations -> the ``diagnosis_configurations`` section of
results/benchmark.json.

The rules (:mod:`twin.diagnosis.configurations`): a harmonic above the order its joint's sampling supports is not
offered, and a term of joint angles must also predict folds of its joints' values it was not fitted on. Each case is
a simulated campaign (``tests/_diagnosis_helpers.py``: the grid campaign and the random-pose one of the diagnosis
tests), diagnosed with the rules and, for the grid cases, with each rule switched off (the code before them), over
``--seeds`` seeds:

* ``alias_trap``: joint 1 on a 5 deg grid over [-40, 40] deg (alias frequency 72: orders 36 and above are not told
  apart from lower ones there) turns by ``0.01 deg sin(6 q1 + 0.7)``: 1.3 periods over the range, an order the scan
  does not offer (fewer than 1.5 periods), whose aliases 66, 78, 138, 150 take the same values at every grid
  value. Recorded: whether a harmonic of joint 1 above 35 is kept, and the RMS of the model in use on the report
  rows (at the grid's values) and between the grid's values (joint 1 drawn over its range; noise-free truth).
* ``true_harmonic``: the same grid, ``0.01 deg sin(11 q1 + 0.7)`` (within the bound): kept, with its order.
* ``rough_pattern``: the same grid, joint 1 off by a value of its own in each 1 deg cell of its angle (``N(0, 0.01
  deg)``): a function of the configuration rougher than the grid's step, whose values at the grid's values say
  nothing of the cells between them: whether a harmonic of joint 1 is kept, and the RMS at and between the values.
* ``random_harmonic``: random poses (no grid), ``0.01 deg sin(40 q4 + 0.3)`` on joint 4: kept (the rules must not
  kill a true term where the sampling resolves it).

    python experiments/bench_configurations.py [--seeds 10]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from twin.runtime import set_process_defaults  # noqa: E402

set_process_defaults()  # one BLAS thread before numpy loads (2 shared cores)

import numpy as np  # noqa: E402

sys.path.insert(0, str(ROOT / "tests"))
import _diagnosis_helpers as H  # noqa: E402  (the synthetic generators of the diagnosis tests)

import twin.diagnosis.diagnose  # noqa: E402,F401  (the module, for switching a rule off)
from twin.benchio import provenance, update_benchmark_section  # noqa: E402
from twin.diagnosis import diagnose  # noqa: E402
from twin.units import RAD_PER_DEG  # noqa: E402

SECTION = "diagnosis_configurations"
AMP = 0.01 * RAD_PER_DEG  # [rad]
DIAGNOSE = sys.modules["twin.diagnosis.diagnose"]
RULE = sys.modules["twin.diagnosis.rule"]


def _joint1(order: float, phase: float = 0.7):
    def eff(q):
        out = q.copy()
        out[:, 0] += AMP * np.sin(order * q[:, 0] + phase)
        return out
    return eff


def _rough_pattern(seed: int):
    """Joint 1 off by a value of its own (N(0, 0.01 deg)) in each 1 deg cell of its angle: a function of the
    configuration rougher than the grid's step, so that the grid's values say nothing of the cells between them."""
    off = np.random.default_rng(500 + seed).normal(0.0, AMP, 400)

    def eff(q):
        out = q.copy()
        out[:, 0] += off[np.floor(q[:, 0] / RAD_PER_DEG + 0.5).astype(int) + 200]
        return out
    return eff


def _orders(res, joint: int) -> list[float]:
    """Harmonic orders of ``joint`` among the model's kept terms."""
    out = []
    for a in res.atoms:
        for f in a.get("features", []):
            if f.get("kind") in ("sin", "cos") and f.get("ch") == f"q{joint}":
                out.append(float(f["k"]))
    return sorted(set(out))


class _Rules:
    """Switch the order bound and/or the fold check off (the code before them) for one diagnosis."""

    def __init__(self, bound: bool = True, folds: bool = True):
        self.bound, self.folds = bound, folds

    def __enter__(self):
        self.saved = DIAGNOSE.offered, RULE.confirm_configurations
        if not self.bound:
            DIAGNOSE.offered = lambda features, sampling: True
        if not self.folds:
            RULE.confirm_configurations = lambda *args: None
        return self

    def __exit__(self, *exc):
        DIAGNOSE.offered, RULE.confirm_configurations = self.saved


def _grid_record(seed: int, effect, rules: _Rules) -> dict:
    ds, truth = H.grid_dataset(seed=seed, effect=effect)
    t = time.process_time()
    with rules:
        res = diagnose(ds)
    cpu = time.process_time() - t
    return {"seed": seed, "orders_joint1": _orders(res, 1), "model": res.model_in_use,
            "report_rms_mm": res.after["position_mm"]["rms"],
            "between_rms_mm": H.between_grid_rms(res.calibration, truth, seed=seed),
            "max_order_joint1": res.sampling["joints"][0]["max_order"], "cpu_s": round(cpu, 2)}


def _random_record(seed: int) -> dict:
    def eff(q, model):
        out = q.copy()
        out[:, 3] += AMP * np.sin(40 * q[:, 3] + 0.3)
        return out
    rng = np.random.default_rng(700 + seed)
    m = 200
    ds, _ = H.make_dataset(seed=seed, n=160, effect=eff, t_s=np.cumsum(rng.uniform(8, 12, m)))
    t = time.process_time()
    res = diagnose(ds)
    return {"seed": seed, "orders_joint4": _orders(res, 4), "cpu_s": round(time.process_time() - t, 2),
            "z_configurations": [s.z_configurations for s in res.scores if "40" in s.name and s.decision == "kept"]}


def _rate(records: list[dict], pred) -> str:
    return f"{sum(bool(pred(r)) for r in records)}/{len(records)}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    a = ap.parse_args(argv)
    if a.seeds < 1:
        ap.error(f"--seeds must be >= 1, got {a.seeds}")
    seeds = range(a.seeds)
    out: dict = {"seeds": a.seeds, "cases": {}}
    above = lambda r: any(k > 35 for k in r["orders_joint1"])  # noqa: E731
    for name, eff, arms in (
            ("alias_trap", lambda s: _joint1(6), {"rules": _Rules(), "without_order_bound": _Rules(bound=False)}),
            ("true_harmonic", lambda s: _joint1(11), {"rules": _Rules(), "without_order_bound": _Rules(bound=False)}),
            ("rough_pattern", _rough_pattern, {"rules": _Rules(), "without_fold_check": _Rules(folds=False)})):
        case = {}
        for arm, rules in arms.items():
            recs = [_grid_record(s, eff(s), rules) for s in seeds]
            case[arm] = {"records": recs,
                         "harmonic_of_joint1_above_35_kept": _rate(recs, above),
                         "any_harmonic_of_joint1_kept": _rate(recs, lambda r: r["orders_joint1"]),
                         "order_11_kept": _rate(recs, lambda r: 11.0 in r["orders_joint1"]),
                         "median_report_rms_mm": float(np.median([r["report_rms_mm"] for r in recs])),
                         "median_between_rms_mm": float(np.median([r["between_rms_mm"] for r in recs])),
                         "median_cpu_s": float(np.median([r["cpu_s"] for r in recs]))}
            print(name, arm, {k: v for k, v in case[arm].items() if k != "records"}, flush=True)
        out["cases"][name] = case
    recs = [_random_record(s) for s in seeds]
    out["cases"]["random_harmonic"] = {"rules": {
        "records": recs, "order_40_kept": _rate(recs, lambda r: 40.0 in r["orders_joint4"]),
        "median_cpu_s": float(np.median([r["cpu_s"] for r in recs]))}}
    print("random_harmonic", out["cases"]["random_harmonic"]["rules"]["order_40_kept"], flush=True)
    out["provenance"] = provenance()
    out["note"] = ("rates over seeds of simulated campaigns (tests/_diagnosis_helpers.py); between_rms_mm: the model "
                   "in use on rows whose joint 1 lies between its grid's values, against the noise-free truth")
    update_benchmark_section(SECTION, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
