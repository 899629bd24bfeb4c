"""``truth.json``: what the world knows and nobody downstream may read but evaluation.

The one writer (:func:`write_truth`); the reader is ``twin.evaluation.truth.read_truth``. Field-by-field
reference in ``docs/formats.md`` ("truth.json"). SI units throughout ([m], [rad]); transforms are 4x4
row-major nested lists, named ``A2B``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .records import Capture

__all__ = ["TRUTH_SCHEMA_VERSION", "truth_dict", "write_truth"]

TRUTH_SCHEMA_VERSION = 1


def _m(T: np.ndarray) -> list:
    return np.asarray(T, dtype=float).tolist()


def _intr(K) -> dict:
    return {"fx_px": K.fx, "fy_px": K.fy, "cx_px": K.cx, "cy_px": K.cy, "width_px": K.width, "height_px": K.height,
            "dist_k1_k2_p1_p2_k3": list(K.dist)}


def truth_dict(world: Any, captures: Sequence[Capture]) -> dict[str, Any]:
    """The truth of ``world`` and of ``captures`` as a JSON-ready dict (see ``docs/formats.md``).

    ``world`` is a :class:`twin.world.World` (taken by its public ``true_*`` members and attributes, not
    imported here: the world imports this module, not the other way round).
    """
    tr = world.true_robot
    nom = world.nominal_robot
    il, ir = world.true_intrinsics()
    stations = []
    for s, st in enumerate(world.config.stations):
        left, right = world.true_cam2world(s)
        stations.append({
            "index": s,
            "name": st.name,
            "base2meas": _m(world.true_base2meas(s)),
            "left_cam2world": _m(left),
            "right_cam2world": _m(right),
        })
    poses = []
    for c in captures:
        row = {
            "pose_id": int(c.pose_id),
            "station": int(c.station),
            "q_cmd_rad": np.asarray(c.q_cmd, dtype=float).tolist(),
            "q_actual_rad": np.asarray(c.q_actual, dtype=float).tolist(),
            "spheres_meas_m": np.asarray(c.spheres_meas, dtype=float).tolist(),
            "tool2meas": _m(c.tool2meas),
            "t_s": float(c.t_s),
            "temp_c": float(c.temp_c),
        }
        if c.params is not None:
            row["params_actual"] = np.asarray(c.params, dtype=float).tolist()
        poses.append(row)
    return {
        "schema_version": TRUTH_SCHEMA_VERSION,
        "robot": {
            "name": nom.name,
            "convention": tr.convention,
            "beta_joints": list(tr.beta_joints),
            "parameter_names": list(tr.layout.names),
            "parameter_units": list(tr.layout.units),
            "nominal": nom.params.tolist(),
            "true": tr.params.tolist(),
            "note": "true base_* is base2world (robot base in the lab frame); per-station base2meas under stations",
        },
        "base2world": _m(world.true_base2world()),
        "tool2flange": _m(tr.tool2flange),
        "plate": {
            "sphere_diameter_m": world.nominal_plate.sphere_diameter,
            "nominal_spheres_flange_m": world.nominal_plate.spheres_flange.tolist(),
            "spheres_tool_m": np.asarray(world.true_spheres_tool).tolist(),
            "spheres_flange_m": (world.true_spheres_tool @ tr.tool2flange[:3, :3].T + tr.tool2flange[:3, 3]).tolist(),
            "plate_error2flange": _m(world.plate_error2flange),
        },
        "cameras": {
            "left": _intr(il),
            "right": _intr(ir),
            "left2right": _m(world.true_left2right()),
            "render_scale": world.config.render.scale,
            "render_supersample": world.config.render.supersample,
            "render_window_supersample": world.config.render.window_supersample,
            "render_frame_subsample": world.frame_subsample,
            "noise_sigma_grey": world.config.render.noise_sigma,
        },
        "stations": stations,
        "effects": [{"name": getattr(e, "name", type(e).__name__), "params": e.params()} for e in world.effects],
        "poses": poses,
        "board_views": [{"index": int(k), "board2meas": _m(T)} for k, T in world.truth_board_views],
        "config": {"seed": world.config.seed, "preset": world.config.preset},
    }


def _check_finite(obj: Any, where: str = "truth") -> None:
    if isinstance(obj, float):
        if not math.isfinite(obj):
            raise ValueError(f"{where}: non-finite number {obj!r}")
    elif isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, f"{where}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            _check_finite(v, f"{where}[{i}]")


def write_truth(path: str | os.PathLike, truth: dict[str, Any]) -> Path:
    """Write ``truth`` (from :func:`truth_dict`) to ``path`` atomically; refuses non-finite numbers."""
    if not isinstance(truth, dict) or truth.get("schema_version") != TRUTH_SCHEMA_VERSION:
        raise ValueError(f"truth must be a dict with schema_version {TRUTH_SCHEMA_VERSION}")
    _check_finite(truth)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(truth, indent=1) + "\n")
    os.replace(tmp, path)
    return path
