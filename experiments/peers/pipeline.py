"""The ``pipeline`` section: what one measured pose costs in a rendered campaign, stage by stage, against
MuJoCo's bare rendering of the same two images (the limit for a rendered twin).

The campaign's own measurement backend is used (``twin.runner.measure``, ``images`` mode, the
``experiments/separation.toml`` campaign at full resolution), on the first poses of its plan:

* ``bare_render``: ``mujoco.Renderer.update_scene`` + ``render()`` for both cameras of the same scene (as the
  world's own benchmark does, ``experiments/bench_world.py``);
* ``render``: the world's capture -- kinematics and effects, both cameras rendered, grey, lens distortion, sensor
  noise, truth of the pose (``timings["render_s"]`` of the backend);
* ``detect``: the time ``measure_pair`` spends in the instrument's sphere detection on both images (the calls
  to ``detect_spheres`` inside it are timed by a wrapper; nothing else changes);
* ``triangulate``: the rest of ``measure_pair`` -- matching, triangulation with the perspective-bias correction,
  labelling (the backend's ``measure_s`` minus ``detect``);
* ``write``: JPEG encoding of the pair for the recording (``encode_s``) plus the atomic write of the pose's
  result file (``PoseStore.write``), as the campaign does for every pose.

The one-off costs of a campaign (renderer start-up, the stereo calibration from board views) are reported
apart. Medians over the poses; the bare render is interleaved with the pipeline so machine load hits both.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["pipeline_section"]

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "experiments" / "separation.toml"


def pipeline_section(quick: bool = False, poses: int = 12) -> dict:
    try:
        from twin.runtime import set_process_defaults

        set_process_defaults()  # MUJOCO_GL=egl before mujoco loads
        import mujoco
        from twin.runner.config import load_campaign_config
        from twin.runner.measure import PoseTask, backend_spec_for, get_backend
        from twin.runner.plan import make_plan, pose_seed
        from twin.runner.store import PoseStore
        import twin.instrument.measure as instrument_measure
    except ImportError as e:
        return {"missing": f"world / instrument / runner modules not available ({e}); nothing measured"}
    n = 3 if quick else poses
    cfg = load_campaign_config(CONFIG)
    out: dict = {"config": str(CONFIG.relative_to(ROOT)), "poses": n, "load_average_1min_at_start": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / "work"
        spec = backend_spec_for(cfg, work, None)
        t = time.perf_counter()
        backend = get_backend(spec)
        backend.prepare()
        out["one_off_prepare_s"] = time.perf_counter() - t  # world build + board views + stereo calibration
        world = backend.world
        plan = make_plan(cfg)
        store = PoseStore(work / "poses")
        w, h = world.image_size
        bare_renderer = mujoco.Renderer(world.model, h, w)
        spent = {"detect": 0.0}
        original_detect = instrument_measure.detect_spheres

        def timed_detect(*a, **k):
            t = time.perf_counter()
            try:
                return original_detect(*a, **k)
            finally:
                spent["detect"] += time.perf_counter() - t

        instrument_measure.detect_spheres = timed_detect
        rows = {k: [] for k in ("bare_render", "render", "detect", "triangulate", "write", "whole")}
        statuses = []
        for i in range(n + 1):  # the first pose warms up (renderer creation, caches); not counted
            key = f"m/{int(plan.pose_id[i]):05d}"
            task = PoseTask(key, int(plan.pose_id[i]), plan.q[i], str(plan.station[i]), pose_seed(cfg.seed, key),
                            plan.q[i - 1] if i > 0 else None)
            # bare MuJoCo: same model and scene, both cameras
            world.place(np.asarray(task.q, dtype=float), backend.station_index[task.station])
            t = time.perf_counter()
            world.render_bare(bare_renderer)
            bare = time.perf_counter() - t
            spent["detect"] = 0.0
            t = time.perf_counter()
            res = backend.measure(task)
            store.write(res)
            whole = time.perf_counter() - t
            detect = spent["detect"]
            if i == 0:
                continue
            write = whole - res.timings["render_s"] - res.timings["measure_s"]
            rows["bare_render"].append(bare)
            rows["render"].append(res.timings["render_s"])
            rows["detect"].append(detect)
            rows["triangulate"].append(max(res.timings["measure_s"] - detect, 0.0))
            rows["write"].append(write)
            rows["whole"].append(whole)
            statuses.append({"spheres": sum(s is not None for s in res.spheres), "status": res.status})
        instrument_measure.detect_spheres = original_detect
        bare_renderer.close()
    med = {k: float(np.median(v)) for k, v in rows.items()}
    out.update(
        {
            "image_size_px": [int(w), int(h)],
            "stages": [
                {"stage": "bare MuJoCo render (both cameras)", "seconds": med["bare_render"]},
                {"stage": "render (world capture: render, grey, distortion, noise, truth)", "seconds": med["render"]},
                {"stage": "detect (both images)", "seconds": med["detect"]},
                {"stage": "triangulate (match, triangulate, label)", "seconds": med["triangulate"]},
                {"stage": "write (JPEG for the recording, pose file)", "seconds": med["write"]},
                {"stage": "whole pose (render + detect + triangulate + write)", "seconds": med["whole"]},
            ],
            "ratio_to_bare_render": med["whole"] / med["bare_render"],
            "ratio_render_to_bare_render": med["render"] / med["bare_render"],
            "target_ratio": 2.0,
            "spheres_measured_per_pose": statuses,
            "runs_seconds": {k: [round(x, 5) for x in v] for k, v in rows.items()},
            "load_average_1min_at_end": os.getloadavg()[0],
        }
    )
    return out
