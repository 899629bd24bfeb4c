"""The side-by-side grid: every method on the same datasets in one process, scored against the floor.

Cells are (number of calibration poses, noise level); each cell is run on several seeds. On the first seed every
method is run ``repeats`` times and its identification wall time is the median of those runs (all methods of a
cell are timed in the same process, one after the other, so the ratios to ours compare like with like); the
other seeds are run once, for accuracy.

Per cell and method the summary holds: the position mean [mm] (mean over seeds), the pooled position RMS [mm]
(``sqrt(mean over seeds of RMS^2)``), the position max [mm] (max over seeds), the pooled orientation RMS [deg],
the ratios of the pooled RMS to the pooled floor RMS of the same seeds -- against the full-pose floor and
against the floor of the data the method used (position-only methods: the position-only floor) -- and the worst
per-seed ratio, the median fit time [s] and its ratio to ours (``ours: default`` of the same cell), and the
failures (seed and error text).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from twin.kinematics import tool2meas
from twin.units import MM_PER_M

from .common import PeerResult, register_base_and_tool
from .floor import floor_fit
from .metrics import ValidationErrors, validation_errors
from .synthetic import NoiseLevel, Problem, Split, make_split

__all__ = ["Method", "run_grid", "OURS_DEFAULT", "summarise"]

OURS_DEFAULT = "ours: default"


@dataclass(frozen=True)
class Method:
    """A calibrator of the grid. ``data`` is ``"pose"`` or ``"position"`` (which floor is its own);
    ``run(problem, split)`` returns a :class:`PeerResult`."""

    name: str
    family: str  # "ours" or "peer"
    data: str
    run: Callable[[Problem, Split], PeerResult]
    settings: dict
    data_used: str


def _errors(res: PeerResult, split: Split) -> ValidationErrors | None:
    if res.positions is None:
        return None
    return validation_errors(split.tool2meas_val_true, res.positions, res.rotations)


def _floor_errors(problem: Problem, split: Split, use_orientation: bool) -> ValidationErrors:
    f = floor_fit(
        problem.truth, split.q_cal, split.tool2meas_cal, split.noise.position, split.noise.orientation,
        use_orientation=use_orientation,
    )
    T = tool2meas(f.model, split.q_val)
    return validation_errors(split.tool2meas_val_true, T[:, :3, 3], T[:, :3, :3] if use_orientation else None)


def _nominal_errors(problem: Problem, split: Split) -> ValidationErrors:
    """Before calibration: nominal joints, base and tool point registered in closed form."""
    base2meas, tool_point = register_base_and_tool(problem.nominal, split.q_cal, split.positions_cal)
    tool = np.eye(4)
    tool[:3, 3] = tool_point
    T = tool2meas(problem.nominal.with_frames(base2meas=base2meas, tool2flange=tool), split.q_val)
    return validation_errors(split.tool2meas_val_true, T[:, :3, 3])


def run_grid(
    methods: list[Method],
    problem: Problem,
    *,
    seeds: list[int],
    n_cals: list[int],
    noises: list[NoiseLevel],
    repeats: int,
    log: Callable[[str], None] = lambda s: None,
) -> dict:
    """Run every method on every cell and seed; the raw per-seed records and the per-cell summaries."""
    if repeats < 1 or not seeds:
        raise ValueError(f"repeats must be >= 1 and seeds non-empty, got {repeats}, {seeds}")
    cells = []
    for noise in noises:
        for n_cal in n_cals:
            per_seed = []
            timing: dict[str, list[float]] = {m.name: [] for m in methods}
            for k, seed in enumerate(seeds):
                split = make_split(problem, seed, n_cal, noise)
                rec = {
                    "seed": seed,
                    "floor_pose": _floor_errors(problem, split, True).as_dict(),
                    "floor_position": _floor_errors(problem, split, False).as_dict(),
                    "nominal": _nominal_errors(problem, split).as_dict(),
                    "methods": {},
                }
                for m in methods:
                    n_runs = repeats if k == 0 else 1
                    res = None
                    for _ in range(n_runs):
                        res = m.run(problem, split)
                        if res.fit_seconds is not None and k == 0:
                            timing[m.name].append(res.fit_seconds)
                    err = _errors(res, split)
                    rec["methods"][m.name] = {
                        "errors": None if err is None else err.as_dict(),
                        "fit_seconds": res.fit_seconds,
                        "error": res.error,
                        "notes": list(res.notes),
                    }
                    log(
                        f"{noise.label:>20} n={n_cal:<4} seed={seed} {m.name:<34} "
                        + (f"pos RMS {err.position_rms_mm:.4f} mm" if err else "no prediction")
                        + (f", {res.fit_seconds:.3f} s" if res.fit_seconds is not None else "")
                        + (f"  [{res.error}]" if res.error else "")
                    )
                per_seed.append(rec)
            cells.append(
                {
                    "n_calibration": n_cal,
                    "noise": {"position_mm": noise.position * MM_PER_M, "orientation_rad": noise.orientation},
                    "noise_label": noise.label,
                    "timing_runs": timing,
                    "seeds": per_seed,
                    "summary": summarise(methods, per_seed, timing),
                }
            )
    return {"cells": cells}


def _pooled(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def summarise(methods: list[Method], per_seed: list[dict], timing: dict[str, list[float]]) -> dict:
    """Per-method summary of one cell (see the module docstring)."""
    floor_pose = _pooled([r["floor_pose"]["position_mm"]["rms"] for r in per_seed])
    floor_pos = _pooled([r["floor_position"]["position_mm"]["rms"] for r in per_seed])
    floor_ori = _pooled([r["floor_pose"]["orientation_deg"]["rms"] for r in per_seed])
    out: dict = {
        "floor_pose": {"position_rms_mm": floor_pose, "orientation_rms_deg": floor_ori},
        "floor_position": {"position_rms_mm": floor_pos},
        "nominal": {"position_rms_mm": _pooled([r["nominal"]["position_mm"]["rms"] for r in per_seed])},
        "order": [m.name for m in methods],
        "methods": {},
    }
    ours_time = float(np.median(timing[OURS_DEFAULT])) if timing.get(OURS_DEFAULT) else None
    for m in methods:
        recs = [(r["seed"], r["floor_pose"], r["floor_position"], r["methods"][m.name]) for r in per_seed]
        ok = [(s, fp, fq, x) for s, fp, fq, x in recs if x["errors"] is not None]
        failures = [{"seed": s, "error": x["error"]} for s, _, _, x in recs if x["error"]]
        t = float(np.median(timing[m.name])) if timing.get(m.name) else None
        summary = {
            "data": m.data,
            "failures": failures,
            "fit_seconds_median": t,
            "fit_seconds_runs": len(timing.get(m.name, [])),
            "time_ratio_to_ours": None if (t is None or not ours_time) else t / ours_time,
        }
        if ok:
            rms = [x["errors"]["position_mm"]["rms"] for _, _, _, x in ok]
            own_floor = [(fq if m.data == "position" else fp)["position_mm"]["rms"] for _, fp, fq, _ in ok]
            pose_floor = [fp["position_mm"]["rms"] for _, fp, _, _ in ok]
            summary.update(
                {
                    "seeds_scored": len(ok),
                    "position_mean_mm": float(np.mean([x["errors"]["position_mm"]["mean"] for *_, x in ok])),
                    "position_rms_mm": _pooled(rms),
                    "position_max_mm": float(np.max([x["errors"]["position_mm"]["max"] for *_, x in ok])),
                    "ratio_position_to_pose_floor": _pooled(rms) / _pooled(pose_floor),
                    "ratio_position_to_own_floor": _pooled(rms) / _pooled(own_floor),
                    "worst_seed_ratio_position_to_own_floor": float(np.max(np.array(rms) / np.array(own_floor))),
                }
            )
            ori = [x["errors"]["orientation_deg"] for *_, x in ok]
            if all(o is not None for o in ori):
                o_rms = [o["rms"] for o in ori]
                o_floor = [fp["orientation_deg"]["rms"] for _, fp, _, _ in ok]
                summary.update(
                    {
                        "orientation_rms_deg": _pooled(o_rms),
                        "ratio_orientation_to_floor": _pooled(o_rms) / _pooled(o_floor),
                        "worst_seed_ratio_orientation_to_floor": float(np.max(np.array(o_rms) / np.array(o_floor))),
                    }
                )
            else:
                summary.update({"orientation_rms_deg": None, "ratio_orientation_to_floor": None})
        out["methods"][m.name] = summary
    return out
