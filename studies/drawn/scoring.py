"""Score `twin diagnose` on drawn campaigns: the blind study's scoring (``studies/blind/blind_scoring.py``: the user's
commands, the oracle, the report rows and the rows after the campaign) and each family's verdict.

Study code: it reads the answer key (the truth); nothing here feeds back into the diagnosis.

* **Named right.** A catalogue family: the names ``twin diagnose`` gives (``effects``) are exactly the key's. A
  change (a joint zero re-latched or glitching, a frame knocked, slipped or bumped): no catalogue name, and exactly
  one change (not minor) of the right kind (a step; a window for a glitch) at the right place (``theta<j>``; the
  ``tool`` frame for a knock or a slip, the measurement frame ``base`` for a bump), starting within 2 rows of the
  key's row (and, for a window, ending within 2 rows of its end). A clean campaign: not structured, no name, no
  change (else a false alarm).
* **Several effects at once** (``mixed``): the names are exactly the union of the catalogue families' names, and
  every change of a family outside the catalogue is found as above among the changes (not minor) the diagnosis
  reports.
* **Within the oracle goal.** After/oracle (RMS of the extended model's error over the oracle's) at most 1.2 for a
  catalogue family, 1.5 for a change outside the catalogue (and for a campaign of several effects with one among
  them); on the report rows (the diagnosis' held-out rows used for nothing else, the models fitted before them) and on
  the rows measured after the campaign (the models to use).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from studies.blind.blind_scoring import score_campaign
from studies.drawn.generator.campaign import MIXED
from studies.drawn.generator.families import FAMILIES

__all__ = ["GOAL", "brief", "family_verdict", "instance_goal", "score_instance", "summarise", "summary_markdown"]

GOAL = {"catalogue": 1.2, "outside": 1.5, "clean": 1.5}
ROW_TOLERANCE = 2


def _pct(row: int, n: int) -> str:
    return f"{row + 1}/{n}"


def brief(key: dict) -> str:
    """The drawn instance in a few words: where, which shape, when (rows as row/dataset rows)."""
    d = key.get("drawn", {})
    n = d.get("rows", 0)
    if not key.get("effects"):
        parts = []
        if "correlated" in d:
            parts.append(f"AR(1) rho {d['correlated']['rho']}, {d['correlated']['amplitude_of_noise']}x noise")
        if "gross_rows" in d:
            parts.append(f"gross rows {d['gross_rows']}")
        if "burst" in d:
            parts.append(f"burst rows {d['burst']['rows'][0]}-{d['burst']['rows'][1]} x{d['burst']['noise_factor']}")
        return "; ".join(parts) or "noise only"
    if len(key["effects"]) > 1:
        return " + ".join(f"{e['family']} ({_brief(e, d)})" for e in key["effects"])
    return _brief(key["effects"][0], d)


def _brief(e: dict, d: dict) -> str:
    n = d.get("rows", 0)
    p, fam = e["params"], e["family"]
    if fam == "compliance":
        return f"joints {'+'.join(p['per_joint'])}, {p['shape']}"
    if fam == "payload":
        when = (f"{p['timing']} at row {_pct(p['row'], n)}" if p["timing"] != "window"
                else f"window rows {p['row'] + 1}-{p['end_row']}/{n}")
        return f"joints {'+'.join(p['per_joint'])}, {p['mass_kg']:.1f} kg {when}"
    if fam == "backlash_motion":
        return f"joint {p['joint']}"
    if fam == "backlash_load":
        return f"joint {p['joint']}, {p['shape']}"
    if fam == "backlash_size":
        return f"joint {p['joint']}, {p['shape']} {p['size0_deg']:.0f} deg"
    if fam == "tilt":
        return f"anisotropy {p['anisotropy']:.2f} at {p['axis_deg']:.0f} deg"
    span = max(d.get("span_s", 1.0), 1.0)
    if fam == "thermal":
        when = (f"ramp {p['delta_k']:+.1f} K from {p['ramp_start_s'] / span:.2f} over {p['ramp_s'] / span:.2f} span"
                if p["profile"] == "ramp" else f"step {p['delta_k']:+.1f} K at {p['step_at_s'] / span:.2f} span")
        links = "all links" if len(p["links"]) > 1 else p["links"][0]
        return f"{when}, lag {p['tau_s'] / span:.2f} span, {links}, {'temp_c' if p['temp_column'] else 't_s only'}"
    if fam == "motion_heat":
        links = "all links" if len(p["links"]) > 1 else p["links"][0]
        return f"joints {p['heat_joints']} heat, tau {p['tau_s'] / span:.2f} span, {links}"
    if fam == "zero_step":
        return f"joint {p['joint']} at row {_pct(p['row'], n)}"
    if fam == "zero_glitch":
        return f"joint {p['joint']} rows {p['row'] + 1}-{p['end_row']}/{n}"
    if fam == "cyclic":
        return f"joint {p['joint']}, orders {p['orders']}"
    if fam == "gear_ratio":
        return f"joint {p['joint']}"
    if fam == "coupling":
        return f"joint {p['driven']} follows q{p['driving']}"
    if fam == "frame_change":
        return f"{p['kind']} at row {_pct(p['row'], n)}"
    return fam


def _expected_changes(key: dict) -> list[dict]:
    return [c for c in (_expected_change(e) for e in key.get("effects", [])) if c is not None]


def _expected_change(e: dict | None) -> dict | None:
    if e is None or FAMILIES[e["family"]].change is None:
        return None
    p = e["params"]
    kind = FAMILIES[e["family"]].change[0]
    if e["family"] == "frame_change":
        target = "base" if p["kind"] == "bump" else "tool"
    else:
        target = f"theta{p['joint']}"
    return {"kind": kind, "target": target, "row": p["row"], "end_row": p.get("end_row")}


def family_verdict(key: dict, diagnosis: dict) -> dict[str, Any]:
    """``named`` (module docstring) and what it rests on: the names, the changes found, the change expected."""
    effects = list(diagnosis["effects"])
    changes = [c for c in diagnosis.get("changes", []) if not c.get("minor")]
    out: dict[str, Any] = {"changes_found": [
        {k: c.get(k) for k in ("kind", "target", "row", "end_row", "found") if c.get(k) is not None} for c in changes]}
    if key["category"] == "clean":
        out["named"] = (not diagnosis["structured"]) and not effects and not changes
        return out
    if key["category"] == "mixed":
        wants = _expected_changes(key)
        out["changes_expected"] = wants
        out["named"] = (sorted(set(effects)) == sorted(set(key["expected_names"]))
                        and all(any(_hit(c, w) for c in changes) for w in wants))
        return out
    want = _expected_change(key["effects"][0] if key.get("effects") else None)
    if want is None:
        out["named"] = sorted(set(effects)) == sorted(set(key["expected_names"]))
        return out
    out["change_expected"] = want
    out["named"] = not effects and len(changes) == 1 and _hit(changes[0], want)
    return out


def _hit(c: dict, want: dict) -> bool:
    """The change ``c`` found is the change ``want`` expected: its kind and place, its row (and a window's end) within
    ``ROW_TOLERANCE`` rows."""
    ok = c["kind"] == want["kind"] and c["target"] == want["target"] and c.get("row") is not None \
        and abs(c["row"] - want["row"]) <= ROW_TOLERANCE
    if want["kind"] == "window":
        ok = ok and c.get("end_row") is not None and abs(c["end_row"] - want["end_row"]) <= ROW_TOLERANCE
    return ok


def instance_goal(key: dict) -> float:
    """The after/oracle goal of a campaign (module docstring): its category's; for several effects at once, 1.5 when
    one of them is outside the catalogue, else 1.2."""
    if key["category"] != "mixed":
        return GOAL[key["category"]]
    return max(GOAL[FAMILIES[e["family"]].category] for e in key["effects"])


def score_instance(folder: str | os.PathLike, work: str | os.PathLike, *, in_process: bool = True) -> dict[str, Any]:
    """``twin diagnose`` and ``twin predict`` on one drawn campaign (the blind study's scoring), and its family's
    verdict; a JSON-able record with the drawn parameters."""
    t0 = time.process_time()
    folder, work = Path(folder), Path(work)
    key = json.loads((folder / "key" / "key.json").read_text())
    family = key["drawn"]["family"]
    r = score_campaign(folder, work, in_process=in_process)
    out: dict[str, Any] = {"name": key["name"], "family": family, "seed": key["drawn"]["seed"],
                           "category": key["category"], "expected_names": key["expected_names"], "brief": brief(key),
                           "drawn": key["drawn"],
                           "params": key["effects"][0]["params"] if len(key["effects"]) == 1 else {},
                           "description": " + ".join(e["description"] for e in key["effects"]) or "clean"}
    if len(key["effects"]) > 1:
        out["components"] = [{"family": e["family"], "params": e["params"]} for e in key["effects"]]
    if "error" in r:
        out["error"] = r["error"]
        return out
    dj = json.loads((work / "diagnosis" / "diagnosis.json").read_text())
    out.update({"structured": r["structured"], "effects": r["effects"], "labels": r["labels"],
                "extra_names": r["extra_names"], "traced": r["trace"]["all_traced"], "floor_mm": r["floor_mm"],
                **family_verdict(key, dj)})
    goal = instance_goal(key)
    out["goal"] = goal
    for part in ("report", "test"):
        b = r[part]
        out[part] = {k: b[k]["rms"] for k in ("before", "after", "oracle", "truth")}
        out[part]["n"] = b["after"]["n"]
        ratio = b.get("after_over_oracle")
        out[part]["after_over_oracle"] = ratio
        out[part]["within_goal"] = bool(ratio is not None and np.isfinite(ratio) and ratio <= goal)
        out[part]["within_1.2"] = bool(ratio is not None and np.isfinite(ratio) and ratio <= 1.2)
        out[part]["within_1.5"] = bool(ratio is not None and np.isfinite(ratio) and ratio <= 1.5)
    out["cpu_s"] = round(time.process_time() - t0, 2)
    return out


def _range(vals) -> list | None:
    v = [x for x in vals if x is not None]
    if not v:
        return None
    if all(isinstance(x, (int, float)) for x in v):
        return [round(float(min(v)), 4), round(float(max(v)), 4)]
    return sorted({str(x) for x in v})


def draws_ranges(rs: list[dict]) -> dict[str, Any]:
    """What the instances of a family drew: robots, instruments, rows, size ratios and the family's own draws
    (joints, shapes, timings)."""
    out = {"robots": _range([r["drawn"]["robot"] for r in rs]), "masses_stated": sum(r["drawn"]["masses_stated"] for r in rs),
           "rows": _range([r["drawn"]["rows"] for r in rs]), "later_rows": _range([r["drawn"]["later_rows"] for r in rs]),
           "order": _range([r["drawn"]["order"] for r in rs]), "noise_rms_mm": _range([r["drawn"]["noise_rms_mm"] for r in rs])}
    if any("ratio_visible" in r["drawn"] for r in rs):
        out["ratio_visible"] = _range([r["drawn"].get("ratio_visible") for r in rs])
    comps = [c["family"] for r in rs for c in r.get("components", [])]
    if comps:
        out["families"] = {f: comps.count(f) for f in sorted(set(comps))}
        out["families_per_campaign"] = _range([len(r["components"]) for r in rs if r.get("components")])
    ps = [r["params"] for r in rs if r.get("params")]
    for k in ("joint", "shape", "timing", "kind", "profile", "driven", "temp_column"):
        vals = [p[k] for p in ps if k in p]
        if vals:
            out[k] = sorted({str(v) for v in vals})
    if ps and "per_joint" in ps[0]:
        out["joints"] = sorted({"+".join(p["per_joint"]) for p in ps})
    if ps and "orders" in ps[0]:
        out["orders"] = sorted({str(p["orders"]) for p in ps})
    n = [r["drawn"]["rows"] for r in rs]
    rows = [p["row"] / m for p, m in zip([r["params"] for r in rs], n) if "row" in p]
    if rows:
        out["change_at_fraction"] = _range(rows)
    span = [(r["params"], max(r["drawn"].get("span_s", 1.0), 1.0)) for r in rs if "tau_s" in r["params"]]
    if span:
        out["lag_over_span"] = _range([p["tau_s"] / s for p, s in span])
    return out


def summarise(results: list[dict]) -> dict[str, Any]:
    """Per family: instances, errors, the rate named right, the rates within the oracle goal and within 1.2x on the
    report rows and on the rows after the campaign, the median and worst after/oracle, false alarms (clean), and the
    draws' ranges."""
    out: dict[str, Any] = {}
    for fam in list(FAMILIES) + [MIXED]:
        rs = [r for r in results if r["family"] == fam]
        if not rs:
            continue
        ok = [r for r in rs if "error" not in r]
        category = "mixed" if fam == MIXED else FAMILIES[fam].category
        goals = sorted({r["goal"] for r in ok if "goal" in r})
        s: dict[str, Any] = {"n": len(rs), "errors": len(rs) - len(ok), "category": category,
                             "goal": GOAL[category] if category in GOAL else " / ".join(f"{g:g}" for g in goals)}
        s["named"] = sum(bool(r["named"]) for r in ok)
        if category == "clean":
            s["false_alarms"] = len(ok) - s["named"]
        for part in ("report", "test"):
            ratios = [r[part]["after_over_oracle"] for r in ok if r[part]["after_over_oracle"] is not None]
            s[part] = {"within_goal": sum(r[part]["within_goal"] for r in ok),
                       "within_1.2": sum(r[part]["within_1.2"] for r in ok),
                       "within_1.5": sum(r[part].get("within_1.5", False) for r in ok),
                       "median_after_over_oracle": round(float(np.median(ratios)), 4) if ratios else None,
                       "worst_after_over_oracle": round(float(np.max(ratios)), 4) if ratios else None}
        s["named_and_test_within_1.2"] = sum(bool(r["named"]) and r["test"]["within_1.2"] for r in ok)
        if category == "mixed":
            # the campaigns with a change outside the catalogue among their effects, and those without one
            for part, sel in (("with_change", True), ("without_change", False)):
                rp = [r for r in ok if any(FAMILIES[c["family"]].change is not None for c in r["components"]) == sel]
                s[part] = {"n": len(rp), "named": sum(bool(r["named"]) for r in rp),
                           "test_within_goal": sum(r["test"]["within_goal"] for r in rp),
                           "test_within_1.5": sum(r["test"].get("within_1.5", False) for r in rp)}
        s["draws"] = draws_ranges(ok or rs)
        s["cpu_s"] = round(sum(r.get("cpu_s", 0.0) for r in rs), 1)
        out[fam] = s
    return out


def totals(summary: dict[str, Any]) -> dict[str, Any]:
    """Over the families of ``summary`` (:func:`summarise`): the effect instances, named, within the goals, the
    families at the issue's target (named and the rows after the campaign within 1.2x on 9 of 10 instances), the
    clean instances and their false alarms."""
    effect = [s for s in summary.values() if s["category"] != "clean"]
    clean = [s for s in summary.values() if s["category"] == "clean"]
    return {
        "effect_families": len(effect),
        "effect_instances": sum(s["n"] for s in effect),
        "errors": sum(s["errors"] for s in summary.values()),
        "named": sum(s["named"] for s in effect),
        "report_within_goal": sum(s["report"]["within_goal"] for s in effect),
        "test_within_goal": sum(s["test"]["within_goal"] for s in effect),
        "test_within_1.2": sum(s["test"]["within_1.2"] for s in effect),
        "named_and_test_within_1.2": sum(s["named_and_test_within_1.2"] for s in effect),
        "families_at_9_of_10": sum(s["named_and_test_within_1.2"] >= 0.9 * (s["n"] - s["errors"]) for s in effect),
        "clean_instances": sum(s["n"] for s in clean),
        "clean_false_alarms": sum(s["false_alarms"] for s in clean),
    }


def _ratio(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def summary_markdown(results: list[dict], summary: dict, title: str) -> str:
    """Per family: the rates, then every instance (what was drawn, what the diagnosis named, after/oracle)."""
    lines = [f"# {title}", "",
             "Per family: instances; named right; after/oracle (the extended model's RMS over the oracle's) within the "
             "family's goal (1.2 catalogue, 1.5 outside) and within 1.2 on the report rows and on the later rows (measured "
             "after the campaign); median and worst after/oracle (report / later). Per instance: what was drawn, its size "
             "(the part the geometry cannot take over the noise), what the diagnosis named and its terms (`?`: unnamed), "
             "the report rows' RMS, after/oracle on both blocks (**x**: beyond the goal).", "",
             "| family | n | goal | named | report <= goal | report <= 1.2 | later <= goal | later <= 1.2 | named and later <= 1.2 "
             "| median report / later | worst report / later |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for fam, s in summary.items():
        n = s["n"] - s["errors"]
        lines.append(f"| {fam} | {s['n']}{' (' + str(s['errors']) + ' errors)' if s['errors'] else ''} | {s['goal']} | "
                     f"{s['named']}/{n} | {s['report']['within_goal']}/{n} | {s['report']['within_1.2']}/{n} | "
                     f"{s['test']['within_goal']}/{n} | {s['test']['within_1.2']}/{n} | {s['named_and_test_within_1.2']}/{n} | "
                     f"{_ratio(s['report']['median_after_over_oracle'])} / {_ratio(s['test']['median_after_over_oracle'])} | "
                     f"{_ratio(s['report']['worst_after_over_oracle'])} / {_ratio(s['test']['worst_after_over_oracle'])} |")
    for fam in summary:
        rs = sorted((r for r in results if r["family"] == fam), key=lambda r: r["seed"])
        lines += ["", f"## {fam}", "", "| instance | robot, K, rows | drawn | size / noise | named (what the diagnosis "
                  "said) | terms | report before / after / oracle [mm] | after/oracle report | after/oracle later |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in rs:
            d = r["drawn"]
            where = f"{d['robot']}{' (masses)' if d['masses_stated'] else ''}, K={d['K']}, {d['rows']}+{d['later_rows']}"
            size = f"{d['ratio_visible']:.2f}" if "ratio_visible" in d else "-"
            if "error" in r:
                lines.append(f"| {r['name']} | {where} | {r['brief']} | {size} | ERROR {r['error'].splitlines()[-1][:100]} "
                             f"| | | | |")
                continue
            said = ", ".join(r["effects"]) or "-"
            if r.get("changes_found"):
                said += "; changes " + ", ".join(f"{c['kind']} {c['target']} row {c['row'] + 1}"
                                                 + (f"-{c['end_row']}" if c.get("end_row") is not None else "")
                                                 for c in r["changes_found"])
            if not r["structured"]:
                said += " (not structured)"
            terms = "; ".join(x.replace("unnamed: ", "?") for x in r["labels"]) or "-"
            v, t = r["report"], r["test"]
            mark = lambda ok: "" if ok else " **x**"
            lines.append(f"| {r['name']} | {where} | {r['brief']} | {size} | {'yes' if r['named'] else '**no**'}: {said} | "
                         f"{terms} | {v['before']:.4f} / {v['after']:.4f} / {v['oracle']:.4f} | "
                         f"{_ratio(v['after_over_oracle'])}{mark(v['within_goal'])} | "
                         f"{_ratio(t['after_over_oracle'])}{mark(t['within_goal'])} |")
    return "\n".join(lines) + "\n"
