"""``twin measure --render``: the measure stage alone, on configurations given by the user (or drawn in view).

The world renders each commanded configuration in order, in one process (the world's own image-noise sequence,
as a rig filming one pose after the other), and the instrument measures it through the runner's one loop
(:mod:`twin.runner.measure`); the rig is calibrated from rendered board views, never read from the world. The
dataset goes to one folder, the truth of the rendered poses to a separate file that only evaluation reads.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..dataset import Joints, Plate, write_dataset_toml
from ..instrument.folder import CALIBRATION_FILE, MeasureSummary, instrument_provenance
from ..world.effects import contexts_for_sequence
from ..world.truth import write_truth
from .executor import SerialExecutor
from .measure import BACKENDS, BackendSpec, InstrumentSetup, PoseTask, get_backend, measure_tasks
from .measure import write_measured_dataset
from .store import MemoryStore, PoseResult

__all__ = ["measure_rendered"]


def measure_rendered(
    world: dict[str, Any],
    out: str | os.PathLike,
    *,
    joints: Joints | None = None,
    poses: int = 20,
    station: int = 0,
    seed: int = 0,
    plate: Plate | None = None,
    calibration_file: str | os.PathLike | None = None,
    board_views: int | None = None,
    bias_correction: bool = True,
    keep_images: str | os.PathLike | None = None,
    truth: str | os.PathLike | None = None,
    robot: Any = None,
    provenance: str = "",
    on_row: Callable[[int, PoseResult], None] | None = None,
) -> MeasureSummary:
    """Render and measure ``joints`` (or ``poses`` configurations the cameras see at ``station``, drawn with
    ``seed``) with the world of the ``[world]`` table ``world``; write the dataset folder ``out`` (``poses.csv``,
    ``dataset.toml``, the stereo calibration) and the truth file (default ``truth.json`` beside ``out``).

    ``plate``: the nominal plate of the dataset (default the world's); ``calibration_file``: a stereo
    calibration to use instead of calibrating from ``board_views`` rendered board views; ``keep_images``: also
    write the rendered image folder there (what ``twin render`` writes); ``robot``: the name in
    ``dataset.toml`` (default the world's robot, or ``irb1200`` for an inline table). ``on_row(k, result)``
    after each measured row.
    """
    from ..world.images import ImageFolderWriter

    out = Path(out)
    setup = InstrumentSetup(world=dict(world), mode="images", bias_correction=bias_correction, board_views=board_views,
                            calibration_file=None if calibration_file is None else str(calibration_file), plate=plate)
    spec = BackendSpec(BACKENDS["images"], setup, work_dir=None)
    backend = get_backend(spec)
    w = backend.world
    writer = ImageFolderWriter(keep_images, w.rig_info()) if keep_images is not None else None
    row: dict[int, int] = {}

    def sink(kind: str, what, left: np.ndarray, right: np.ndarray) -> None:
        if kind == "board":
            writer.add_board_view(left, right)
            return
        k = row[int(what.pose_id)]
        writer.add_pair(
            int(what.pose_id), joints.q[k], left, right, station=None if joints.station is None else joints.station[k],
            set=None if joints.set is None else joints.set[k],
            temp_c=None if joints.temp_c is None else float(joints.temp_c[k]),
            t_s=None if joints.t_s is None else float(joints.t_s[k]),
        )

    if writer is not None:
        backend.image_sink = sink
    backend.prepare()  # the board views first (the world's image-noise sequence starts with them)
    if joints is None:
        q = w.visible_configurations(station, poses, seed=seed)
        joints = Joints(np.arange(len(q)), q, station=np.array([str(station)] * len(q), dtype=object))
    row.update({int(pid): k for k, pid in enumerate(joints.pose_id)})
    n = len(joints.pose_id)
    st_idx = [w.station_index(s) for s in joints.station] if joints.station is not None else [0] * n
    ctx = contexts_for_sequence(joints.q, t_s=joints.t_s, temp_c=joints.temp_c, stations=st_idx)
    tasks = [PoseTask(f"m/{int(pid):05d}", int(pid), joints.q[k], w.station_names[st_idx[k]], None, context=ctx[k])
             for k, pid in enumerate(joints.pose_id)]
    calib = backend.calibration
    out.mkdir(parents=True, exist_ok=True)
    calib.save(out / CALIBRATION_FILE)
    store = MemoryStore()
    measure_tasks(SerialExecutor(), spec, tasks, store,
                  on_result=None if on_row is None else (lambda task, res: on_row(row[int(task.pose_id)], res)))
    results = [store.read(t.key) for t in tasks]
    if robot is None:
        robot = w.config.robot if isinstance(w.config.robot, str) else "irb1200"
    prov = provenance or f"twin measure --render (world seed {w.config.seed})"
    prov = f"{prov}; {instrument_provenance(calib, bias_correction)}"
    write_dataset_toml(out, robot, backend.plate, provenance=prov)
    rows = write_measured_dataset(out, results, joints.q, set=joints.set, station=joints.station, t_s=joints.t_s,
                                  temp_c=joints.temp_c)
    write_truth(Path(truth) if truth is not None else out.parent / "truth.json", backend.truth_record(results))
    w.close()
    return rows.summary(calib)
