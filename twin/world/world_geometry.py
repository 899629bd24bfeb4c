"""The world's geometry: its stations and cameras as placed, and where the robot's plate and spheres truly are.

A part of :class:`twin.world.World` (it uses the model, data and placement the world builds). Everything named
``true_*`` is truth.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from ..camera import CameraIntrinsics, mujoco_to_opencv_cam2world, project_points
from ..kinematics import N_JOINTS, RobotModel
from ..transforms import invert_transform, make_transform, matrix_to_quat_wxyz
from ..units import MM_PER_M

__all__ = ["WorldGeometry"]


class WorldGeometry:
    """Stations, cameras and true poses of :class:`twin.world.World`."""

    @property
    def station_names(self) -> list[str]:
        return [s.name for s in self.config.stations]

    @property
    def n_stations(self) -> int:
        return len(self.config.stations)

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` [px] of the images."""
        return self._pipes[0].intr.width, self._pipes[0].intr.height

    def rig_info(self) -> dict:
        """The content of ``rig.toml`` (image size, board geometry): no intrinsics, those are estimated."""
        b = self.config.board
        w, h = self.image_size
        return {
            "schema_version": 1,
            "image_width": w,
            "image_height": h,
            "board": {
                "type": "charuco",
                "squares_x": b.squares_x,
                "squares_y": b.squares_y,
                "square_mm": round(b.square * MM_PER_M, 9),
                "marker_mm": round(b.marker * MM_PER_M, 9),
                "dictionary": b.dictionary,
            },
        }

    def _check_station(self, station: int) -> int:
        try:
            s = int(station)
        except (TypeError, ValueError):
            raise ValueError(f"station must be an index 0..{self.n_stations - 1}, got {station!r}") from None
        if not 0 <= s < self.n_stations:
            raise ValueError(f"station must be an index 0..{self.n_stations - 1}, got {station!r}")
        return s

    def true_rig2world(self, station: int) -> np.ndarray:
        """Rig pose ``(4, 4)`` in the lab frame (MuJoCo axes) at ``station``."""
        return self._rig2world[self._check_station(station)].copy()

    def true_cam2world(self, station: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right camera poses ``(4, 4)`` in the lab frame, OpenCV camera axes."""
        R = self._rig2world[self._check_station(station)]
        out = []
        for c2r in self._cam2rig:
            T = R @ c2r  # MuJoCo camera axes; the one flip function turns them into OpenCV's
            out.append(mujoco_to_opencv_cam2world(T[:3, 3], T[:3, :3].reshape(9)))
        return out[0], out[1]

    def true_base2world(self) -> np.ndarray:
        """True robot base pose ``(4, 4)`` in the lab (MuJoCo world) frame."""
        return self.true_robot.base2meas.copy()

    def true_base2meas(self, station: int) -> np.ndarray:
        """True ``base2meas`` ``(4, 4)`` of ``station`` (measurement frame = left camera, OpenCV axes)."""
        left, _ = self.true_cam2world(station)
        return invert_transform(left) @ self.true_robot.base2meas

    def true_intrinsics(self) -> tuple[CameraIntrinsics, CameraIntrinsics]:
        """True intrinsics of the left and right cameras (at the render scale)."""
        return self._pipes[0].intr, self._pipes[1].intr

    def true_left2right(self) -> np.ndarray:
        """True stereo extrinsics ``(4, 4)``: left-camera points -> right-camera points (OpenCV axes)."""
        left, right = self.true_cam2world(0)
        return invert_transform(right) @ left

    def true_model_for_station(self, station: int) -> RobotModel:
        """The true robot with ``base2meas`` of ``station``: ``tool2meas(model, q_actual)`` is the plate pose."""
        return self.true_robot.with_frames(base2meas=self.true_base2meas(station))

    def _place(self, q_actual: np.ndarray, station: int | None = None) -> None:
        q = np.asarray(q_actual, dtype=float).reshape(-1)
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_actual must be {N_JOINTS} finite joint angles [rad], got {q_actual!r}")
        self.data.qpos[self._qadr] = q
        if station is not None and station != self._station:
            T = self._rig2world[station]
            k = self._mocap["rig"]
            self.data.mocap_pos[k] = T[:3, 3]
            self.data.mocap_quat[k] = matrix_to_quat_wxyz(T[:3, :3])
            self._station = station
        # Body, site and camera poses only: mj_kinematics places bodies/sites from qpos and mocap poses,
        # mj_camlight the cameras and lights; nothing dynamic (inertia, forces) is needed to render.
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def place(self, q_actual: np.ndarray, station: int = 0) -> None:
        """Put the twin at actual joints ``q_actual`` ``(6,)`` [rad] with the rig at ``station`` (MuJoCo state only:
        no effect is evaluated, nothing is recorded), for :meth:`render_bare`."""
        self._place(q_actual, self._check_station(station))

    def true_spheres_meas(self, q_actual: np.ndarray, station: int) -> np.ndarray:
        """True sphere centres ``(3, 3)`` [m] (rows p0, p1, p2) in ``station``'s measurement frame."""
        station = self._check_station(station)
        self._place(q_actual)
        p_world = np.array([self.data.site_xpos[s] for s in self._sphere_sites])
        w2m = invert_transform(self.true_cam2world(station)[0])
        return p_world @ w2m[:3, :3].T + w2m[:3, 3]

    def true_tool2meas(self, q_actual: np.ndarray, station: int) -> np.ndarray:
        """True plate (tool) pose ``(4, 4)`` in ``station``'s measurement frame."""
        station = self._check_station(station)
        self._place(q_actual)
        T = make_transform(self.data.site_xmat[self._plate_site].reshape(3, 3), self.data.site_xpos[self._plate_site])
        return invert_transform(self.true_cam2world(station)[0]) @ T

    def mujoco_cam2world(self, station: int) -> tuple[np.ndarray, np.ndarray]:
        """Camera poses (OpenCV axes) as MuJoCo places them (``data.cam_xpos/xmat``), for cross-checks."""
        station = self._check_station(station)
        self._place(self.data.qpos[self._qadr].copy(), station)
        return tuple(mujoco_to_opencv_cam2world(self.data.cam_xpos[c], self.data.cam_xmat[c]) for c in self._cam_ids)

    def project_spheres(self, spheres_meas: np.ndarray, station: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """True pixel positions ``(3, 2)`` of sphere centres in the left and right images (truth)."""
        station = self._check_station(station)
        il, ir = self.true_intrinsics()
        l2r = self.true_left2right()
        return project_points(spheres_meas, np.eye(4), il), project_points(spheres_meas, l2r, ir)

    def station_index(self, station: Any) -> int:
        """Index of a station given by index (int or digit string) or by name."""
        if isinstance(station, (int, np.integer)):
            return self._check_station(int(station))
        s = str(station).strip()
        if s in self.station_names:
            return self.station_names.index(s)
        if s.lstrip("-").isdigit():
            return self._check_station(int(s))
        raise ValueError(f"unknown station {station!r}; stations: {self.station_names}")
