"""Helpers of the campaign tests: a small config, a reference least-squares identification (a stand-in for
the estimator so the runner's tests do not depend on it), and counting backends."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np

from twin.dataset import Dataset
from twin.runner.config import parse_campaign_config
from twin.runner.methods import MethodResult
from twin.runner.measure import TruthNoiseBackend
from twin.kinematics import point_jacobian, tool2meas
from twin.transforms import pose6_to_transform, transform_to_pose6

SMALL_TOML = """
schema_version = 1
name = "small"
seed = 7
methods = ["full_pose"]

[world]
robot = "irb1200"
preset = "separation_tables_2_4"
[world.rig]
baseline_mm = 250
standoff_mm = 700
[world.render]
scale = 0.25        # truth_noise renders nothing; a small sensor keeps the world's start-up short
[[world.stations]]
name = "front"
target_mm = [500, 0, 550]
elevation_deg = 5
[[world.stations]]
name = "left"
target_mm = [420, 220, 450]
azimuth_deg = 35
elevation_deg = 10

[sampling]
max_roll_deg = 45

[measurement]
mode = "truth_noise"
noise_mm = 0.01

[[poses]]
name = "calibration"
set = "calibration"
kind = "motion_pairs"
count = 12

[[poses]]
name = "compensation"
set = "validation"
kind = "motion_pairs"
count = 4
evaluate = ["angle"]

[[poses]]
name = "distance"
set = "validation"
kind = "distance_moves"
distances_mm = [50, 100]
per_distance = 2
evaluate = ["position"]

[outputs]
recording = false
figures = false

[execution]
workers = 1
"""


def small_config(**over):
    raw = tomllib.loads(SMALL_TOML)
    for k, v in over.items():
        raw[k] = v
    return parse_campaign_config(raw)


def reference_full_pose(dataset: Dataset, seed: int, iterations: int = 8) -> MethodResult:
    """Gauss-Newton on the sphere centres: every chain parameter plus a base2meas per station (tool held at
    nominal), minimum-norm steps (lstsq) so unidentifiable combinations stay at their start. Uses only the
    dataset: the calibration rows, the nominal model, the plate and the nominal station frames."""
    cal = dataset.subset(dataset.set == "calibration") if dataset.set is not None else dataset
    ok = cal.sphere_seen.all(axis=1)
    cal = cal.subset(ok)
    nominal = dataset.robot
    lay = nominal.layout
    chain = np.array([i for i, n in enumerate(lay.names) if not n.startswith(("base_", "tool_"))])
    stations = sorted(set(cal.station_ids.tolist()))
    base = {s: transform_to_pose6(dataset.stations_base2meas.get(s, np.eye(4))) for s in stations}
    x = nominal.params.copy()
    pts = dataset.plate.spheres_flange
    for _ in range(iterations):
        rows_J, rows_r = [], []
        for k, s in enumerate(stations):
            sel = cal.station_ids == s
            p = x.copy()
            p[lay.base_slice] = base[s]
            m = nominal.with_params(p)
            T = tool2meas(m, cal.q[sel])
            pred = np.einsum("nij,mj->nmi", T[:, :3, :3], pts) + T[:, None, :3, 3]
            r = (cal.spheres[sel] - pred).reshape(-1)
            J = point_jacobian(m, cal.q[sel], pts).reshape(-1, lay.size)
            Jfull = np.zeros((J.shape[0], chain.size + 6 * len(stations)))
            Jfull[:, : chain.size] = J[:, chain]
            Jfull[:, chain.size + 6 * k: chain.size + 6 * k + 6] = J[:, lay.base_slice]
            rows_J.append(Jfull)
            rows_r.append(r)
        J = np.vstack(rows_J)
        r = np.concatenate(rows_r)
        scale = np.linalg.norm(J, axis=0) + 1e-12
        dx = np.linalg.lstsq(J / scale, r, rcond=1e-10)[0] / scale
        x[chain] += dx[: chain.size]
        for k, s in enumerate(stations):
            base[s] = transform_to_pose6(pose6_to_transform(base[s] + dx[chain.size + 6 * k: chain.size + 6 * k + 6]))
    robot = nominal.with_params(x).with_frames(base2meas=np.eye(4))
    return MethodResult("full_pose", robot, {s: pose6_to_transform(b) for s, b in base.items()},
                        tuple(lay.names[i] for i in chain), {"iterations": iterations})


class CountingBackend(TruthNoiseBackend):
    """The truth-noise backend that counts its renders in a file and can stop the campaign after N of them
    (``TWIN_TEST_KILL_AFTER``), as if the process had been killed."""

    def measure(self, task):
        path = Path(self.spec.work_dir) / "count.txt"
        n = int(path.read_text()) if path.exists() else 0
        limit = os.environ.get("TWIN_TEST_KILL_AFTER")
        if limit is not None and n >= int(limit):
            raise KeyboardInterrupt("simulated kill")
        path.write_text(str(n + 1))
        return super().measure(task)


class BlindAfterBackend(TruthNoiseBackend):
    """The truth-noise backend whose compensated measurements all fail (no sphere seen), as if the
    instrument lost the plate after compensation."""

    def measure(self, task):
        from dataclasses import replace

        r = super().measure(task)
        if task.key.startswith("c/"):
            r = replace(r, spheres=[None, None, None], status="p0:not_found;p1:not_found;p2:not_found")
        return r
