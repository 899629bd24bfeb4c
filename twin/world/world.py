"""The world: a MuJoCo twin of the robot with its plate, the stereo rig at its stations, and the board.

Commanded joints in, rendered 8-bit greyscale stereo images out. The world knows the truth (true
parameters, true plate, true cameras, actual joints, true sphere centres) and hands it out only through
the ``true_*`` methods and the truth file, which only evaluation reads. Nothing it passes to the
instrument (images, :meth:`World.rig_info`) carries camera parameters.

MuJoCo calls: placing bodies and cameras needs only ``mj_kinematics`` (body/site poses from ``qpos`` and
mocap poses) and ``mj_camlight`` (camera and light poses from the bodies); ``mj_forward`` would also run
inertia, actuation and constraint stages that nothing here needs. Gravity statics (the ``compliance``
effect) run ``mj_kinematics`` + ``mj_comPos`` + ``mj_comVel`` + ``mj_rne`` on a separate ``MjData``
(:meth:`World.gravity_torque`).
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: offscreen rendering through Mesa EGL

import cv2
import mujoco
import numpy as np

from ..camera import CameraIntrinsics, discs_in_image, mujoco_to_opencv_cam2world, project_points
from ..dataset import Plate, default_plate
from ..kinematics import N_JOINTS, RobotModel, UnreachableError, closest_branch, inverse_kinematics_closed_form
from ..transforms import invert_transform, make_transform, matrix_to_quat_wxyz, pose6_to_transform, rotvec_to_matrix
from . import mjcf
from .board import board_extent, board_texcoords, board_texture, sample_board_poses
from .config import WorldConfig, nominal_robot_from_spec
from .effects import (
    EffectContext,
    SceneState,
    apply_geometry_effects,
    apply_joint_effects,
    apply_scene_effects,
    as_effect,
    contexts_for_sequence,
)
from .effects_catalogue import effect_from_spec
from .render import CameraPipeline, ImageFormer, scene_option
from .records import BoardView, Capture
from .rig import camera2rig, station_rig2world, true_intrinsics
from .truth import truth_dict as _truth_dict
from .truth import write_truth as _write_truth

__all__ = ["World", "Capture", "BoardView"]

_BOARD_TEXTURE = "board_texture.png"
_PROBE_TEXTURE = "probe_texture.png"


def _png_bytes(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def _probe_texture(size: int = 64, sigma: float = 8.0, peak: float = 225.0) -> np.ndarray:
    c = (size - 1) / 2.0
    u = np.arange(size) - c
    g = np.exp(-0.5 * (u[None, :] ** 2 + u[:, None] ** 2) / sigma**2) * peak
    return np.round(g).astype(np.uint8)


class World:
    """The truth side of the testbed. Build with :meth:`from_config`.

    Public data a real user also has: :attr:`nominal_robot`, :attr:`nominal_plate`, :meth:`rig_info`,
    :attr:`station_names`. Everything named ``true_*`` is truth.
    """

    def __init__(self, config: WorldConfig, effects: Sequence[Any] = ()):
        if not isinstance(config, WorldConfig):
            raise ValueError(f"config must be a WorldConfig (use World.from_config for a dict), got {type(config).__name__}")
        self.config = cfg = config
        self.nominal_robot: RobotModel = nominal_robot_from_spec(cfg.robot)
        self.nominal_plate: Plate = default_plate()
        rng = np.random.default_rng([cfg.seed, 0])

        # --- the true robot: nominal on its mount + injected deviations + the plate's own error --------
        mounted = self.nominal_robot.with_frames(base2meas=pose6_to_transform(cfg.mount_pose6))
        true = mounted.perturbed(cfg.deviation(self.nominal_robot), name=f"{self.nominal_robot.name}_true")
        pc = cfg.plate
        plate_err = rng.normal(size=6) * np.array([pc.translation_sigma] * 3 + [pc.rotation_sigma] * 3)
        plate_err = plate_err + pc.error_pose6
        self.plate_error2flange = pose6_to_transform(plate_err)
        self.true_robot: RobotModel = true.with_frames(tool2flange=true.tool2flange @ self.plate_error2flange)
        self.true_spheres_tool = self.nominal_plate.spheres_flange + rng.normal(size=(3, 3)) * pc.sphere_sigma

        # --- effects -----------------------------------------------------------------------------------
        self.effects: list = [effect_from_spec(s) for s in cfg.effects] + [as_effect(e) for e in effects]

        # --- cameras -----------------------------------------------------------------------------------
        il, ir = true_intrinsics(cfg.rig, cfg.render)
        ss = cfg.render.supersample
        # image effects work on the whole ideal render of one sampling grid (and turn the windows off): with
        # them the frame is rendered at full resolution whatever render.frame_subsample says
        self.frame_subsample = 1 if any(getattr(e, "changes_image", True) for e in self.effects) else cfg.render.frame_subsample
        fs = self.frame_subsample
        if il.width % fs or il.height % fs:
            raise ValueError(f"world.render.frame_subsample = {fs} must divide the image size {il.width}x{il.height} "
                             f"(render.scale {cfg.render.scale})")
        self._pipes = (CameraPipeline.build("left", il, ss, fs), CameraPipeline.build("right", ir, ss, fs))
        # the rig as placed: the nominal geometry with seeded placement errors (its own random stream, so that
        # the other draws do not depend on the tolerances); the nominal one is what a dataset states
        rig_rng = np.random.default_rng([cfg.seed, 7])
        rc = cfg.rig

        def placement_error(sigma: float, sigma_rot: float) -> np.ndarray:
            return pose6_to_transform(rig_rng.normal(size=6) * np.array([sigma] * 3 + [sigma_rot] * 3))

        self._cam2rig = tuple(c2r @ placement_error(rc.camera_mount_sigma, rc.camera_mount_sigma_rot)
                              for c2r in camera2rig(rc))
        self._rig2world = [station_rig2world(s, rc) @ placement_error(rc.placement_sigma, rc.placement_sigma_rot)
                           for s in cfg.stations]

        # --- MJCF -------------------------------------------------------------------------------------
        board_tex = board_texture(cfg.board)
        self._assets = {_BOARD_TEXTURE: _png_bytes(board_tex), _PROBE_TEXTURE: _png_bytes(_probe_texture())}
        r = cfg.render
        key_dir = np.array([
            -np.sin(r.key_light_azimuth) * np.cos(r.key_light_elevation),
            -np.sin(r.key_light_elevation),
            -np.cos(r.key_light_azimuth) * np.cos(r.key_light_elevation),
        ])  # light travels into the scene (-z of the rig), coming from the upper left at the defaults
        backdrop = cfg.rig.backdrop_behind
        far = cfg.rig.standoff + (backdrop if backdrop is not None else 0.3)
        half_view = 0.5 * far * cfg.rig.width_px / cfg.rig.focal_px
        opts = mjcf.ComposeOptions(
            camera_poses_rig=self._cam2rig,
            fovy_deg=(self._pipes[0].fovy_deg, self._pipes[1].fovy_deg),
            backdrop_distance=far if backdrop is not None else 50.0,
            backdrop_half_size=(half_view + cfg.rig.baseline + 0.1, 0.8 * half_view + 0.1),
            key_light_dir_rig=key_dir,
            key_light_diffuse=r.key_light,
            key_light_ambient=r.key_ambient,
            headlight_diffuse=r.headlight,
            headlight_ambient=r.ambient,
            board_extent=board_extent(cfg.board),
            board_thickness=cfg.board.thickness,
            board_texture_file=_BOARD_TEXTURE,
            board_texcoords=board_texcoords(cfg.board),
            # the offscreen buffer holds the supersampled render (s times the image along each axis)
            offwidth=max(il.width * cfg.render.supersample, 64),
            offheight=max(il.height * cfg.render.supersample, 64),
            probe_texture_file=_PROBE_TEXTURE,
        )
        robot_el = mjcf.robot_body_element(self.true_robot, self.true_spheres_tool, self.nominal_plate.sphere_diameter)
        self.mjcf_xml: str = mjcf.compose_twin_xml(robot_el, opts, model_name=f"twin_{self.nominal_robot.name}")
        self.model = mujoco.MjModel.from_xml_string(self.mjcf_xml, self._assets)
        self.data = mujoco.MjData(self.model)
        m = self.model

        def oid(kind, name):
            i = mujoco.mj_name2id(m, kind, name)
            if i < 0:
                raise RuntimeError(f"composed twin lacks {name!r}")
            return i

        self._cam_ids = (oid(mujoco.mjtObj.mjOBJ_CAMERA, "left"), oid(mujoco.mjtObj.mjOBJ_CAMERA, "right"))
        self._sphere_sites = [oid(mujoco.mjtObj.mjOBJ_SITE, f"sphere{k}") for k in range(3)]
        self._plate_site = oid(mujoco.mjtObj.mjOBJ_SITE, "plate")
        self._mocap = {
            name: int(m.body_mocapid[oid(mujoco.mjtObj.mjOBJ_BODY, name)]) for name in ("rig", "board", "probe")
        }
        self._jnt_ids = [oid(mujoco.mjtObj.mjOBJ_JOINT, f"joint{i + 1}") for i in range(N_JOINTS)]
        self._qadr = np.array([m.jnt_qposadr[j] for j in self._jnt_ids])
        self._dofadr = np.array([m.jnt_dofadr[j] for j in self._jnt_ids])
        self._plate_body = oid(mujoco.mjtObj.mjOBJ_BODY, "plate")
        self._sphere_geoms = [oid(mujoco.mjtObj.mjOBJ_GEOM, f"sphere{k}") for k in range(3)]
        r = 0.5 * self.nominal_plate.sphere_diameter
        self._default_scene = SceneState(np.full((3, 3), r))
        self._scene = self._default_scene
        # statics run on their own MjData so that they never disturb the pose being rendered
        self._statics = mujoco.MjData(m)
        self._robot_bodies = [oid(mujoco.mjtObj.mjOBJ_BODY, n) for n in
                              ["robot_base"] + [f"link{i + 1}" for i in range(N_JOINTS)] + ["plate"]]
        self._opt_pairs = scene_option((mjcf.GROUP_SCENE, mjcf.GROUP_ROBOT, mjcf.GROUP_PLATE, mjcf.GROUP_BACKDROP))
        self._opt_board = scene_option((mjcf.GROUP_SCENE, mjcf.GROUP_BOARD))
        self._opt_probe = scene_option((mjcf.GROUP_PROBE,))
        self._former: ImageFormer | None = None
        self._station: int | None = None
        self._geometry_robot: RobotModel = self.true_robot
        self._image_counter = 0
        self._next_pose_id = 0
        self._prev: tuple[np.ndarray, np.ndarray] | None = None
        self._history: list[np.ndarray] = []  # every command executed since reset_history, in order
        self._q_start: np.ndarray | None = None
        self._true_jg = mjcf.joint_geometry(self.true_robot)
        self.truth_poses: list[Capture] = []  # truth of every capture (images dropped), for write_truth
        self.truth_board_views: list[tuple[int, np.ndarray]] = []
        self.last_capture: Capture | None = None
        self._hide("board")
        self._hide("probe")

    # ------------------------------------------------------------------------------------------------
    @classmethod
    def from_config(cls, config: WorldConfig | Mapping[str, Any], effects: Sequence[Any] = ()) -> "World":
        """A world from a :class:`WorldConfig` or a config table (the ``[world]`` table or a whole config)."""
        if not isinstance(config, WorldConfig):
            config = WorldConfig.from_dict(config)
        return cls(config, effects)

    # --- what a real user knows ----------------------------------------------------------------------
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
                "square_mm": round(b.square * 1e3, 9),
                "marker_mm": round(b.marker * 1e3, 9),
                "dictionary": b.dictionary,
            },
        }

    def write_mjcf(self, folder: str | os.PathLike, name: str = "twin.xml") -> Path:
        """Write the composed MJCF and its textures into ``folder``; the file loads on its own."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for fname, data in self._assets.items():
            (folder / fname).write_bytes(data)
        path = folder / name
        path.write_text(self.mjcf_xml)
        return path

    # --- truth ---------------------------------------------------------------------------------------
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

    def render_bare(self, renderer: mujoco.Renderer) -> list[np.ndarray]:
        """MuJoCo's own render of both cameras at the current placement (:meth:`place`) with ``renderer`` (a
        ``mujoco.Renderer`` of :attr:`model`): no image formation (no windows, distortion or noise). The reference
        cost of a render, for benchmarks."""
        out = []
        for cam in self._cam_ids:
            renderer.update_scene(self.data, camera=cam, scene_option=self._opt_pairs)
            out.append(renderer.render())
        return out

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

    # --- commanded -> actual -------------------------------------------------------------------------
    def temperature_c(self, t_s: float) -> float | None:
        """The robot's true temperature [°C] at ``t_s`` [s] when an effect defines it (the first effect with a
        ``temperature_c(t_s)`` that is not ``None``, e.g. ``thermal`` in warm-up mode), else ``None``."""
        for e in self.effects:
            f = getattr(e, "temperature_c", None)
            if callable(f):
                T = f(t_s)
                if T is not None:
                    return float(T)
        return None

    def reset_history(self, q_start: np.ndarray | None = None) -> None:
        """Start a new campaign: forget the commands executed so far; the robot starts at ``q_start`` ``(6,)``
        [rad] (``None``: home, all zeros). History-dependent effects (backlash) take the first approach from it."""
        self._history = []
        self._prev = None
        if q_start is not None:
            q_start = np.asarray(q_start, dtype=float).reshape(-1)
            if q_start.shape != (N_JOINTS,) or not np.all(np.isfinite(q_start)):
                raise ValueError(f"q_start must be {N_JOINTS} finite joint angles [rad], got {q_start!r}")
        self._q_start = None if q_start is None else q_start.copy()

    @property
    def command_history(self) -> np.ndarray:
        """Commands ``(k, 6)`` [rad] executed by :meth:`capture` since :meth:`reset_history`, in order."""
        return np.array(self._history).reshape(-1, N_JOINTS)

    def _context(self, context: EffectContext | None, station: int, q_cmd: np.ndarray) -> EffectContext:
        """The context of one measurement, completed from the world's own record where the caller left gaps.

        No context, or one without ``q_cmd_prev`` and ``q_cmd_history``: the history is the commands this
        world executed since :meth:`reset_history`. A context with ``q_cmd_prev`` but no history is left as is
        (history-dependent effects refuse it). A world with a temperature profile sets ``temp_c``.
        """
        ctx = context if context is not None else EffectContext(pose_index=len(self._history), station=station)
        fill: dict[str, Any] = {}
        if ctx.world is None:
            fill["world"] = self
        if ctx.q_cmd is None:
            fill["q_cmd"] = q_cmd
        if ctx.q_cmd_prev is None and ctx.q_cmd_history is None:
            fill["q_cmd_history"] = self.command_history
            if ctx.q_actual_prev is None and self._prev is not None:
                fill["q_actual_prev"] = self._prev[1].copy()
        if ctx.q_start is None and self._q_start is not None:
            fill["q_start"] = self._q_start
        T = self.temperature_c(ctx.t_s)
        if T is not None:
            fill["temp_c"] = T
        return ctx.with_(**fill) if fill else ctx

    def _check_q(self, q_cmd: np.ndarray) -> np.ndarray:
        q = np.asarray(q_cmd, dtype=float).reshape(-1)
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_cmd must be {N_JOINTS} finite joint angles [rad], got {q_cmd!r}")
        return q

    def _evaluate(self, q_cmd: np.ndarray, ctx: EffectContext) -> tuple[RobotModel, np.ndarray]:
        """Geometry effects (applied to the MuJoCo model; the caller restores), then joint effects."""
        robot = apply_geometry_effects(self.effects, self.true_robot, ctx)
        self._apply_geometry(robot)
        return robot, apply_joint_effects(self.effects, q_cmd, ctx)

    def actual_joints(self, q_cmd: np.ndarray, context: EffectContext | None = None) -> np.ndarray:
        """Actual joints ``(6,)`` [rad] for commanded ``q_cmd`` ``(6,)`` [rad]: the joint effects in order (on the
        geometry of this measurement). Pure given the context: it does not advance the world's history."""
        q_cmd = self._check_q(q_cmd)
        ctx = self._context(context, context.station if context else 0, q_cmd)
        try:
            return self._evaluate(q_cmd, ctx)[1]
        finally:
            self._apply_geometry(self.true_robot)

    def gravity_torque(self, q_actual: np.ndarray, *, payload_kg: float = 0.0,
                       payload_com_tool: np.ndarray | None = None) -> np.ndarray:
        """Torque ``(6,)`` [N m] that gravity exerts on each joint of the robot at rest at ``q_actual`` [rad].

        Computed by MuJoCo from the twin's own bodies (masses, centres of mass: the arm, flange, plate, posts
        and spheres; gravity ``model.opt.gravity``) on the current geometry: ``-qfrc_bias`` at zero velocity.
        ``mj_rne`` needs the body poses (``mj_kinematics``), the composite inertias and motion axes
        (``mj_comPos``) and the body velocities (``mj_comVel``, zero here, so no Coriolis term enters);
        ``mj_forward`` would add actuation and constraint stages this does not need. An optional point
        payload ``payload_kg`` [kg] at ``payload_com_tool`` ``(3,)`` [m] (plate frame) adds ``J_p^T m g`` with
        its point Jacobian from ``mj_jac``.
        """
        q = np.asarray(q_actual, dtype=float).reshape(-1)
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_actual must be {N_JOINTS} finite joint angles [rad], got {q_actual!r}")
        m, d = self.model, self._statics
        d.qpos[self._qadr] = q
        d.qvel[:] = 0.0
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        bias = np.zeros(m.nv)
        mujoco.mj_rne(m, d, 0, bias)
        tau = -bias[self._dofadr]
        if payload_kg:
            if not (np.isfinite(payload_kg) and payload_kg > 0):
                raise ValueError(f"payload_kg must be a non-negative mass [kg], got {payload_kg!r}")
            c = np.zeros(3) if payload_com_tool is None else np.asarray(payload_com_tool, dtype=float).reshape(3)
            R = d.xmat[self._plate_body].reshape(3, 3)
            point = d.xpos[self._plate_body] + R @ c
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jacp, None, point, self._plate_body)
            tau = tau + (jacp.T @ (payload_kg * m.opt.gravity))[self._dofadr]
        return tau

    def _apply_geometry(self, robot: RobotModel) -> None:
        """Move the MuJoCo bodies and hinges to ``robot``'s geometry (same structure as the true robot)."""
        if robot is self._geometry_robot:
            return
        jg = self._true_jg if robot is self.true_robot else mjcf.joint_geometry(robot)
        m = self.model
        frames = [robot.base2meas] + [j.body2parent for j in jg] + [robot.tool2flange]
        for b, T in zip(self._robot_bodies, frames):
            m.body_pos[b] = T[:3, 3]
            m.body_quat[b] = matrix_to_quat_wxyz(T[:3, :3])
        for j, g in zip(self._jnt_ids, jg):
            m.jnt_pos[j] = g.anchor
            m.jnt_axis[j] = g.axis
        self._geometry_robot = robot

    def _apply_scene(self, state: SceneState) -> None:
        """Give the sphere geoms ``state``'s shapes: a sphere, or an ellipsoid along the plate axes (the geom's
        frame is the plate frame). MuJoCo reads ``geom_type``/``geom_size`` when it builds the scene, and
        ``geom_rbound`` for culling and ray casts."""
        if state is self._scene:
            return
        m = self.model
        for g, axes in zip(self._sphere_geoms, state.sphere_semi_axes):
            if np.ptp(axes) == 0.0:
                m.geom_type[g] = mujoco.mjtGeom.mjGEOM_SPHERE
                m.geom_size[g] = [axes[0], 0.0, 0.0]
            else:
                m.geom_type[g] = mujoco.mjtGeom.mjGEOM_ELLIPSOID
                m.geom_size[g] = axes
            m.geom_rbound[g] = float(np.max(axes))
        self._scene = state

    # --- images --------------------------------------------------------------------------------------
    def _get_former(self) -> ImageFormer:
        if self._former is None:
            w, h = self.image_size
            self._former = ImageFormer(self.model, w, h, self.config.render.supersample, self.frame_subsample)
        return self._former

    def _noise_seed(self, pair_seed: int | None = None, camera: int = 0) -> int:
        if pair_seed is not None:
            return int(np.random.SeedSequence([self.config.seed, 5, int(pair_seed), camera]).generate_state(1)[0])
        self._image_counter += 1
        return int(np.random.SeedSequence([self.config.seed, 2, self._image_counter]).generate_state(1)[0])

    def target_windows(self, targets_world: np.ndarray, radii: np.ndarray, station: int = 0, *,
                       outline_arc_px: float | None = None
                       ) -> tuple[tuple[tuple[int, int, int, int], ...], tuple[tuple[int, int, int, int], ...]]:
        """Image windows ``(u0, v0, u1, v1)`` [px] (columns ``u0..u1-1``) around targets, per camera (left, right).

        ``targets_world`` ``(n, 3)`` [m] are centres of balls of ``radii`` ``(n,)`` [m] (a plane region: its
        corners with radius 0). Each window is the bounding box of the true projections (distortion included) of
        the target's bounding cube, grown by ``render.window_margin_px`` [px] plus 2 px for the outline's blur,
        clipped to the image; targets behind the camera or outside the image get none.

        ``outline_arc_px``: a ball whose outline is long enough is covered by a ring of windows instead, one per
        arc of about that length [px] of its true outline (the projected tangent circle), each the arc's
        bounding box grown as above: the outline is what the sampling moves; the smooth shading inside and the
        background outside are the same at one sample per pixel. Windows may overlap: the frame and every window
        sample the same grid with the same tables, so overlaps agree (up to GL rounding) and need no merging.
        """
        pts = np.asarray(targets_world, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
            raise ValueError(f"targets_world must be a finite (n, 3) array [m], got shape {pts.shape}")
        rad = np.asarray(radii, dtype=float)
        if rad.shape != (len(pts),) or not np.all(np.isfinite(rad)) or np.any(rad < 0):
            raise ValueError(f"radii must be {len(pts)} finite radii >= 0 [m], got {radii!r}")
        if outline_arc_px is not None and not outline_arc_px > 0:
            raise ValueError(f"outline_arc_px must be positive [px] or None, got {outline_arc_px!r}")
        station = self._check_station(station)
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
        margin = self.config.render.window_margin_px + 2.0
        out = []
        for c2w, pipe in zip(self.true_cam2world(station), self._pipes):
            w2c = invert_transform(c2w)
            intr = pipe.intr
            K = np.array([[intr.fx, 0, intr.cx], [0, intr.fy, intr.cy], [0, 0, 1.0]])
            dist = np.asarray(intr.dist, dtype=float)
            rects = []

            def box(uv: np.ndarray) -> None:
                u0 = max(int(np.floor(uv[:, 0].min() - margin)), 0)
                v0 = max(int(np.floor(uv[:, 1].min() - margin)), 0)
                u1 = min(int(np.ceil(uv[:, 0].max() + margin)) + 1, intr.width)
                v1 = min(int(np.ceil(uv[:, 1].max() + margin)) + 1, intr.height)
                if u1 > u0 and v1 > v0:
                    rects.append((u0, v0, u1, v1))

            for p, r in zip(pts, rad):
                pc = w2c[:3, :3] @ p + w2c[:3, 3]
                cube = pc + r * corners
                if np.any(cube[:, 2] <= 1e-3):
                    continue
                d = float(np.linalg.norm(pc))
                r_px = intr.fx * r / max(d, 1e-9)
                n_arcs = int(np.ceil(2 * np.pi * r_px / outline_arc_px)) if outline_arc_px and r > 0 else 0
                if n_arcs < 4 or r_px < 4 * margin:
                    box(cv2.projectPoints(cube, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2))
                    continue
                # the tangent circle: centre pc (1 - r^2/d^2), radius r sqrt(1 - r^2/d^2), normal pc/d
                n = pc / d
                e1 = np.cross(n, [0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [1.0, 0.0, 0.0])
                e1 /= np.linalg.norm(e1)
                e2 = np.cross(n, e1)
                per = 8
                a = np.linspace(0, 2 * np.pi, n_arcs * per + 1)[:, None]
                rim = pc * (1 - r**2 / d**2) + r * np.sqrt(1 - r**2 / d**2) * (np.cos(a) * e1 + np.sin(a) * e2)
                uv = cv2.projectPoints(rim, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)
                for k in range(n_arcs):
                    box(uv[k * per:(k + 1) * per + 1])
            out.append(tuple(rects))
        return out[0], out[1]

    def board_windows(self, board2meas: np.ndarray, station: int = 0
                      ) -> tuple[tuple[tuple[int, int, int, int], ...], tuple[tuple[int, int, int, int], ...]]:
        """The target windows of a board view (per camera, as :meth:`target_windows`): one around each inner
        chessboard corner, reaching a quarter square from it plus the margin.

        What the instrument measures on a board view is the inner corners (sub-pixel corner refinement looks a
        few pixels around each); the markers in between are found at one sample per pixel all the same. A
        window per corner rather than one over the whole board: a quarter of the samples."""
        station = self._check_station(station)
        T = np.asarray(board2meas, dtype=float)
        board2world = self.true_cam2world(station)[0] @ T
        b = self.config.board
        ii, jj = np.meshgrid(np.arange(1, b.squares_x), np.arange(1, b.squares_y))
        corners = np.stack([ii.ravel() * b.square, jj.ravel() * b.square, np.zeros(ii.size)], axis=1)
        corners_world = (board2world[:3, :3] @ corners.T).T + board2world[:3, 3]
        return self.target_windows(corners_world, np.full(len(corners), 0.25 * b.square), station)

    def _sphere_windows(self, station: int):
        if self.config.render.window_supersample < 1:
            return None
        g = self._sphere_geoms
        # where MuJoCo draws the spheres now (after scene effects): geom centres and bounding radii
        return self.target_windows(self.data.geom_xpos[g], self.model.geom_rbound[g], station,
                                   outline_arc_px=self.config.render.window_arc_px)

    def _form_pair(self, option: mujoco.MjvOption, ctx: EffectContext | None, noise: bool = True,
                   analog: bool = False, pair_seed: int | None = None, cameras: tuple[int, ...] = (0, 1),
                   windows=None):
        """Both images (``cameras`` selects which are rendered; the other comes back ``None``, its noise seed
        is drawn all the same so that later images do not depend on the selection). ``windows``: per camera,
        image rectangles rendered at ``render.window_supersample`` (:meth:`target_windows`)."""
        former = self._get_former()
        images = []
        for c, (cam_name, cam_id, pipe) in enumerate(zip(("left", "right"), self._cam_ids, self._pipes)):
            if c not in cameras:
                self._noise_seed(pair_seed, c)
                images.append(None)
                continue
            fx = ()
            if ctx is not None:
                fx = tuple(
                    (lambda img, e=e, c=cam_name: e.image(img, ctx, c))
                    for e in self.effects if getattr(e, "changes_image", True)
                )
            sigma = self.config.render.noise_sigma if noise else 0.0
            images.append(former.form(self.data, cam_id, pipe, option, sigma, self._noise_seed(pair_seed, c), fx,
                                      analog=analog, windows=() if windows is None else windows[c],
                                      window_supersample=self.config.render.window_supersample))
        return images[0], images[1]

    def _truth_of(self, q_cmd: np.ndarray, station: int, ctx: EffectContext, pose_id: int, render: bool,
                   noise_seed: int | None) -> Capture:
        """Evaluate the effects for one measurement, place the twin, optionally render; restores the model."""
        try:
            robot, q_act = self._evaluate(q_cmd, ctx)
            self._place(q_act, station)
            left = right = np.empty((0, 0), np.uint8)
            if render:
                self._apply_scene(apply_scene_effects(self.effects, self._default_scene, ctx))
                left, right = self._form_pair(self._opt_pairs, ctx, pair_seed=noise_seed,
                                              windows=self._sphere_windows(station))
            spheres = self.true_spheres_meas(q_act, station)
            tool = self.true_tool2meas(q_act, station)
        finally:
            self._apply_geometry(self.true_robot)
            self._apply_scene(self._default_scene)
        return Capture(
            pose_id=int(pose_id), station=station, q_cmd=q_cmd.copy(), q_actual=q_act, left=left, right=right,
            spheres_meas=spheres, tool2meas=tool, t_s=float(ctx.t_s), temp_c=float(ctx.temp_c),
            params=None if robot is self.true_robot else robot.params.copy(),
        )

    def capture(
        self,
        q_cmd: np.ndarray,
        station: int = 0,
        context: EffectContext | None = None,
        pose_id: int | None = None,
        *,
        record: bool = True,
        noise_seed: int | None = None,
        render: bool = True,
    ) -> Capture:
        """Command ``q_cmd`` ``(6,)`` [rad], render the stereo pair at ``station``, keep the truth.

        The robot moves there: the command joins the world's history (:attr:`command_history`), which the
        next measurement's context reads when the caller gives none (:meth:`_context`). Effects run on the
        context: geometry hooks, then joint hooks, then scene and image hooks while rendering. With ``record``
        the truth (without images) joins :attr:`truth_poses` for :meth:`write_truth`. ``noise_seed`` makes
        this pair's sensor noise a function of (world seed, ``noise_seed``) alone, whatever was rendered
        before (for campaigns spread over processes); by default it follows the world's own image counter.
        ``render=False`` skips the images (empty arrays) and keeps everything else.
        """
        station = self._check_station(station)
        q_cmd = self._check_q(q_cmd)
        if pose_id is None:
            pose_id = self._next_pose_id
        self._next_pose_id = max(self._next_pose_id, int(pose_id) + 1)
        ctx = self._context(context, station, q_cmd)
        cap = self._truth_of(q_cmd, station, ctx, int(pose_id), render, noise_seed)
        self._history.append(q_cmd.copy())
        self._prev = (q_cmd.copy(), cap.q_actual.copy())
        self.last_capture = cap
        if record:
            empty = np.empty((0, 0), np.uint8)
            self.truth_poses.append(replace(cap, left=empty, right=empty))
        return cap

    def true_pose(self, q_cmd: np.ndarray, station: int = 0, context: EffectContext | None = None,
                  pose_id: int = 0) -> Capture:
        """The truth of one measurement without rendering and without moving the robot (for evaluation and
        synthetic tests): a :class:`Capture` with empty images, the actual joints, the true sphere centres and
        plate pose in ``station``'s measurement frame, ``t_s``/``temp_c`` and the actual parameters (when an
        effect changed the geometry). Pure: the world's history and records are untouched; a context without
        history takes the world's current one (as :meth:`capture` would)."""
        station = self._check_station(station)
        q_cmd = self._check_q(q_cmd)
        ctx = self._context(context, station, q_cmd)
        return self._truth_of(q_cmd, station, ctx, int(pose_id), False, None)

    def true_sequence(self, q_cmd: np.ndarray, stations: Sequence[Any] | None = None, *,
                      t_s: Sequence[float] | np.ndarray | None = None,
                      temp_c: Sequence[float] | np.ndarray | None = None,
                      q_start: np.ndarray | None = None,
                      pose_ids: Sequence[int] | None = None) -> list[Capture]:
        """The truth of a whole campaign measured in the order of ``q_cmd`` ``(n, 6)`` [rad], without rendering.

        Contexts come from the plan alone (:func:`twin.world.effects.contexts_for_sequence`: pose ``k`` has the
        commands ``q_cmd[:k]`` as history, ``q_start`` as start, home when ``None``, time ``t_s[k]`` [s]); so the
        result is what :meth:`capture` would record for the same plan, in any process. ``stations`` (index or
        name per pose, default 0); ``temp_c`` [°C] is used only when no effect defines the temperature.
        """
        q = np.atleast_2d(np.asarray(q_cmd, dtype=float))
        n = len(q)
        st = [0] * n if stations is None else [self.station_index(s) for s in stations]
        ids = list(range(n)) if pose_ids is None else [int(i) for i in pose_ids]
        if len(st) != n or len(ids) != n:
            raise ValueError(f"stations and pose_ids must have {n} entries (one per configuration)")
        ctxs = contexts_for_sequence(q, t_s=t_s, temp_c=temp_c, stations=st, q_start=q_start, world=self)
        return [self._truth_of(q[k].copy(), st[k], self._context(ctxs[k], st[k], q[k]), ids[k], False, None)
                for k in range(n)]

    def render_pair(self, q_cmd: np.ndarray, station: int = 0, context: EffectContext | None = None,
                    pose_id: int | None = None, *, noise_seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Left and right images ``(H, W)`` uint8 for commanded ``q_cmd`` [rad] (see :meth:`capture`)."""
        cap = self.capture(q_cmd, station, context, pose_id, noise_seed=noise_seed)
        return cap.left, cap.right

    def render_board_views(self, n: int | None = None, seed: int | None = None, station: int = 0) -> list[BoardView]:
        """``n`` board views (default ``config.board.views``): both cameras at the same moment.

        Only views with at least ``config.board.min_corners`` interior corners inside both images are
        returned; parts of the board may fall outside an image (ChArUco copes). The arm and plate are
        hidden. The true ``board2meas`` of each view joins :attr:`truth_board_views`.
        """
        n = self.config.board.views if n is None else int(n)
        station = self._check_station(station)
        rng = np.random.default_rng([self.config.seed, 3] if seed is None else [seed, 3])
        c2w = self.true_cam2world(station)
        w2c = (invert_transform(c2w[0]), invert_transform(c2w[1]))
        poses = sample_board_poses(self.config.board, n, rng, w2c, self.true_intrinsics(), self._rig2world[station])
        return [self.render_board(w2c[0] @ T, station) for T in poses]

    def render_board(self, board2meas: np.ndarray, station: int = 0, *, noise: bool = True,
                     record: bool = True) -> BoardView:
        """Both cameras' images of the board at ``board2meas`` ``(4, 4)`` (board frame -> the station's
        measurement frame, i.e. the left camera, OpenCV axes), arm and plate hidden.

        Any pose is drawn, seen or not (:meth:`render_board_views` samples poses both cameras see). With
        ``record`` the pose joins :attr:`truth_board_views` (the view's ``index`` is its position there; -1
        otherwise); ``noise=False`` leaves out the sensor noise.
        """
        station = self._check_station(station)
        T = np.asarray(board2meas, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"board2meas must be a finite (4, 4) transform, got {board2meas!r}")
        board2world = self.true_cam2world(station)[0] @ T
        k = self._mocap["board"]
        try:
            self.data.mocap_pos[k] = board2world[:3, 3]
            self.data.mocap_quat[k] = matrix_to_quat_wxyz(board2world[:3, :3])
            self._place(self.data.qpos[self._qadr].copy(), station)
            windows = self.board_windows(T, station) if self.config.render.window_supersample >= 1 else None
            left, right = self._form_pair(self._opt_board, None, noise=noise, windows=windows)
        finally:
            self._hide("board")
        index = -1
        if record:
            index = len(self.truth_board_views)
            self.truth_board_views.append((index, T.copy()))
        return BoardView(index, left, right, T.copy())

    def render_probe(self, point_meas: np.ndarray, station: int = 0, camera: str = "left", *,
                     noise: bool = False, analog: bool = False) -> np.ndarray:
        """Image of a fronto-parallel Gaussian spot centred at ``point_meas`` ``(3,)`` [m] (measurement frame).

        A diagnostic: the spot is parallel to ``camera``'s image plane, so its ideal image is a similarity
        of the texture and its intensity centroid is the projection of the point; distortion moves that by
        far less than 0.001 px. Only the probe is drawn (black elsewhere), without noise unless asked.
        ``analog`` returns the float32 image before noise and 8-bit rounding (whose rounding, without the
        noise that dithers it in real images, would hide shifts below ~0.03 px).
        """
        station = self._check_station(station)
        if camera not in ("left", "right"):
            raise ValueError(f"camera must be 'left' or 'right', got {camera!r}")
        p = np.asarray(point_meas, dtype=float).reshape(3)
        left, right = self.true_cam2world(station)
        p_world = left[:3, :3] @ p + left[:3, 3]
        cam = left if camera == "left" else right
        k = self._mocap["probe"]
        self.data.mocap_pos[k] = p_world
        self.data.mocap_quat[k] = matrix_to_quat_wxyz(cam[:3, :3])
        try:
            self._place(self.data.qpos[self._qadr].copy(), station)
            c = 0 if camera == "left" else 1
            pair = self._form_pair(self._opt_probe, None, noise=noise, analog=analog, cameras=(c,))
        finally:
            self._hide("probe")
        return pair[0] if camera == "left" else pair[1]

    def _hide(self, mocap: str) -> None:
        k = self._mocap[mocap]
        self.data.mocap_pos[k] = np.array([0.0, 0.0, -50.0])

    # --- helpers for campaigns -----------------------------------------------------------------------
    def project_spheres(self, spheres_meas: np.ndarray, station: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """True pixel positions ``(3, 2)`` of sphere centres in the left and right images (truth)."""
        station = self._check_station(station)
        il, ir = self.true_intrinsics()
        l2r = self.true_left2right()
        return project_points(spheres_meas, np.eye(4), il), project_points(spheres_meas, l2r, ir)

    def visible_configurations(self, station: int, n: int, seed: int = 0, *, margin_px: float = 60.0,
                               max_tilt_deg: float = 25.0, spread_mm: tuple[float, float, float] = (50, 35, 80),
                               max_tries: int = 100) -> np.ndarray:
        """``n`` commanded configurations ``(n, 6)`` [rad] that show the whole plate to both cameras.

        Emulates an operator jogging the robot until the plate is in view: plate centre scattered around the
        station's target (``spread_mm`` across, up and along the view), plate facing the rig within
        ``max_tilt_deg``, nominal closed-form inverse, and kept only if every sphere's true image lies
        ``margin_px`` inside both images (scaled with the render scale).
        """
        station = self._check_station(station)
        if n < 1:
            raise ValueError(f"n must be positive, got {n}")
        rng = np.random.default_rng([seed, 4, station])
        R = self._rig2world[station]
        st = self.config.stations[station]
        base2world_nominal = pose6_to_transform(self.config.mount_pose6)
        world2base = invert_transform(base2world_nominal)
        w, h = self.image_size
        margin = margin_px * self.config.render.scale
        r_px = 0.5 * self.nominal_plate.sphere_diameter * self._pipes[0].intr.fx / self.config.rig.standoff
        nominal = self.nominal_robot
        q_ref = np.zeros(N_JOINTS)
        tgt_base = world2base[:3, :3] @ st.target + world2base[:3, 3]
        q_ref[0] = np.arctan2(tgt_base[1], tgt_base[0])
        q_ref[4] = 0.5
        out = []
        tries = 0
        while len(out) < n:
            tries += 1
            if tries > max_tries * n:
                raise RuntimeError(f"station {station}: found only {len(out)} of {n} visible configurations")
            off = rng.uniform(-1, 1, 3) * np.array(spread_mm) * 1e-3
            centre = st.target + R[:3, :3] @ np.array([off[0], off[1], off[2]])
            to_rig = R[:3, 3] - centre
            z = to_rig / np.linalg.norm(to_rig)
            tilt = np.deg2rad(max_tilt_deg) * np.sqrt(rng.uniform())
            a = rng.uniform(0, 2 * np.pi)
            perp = np.cross(z, [0.0, 0.0, 1.0])
            if np.linalg.norm(perp) < 1e-6:
                perp = np.array([1.0, 0, 0])
            perp /= np.linalg.norm(perp)
            perp2 = np.cross(z, perp)
            z = rotvec_to_matrix((np.cos(a) * perp + np.sin(a) * perp2) * tilt) @ z
            x = np.cross([0.0, 0.0, 1.0], z)
            x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0, 0])
            x = rotvec_to_matrix(z * rng.uniform(-np.pi, np.pi)) @ x
            y = np.cross(z, x)
            # plate centre = centre of the sphere circle, 50 mm above the tool origin
            sph = self.nominal_plate.spheres_flange
            tool_centre = sph.mean(axis=0) * np.array([0, 0, 1.0])
            Rt = np.stack([x, y, z], axis=1)
            tool2world = make_transform(Rt, centre - Rt @ tool_centre)
            flange2base = world2base @ tool2world @ invert_transform(nominal.tool2flange)
            try:
                q = closest_branch(inverse_kinematics_closed_form(nominal, flange2base), q_ref[None])[0]
            except UnreachableError:
                continue
            spheres = self.true_spheres_meas(q, station)
            ok = all(discs_in_image(uv, margin + r_px, w, h).all() for uv in self.project_spheres(spheres, station))
            if ok and not self.spheres_occluded(q, station):
                out.append(q)
        return np.array(out)

    def spheres_occluded(self, q_actual: np.ndarray, station: int, n_rim: int = 12) -> bool:
        """Whether any part of a sphere's outline is hidden from either camera (by the arm, plate or posts).

        Casts MuJoCo rays (``mj_ray``) from each camera centre to points just inside each sphere's outline and
        to its centre; the first geom hit must be that sphere.
        """
        station = self._check_station(station)
        self._place(q_actual, station)
        groups = np.zeros(6, dtype=np.uint8)
        groups[[mjcf.GROUP_ROBOT, mjcf.GROUP_PLATE]] = 1
        geomid = np.zeros(1, dtype=np.int32)
        r = 0.5 * self.nominal_plate.sphere_diameter
        for cam in self.true_cam2world(station):
            c = cam[:3, 3]
            for k, site in enumerate(self._sphere_sites):
                p = self.data.site_xpos[site]
                view = (p - c) / np.linalg.norm(p - c)
                a = np.cross(view, [0.0, 0.0, 1.0])
                if np.linalg.norm(a) < 1e-6:
                    a = np.cross(view, [1.0, 0.0, 0.0])
                a /= np.linalg.norm(a)
                b = np.cross(view, a)
                ang = np.linspace(0, 2 * np.pi, n_rim, endpoint=False)
                targets = [p] + [p + 0.97 * r * (np.cos(t) * a + np.sin(t) * b) for t in ang]
                sphere_geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f"sphere{k}")
                for tgt in targets:
                    vec = tgt - c
                    mujoco.mj_ray(self.model, self.data, c, vec, groups, 1, -1, geomid)
                    if geomid[0] != sphere_geom:
                        return True
        return False

    # --- files ---------------------------------------------------------------------------------------
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

    def write_image_folder(
        self,
        folder: str | os.PathLike,
        q_cmd: np.ndarray | None = None,
        stations: Sequence[Any] | None = None,
        *,
        pose_ids: Sequence[int] | None = None,
        contexts: Sequence[EffectContext] | None = None,
        per_station: int = 0,
        board_views: int | None = None,
        seed: int = 0,
        callback: Any = None,
        channels: Sequence[str] | None = None,
    ) -> dict:
        """Render into an image folder (``docs/formats.md``): board views, then one pair per configuration.

        Configurations are ``q_cmd`` ``(n, 6)`` [rad] with their ``stations`` (index or name; default 0), or,
        when ``q_cmd`` is ``None``, ``per_station`` visible configurations at every station
        (:meth:`visible_configurations`). ``board_views`` defaults to ``config.board.views``. Each capture's
        truth is recorded for :meth:`write_truth`. ``callback(kind, index, total)`` reports progress.
        ``channels``: the auxiliary channels the instrument records into ``joints.csv`` (and so into the
        dataset), a subset of ``("t_s", "temp_c")``; default: both when ``contexts`` are given, none otherwise.
        The values written are the capture's (``temp_c`` is the world's true temperature when an effect
        defines it). Returns a summary (counts and the folder).
        """
        from .images import ImageFolderWriter

        if q_cmd is None:
            if per_station < 1:
                raise ValueError(f"per_station must be >= 1 when no q_cmd is given, got {per_station}")
            qs, st = [], []
            for s in range(self.n_stations):
                q = self.visible_configurations(s, per_station, seed=seed)
                qs.append(q)
                st += [s] * len(q)
            q_cmd = np.concatenate(qs)
            stations = st
        q_cmd = np.atleast_2d(np.asarray(q_cmd, dtype=float))
        if q_cmd.ndim != 2 or q_cmd.shape[1] != N_JOINTS:
            raise ValueError(f"q_cmd must have shape (n, {N_JOINTS}) [rad], got {q_cmd.shape}")
        n = q_cmd.shape[0]
        st_idx = [0] * n if stations is None else [self.station_index(s) for s in stations]
        if len(st_idx) != n:
            raise ValueError(f"stations has {len(st_idx)} entries for {n} configurations")
        ids = list(range(n)) if pose_ids is None else [int(i) for i in pose_ids]
        if len(ids) != n or len(set(ids)) != n:
            raise ValueError("pose_ids must be unique, one per configuration")
        if contexts is not None and len(contexts) != n:
            raise ValueError(f"contexts has {len(contexts)} entries for {n} configurations")
        if channels is None:
            channels = ("t_s", "temp_c") if contexts is not None else ()
        channels = tuple(channels)
        bad = sorted(set(channels) - {"t_s", "temp_c"})
        if bad:
            raise ValueError(f"channels must be a subset of ('t_s', 'temp_c'), got {channels!r}")
        writer = ImageFolderWriter(folder, self.rig_info())
        nb = self.config.board.views if board_views is None else int(board_views)
        for k, view in enumerate(self.render_board_views(nb, seed=seed) if nb > 0 else []):
            writer.add_board_view(view.left, view.right)
            if callback is not None:
                callback("board", k, nb)
        for k in range(n):
            ctx = contexts[k] if contexts is not None else None
            cap = self.capture(q_cmd[k], st_idx[k], ctx, pose_id=ids[k])
            extra = {c: getattr(cap, c) for c in channels}
            writer.add_pair(cap.pose_id, cap.q_cmd, cap.left, cap.right, station=str(cap.station), **extra)
            if callback is not None:
                callback("pair", k, n)
        return {"folder": str(folder), "pairs": writer.n_pairs, "board_views": writer.n_board_views}

    def truth_dict(self, captures: Iterable[Capture] | None = None) -> dict:
        """Everything :func:`twin.world.truth.write_truth` writes (SI, JSON-ready)."""
        return _truth_dict(self, self.truth_poses if captures is None else list(captures))

    def write_truth(self, path: str | os.PathLike, captures: Iterable[Capture] | None = None) -> Path:
        """Write ``truth.json`` (``docs/formats.md``) for the recorded (or the given) captures."""
        return _write_truth(path, self.truth_dict(captures))

    def close(self) -> None:
        """Free the renderer (its GL context); the world can still compute truth afterwards."""
        if self._former is not None:
            self._former.close()
            self._former = None

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
