"""Regression bands of the campaign statistics (``results/regression.json``).

:func:`bands_from_repeats` turns a Monte-Carlo run (:func:`twin.evaluation.campaign.run_repeats`) into bands:
for each tracked statistic its mean, sample std, min and max over the seeds, and for each of the paper's
ordering claims the fraction of seeds where it holds. :func:`check_against_bands` tells which statistics of
one run fall outside ``[min(min, mean - k std), max(max, mean + k std)]`` and which claims that held in at
least ``required_fraction`` of the seeds fail in it.

Tracked statistics (dotted paths into ``results.json``'s ``methods``): for every method, the measured and
true ``angle_deg`` / ``position_mm`` ``before``/``after`` ``mean``, ``max`` and ``std`` and the improvements.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
from pathlib import Path
from typing import Any, Mapping

from .executor import flatten_numbers
from .report import _clean
from .store import atomic_write_text

__all__ = ["tracked_statistics", "bands_from_repeats", "check_against_bands", "update_regression_file", "DEFAULT_PATH"]

DEFAULT_PATH = Path(__file__).resolve().parents[2] / "results" / "regression.json"


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
    return {
        "config": config_name,
        "command": command,
        "seeds": list(repeats["seeds"]),
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "statistics": bands,
        "orderings": repeats["orderings"],
    }


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


def update_regression_file(section: str, data: Mapping[str, Any], path: str | os.PathLike | None = None) -> Path:
    """Replace one configuration's section of ``results/regression.json`` (others untouched), under a lock."""
    p = Path(path) if path else DEFAULT_PATH
    p.parent.mkdir(parents=True, exist_ok=True)
    lock = p.with_suffix(".lock")
    with open(lock, "w") as lf:
        fcntl.flock(lf, fcntl.LOCK_EX)
        current = json.loads(p.read_text()) if p.exists() else {"schema_version": 1}
        current[section] = _clean(dict(data))
        atomic_write_text(p, json.dumps(current, indent=1, sort_keys=True) + "\n")
    try:
        lock.unlink()
    except FileNotFoundError:
        pass
    return p
