"""Blind campaigns: score ``twin diagnose`` on datasets and answer keys written by another generator.

Study code (it reads the answer key, i.e. the truth; the diagnosis never does). A blind campaign is a folder
(format in ``docs/formats.md``, "Blind campaigns")::

    CAMPAIGN/dataset/{poses.csv, dataset.toml}   what the diagnosis sees
    CAMPAIGN/key/key.json                       category, expected effect names, the effects in words
    CAMPAIGN/key/sequence.csv                   every row in time order (the dataset's, then 'test' rows measured
                                                after it): joints, channels, measured (m*), true (t*) and the
                                                effect's contribution (e*) to each sphere centre [mm]

Scoring runs what a user runs (``twin diagnose``, ``twin predict``: on the command line, or the same commands
in this process with ``in_process``), then compares on the held-out rows the diagnosis used for nothing (its
*report* rows: ``diagnosis.json`` ``held_out.report_pose_ids``) and on the ``test`` block it never saw:

* ``before``: the geometric-only calibration of the diagnosis; ``after``: its extended calibration;
* ``oracle``: the true effect known exactly (the key's ``e``) and the geometry re-identified on the same
  calibration rows (the same fit as the diagnosis', on ``measured - e``): prediction ``geometric + e``;
* ``truth``: the key's noise-free centres (what the instrument's noise alone leaves).

Rows whose measurement is off the truth by more than 10x the campaign's median error (the generator's gross
rows) are left out of every statistic alike. Nothing here feeds back into the diagnosis.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from twin.dataset import Joints, read_dataset, write_joints_csv
from twin.estimator.files import read_pred_csv
from twin.units import M_PER_MM, RAD_PER_DEG

__all__ = ["BlindKey", "read_key", "score_campaign", "summarise", "summary_markdown", "CATEGORIES", "alone_and_in_file"]

CATEGORIES = ("clean", "catalogue", "outside", "mixed")


class BlindKey:
    """A campaign's answer key: ``meta`` (key.json) and the sequence ``(n,)`` rows with ``q`` ``(n, 6)`` [rad],
    ``measured``, ``true``, ``effect`` ``(n, K, 3)`` [m] (NaN where not measured; K points: the columns
    ``m0_x .. m<K-1>_z``, three for the sphere plate), ``role``, channels."""

    def __init__(self, meta: dict, rows: list[dict[str, str]], path: Path):
        self.meta = meta
        self.path = path
        n = len(rows)
        self.pose_id = np.array([int(r["pose_id"]) for r in rows])
        self.q = np.array([[float(r[f"q{j}"]) for j in range(1, 7)] for r in rows]) * RAD_PER_DEG
        self.role = np.array([r["role"].strip() for r in rows], dtype=object)
        n_points = 0
        while f"m{n_points}_x" in rows[0]:
            n_points += 1

        def block(prefix: str) -> np.ndarray:
            out = np.full((n, n_points, 3), np.nan)
            for i, r in enumerate(rows):
                for k in range(n_points):
                    cells = [(r.get(f"{prefix}{k}_{c}") or "").strip() for c in "xyz"]
                    if all(cells):
                        out[i, k] = np.array([float(x) for x in cells]) * M_PER_MM
            return out

        self.measured = block("m")
        self.true = block("t")
        self.effect = block("e")
        self.effect[np.isnan(self.effect)] = 0.0

        def chan(c: str) -> np.ndarray | None:
            if c not in rows[0] or not all((r.get(c) or "").strip() for r in rows):
                return None
            return np.array([float(r[c]) for r in rows])

        self.t_s = chan("t_s")
        self.temp_c = chan("temp_c")
        self.station = (np.array([r["station"].strip() for r in rows], dtype=object)
                        if "station" in rows[0] and all((r.get("station") or "").strip() for r in rows) else None)

    @property
    def category(self) -> str:
        return str(self.meta.get("category", ""))

    @property
    def expected_names(self) -> list[str]:
        return [str(x) for x in self.meta.get("expected_names", [])]


def read_key(campaign: str | os.PathLike) -> BlindKey:
    """Read ``CAMPAIGN/key/key.json`` and ``CAMPAIGN/key/sequence.csv``; ``ValueError`` naming what is wrong."""
    key = Path(campaign) / "key"
    meta = json.loads((key / "key.json").read_text())
    if meta.get("category") not in CATEGORIES:
        raise ValueError(f"{key / 'key.json'}: category must be one of {CATEGORIES}, got {meta.get('category')!r}")
    with open(key / "sequence.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{key / 'sequence.csv'}: no rows")
    need = ["pose_id", "role"] + [f"q{j}" for j in range(1, 7)]
    miss = [c for c in need if c not in rows[0]]
    if miss:
        raise ValueError(f"{key / 'sequence.csv'}: missing columns {miss}")
    return BlindKey(meta, rows, key)


def _twin(*args: str, in_process: bool = False) -> subprocess.CompletedProcess:
    """``twin ARGS``: the project's own command, in a subprocess or (``in_process``) through ``twin.cli.main`` in
    this process (the same code without the interpreter's start-up)."""
    if in_process:
        import contextlib
        import io

        from twin.cli import main

        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(list(args))
            except Exception as exc:  # a failure of the command is a result (named, never hidden)
                print(f"{type(exc).__name__}: {exc}", file=err)
                rc = 1
        return subprocess.CompletedProcess(list(args), rc, out.getvalue(), err.getvalue())
    exe = Path(sys.executable).with_name("twin")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "twin.cli"]
    return subprocess.run(cmd + list(args), capture_output=True, text=True)


def _predict(cal_path: Path, joints_path: Path, out: Path, in_process: bool = False) -> np.ndarray:
    """``twin predict`` (the user's command) -> predicted centres ``(n, 3, 3)`` [m]."""
    r = _twin("predict", str(cal_path), str(joints_path), "--out", str(out), "--force", in_process=in_process)
    if r.returncode != 0:
        raise RuntimeError(f"twin predict {cal_path.name} failed: {r.stderr.strip()[-600:]}")
    return read_pred_csv(out)["spheres"]


def _stats(err_mm: np.ndarray) -> dict[str, float]:
    e = err_mm[np.isfinite(err_mm)]
    if e.size == 0:
        return {"n": 0, "mean": float("nan"), "rms": float("nan"), "max": float("nan")}
    return {"n": int(e.size), "mean": float(e.mean()), "rms": float(np.sqrt(np.mean(e**2))), "max": float(e.max())}


def _trace(key: BlindKey, atoms: list[dict]) -> dict[str, Any]:
    """Does any non-minor term act where the key's effects act? (joint -> theta<j>, length -> its link, base /
    measurement -> base frame or measurement scale, tool -> tool frame, plate -> a sphere)."""
    places = []
    for e in key.meta.get("effects", []):
        pl = str(e.get("place", ""))
        joints = [int(j) for j in e.get("joints", []) or []]
        links = [str(x) for x in e.get("links", []) or []]  # names (a3, d4) or joint numbers (3: any of a3, d3, ...)
        ok = False
        for a in atoms:
            if a.get("minor"):
                continue
            tgt, apl = str(a.get("target", "")), str(a.get("place", ""))
            if pl == "joint" and apl == "joint" and (not joints or int(tgt[5:] or 0) in joints):
                ok = True
            elif pl == "length" and apl in ("length", "param") and (
                    not links or tgt == "all_lengths" or any(tgt == x or (x.isdigit() and tgt[-1:] == x) for x in links)):
                ok = True
            elif pl in ("base", "measurement") and (tgt in ("base", "base_along") or apl in ("scale", "field")):
                ok = True
            elif pl == "tool" and tgt == "tool":
                ok = True
            elif pl == "plate" and apl == "plate":
                ok = True
        places.append({"place": pl, "joints": joints, "links": links, "traced": ok})
    return {"per_effect": places, "all_traced": bool(places) and all(p["traced"] for p in places)}


def score_campaign(campaign: str | os.PathLike, out: str | os.PathLike, *, in_process: bool = False) -> dict[str, Any]:
    """Diagnose ``CAMPAIGN/dataset`` with the CLI, predict every row of the key's sequence with the extended,
    the geometric and the oracle calibrations, and score against the key. Returns a JSON-able dict.
    ``named_right``: the catalogue names found are exactly the key's (None when it expects none);
    ``extra_names``: names found that the key does not expect."""
    from twin.diagnosis import diagnose

    campaign, out = Path(campaign), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    key = read_key(campaign)
    ds = read_dataset(campaign / "dataset")
    res: dict[str, Any] = {"name": campaign.name, "key_name": str(key.meta.get("name", "")), "category": key.category,
                           "expected_names": key.expected_names,
                           "effects_key": [e.get("description", "") for e in key.meta.get("effects", [])],
                           "rows": int(ds.n), "has_set": ds.set is not None}
    args = ["diagnose", str(campaign / "dataset"), "--out", str(out / "diagnosis"), "--no-plots", "--no-recording"]
    r = _twin(*args, in_process=in_process)
    res["diagnose_command"] = f"twin diagnose {campaign.parent.name}/{campaign.name}/dataset --out DIR --no-plots --no-recording"
    if r.returncode != 0:
        res["error"] = r.stderr.strip()[-800:] or r.stdout.strip()[-800:]
        return res
    dj = json.loads((out / "diagnosis" / "diagnosis.json").read_text())
    res.update({
        "structured": bool(dj["structured"]), "p_value": dj["p_value"], "effects": list(dj["effects"]),
        "terms": [a["text"] + (" (minor)" if a.get("minor") else "") for a in dj["atoms"]],
        "labels": [a["label"] + (" (minor)" if a.get("minor") else "") for a in dj["atoms"]],
        "alternatives": [f"{a['alternative']} for {a['of']}" for a in dj.get("alternatives", [])],
        "floor_mm": dj["noise_floor"]["position_mm"], "diag_before": dj["before"], "diag_after": dj["after"],
        "explained_fraction": dj.get("explained_fraction"), "held_out": {k: v for k, v in dj["held_out"].items()
                                                                         if not k.endswith("pose_ids")},
        "kinds": sorted({f.get("kind", "") for a in dj["atoms"] for f in a["features"]}),
    })
    res["trace"] = _trace(key, dj["atoms"])

    # the rows of the sequence in time order, for `twin predict` (history and channels as measured)
    ds_ids = {int(p): i for i, p in enumerate(ds.pose_id)}
    joints = Joints(pose_id=key.pose_id, q=key.q, temp_c=key.temp_c if ds.temp_c is not None else None,
                    t_s=key.t_s if ds.t_s is not None else None,
                    station=key.station if ds.station is not None else None)
    jpath = write_joints_csv(out / "sequence_joints.csv", joints)
    # the rows after the campaign: the models to use (refitted on every row of the campaign); the report rows: the
    # models fitted on the calibration rows only (the report rows took no part in them)
    d = out / "diagnosis"
    blk = dj["calibrations_blocked"]
    pred = {"after": _predict(d / dj["calibration"], jpath, out / "pred_after.csv", in_process),
            "before": _predict(d / dj["calibration_geometric"], jpath, out / "pred_before.csv", in_process)}
    pred_report = {"after": _predict(d / blk["extended"], jpath, out / "pred_after_blocked.csv", in_process),
                   "before": _predict(d / blk["geometric"], jpath, out / "pred_before_blocked.csv", in_process)}

    # the oracle: the same geometric fit on measured - e (the diagnosis' split), then geometric + e
    in_ds = np.array([int(p) in ds_ids for p in key.pose_id])
    idx = np.array([ds_ids[int(p)] for p in key.pose_id[in_ds]])
    e_ds = np.zeros_like(ds.spheres)
    e_ds[idx] = key.effect[in_ds]
    holdout = None if ds.set is not None else 0.3
    ores = diagnose(replace(ds, spheres=ds.spheres - e_ds), holdout=holdout, max_effects=0, generic=False)
    oracle_path = out / "calibration_oracle.json"
    ores.calibration_geometric.save(oracle_path)
    pred["oracle"] = _predict(oracle_path, jpath, out / "pred_oracle.csv", in_process) + key.effect
    pred["truth"] = key.true
    oracle_blocked = out / "calibration_oracle_blocked.json"
    ores.calibrations_blocked["geometric"].save(oracle_blocked)
    pred_report["oracle"] = _predict(oracle_blocked, jpath, out / "pred_oracle_blocked.csv", in_process) + key.effect
    pred_report["truth"] = key.true

    # which rows count: the diagnosis' report rows (held out, used for nothing) and the test block; gross rows
    # (the generator's) left out of every statistic alike
    report_ids = set(int(p) for p in dj["held_out"]["report_pose_ids"]) | set(
        int(p) for p in dj["held_out"].get("gross_report_pose_ids", []))
    # (the diagnosis chooses its report rows as a block of time, whatever the dataset's set column says)
    role = np.array(["report" if (r != "test" and int(p) in report_ids) else r
                     for r, p in zip(key.role, key.pose_id)], dtype=object)
    err_true = np.linalg.norm(key.measured - key.true, axis=-1) / M_PER_MM
    med = np.nanmedian(err_true)
    gross = np.nanmax(np.where(np.isfinite(err_true), err_true, 0), axis=1) > 10 * max(med, 1e-6)
    res["gross_rows_left_out"] = [int(p) for p in key.pose_id[gross]]
    for part in ("report", "test"):
        rows = (role == part) & ~gross
        block = {}
        for name, P in (pred_report if part == "report" else pred).items():
            block[name] = _stats((np.linalg.norm(key.measured[rows] - P[rows], axis=-1) / M_PER_MM).ravel())
        if block["oracle"]["n"]:
            block["after_over_oracle"] = block["after"]["rms"] / block["oracle"]["rms"]
            block["before_over_oracle"] = block["before"]["rms"] / block["oracle"]["rms"]
        res[part] = block
    exp = set(key.expected_names)
    got = set(res["effects"])
    res["named_right"] = exp == got if exp else None
    res["extra_names"] = sorted(got - exp)
    return res


def alone_and_in_file(cal_path: str | os.PathLike, joints: Joints, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Predictions of the rows ``rows`` (indices into ``joints``) by the calibration at ``cal_path``, each row
    predicted alone and inside the whole file, as ``twin predict`` reads a JOINTS.csv, and the rows the prediction
    alone flags as lacking the history an order-dependent term needs: ``{alone, in_file (k, 3, 3) [m], flagged
    (k,)}``."""
    from twin.diagnosis.apply import history_unknown_rows, predict_extended
    from twin.diagnosis.floor import joints_context
    from twin.estimator import Calibration

    cal = Calibration.load(cal_path)

    def ctx(idx):
        return joints_context(joints, idx)

    def station(idx):
        return None if joints.station is None else joints.station[idx]

    every = np.arange(len(joints.pose_id))
    full = predict_extended(cal, ctx(every), station(every)).spheres[rows]
    alone = np.stack([predict_extended(cal, ctx(np.array([i])), station(np.array([i]))).spheres[0] for i in rows])
    flagged = np.array([history_unknown_rows(cal, ctx(np.array([i])))[0] for i in rows], dtype=bool)
    return {"alone": alone, "in_file": full, "flagged": flagged}


def summarise(results: list[dict]) -> dict[str, Any]:
    """Per category: alarms, naming, tracing, after/oracle on the report rows and on the test block."""
    out: dict[str, Any] = {}
    for cat in CATEGORIES:
        rs = [r for r in results if r["category"] == cat]
        if not rs:
            continue
        ok = [r for r in rs if "error" not in r]
        s: dict[str, Any] = {"n": len(rs), "errors": len(rs) - len(ok)}
        s["structured"] = sum(r["structured"] for r in ok)
        if cat in ("catalogue", "mixed"):
            s["named_right"] = sum(bool(r["named_right"]) for r in ok if r["named_right"] is not None)
        if cat != "clean":
            s["traced"] = sum(r["trace"]["all_traced"] for r in ok)
        s["extra_names"] = sum(bool(r["extra_names"]) for r in ok)
        for part in ("report", "test"):
            ratios = [r[part]["after_over_oracle"] for r in ok if part in r and "after_over_oracle" in r[part]]
            if ratios:
                s[f"after_over_oracle_{part}"] = {"median": float(np.median(ratios)), "max": float(np.max(ratios)),
                                                  "within_1.2": int(np.sum(np.array(ratios) <= 1.2)),
                                                  "within_1.5": int(np.sum(np.array(ratios) <= 1.5))}
        out[cat] = s
    return out


def summary_markdown(results: list[dict], summary: dict, title: str) -> str:
    """A table per campaign and the per-category summary."""
    lines = [f"# {title}", "", "| campaign | category | expected | structured | named | traced | terms | "
             "report rows before / after / oracle [mm RMS] | after/oracle report | after/oracle test |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        if "error" in r:
            lines.append(f"| {r['name']} | {r['category']} | {', '.join(r['expected_names'])} | ERROR: "
                         f"{r['error'].splitlines()[-1][:120]} | | | | | | |")
            continue
        v, t = r.get("report", {}), r.get("test", {})
        terms = "; ".join(x.replace("unnamed: ", "?") for x in r.get("labels", r["terms"])) or "-"
        lines.append(
            f"| {r['name']} | {r['category']} | {', '.join(r['expected_names']) or '-'} | {r['structured']} | "
            f"{', '.join(r['effects']) or '-'} | {r['trace']['all_traced'] if r['category'] != 'clean' else '-'} | "
            f"{terms} | {v['before']['rms']:.4f} / {v['after']['rms']:.4f} / {v['oracle']['rms']:.4f} | "
            f"{v.get('after_over_oracle', float('nan')):.2f} | {t.get('after_over_oracle', float('nan')):.2f} |")
    lines += ["", "| category | n | errors | structured | named right | traced | extra names | after/oracle report "
              "(median, max, <=1.2, <=1.5) | after/oracle test |", "|---|---|---|---|---|---|---|---|---|"]
    for cat, s in summary.items():
        def ratio(part):
            x = s.get(f"after_over_oracle_{part}")
            return "-" if not x else f"{x['median']:.2f}, {x['max']:.2f}, {x['within_1.2']}, {x['within_1.5']}"
        lines.append(f"| {cat} | {s['n']} | {s['errors']} | {s['structured']} | {s.get('named_right', '-')} | "
                     f"{s.get('traced', '-')} | {s['extra_names']} | {ratio('report')} | {ratio('test')} |")
    return "\n".join(lines) + "\n"
