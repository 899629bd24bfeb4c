"""Regression bands of the campaign statistics (``studies/separation_paper/results/regression.json``).

:func:`bands_from_repeats` turns a Monte-Carlo run (:func:`twin.runner.campaign.run_repeats`) into bands:
for each tracked statistic its mean, sample std, min and max over the seeds, and for each of the paper's
ordering claims the fraction of seeds where it holds. Two band kinds:

* ``minmax`` (:func:`check_against_bands`): a run's statistic inside ``[min(min, mean - k std), max(max,
  mean + k std)]`` of the band seeds. Loose by construction (it contains every band seed): it catches a
  broken pipeline, not a 20 % worsening.
* ``prediction`` (:func:`prediction_band`, :func:`check_prediction`): a one-sided prediction interval for the
  mean of ``n_new`` *new* seeds (seeds not among the band seeds), at ``confidence``. For the after-compensation
  errors (``after.mean`` / ``after.max``, positive and right-skewed) it is built on the log scale: a worsening
  is a factor, and the run fails when ``mean_j log x_j > m + t_{c, n-1} s sqrt(1/n_new + 1/n)`` with ``m``,
  ``s`` the mean and sample std of ``log x`` over the ``n`` band seeds and ``t`` Student's quantile. For the
  improvements (percent) it is linear and lower-sided: ``mean_j x_j < m - t s sqrt(1/n_new + 1/n)``. If the
  code has not changed, the new seeds' mean falls outside with probability ``1 - confidence`` per statistic
  (for normally distributed log errors). :func:`detectable_factor` is the smallest worsening factor that
  a run at the band's typical value fails: ``exp(t s sqrt(1/n_new + 1/n))``.

Tracked statistics (dotted paths into ``results.json``'s ``methods``): for every method, the measured and
true ``angle_deg`` / ``position_mm`` ``before``/``after`` ``mean``, ``max`` and ``std`` and the improvements.
"""

from __future__ import annotations

import datetime as _dt
import math
import fcntl
import json
import os
from pathlib import Path
from typing import Any, Mapping

from ..benchio import atomic_write_text
from ..files import read_json
from .report import clean_json
from .statistics import flatten_numbers

__all__ = ["tracked_statistics", "bands_from_repeats", "check_against_bands", "update_regression_file",
           "PREDICTION_STATISTICS", "prediction_band", "detectable_factor", "check_prediction", "literal_orderings",
           "pairwise_orderings", "check_pairwise", "pooled_after_means"]

def tracked_statistics(methods_summary: Mapping[str, Any]) -> dict[str, float]:
    """The statistics the bands track, from ``results['methods']`` (dotted path -> value)."""
    flat = flatten_numbers(methods_summary)
    out = {}
    for k, v in flat.items():
        parts = k.split(".")
        # <method>.<measured|truth>.<angle_deg|position_mm>.<before|after>.<stat> or ...improvement_percent
        if len(parts) == 5 and parts[2] in ("angle_deg", "position_mm") and parts[3] in ("before", "after") \
                and parts[4] in ("mean", "max", "std"):
            out[k] = v
        elif len(parts) == 4 and parts[2] in ("angle_deg", "position_mm") and parts[3] == "improvement_percent":
            out[k] = v
    return out


def bands_from_repeats(repeats: Mapping[str, Any], command: str, config_name: str) -> dict[str, Any]:
    """Bands of one configuration from a ``run_repeats`` result."""
    per_seed = repeats["per_seed"]
    stats: dict[str, list[float]] = {}
    for r in per_seed:
        for k, v in tracked_statistics(r["methods"]).items():
            stats.setdefault(k, []).append(v)
    import numpy as np

    bands = {}
    for k, vals in sorted(stats.items()):
        a = np.asarray(vals, dtype=float)
        bands[k] = {
            "n": int(a.size), "mean": float(a.mean()), "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
            "min": float(a.min()), "max": float(a.max()),
        }
        if np.all(a > 0):
            la = np.log(a)
            bands[k]["log_mean"] = float(la.mean())
            bands[k]["log_std"] = float(la.std(ddof=1)) if a.size > 1 else 0.0
    return {
        "config": config_name,
        "command": command,
        "seeds": list(repeats["seeds"]),
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "statistics": bands,
        "orderings": repeats["orderings"],
        "orderings_literal": literal_orderings(per_seed),
        "pairwise": pairwise_orderings(per_seed),
    }


def literal_orderings(per_seed: list[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """The paper's Figure 11 claims (:func:`twin.evaluation.evaluate.paper_orderings`) over the seeds with the
    paper-literal separation variant (``separation_paper``) in the separation method's place; empty when the
    runs have no such method."""
    from .evaluate import paper_orderings

    claims: dict[str, dict[str, Any]] = {}
    for r in per_seed:
        m = r["methods"]
        if "separation_paper" not in m:
            return {}
        swapped = {k: v for k, v in m.items() if k != "separation"}
        swapped["separation"] = m["separation_paper"]
        for c in paper_orderings(swapped):
            e = claims.setdefault(c["claim"], {"holds": 0, "n": 0})
            e["n"] += 1
            e["holds"] += int(bool(c["holds"]))
    for e in claims.values():
        e["fraction"] = e["holds"] / e["n"] if e["n"] else float("nan")
    return claims


def pairwise_orderings(per_seed: list[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, int]]]:
    """For each measured ``<unit>.after.mean``: in how many seeds each method's value is below each other's
    (``"a < b" -> {"holds", "n"}``); the orderings a regression test may assert are those holding in >= 95 %."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    for unit in ("angle_deg", "position_mm"):
        key = f"{unit}.after.mean"
        table: dict[str, dict[str, int]] = {}
        for r in per_seed:
            vals = {}
            for m, v in r["methods"].items():
                try:
                    vals[m] = float(v["measured"][unit]["after"]["mean"])
                except (KeyError, TypeError):
                    continue
            for a in sorted(vals):
                for b in sorted(vals):
                    if a != b:
                        e = table.setdefault(f"{a} < {b}", {"holds": 0, "n": 0})
                        e["n"] += 1
                        e["holds"] += int(vals[a] < vals[b])
        out[key] = table
    return out


def check_pairwise(results: Mapping[str, Any], bands: Mapping[str, Any], required_fraction: float = 0.95) -> list[str]:
    """Pairwise orderings (``<unit>.after.mean: a < b``) that held in ``>= required_fraction`` of the band seeds
    but fail in ``results``."""
    failed = []
    for key, table in bands.get("pairwise", {}).items():
        unit = key.split(".")[0]
        for pair, e in table.items():
            if not (e["n"] and e["holds"] / e["n"] >= required_fraction):
                continue
            a, b = pair.split(" < ")
            try:
                va = results["methods"][a]["measured"][unit]["after"]["mean"]
                vb = results["methods"][b]["measured"][unit]["after"]["mean"]
            except (KeyError, TypeError):
                failed.append(f"{key}: {pair} (missing)")
                continue
            if not va < vb:
                failed.append(f"{key}: {pair}")
    return failed


def check_against_bands(results: Mapping[str, Any], bands: Mapping[str, Any], k: float = 3.0,
                        required_fraction: float = 0.95) -> dict[str, list]:
    """Statistics of ``results`` (a results.json dict) outside their band, bands missing from the run, and
    ordering claims that held in ``>= required_fraction`` of the band seeds but fail here."""
    got = tracked_statistics(results["methods"])
    outside, missing = [], []
    for name, b in bands["statistics"].items():
        if name not in got:
            missing.append(name)
            continue
        lo = min(b["min"], b["mean"] - k * b["std"])
        hi = max(b["max"], b["mean"] + k * b["std"])
        v = got[name]
        if not (lo <= v <= hi):
            outside.append({"statistic": name, "value": v, "band": [lo, hi]})
    failed_claims = []
    held = {c["claim"]: c["holds"] for c in results.get("orderings", [])}
    for claim, e in bands.get("orderings", {}).items():
        if e["n"] and e["holds"] / e["n"] >= required_fraction and held.get(claim) is False:
            failed_claims.append(claim)
    return {"outside": outside, "missing": missing, "failed_claims": failed_claims}


def _prediction_kind(name: str) -> str | None:
    """'log_upper' for a measured after-compensation mean/max, 'lower' for a measured improvement, else None."""
    parts = name.split(".")
    if len(parts) == 5 and parts[1] == "measured" and parts[3] == "after" and parts[4] in ("mean", "max"):
        return "log_upper"
    if len(parts) == 4 and parts[1] == "measured" and parts[3] == "improvement_percent":
        return "lower"
    return None


PREDICTION_STATISTICS = "measured after-compensation mean and max (log scale, upper) and improvements (lower)"


def _t_quantile(confidence: float, dof: int) -> float:
    from scipy.stats import t

    return float(t.ppf(confidence, dof))


def prediction_band(band: Mapping[str, Any], kind: str, n_new: int = 1, confidence: float = 0.99) -> float:
    """The one-sided limit of a ``prediction`` band (module docstring) for the mean of ``n_new`` new seeds:
    ``kind`` 'log_upper' gives an upper limit on the statistic's value (the exponential of the log-scale
    limit), 'lower' a lower limit."""
    if n_new < 1:
        raise ValueError(f"n_new must be >= 1, got {n_new}")
    if not (0.5 < confidence < 1):
        raise ValueError(f"confidence must be in (0.5, 1), got {confidence}")
    n = int(band["n"])
    if n < 3:
        raise ValueError(f"a prediction band needs >= 3 band seeds, got n = {n}")
    t = _t_quantile(confidence, n - 1)
    w = (1.0 / n_new + 1.0 / n) ** 0.5
    if kind == "log_upper":
        return float(math.exp(band["log_mean"] + t * band["log_std"] * w))
    if kind == "lower":
        return float(band["mean"] - t * band["std"] * w)
    raise ValueError(f"kind must be 'log_upper' or 'lower', got {kind!r}")


def detectable_factor(band: Mapping[str, Any], n_new: int = 1, confidence: float = 0.99) -> float:
    """Smallest factor by which a statistic at its band's typical value (geometric mean) must worsen for the
    mean of ``n_new`` new seeds to fail the 'log_upper' prediction band."""
    return prediction_band(band, "log_upper", n_new, confidence) / float(math.exp(band["log_mean"]))


def check_prediction(runs: list[Mapping[str, Any]], bands: Mapping[str, Any], n_new: int | None = None,
                     confidence: float | Mapping[str, float] = 0.99, required_fraction: float = 0.95,
                     orderings: bool = True) -> dict[str, list]:
    """``prediction`` band check of ``runs`` (results.json dicts of seeds NOT among the band seeds): the
    statistics whose mean over the runs (geometric for the after-compensation errors) passes its one-sided
    limit, statistics missing, and the orderings (the paper's claims and the pairwise method orderings) that
    held in ``>= required_fraction`` of the band seeds but fail for the runs' pooled after-means
    (:func:`pooled_after_means`). ``ValueError`` when a run's seed is one of the band seeds.

    ``confidence`` is one per-statistic level or a mapping by statistic (``"mean"``, ``"max"``,
    ``"improvement_percent"``): with many statistics, a family of ``m`` checks at level ``c`` each raises a
    false alarm for unchanged code with probability up to ``m (1 - c)``; a caller keeps the after-means tight
    (the statistic a worsening must fail) and the maxima and improvements at a higher level. ``orderings=False``
    checks the statistics only (a single new seed cannot test an ordering that fails in one band seed in 20)."""

    import numpy as np

    if not runs:
        raise ValueError("runs must not be empty")
    seeds = set(bands.get("seeds", []))
    for r in runs:
        if r.get("seed") in seeds:
            raise ValueError(f"run seed {r.get('seed')} is one of the band seeds: a prediction band tests new seeds")
    k = n_new or len(runs)
    got = [tracked_statistics(r["methods"]) for r in runs]
    outside, missing = [], []
    for name, b in bands["statistics"].items():
        kind = _prediction_kind(name)
        if kind is None or (kind == "log_upper" and "log_mean" not in b):
            continue
        vals = [g.get(name) for g in got]
        if any(v is None for v in vals):
            missing.append(name)
            continue
        level = confidence if isinstance(confidence, (int, float)) else confidence[name.split(".")[-1]]
        limit = prediction_band(b, kind, k, level)
        if kind == "log_upper":
            value = math.exp(float(np.mean(np.log(np.maximum(vals, 1e-300)))))
            bad = value > limit
        else:
            value = float(np.mean(vals))
            bad = value < limit
        if bad:
            outside.append({"statistic": name, "value": value, "limit": limit, "kind": kind})
    if not orderings:
        return {"outside": outside, "missing": missing, "failed_claims": []}
    pooled = pooled_after_means(runs)
    failed_claims = []
    from .evaluate import paper_orderings

    held = {c["claim"]: c["holds"] for c in paper_orderings(pooled)}
    for claim, e in bands.get("orderings", {}).items():
        if e["n"] and e["holds"] / e["n"] >= required_fraction and held.get(claim) is False:
            failed_claims.append(claim)
    failed_claims += check_pairwise({"methods": pooled}, bands, required_fraction)
    return {"outside": outside, "missing": missing, "failed_claims": failed_claims}


def pooled_after_means(runs: list[Mapping[str, Any]]) -> dict[str, Any]:
    """``methods``-shaped dict of the geometric means over ``runs`` of each method's measured after-compensation
    means (``{method: {"measured": {unit: {"after": {"mean": ...}}}}}``), for the ordering checks of new seeds:
    an ordering that holds in 95 % of single seeds fails in some of several new seeds, the ordering of their
    pooled means is what a group of new seeds can test."""
    import numpy as np

    out: dict[str, Any] = {}
    methods = set.intersection(*(set(r["methods"]) for r in runs))
    for m in sorted(methods):
        for unit in ("angle_deg", "position_mm"):
            try:
                v = [float(r["methods"][m]["measured"][unit]["after"]["mean"]) for r in runs]
            except (KeyError, TypeError):
                continue
            if all(x > 0 for x in v):
                out.setdefault(m, {"measured": {}})["measured"][unit] = {"after": {"mean": float(np.exp(np.mean(np.log(v))))}}
    return out


def update_regression_file(section: str, data: Mapping[str, Any], path: str | os.PathLike) -> Path:
    """Replace one configuration's section of the regression file ``path`` (others untouched), under a lock."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    lock = p.with_suffix(".lock")
    with open(lock, "w") as lf:
        fcntl.flock(lf, fcntl.LOCK_EX)
        current = read_json(p) if p.exists() else {"schema_version": 1}
        current[section] = clean_json(dict(data))
        atomic_write_text(p, json.dumps(current, indent=1, sort_keys=True) + "\n")
    try:
        lock.unlink()
    except FileNotFoundError:
        pass
    return p
