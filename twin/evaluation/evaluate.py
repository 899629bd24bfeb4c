"""Campaign evaluation: the separation paper's statistics before and after compensation, per method.

Inputs are the plan, the per-pose results (measured spheres and the world's truth) of the campaign's own
poses (before compensation) and of each method's compensated poses, and the true station frames. The
commanded reference of every motion is the *nominal* model at the commanded joints (what the operator
asked for); after compensation the robot is sent the compensated joints but the reference stays the same.

* ``measured`` statistics follow the paper's protocol: the plate frame is measured from the three sphere
  centres (eq. 38-40) in the station's frame and expressed in the robot base frame with the camera-to-base
  transform the user has, the paper's ``R_bc`` (eq. 42): the method's own identified ``base2meas`` of the
  station (the true one for a method that identifies none, and for a run without methods). Angle errors are
  eq. 25 on ZYX Euler-angle changes, position errors are errors of the moved distance of the plate centre.
  Pairs with a sphere not measured are left out (and counted).
* ``truth`` statistics (our extra columns) use the world's true sphere centres in the same frames (no
  measurement noise), plus absolute pose errors of every validation pose: the true plate pose against the
  nominal target in the true robot base frame (``absolute``) and after the one rigid transform that best
  aligns the validation poses (``absolute_aligned``: what is left once the base frame, which the plate's
  measurements cannot fix, is registered).

Why the frame matters: the Euler-angle *changes* are not invariant to a rotation of the base frame. A base
rotation the measurements cannot identify (e.g. ``alpha1``, absorbed in ``base2meas``) leaves a floor in the
angle statistic when it is evaluated in the *true* base frame although the compensated motions are right
in the frame the user calibrated in; results.json keeps that variant as ``truth.angle_deg_true_base``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np

from ..dataset import Plate
from ..instrument.plate import paper_frame_from_spheres
from ..kinematics import RobotModel, flange2base
from ..transforms import invert_transform, kabsch, make_transform
from ..units import MM_PER_M, DEG_PER_RAD
from .statistics import (
    absolute_pose_errors,
    euler_change_error,
    improvement_percent,
    moved_distance_error,
    summarize,
)

__all__ = ["PairErrors", "MethodEvaluation", "evaluate_campaign", "parameter_comparison", "paper_orderings"]

# Figure 11's "almost the same" position accuracy of separation and full pose, read as after-means within 25 %
SAME_WITHIN = 0.25


class PoseResult(Protocol):
    """What evaluation reads of a measured pose (the runner's ``PoseResult``): its ``station``, the measured
    centres (``spheres_array()``: ``(3, 3)`` [m], NaN where not measured, and the seen mask ``(3,)``) and the
    world's ``truth`` (``spheres_meas`` ``(3, 3)`` [m] in the station's true frame)."""

    station: str
    truth: dict

    def spheres_array(self) -> tuple[np.ndarray, np.ndarray]: ...


class CampaignPlan(Protocol):
    """What evaluation reads of a plan (the runner's ``CampaignPlan``): rows in measurement order with their
    ``pose_id``, commanded ``q`` ``(n, 6)`` [rad], ``group``, commanded ``distance`` [m], and the motion pairs of
    a group (``pairs(group) -> (start rows, end rows)``)."""

    pose_id: np.ndarray
    q: np.ndarray
    group: np.ndarray
    distance: np.ndarray

    def pairs(self, group: str) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass
class PairErrors:
    """Per-motion errors of one evaluation group: ``angle`` [rad] / ``position`` [m] ``(n_pairs,)`` with NaN
    where the motion could not be measured; ``distance`` [m] commanded move (NaN for motion pairs)."""

    group: str
    pose_id_start: np.ndarray
    pose_id_end: np.ndarray
    distance: np.ndarray
    angle: dict[str, np.ndarray] = field(default_factory=dict)  # key: "measured_before", "truth_after", ...
    position: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class MethodEvaluation:
    """Everything evaluated for one method (``before`` entries are the same for every method)."""

    method: str
    pairs: list[PairErrors]
    absolute: dict[str, np.ndarray]  # "before_position", "after_rotation", ... per validation row
    summary: dict[str, Any]


def _plate_in_flange(plate: Plate) -> np.ndarray:
    return paper_frame_from_spheres(plate.spheres_flange)


def commanded_plate2base(nominal: RobotModel, plate: Plate, q: np.ndarray) -> np.ndarray:
    """Nominal plate frames ``(n, 4, 4)`` in the base frame at commanded joints ``q`` ``(n, 6)``."""
    m = nominal.with_frames(base2meas=np.eye(4))
    return flange2base(m, np.atleast_2d(q)) @ m.tool2flange @ _plate_in_flange(plate)


def _frames_from(results: Mapping[int, PoseResult], pose_ids: np.ndarray, meas2base: Mapping[str, np.ndarray], truth: bool):
    """Plate frames ``(n, 4, 4)`` in the base frame from measured (or true) sphere centres, and a mask."""
    out = np.full((len(pose_ids), 4, 4), np.nan)
    ok = np.zeros(len(pose_ids), dtype=bool)
    for k, pid in enumerate(pose_ids):
        r = results.get(int(pid))
        if r is None:
            continue
        if truth:
            s = np.asarray(r.truth.get("spheres_meas"), dtype=float)
            if s.shape != (3, 3) or not np.all(np.isfinite(s)):
                continue
        else:
            s, seen = r.spheres_array()
            if not seen.all():
                continue
        out[k] = meas2base[r.station] @ paper_frame_from_spheres(s)
        ok[k] = True
    return out, ok


def _pair_errors(kind: str, P_start, P_end, C_start, C_end, ok) -> np.ndarray:
    e = np.full(len(ok), np.nan)
    if not ok.any():
        return e
    if kind == "angle":
        e[ok] = euler_change_error(P_start[ok, :3, :3], P_end[ok, :3, :3], C_start[ok, :3, :3], C_end[ok, :3, :3])
    else:
        e[ok] = moved_distance_error(P_start[ok, :3, 3], P_end[ok, :3, 3], C_start[ok, :3, 3], C_end[ok, :3, 3])
    return e


def _summ(values: np.ndarray, scale: float) -> dict | None:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return None
    return summarize(v * scale).to_dict()


def _absent(before: str | None, after: str | None) -> dict[str, Any]:
    """A statistic that could not be computed: ``None`` values and, per phase, the reason."""
    reasons = {k: v for k, v in (("before", before), ("after", after)) if v is not None}
    return {"before": None, "after": None, "absent": reasons}


def _summary_block(pairs: list[PairErrors], absolute: dict[str, np.ndarray], source: str, *,
                   identified: bool = True, n_validation: int | None = None) -> dict[str, Any]:
    """Summaries of one source (``measured``, ``truth``, ``truthbase``). A statistic that cannot be computed
    (no validation motion evaluates it, no motion was measured, no method was identified) is ``None`` with
    its reason under ``absent`` (never NaN)."""
    out: dict[str, Any] = {}
    what = "measured" if source == "measured" else "true"
    for quantity, scale, unit in (("angle", DEG_PER_RAD, "angle_deg"), ("position", MM_PER_M, "position_mm")):
        having = [p for p in pairs if f"{source}_before" in getattr(p, quantity)]
        if not having:
            why = (f"no validation motion evaluates the {quantity} error" if pairs else
                   "no validation rows: no group is evaluated (every pose is in the calibration set)")
            out[unit] = _absent(why, why)
            continue
        b = np.concatenate([getattr(p, quantity)[f"{source}_before"] for p in having])
        a = np.concatenate([getattr(p, quantity).get(f"{source}_after", np.full(len(p.pose_id_end), np.nan)) for p in having])
        has_after = any(f"{source}_after" in getattr(p, quantity) for p in having)
        sb, sa = _summ(b, scale), (_summ(a, scale) if has_after else None)
        block: dict[str, Any] = {"before": sb, "after": sa}
        if sb is not None and sa is not None and sb["mean"] > 0:
            block["improvement_percent"] = improvement_percent(sb["mean"], sa["mean"])
        block["n_unmeasured"] = {"before": int(np.sum(~np.isfinite(b))), "after": int(np.sum(~np.isfinite(a))) if has_after else None}
        absent: dict[str, str] = {}
        if sb is None:
            absent["before"] = f"none of the {b.size} motions has {what} spheres at both ends before compensation"
        if sa is None:
            absent["after"] = ("no method identified: nothing was compensated" if not identified or not has_after else
                               f"none of the {a.size} compensated motions has {what} spheres at both ends "
                               "(every compensated measurement failed)")
        if absent:
            block["absent"] = absent
        if quantity == "position":
            by_d: dict[str, Any] = {}
            dist = np.concatenate([p.distance for p in having])
            for d in np.unique(dist[np.isfinite(dist)]):
                m = dist == d
                by_d[f"{d * MM_PER_M:g}"] = {"before": _summ(b[m], scale), "after": _summ(a[m], scale) if has_after else None}
            if by_d:
                block["by_distance_mm"] = by_d
        out[unit] = block
    if source == "truth":
        for what_abs in ("absolute", "absolute_aligned"):
            pos_b, pos_a = absolute.get(f"{what_abs}_before_position"), absolute.get(f"{what_abs}_after_position")
            rot_b, rot_a = absolute.get(f"{what_abs}_before_rotation"), absolute.get(f"{what_abs}_after_rotation")
            need = "at least 3 validation poses" if what_abs == "absolute_aligned" else "a validation pose"
            if pos_b is None:
                why = ("no validation rows: no group is evaluated" if not n_validation else
                       f"no true plate pose for {need} before compensation")
                out[f"{what_abs}_position_mm"] = _absent(why, why)
                out[f"{what_abs}_rotation_deg"] = _absent(why, why)
                continue
            why_after = None
            if pos_a is None:
                why_after = ("no method identified: nothing was compensated" if not identified else
                             f"no true plate pose for {need} after compensation")
            for name, vb, va, sc in (("position_mm", pos_b, pos_a, MM_PER_M), ("rotation_deg", rot_b, rot_a, DEG_PER_RAD)):
                blk = {"before": _summ(vb, sc), "after": _summ(va, sc) if va is not None else None}
                if why_after is not None:
                    blk["absent"] = {"after": why_after}
                out[f"{what_abs}_{name}"] = blk
    return out


def evaluate_campaign(
    plan: CampaignPlan,
    groups: Mapping[str, tuple[str, ...]],
    nominal: RobotModel,
    plate: Plate,
    base2meas_true: Mapping[str, np.ndarray],
    before: Mapping[int, PoseResult],
    after: Mapping[str, Mapping[int, PoseResult]],
    base2meas_identified: Mapping[str, Mapping[str, np.ndarray]] | None = None,
) -> dict[str, MethodEvaluation]:
    """Statistics per method (``after`` keys); with no method, one entry ``"before"`` with only before.

    ``groups``: evaluated group name -> ``("angle",)``, ``("position",)`` or both. ``base2meas_identified``:
    per method, its identified ``base2meas`` per station (the frames the pair statistics are taken in).
    """
    true_m2b = {k: invert_transform(v) for k, v in base2meas_true.items()}
    methods = list(after) or ["before"]
    out: dict[str, MethodEvaluation] = {}
    val_rows = np.flatnonzero(np.isin(plan.group, list(groups)))
    val_ids = plan.pose_id[val_rows]
    C_val = commanded_plate2base(nominal, plate, plan.q[val_rows])
    for method in methods:
        res_after = after.get(method, {})
        ident = (base2meas_identified or {}).get(method, {})
        meas2base = {k: invert_transform(ident[k]) if k in ident else v for k, v in true_m2b.items()}
        pairs: list[PairErrors] = []
        for gname, what in groups.items():
            s, e = plan.pairs(gname)
            pe = PairErrors(gname, plan.pose_id[s], plan.pose_id[e], plan.distance[s])
            Cs = commanded_plate2base(nominal, plate, plan.q[s])
            Ce = commanded_plate2base(nominal, plate, plan.q[e])
            for source, truth, frames in (("measured", False, meas2base), ("truth", True, meas2base),
                                          ("truthbase", True, true_m2b)):
                for phase, res in (("before", before), ("after", res_after)):
                    if phase == "after" and method == "before":
                        continue
                    Ps, oks = _frames_from(res, pe.pose_id_start, frames, truth)
                    Pe, oke = _frames_from(res, pe.pose_id_end, frames, truth)
                    ok = oks & oke
                    for quantity in what:
                        store = pe.angle if quantity == "angle" else pe.position
                        store[f"{source}_{phase}"] = _pair_errors(quantity, Ps, Pe, Cs, Ce, ok)
            pairs.append(pe)
        absolute: dict[str, np.ndarray] = {}
        for phase, res in (("before", before), ("after", res_after)):
            if phase == "after" and method == "before":
                continue
            P, ok = _frames_from(res, val_ids, true_m2b, truth=True)
            if not ok.any():
                continue
            pos, rot = np.full(len(ok), np.nan), np.full(len(ok), np.nan)
            pos[ok], rot[ok] = absolute_pose_errors(P[ok], C_val[ok])
            absolute[f"absolute_{phase}_position"], absolute[f"absolute_{phase}_rotation"] = pos, rot
            if ok.sum() >= 3:
                R, t = kabsch(P[ok, :3, 3], C_val[ok, :3, 3])
                T = make_transform(R, t)
                Pa = T @ P[ok]
                pa, ra = np.full(len(ok), np.nan), np.full(len(ok), np.nan)
                pa[ok], ra[ok] = absolute_pose_errors(Pa, C_val[ok])
                absolute[f"absolute_aligned_{phase}_position"], absolute[f"absolute_aligned_{phase}_rotation"] = pa, ra
        kw = {"identified": method != "before", "n_validation": int(len(val_rows))}
        summary = {"measured": _summary_block(pairs, absolute, "measured", **kw),
                   "truth": _summary_block(pairs, absolute, "truth", **kw)}
        tb = _summary_block(pairs, {}, "truthbase", **kw).get("angle_deg")
        if tb is not None:
            summary["truth"]["angle_deg_true_base"] = tb
        out[method] = MethodEvaluation(method, pairs, absolute, summary)
    return out


def parameter_comparison(nominal: RobotModel, true_deviation: Mapping[str, float], identified: RobotModel,
                         identified_names: tuple[str, ...] = ()) -> dict[str, dict[str, Any]]:
    """Identified vs injected deviations of the chain parameters (the paper's Tables 3 and 5), in deg / mm.

    Keys ``theta1_deg`` ... ``beta2_deg``, ``d1_mm`` ..., plus ``theta2_plus_theta3_deg`` (the sum the angle
    constraints see, eq. 21). ``identified`` is False where the method held the parameter fixed.
    """
    lay = nominal.layout
    dev = identified.params - nominal.params
    out: dict[str, dict[str, Any]] = {}
    chain = [n for n in lay.names if not n.startswith(("base_", "tool_"))]
    for n in chain:
        i = lay.index(n)
        scale, unit = (MM_PER_M, "mm") if lay.units[i] == "m" else (DEG_PER_RAD, "deg")
        out[f"{n}_{unit}"] = {
            "true": float(true_deviation.get(n, 0.0) * scale),
            "identified": float(dev[i] * scale),
            "estimated": (n in identified_names) if identified_names else True,
        }
    t23 = lay.indices(["theta2", "theta3"])
    out["theta2_plus_theta3_deg"] = {
        "true": float((true_deviation.get("theta2", 0.0) + true_deviation.get("theta3", 0.0)) * DEG_PER_RAD),
        "identified": float(dev[t23].sum() * DEG_PER_RAD),
        "estimated": True,
    }
    return out


def paper_orderings(summaries: Mapping[str, Mapping[str, Any]], source: str = "measured") -> list[dict[str, Any]]:
    """The separation paper's Figure 11 claims, checked on one run (after compensation, means):

    1. separation has the best angle accuracy of the three methods; 2. distance-only the worst;
    3. separation ahead of distance-only in position; 4. full pose ahead of distance-only in position;
    5. separation and full pose "almost the same" in position: the paper gives no number, we read it as the
    larger after-mean within ``SAME_WITHIN`` (25 %) of the smaller.
    A claim whose methods are missing is left out.
    """

    def get(m, unit):
        try:
            return float(summaries[m][source][unit]["after"]["mean"])
        except (KeyError, TypeError):
            return None

    checks = []
    a = {m: get(m, "angle_deg") for m in ("distance", "full_pose", "separation")}
    p = {m: get(m, "position_mm") for m in ("distance", "full_pose", "separation")}
    if all(v is not None for v in a.values()):
        checks.append({"claim": "separation has the best angle accuracy", "holds": a["separation"] < min(a["distance"], a["full_pose"]), "values": a})
        checks.append({"claim": "distance-only has the worst angle accuracy", "holds": a["distance"] > max(a["separation"], a["full_pose"]), "values": a})
    if p["separation"] is not None and p["distance"] is not None:
        checks.append({"claim": "separation is ahead of distance-only in position", "holds": p["separation"] < p["distance"], "values": p})
    if p["full_pose"] is not None and p["distance"] is not None:
        checks.append({"claim": "full pose is ahead of distance-only in position", "holds": p["full_pose"] < p["distance"], "values": p})
    if p["separation"] is not None and p["full_pose"] is not None:
        lo, hi = sorted((p["separation"], p["full_pose"]))
        checks.append({"claim": f"separation and full pose are almost the same in position (within {100 * SAME_WITHIN:.0f} %)",
                       "holds": bool(lo > 0 and hi <= (1 + SAME_WITHIN) * lo), "values": p,
                       "ratio": hi / lo if lo > 0 else None})
    return checks


