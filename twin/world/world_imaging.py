"""The world's image formation: stereo pairs, board views and probes rendered by MuJoCo and formed like the
cameras' (windows, distortion, noise).

A part of :class:`twin.world.World` (it uses the model, data, cameras and effects the world builds).
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np

from ..transforms import invert_transform, matrix_to_quat_wxyz
from .board import sample_board_poses
from .effects import EffectContext, SceneState
from .records import BoardView
from .render import ImageFormer

__all__ = ["WorldImaging", "BOARD_WINDOW_PX"]

# How far from each inner corner of a board view the window reaches in the image [px] (World.board_windows).
BOARD_WINDOW_PX = 13.0


class WorldImaging:
    """Image formation of :class:`twin.world.World`."""

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

    def _get_former(self) -> ImageFormer:
        if self._former is None:
            w, h = self.image_size
            disc = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, "plate_disc")
            self._former = ImageFormer(self.model, w, h, self.config.render.supersample, self.frame_subsample,
                                       occluders=(disc,) if disc >= 0 else ())
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
        chessboard corner, reaching :data:`BOARD_WINDOW_PX` from it in both images (at most a quarter square) plus
        the margin.

        What the instrument measures on a board view is the inner corners: OpenCV's ChArUco detector refines each
        in a window of at most 21 x 21 px about its first estimate (two pixels short of the nearest marker corner);
        the window, the gradients' pixel beyond it and 2 px for the first estimate's error are 13 px from the
        corner. The markers in between are found at one sample per pixel all the same. Measured on make run's 24
        views: the same calibration (reprojection RMS 0.042 px, focal lengths and principal points within their
        scatter of the true ones) as with windows a quarter square wide, in less than half the time per view."""
        station = self._check_station(station)
        T = np.asarray(board2meas, dtype=float)
        board2world = self.true_cam2world(station)[0] @ T
        b = self.config.board
        ii, jj = np.meshgrid(np.arange(1, b.squares_x), np.arange(1, b.squares_y))
        corners = np.stack([ii.ravel() * b.square, jj.ravel() * b.square, np.zeros(ii.size)], axis=1)
        corners_world = (board2world[:3, :3] @ corners.T).T + board2world[:3, 3]
        # the radius that reaches BOARD_WINDOW_PX in the image of the farther camera
        depth = np.max([np.linalg.norm(corners_world - c2w[:3, 3], axis=1) for c2w in self.true_cam2world(station)],
                       axis=0)
        f = min(p.intr.fx for p in self._pipes)
        radius = np.minimum(BOARD_WINDOW_PX * depth / f, 0.25 * b.square)
        return self.target_windows(corners_world, radius, station)

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

    def render_pair(self, q_cmd: np.ndarray, station: int = 0, context: EffectContext | None = None,
                    pose_id: int | None = None, *, noise_seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Left and right images ``(H, W)`` uint8 for commanded ``q_cmd`` [rad] (see :meth:`capture`)."""
        cap = self.capture(q_cmd, station, context, pose_id, noise_seed=noise_seed)
        return cap.left, cap.right

    def board_view_poses(self, n: int | None = None, seed: int | None = None, station: int = 0
                         ) -> list[tuple[np.ndarray, int]]:
        """The board views :meth:`render_board_views` draws, without drawing or recording them: ``n`` (default
        ``config.board.views``) pairs of the board's pose ``board2meas`` ``(4, 4)`` and the view's noise seed (for
        :meth:`render_board`), from ``seed`` (default the world's) alone. So views can be drawn in any process
        and in any order with the same images."""
        n = self.config.board.views if n is None else int(n)
        station = self._check_station(station)
        base = self.config.seed if seed is None else int(seed)
        rng = np.random.default_rng([base, 3])
        c2w = self.true_cam2world(station)
        w2c = (invert_transform(c2w[0]), invert_transform(c2w[1]))
        poses = sample_board_poses(self.config.board, n, rng, w2c, self.true_intrinsics(), self._rig2world[station])
        seeds = np.random.SeedSequence([base, 4]).generate_state(len(poses))
        return [(w2c[0] @ T, int(s)) for T, s in zip(poses, seeds)]

    def render_board_views(self, n: int | None = None, seed: int | None = None, station: int = 0) -> list[BoardView]:
        """``n`` board views (default ``config.board.views``): both cameras at the same moment.

        Only views with at least ``config.board.min_corners`` interior corners inside both images are
        returned; parts of the board may fall outside an image (ChArUco copes). The arm and plate are
        hidden. The true ``board2meas`` of each view joins :attr:`truth_board_views`. Poses and noise come from
        ``seed`` alone (:meth:`board_view_poses`).
        """
        return [self.render_board(T, station, noise_seed=s) for T, s in self.board_view_poses(n, seed, station)]

    def record_board_view(self, board2meas: np.ndarray) -> int:
        """Add a board view's true ``board2meas`` ``(4, 4)`` to :attr:`truth_board_views` (for a view drawn
        elsewhere with ``record=False``); returns its index there."""
        T = np.asarray(board2meas, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"board2meas must be a finite (4, 4) transform, got {board2meas!r}")
        index = len(self.truth_board_views)
        self.truth_board_views.append((index, T.copy()))
        return index

    def render_board(self, board2meas: np.ndarray, station: int = 0, *, noise: bool = True,
                     record: bool = True, noise_seed: int | None = None) -> BoardView:
        """Both cameras' images of the board at ``board2meas`` ``(4, 4)`` (board frame -> the station's
        measurement frame, i.e. the left camera, OpenCV axes), arm and plate hidden.

        Any pose is drawn, seen or not (:meth:`render_board_views` samples poses both cameras see). With
        ``record`` the pose joins :attr:`truth_board_views` (the view's ``index`` is its position there; -1
        otherwise); ``noise=False`` leaves out the sensor noise; ``noise_seed`` makes the noise a function of
        (world seed, ``noise_seed``) alone (by default it follows the world's own image counter).
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
            left, right = self._form_pair(self._opt_board, None, noise=noise, windows=windows,
                                          pair_seed=None if noise_seed is None else int(noise_seed))
        finally:
            self._hide("board")
        index = self.record_board_view(T) if record else -1
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

    def render_bare(self, renderer: mujoco.Renderer) -> list[np.ndarray]:
        """MuJoCo's own render of both cameras at the current placement (:meth:`place`) with ``renderer`` (a
        ``mujoco.Renderer`` of :attr:`model`): no image formation (no windows, distortion or noise). The reference
        cost of a render, for benchmarks."""
        out = []
        for cam in self._cam_ids:
            renderer.update_scene(self.data, camera=cam, scene_option=self._opt_pairs)
            out.append(renderer.render())
        return out

    def close(self) -> None:
        """Free the renderer (its GL context); the world can still compute truth afterwards."""
        if self._former is not None:
            self._former.close()
            self._former = None
