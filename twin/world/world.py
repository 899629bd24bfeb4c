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

import cv2
import mujoco
import numpy as np

from ..camera import spheres_in_view
from ..dataset import Plate, default_plate
from ..kinematics import N_JOINTS, RobotModel, UnreachableError, closest_branch, inverse_kinematics_closed_form
from ..transforms import invert_transform, make_transform, pose6_to_transform, rotvec_to_matrix
from ..units import M_PER_MM, deg_to_rad
from . import mjcf
from .board import board_extent, board_texcoords, board_texture
from .config import WorldConfig, nominal_robot_from_spec
from .effects import (
    EffectContext,
    SceneState,
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
from .world_geometry import WorldGeometry
from .world_imaging import WorldImaging
from .world_robot import WorldRobot

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


class World(WorldGeometry, WorldRobot, WorldImaging):
    """The truth side of the testbed. Build with :meth:`from_config`.

    Public data a real user also has: :attr:`nominal_robot`, :attr:`nominal_plate`, :meth:`rig_info`,
    :attr:`station_names`. Everything named ``true_*`` is truth.

    Built here (the true robot and plate, the rig as placed, the composed MJCF, the MuJoCo model and its ids) and
    used by its parts: :class:`~twin.world.world_geometry.WorldGeometry` (stations, cameras, where things truly
    are), :class:`~twin.world.world_robot.WorldRobot` (commanded -> actual joints: history, effects, gravity
    statics) and :class:`~twin.world.world_imaging.WorldImaging` (image formation: stereo pairs, board views,
    probes, windows). What stays here ties them together: a measurement's truth (:meth:`capture`,
    :meth:`true_pose`, :meth:`true_sequence`), the configurations an operator would jog to
    (:meth:`visible_configurations`), and the files (MJCF, image folder, truth).
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


    def write_mjcf(self, folder: str | os.PathLike, name: str = "twin.xml") -> Path:
        """Write the composed MJCF and its textures into ``folder``; the file loads on its own."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for fname, data in self._assets.items():
            (folder / fname).write_bytes(data)
        path = folder / name
        path.write_text(self.mjcf_xml)
        return path

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

    # --- helpers for campaigns -----------------------------------------------------------------------

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
            off = rng.uniform(-1, 1, 3) * np.array(spread_mm) * M_PER_MM
            centre = st.target + R[:3, :3] @ np.array([off[0], off[1], off[2]])
            to_rig = R[:3, 3] - centre
            z = to_rig / np.linalg.norm(to_rig)
            tilt = deg_to_rad(max_tilt_deg) * np.sqrt(rng.uniform())
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
            ok = all(spheres_in_view(spheres @ T[:3, :3].T + T[:3, 3], intr, margin_px=margin + r_px)
                     for T, intr in zip((np.eye(4), self.true_left2right()), self.true_intrinsics()))
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

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
