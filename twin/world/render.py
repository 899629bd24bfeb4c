"""Image formation: MuJoCo's ideal pinhole render -> greyscale -> lens distortion -> pixel integration -> noise.

One GL context and offscreen buffer per image former, created once and reused (start-up costs ~0.5 s). Every
image is assembled from *draws*: boxes of an ideal sampling grid of the camera, each drawn by MuJoCo through an
off-axis frustum of the same camera into its own viewport of the offscreen buffer. The draws of one image are
packed side by side into the buffer and read back together (one RGBA read: the GL's native format, a copy), so
the rasteriser sees one batch and the read waits once. The work around the renderer per image is then a
colour conversion, the distortion remap(s), the block means of supersampled pixels and one ``cv2.randn`` +
saturating ``cv2.add``, which also rounds to 8 bits once, at the end.

Supersampling (``render.supersample`` = ``s``): MuJoCo samples each pixel once, so outlines are staircases
whose low-frequency error moves a fitted sphere centre by ~0.04 px. With ``s`` > 1 the renderer draws
``s x s`` samples per pixel (``s`` times the width and height, the same field of view), the distortion is
applied to every sample (remap tables on the sampling grid, :func:`sampling_intrinsics`), and each output
pixel is the mean of its block, as a sensor pixel integrates light. Averaging first and distorting the
averaged image afterwards was measured too: the bilinear remap at output resolution puts 0.03 px of centre
error back (0.033 px against 0.011 px RMS).

Target windows (``render.window_supersample`` = ``S``): windows ``(u0, v0, u1, v1)`` of the output image at
``S x S`` samples per pixel: their samples lie on the whole ``S``-grid (the tables of
:meth:`CameraPipeline.window_tables`), MuJoCo draws only their source boxes, and their block means replace the
frame's noise-free pixels before the noise: one whole image, equal inside each window to the full ``S x S``
render up to GL rounding. The frame under them is drawn at ``s`` samples per pixel, or at one sample per
``k x k`` pixels (``render.frame_subsample`` = ``k``): then it is distorted on its own coarse grid and resized to
the image bilinearly.

Sub-pixel fidelity: resampling an 8-bit image to 8 bits loses shifts smaller than ~1/30 px (each pixel changes
by less than half a grey level and rounds back), so the resampling runs in float32, with float32 tables:
OpenCV 5's ``cv2.remap`` interpolates float tables exactly (bilinear weights from the position itself; its
fixed-point tables would quantize positions to 1/32 px and bias every feature alike; checked in
``tests/test_world_render.py``). The sensor noise then dithers the final 8-bit rounding. Measured: the image
of a known point agrees with the camera model to about 0.001 px (``tests/test_world_render.py``).

The distortion is applied by resampling: a true pixel ``(u, v)`` has normalized distorted coordinates
``((u - cx)/fx, (v - cy)/fy)``; undistorting them gives the ray, which the ideal render (focal length
``f_r``, centred principal point) shows at ``f_r * x + (W/2 - 0.5)``. ``cv2.remap`` interpolates there
bilinearly. On the sampling grid the same holds with ``s fx``, ``s cx + (s - 1)/2``, ``s f_r`` and
``s W/2 - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import mujoco
import numpy as np

from ..camera import CameraIntrinsics, distort_normalized, undistort_normalized
from ..units import rad_to_deg
from .rig import check_distortion_monotonic, distortion_maps, render_focal_px, renders_ideally

__all__ = ["CameraPipeline", "scene_option", "sampling_intrinsics"]
# Bilinear on the sampling grid. Measured (6 poses, both cameras, the instrument's sphere centres against the
# true projections): with 2x2 samples, bilinear 0.011 px RMS, bicubic 0.013 px; with one sample bicubic would
# cut 0.042 px to 0.032 px and Lanczos-4 to 0.023 px (at 7x the remap time), see docs/world.md.
_REMAP_INTERPOLATION = cv2.INTER_LINEAR
# Node spacing [output px] of a camera's window lattice (:meth:`CameraPipeline._window_lattice`): bilinear
# interpolation between nodes 4 px apart stays within 1e-4 sample of the exact inverse distortion (measured with
# the default lenses at S = 4: 2.5e-5 px).
_LATTICE_PX = 4
# A box is drawn on its own when the union with another would add more than this many samples: what one more
# draw costs llvmpipe here (the target's tessellated sphere and a flush of state) is about what this many
# rasterised samples cost (CPU time, measured with 2 rasteriser threads).
_DRAW_COST_SAMPLES = 16384
# Offsets and row pitches (beyond the image width) of an image's sensor noise in the image former's noise stream
# (:meth:`ImageFormer._noise_image`).
_NOISE_OFFSETS = 1 << 22
_NOISE_PITCHES = 1024


def scene_option(groups: tuple[int, ...]) -> mujoco.MjvOption:
    """A MuJoCo scene option showing only the geom ``groups``."""
    opt = mujoco.MjvOption()
    for g in range(len(opt.geomgroup)):
        opt.geomgroup[g] = 1 if g in groups else 0
    # sites and joints are never drawn in images
    for g in range(len(opt.sitegroup)):
        opt.sitegroup[g] = 0
    return opt


def sampling_intrinsics(intr: CameraIntrinsics, supersample: int) -> CameraIntrinsics:
    """The camera on the sampling grid: ``supersample`` ``s`` times the pixels of ``intr``, same optics.

    Output pixel ``u`` integrates the samples ``s*u .. s*u + s - 1``, centred at ``s*u + (s - 1)/2``, so
    ``f -> s f`` and ``c -> s c + (s - 1)/2`` (pixel centres at integers in both grids).
    """
    s = int(supersample)
    return CameraIntrinsics(s * intr.fx, s * intr.fy, s * intr.cx + 0.5 * (s - 1), s * intr.cy + 0.5 * (s - 1),
                            s * intr.width, s * intr.height, intr.dist)


def _coarse_intrinsics(intr: CameraIntrinsics, k: int) -> CameraIntrinsics:
    """The camera on a grid ``k`` times coarser than its pixels (``W/k x H/k``, same optics): coarse pixel ``U``
    covers the pixels ``k*U .. k*U + k - 1``, centred at ``k*U + (k - 1)/2``, so ``f -> f/k``,
    ``c -> (c + 0.5)/k - 0.5``."""
    return CameraIntrinsics(intr.fx / k, intr.fy / k, (intr.cx + 0.5) / k - 0.5, (intr.cy + 0.5) / k - 0.5,
                            intr.width // k, intr.height // k, intr.dist)


def _interp_matrix(pos: np.ndarray, n_nodes: int) -> np.ndarray:
    """``(len(pos), n_nodes)`` linear-interpolation weights of the positions ``pos`` (in node units, inside
    ``[0, n_nodes - 1]``) on a regular lattice: two non-zeros per row, summing to 1."""
    i = np.minimum(pos.astype(np.intp), n_nodes - 2)
    a = pos - i
    W = np.zeros((len(pos), n_nodes))
    flat = W.reshape(-1)
    k = np.arange(len(pos)) * n_nodes + i
    flat[k] = 1.0 - a
    flat[k + 1] = a
    return W


def _merge_boxes(boxes: list[tuple[int, int, int, int]]) -> list[list[int]]:
    """Indices of ``boxes`` ``(x0, y0, x1, y1)`` grouped into draws: two draws become one while their bounding box
    adds at most :data:`_DRAW_COST_SAMPLES` samples to theirs (greedy, cheapest union first)."""
    n = len(boxes)
    groups = [[i] for i in range(n)]
    if n < 2:
        return groups
    b = np.array(boxes, dtype=np.int64).reshape(-1, 4)
    alive = np.ones(n, dtype=bool)

    def extra_with(i: int) -> np.ndarray:
        """Samples the union of box ``i`` with each box adds to the two (``inf`` for itself and merged boxes)."""
        w = np.maximum(b[:, 2], b[i, 2]) - np.minimum(b[:, 0], b[i, 0])
        h = np.maximum(b[:, 3], b[i, 3]) - np.minimum(b[:, 1], b[i, 1])
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        e = (w * h - area - area[i]).astype(float)
        e[i] = np.inf
        e[~alive] = np.inf
        return e

    extra = np.stack([extra_with(i) for i in range(n)])
    while True:
        k = int(np.argmin(extra))
        i, j = divmod(k, n)
        if not extra[i, j] <= _DRAW_COST_SAMPLES:
            break
        b[i] = (min(b[i, 0], b[j, 0]), min(b[i, 1], b[j, 1]), max(b[i, 2], b[j, 2]), max(b[i, 3], b[j, 3]))
        groups[i] += groups[j]
        groups[j] = []
        alive[j] = False
        extra[j, :] = extra[:, j] = np.inf
        extra[i, :] = extra_with(i)
        extra[:, i] = extra[i, :]
    return [g for g in groups if g]


@dataclass
class CameraPipeline:
    """One camera's image formation: its true intrinsics, ideal render focal length, samples per pixel along
    each axis, and the frame's remap tables (:attr:`maps`; ``None``: no resampling needed). The tables map the
    output image's pixels into the frame's sampling grid, or, with ``frame_subsample`` ``k`` > 1, the pixels of a
    ``k`` times coarser image into the coarse render (the frame is then resized to the image)."""

    name: str
    intr: CameraIntrinsics
    f_render: float
    # the grid the tables map into: its intrinsics and the ideal render's focal length on it [px]
    grid: tuple[CameraIntrinsics, float]
    supersample: int = 1
    frame_subsample: int = 1
    ideal: bool = False  # the true camera is the ideal pinhole (no distortion, centred, focal f_r)

    @property
    def maps(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The frame's remap tables (:func:`twin.world.rig.distortion_maps` on :attr:`grid`), made at the first
        frame drawn: a world that only computes truth never draws one (the tables of a full-size camera cost
        ~0.35 s of CPU). ``ValueError`` there when the distortion cannot be inverted over the image."""
        cache = self.__dict__
        if "_maps" not in cache:
            cache["_maps"] = None if self.ideal else distortion_maps(*self.grid)
        return cache["_maps"]

    @classmethod
    def build(cls, name: str, intr: CameraIntrinsics, supersample: int = 1,
              frame_subsample: int = 1) -> "CameraPipeline":
        """``frame_subsample`` ``k`` > 1 (only with ``supersample`` 1): the frame's ideal render has ``W/k x H/k``
        samples (the same field of view), distorted on that coarse grid and resized to the image."""
        check_distortion_monotonic(intr)
        s, k = int(supersample), int(frame_subsample)
        if s != supersample or s < 1:
            raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
        if k != frame_subsample or k < 1 or (k > 1 and s > 1):
            raise ValueError(f"frame_subsample must be an integer >= 1 (> 1 only with supersample 1), got "
                             f"{frame_subsample!r}")
        if intr.width % k or intr.height % k:
            raise ValueError(f"frame_subsample {k} must divide the image size {intr.width}x{intr.height}")
        f_r = render_focal_px(intr)
        if k > 1:
            # the coarse image's pixels into the coarse ideal render (focal f_r / k): the same field of view
            grid = (_coarse_intrinsics(intr, k), f_r / k)
        else:
            # the ideal render on the sampling grid has focal length s * f_r: the same field of view
            grid = (sampling_intrinsics(intr, s), s * f_r)
        ideal = renders_ideally(*grid)  # scale-free: no distortion, centred, focal f_r at every grid scale
        return cls(name, intr, f_r, grid, s, k, ideal)

    def _window_lattice(self, s: int) -> np.ndarray:
        """Where the ideal ``s``-grid shows the rays of a lattice of the true ``s``-grid: nodes every
        :data:`_LATTICE_PX` output pixels (``s * _LATTICE_PX`` samples), from one spacing before the image to two
        after it; ``(2, ny, nx)`` float64 ideal-grid coordinates x and y (node ``(i, j)`` at true sample
        ``(s L (j - 1), s L (i - 1))``), cached per ``s``."""
        cache = self.__dict__.setdefault("_lattices", {})
        if s not in cache:
            si = sampling_intrinsics(self.intr, s)
            step = s * _LATTICE_PX
            xs = np.arange(-1, -(-self.intr.width // _LATTICE_PX) + 3) * float(step)
            ys = np.arange(-1, -(-self.intr.height // _LATTICE_PX) + 3) * float(step)
            X, Y = np.meshgrid(xs, ys)
            xy_d = np.stack([(X - si.cx) / si.fx, (Y - si.cy) / si.fy], axis=-1)
            ray = undistort_normalized(xy_d, si.dist)
            back = distort_normalized(ray, si.dist)
            err = max(np.max(np.abs(back[..., 0] - xy_d[..., 0])) * si.fx,
                      np.max(np.abs(back[..., 1] - xy_d[..., 1])) * si.fy)
            if err > 1e-4:
                raise ValueError(f"distortion {self.intr.dist} cannot be inverted over the image (residual {err:.2g} "
                                 "samples)")
            fr = s * self.f_render
            cache[s] = np.stack([ray[..., 0] * fr + (s * self.intr.width / 2 - 0.5),
                                 ray[..., 1] * fr + (s * self.intr.height / 2 - 0.5)])
        return cache[s]

    def window_tables(self, rects: list[tuple[int, int, int, int]], s: int) -> "_WindowTables":
        """The remap tables of the output windows ``rects`` ``(u0, v0, u1, v1)`` [px] at ``s x s`` samples per pixel:
        for each window, where its samples (``s*(v1-v0) x s*(u1-u0)``) lie in the ideal render's ``s``-grid (the
        whole grid: ``s*W x s*H``, focal ``s*f_r``, centre ``s*W/2 - 0.5``), and the source box of the ideal grid
        that covers every bilinear neighbour (clipped to the grid, where the remap replicates the border as the
        whole grid's does).

        The map is the bilinear interpolation of :meth:`_window_lattice` (< 1e-4 sample from the exact inverse
        distortion), one matrix product per window and coordinate: ``map = Wy @ N @ Wx^T`` with ``Wy``, ``Wx``
        the interpolation weights of the window's rows and columns on the lattice block ``N``. The tables
        themselves are made on demand, in their source box's coordinates (:meth:`_WindowTables.maps`)."""
        return _WindowTables(self, rects, s)

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view of the ideal render [deg]."""
        return float(rad_to_deg(2.0 * np.arctan(0.5 * self.intr.height / self.f_render)))


class _WindowTables:
    """The remap tables of a camera's windows at ``s x s`` samples (:meth:`CameraPipeline.window_tables`)."""

    def __init__(self, cam: CameraPipeline, rects: list[tuple[int, int, int, int]], s: int):
        self.cam, self.rects, self.s = cam, list(rects), int(s)
        gw, gh = s * cam.intr.width, s * cam.intr.height
        self.grid = (gw, gh)
        r = np.array(self.rects, dtype=np.int64).reshape(-1, 4) * s  # the windows' samples: x0, y0, x1, y1 (excl.)
        if cam.ideal:  # the true camera is the ideal one: the window's samples are the ideal grid's
            self.boxes = [tuple(int(v) for v in b) for b in r]
            return
        self._lat = cam._window_lattice(s)
        self._step = float(s * _LATTICE_PX)
        # Each map is monotonic along its own axis (the distortion is checked monotonic), so its range over a window
        # lies on the window's first and last column (x) or row (y): those samples of every window at once.
        hs, ws = r[:, 3] - r[:, 1], r[:, 2] - r[:, 0]
        cols_x = np.concatenate([np.stack([np.full(h, a), np.full(h, b - 1)], 1).ravel()
                                 for a, b, h in zip(r[:, 0], r[:, 2], hs)])
        cols_y = np.concatenate([np.repeat(np.arange(a, b), 2) for a, b in zip(r[:, 1], r[:, 3])])
        rows_x = np.concatenate([np.tile(np.arange(a, b), 2) for a, b in zip(r[:, 0], r[:, 2])])
        rows_y = np.concatenate([np.repeat([a, b - 1], w) for a, b, w in zip(r[:, 1], r[:, 3], ws)])
        ex = self._at(0, cols_x, cols_y)
        ey = self._at(1, rows_x, rows_y)
        ix, iy = np.cumsum(2 * hs)[:-1], np.cumsum(2 * ws)[:-1]
        lo_x, hi_x = np.minimum.reduceat(ex, np.r_[0, ix]), np.maximum.reduceat(ex, np.r_[0, ix])
        lo_y, hi_y = np.minimum.reduceat(ey, np.r_[0, iy]), np.maximum.reduceat(ey, np.r_[0, iy])
        x0 = np.clip(np.floor(lo_x) - 1, 0, gw - 1).astype(np.int64)
        y0 = np.clip(np.floor(lo_y) - 1, 0, gh - 1).astype(np.int64)
        x1 = np.clip(np.ceil(hi_x) + 2, x0 + 1, gw).astype(np.int64)
        y1 = np.clip(np.ceil(hi_y) + 2, y0 + 1, gh).astype(np.int64)
        self.boxes = list(zip(x0.tolist(), y0.tolist(), x1.tolist(), y1.tolist()))

    def _at(self, coord: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Map ``coord`` (0: x, 1: y) at the samples ``(x, y)`` of the true grid: bilinear on the lattice."""
        fx, fy = x / self._step + 1.0, y / self._step + 1.0  # node j at sample s L (j - 1)
        ix, iy = fx.astype(np.intp), fy.astype(np.intp)
        ax, ay = fx - ix, fy - iy
        lat = self._lat[coord]
        top = lat[iy, ix] * (1.0 - ax) + lat[iy, ix + 1] * ax
        bottom = lat[iy + 1, ix] * (1.0 - ax) + lat[iy + 1, ix + 1] * ax
        return top * (1.0 - ay) + bottom * ay

    def maps(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Window ``i``'s float32 maps ``(s*(v1-v0), s*(u1-u0))`` in the coordinates of its source box (origin
        ``boxes[i][:2]``): small numbers, which float32 holds to ~1e-5 sample. Bilinear on the lattice, written
        ``Wy @ N @ Wx^T`` (the interpolation weights of the window's rows and columns, the lattice block ``N``)."""
        s, step = self.s, self._step
        u0, v0, u1, v1 = self.rects[i]
        x0, y0 = self.boxes[i][:2]
        fx = np.arange(s * u0, s * u1) / step + 1.0  # node j at sample s L (j - 1)
        fy = np.arange(s * v0, s * v1) / step + 1.0
        jx, jy = int(fx[0]), int(fy[0])
        Wx = _interp_matrix(fx - jx, int(fx[-1]) + 2 - jx)
        Wy = _interp_matrix(fy - jy, int(fy[-1]) + 2 - jy)
        ny = Wy.shape[1]
        block = self._lat[:, jy:jy + ny, jx:jx + Wx.shape[1]].reshape(2 * ny, -1)
        T = block @ Wx.T  # (2 ny, ws): both maps at the lattice rows, every column
        T[:ny] -= x0
        T[ny:] -= y0
        T = T.astype(np.float32)
        Wy = Wy.astype(np.float32)
        return Wy @ T[:ny], Wy @ T[ny:]


def gl_max_renderbuffer_px() -> int | None:
    """The current GL context's largest renderbuffer side [px] (``GL_MAX_RENDERBUFFER_SIZE``; 16384 on Mesa's
    llvmpipe here), or ``None`` when it cannot be queried. Needs a current context."""
    try:
        from OpenGL import GL  # PyOpenGL: a dependency of mujoco's own GL back ends

        return int(GL.glGetIntegerv(GL.GL_MAX_RENDERBUFFER_SIZE))
    except Exception:  # noqa: BLE001 - no PyOpenGL or no context: MuJoCo's own check still applies
        return None


@dataclass(frozen=True)
class _Occluder:
    """A flat opaque mesh (the plate's disc) as :class:`_FrustumCuller` uses it: in its geom's frame, the axis of
    its thickness, the centre of its box (``geom_aabb``), its half-thickness and the radius of the largest circle
    about that centre inside its outline [m]."""

    geom: int
    axis: int
    centre: np.ndarray
    half_thickness: float
    inscribed_radius: float

    @classmethod
    def of(cls, model: mujoco.MjModel, geom: int) -> "_Occluder":
        """The occluder of mesh geom ``geom`` (its vertices' convex outline across its thinnest box axis)."""
        from scipy.spatial import ConvexHull

        if model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_MESH:
            raise ValueError(f"occluder geom {geom} is not a mesh")
        box = np.asarray(model.geom_aabb[geom], dtype=float)
        axis = int(np.argmin(box[3:]))
        mesh = int(model.geom_dataid[geom])
        adr, num = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
        verts = np.asarray(model.mesh_vert[adr:adr + num], dtype=float) - box[:3]
        flat = np.delete(verts, axis, axis=1)
        hull = ConvexHull(flat)
        # hull.equations: unit normal n and offset b with n.x + b <= 0 inside: the centre's distance to a side is -b
        radius = float(np.min(-hull.equations[:, 2]))
        if not radius > 0:
            raise ValueError(f"occluder geom {geom}: its outline does not surround its centre")
        return cls(geom, axis, box[:3].copy(), float(box[3 + axis]), radius)


class _FrustumCuller:
    """Leaves out of a draw the scene geoms that cannot show in it.

    Why: ``mjr_render`` sends every scene geom down the pipeline whatever the viewport shows, and on llvmpipe a
    primitive sphere at ``quality numslices=128`` costs ~0.2 ms per draw, the floor plane (drawn as a grid)
    ~0.1 ms, against ~0.05 ms for the rest of a small window, and a hidden geom drawn before what hides it costs
    its fragments too; a geom that cannot show produces no visible fragment (no shadows, no reflections here), so
    leaving it out changes no pixel. A geom cannot show when one of its bounding volumes (its bounding sphere; for a
    mesh or a box also its box, the model's ``geom_aabb`` in the geom's frame; for a finite plane its rectangle) lies
    wholly beyond one side of the frustum, or wholly behind the front face of an occluder (a flat opaque mesh:
    the plate's disc) whose outline covers the whole frustum there (the frustum's four edges meet the face's plane
    inside the circle inscribed in the outline). A left-out geom gets ``mjGEOM_NONE``, which ``mjr_render``
    skips; :meth:`restore` puts the types back. Infinite planes and geoms without a bounding radius are always
    drawn.
    """

    _NONE = int(mujoco.mjtGeom.mjGEOM_NONE)
    _PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
    _MESH = int(mujoco.mjtGeom.mjGEOM_MESH)
    # geoms whose model box (geom_aabb) bounds them as drawn: meshes and boxes (scene effects resize only spheres)
    _BOXED = (int(mujoco.mjtGeom.mjGEOM_MESH), int(mujoco.mjtGeom.mjGEOM_BOX))
    _OBJ_GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)

    def __init__(self, scene: mujoco.MjvScene, model: mujoco.MjModel, occluders: tuple[_Occluder, ...] = ()):
        self._scene = scene
        n = int(scene.ngeom)
        geoms = [scene.geoms[i] for i in range(n)]
        self._types = np.array([g.type for g in geoms], dtype=int)
        # mono rendering draws from the average of the two eye cameras (mjv_updateScene places them +-ipd/2 apart)
        cams = (scene.camera[0], scene.camera[1])
        fwd = np.mean([np.array(c.forward, dtype=float) for c in cams], axis=0)
        up = np.mean([np.array(c.up, dtype=float) for c in cams], axis=0)
        eye = np.mean([np.array(c.pos, dtype=float) for c in cams], axis=0)
        # camera coordinates: x right, y up, z along the view direction (depth)
        axes = np.stack([np.cross(fwd, up), up, fwd])
        by_geom = {int(g.objid): i for i, g in enumerate(geoms) if g.objtype == self._OBJ_GEOM}
        # bounding volumes: centre, three half-axis vectors (columns), radius, and the geom they bound
        centres, halves, radii, owners = [], [], [], []
        for i, g in enumerate(geoms):
            pos = np.array(g.pos, dtype=float)
            mat = np.array(g.mat, dtype=float).reshape(3, 3)  # columns: the geom's axes
            if g.modelrbound > 0:
                centres.append(pos)
                halves.append(np.zeros((3, 3)))
                radii.append(float(g.modelrbound))
                owners.append(i)
            if self._types[i] in self._BOXED and g.objtype == self._OBJ_GEOM and g.objid >= 0:
                box = np.asarray(model.geom_aabb[g.objid], dtype=float)
                centres.append(pos + mat @ box[:3])
                halves.append(mat * box[3:])
                radii.append(0.0)
                owners.append(i)
            elif self._types[i] == self._PLANE and g.size[0] > 0 and g.size[1] > 0:
                centres.append(pos)
                halves.append(mat * np.array([g.size[0], g.size[1], 0.0]))
                radii.append(0.0)
                owners.append(i)
        self._c = (np.array(centres).reshape(-1, 3) - eye) @ axes.T
        self._h = np.einsum("ij,kjl->kil", axes, np.array(halves).reshape(-1, 3, 3))
        self._r = np.array(radii)
        self._owner = np.array(owners, dtype=int)
        # occluders seen from their front: the face towards the eye (centre, unit normal towards the eye), the
        # inscribed radius, and which volumes lie wholly behind that face
        self._faces = []
        for occ in occluders:
            i = by_geom.get(occ.geom)
            if i is None or self._types[i] != self._MESH:
                continue
            g = geoms[i]
            mat = np.array(g.mat, dtype=float).reshape(3, 3)
            centre = (np.array(g.pos, dtype=float) + mat @ occ.centre - eye) @ axes.T
            normal = axes @ mat[:, occ.axis]
            if normal @ centre > 0:  # make the normal point towards the eye (the origin)
                normal = -normal
            face = centre + occ.half_thickness * normal
            if normal @ face >= 0:  # the eye within the slab: no front face
                continue
            # behind: the volume's nearest point to the face's plane, towards the eye, is still behind it
            depth = (self._c - face) @ -normal - np.abs(np.einsum("kij,i->kj", self._h, normal)).sum(axis=1) - self._r
            behind = depth > 0
            behind[self._owner == i] = False
            self._faces.append((face, normal, occ.inscribed_radius, behind))
        self._culled = np.zeros(n, dtype=bool)

    def cull(self, left: float, right: float, bottom: float, top: float, near: float) -> None:
        """Draw only the geoms that may show in the frustum of the near-plane window ``[left, right] x [bottom,
        top]`` at depth ``near`` (scene camera units)."""
        # the frustum's sides (coordinate = a z through the eye) and its near plane (z = near), inward unit normals
        a = np.array([left, right, bottom, top]) / near
        sign = np.array([1.0, -1.0, 1.0, -1.0])
        normals = np.zeros((5, 3))
        normals[[0, 1], 0] = sign[:2]
        normals[[2, 3], 1] = sign[2:]
        normals[:4, 2] = -sign * a
        normals[:4] /= np.sqrt(1.0 + a * a)[:, None]
        normals[4, 2] = 1.0
        offset = np.array([0.0, 0.0, 0.0, 0.0, -near])
        # a volume is beyond a plane when even its farthest point inwards (centre + support of the box and sphere)
        # lies outside
        reach = self._c @ normals.T + offset + np.abs(np.einsum("kij,pi->kpj", self._h, normals)).sum(axis=2)
        gone = (reach + self._r[:, None] < 0.0).any(axis=1)
        if self._faces:
            edges = np.array([[left, bottom, near], [right, bottom, near], [left, top, near], [right, top, near]])
            for face, normal, radius, behind in self._faces:
                t = (face @ normal) / (edges @ normal)  # where the frustum's edges meet the face's plane
                if np.all(t > 0) and np.all(np.linalg.norm(t[:, None] * edges - face, axis=1) < radius):
                    gone |= behind
        out = np.zeros_like(self._culled)
        np.logical_or.at(out, self._owner, gone)
        for i in np.flatnonzero(out != self._culled):
            self._scene.geoms[i].type = self._NONE if out[i] else int(self._types[i])
        self._culled = out

    def restore(self) -> None:
        for i in np.flatnonzero(self._culled):
            self._scene.geoms[i].type = int(self._types[i])
        self._culled[:] = False


class ImageFormer:
    """Turns a scene into 8-bit greyscale images for a set of cameras, reusing one GL context.

    ``supersample`` ``s``: MuJoCo renders ``s*width x s*height`` samples with the same field of view; lens
    distortion is applied on that sampling grid (each sample's ray goes through the lens model,
    :func:`sampling_intrinsics`), and every output pixel is the mean of its ``s x s`` samples
    (``cv2.INTER_AREA`` with an integer factor, float32: exact), as a sensor pixel integrates the light
    falling on it; then noise and 8-bit rounding as with one sample.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, supersample: int = 1,
                 frame_subsample: int = 1, occluders: tuple[int, ...] = ()):
        self.model = model
        # flat opaque meshes (model geom ids) that hide what lies behind them from a draw they cover
        self._occluders = tuple(_Occluder.of(model, int(g)) for g in occluders)
        self.width, self.height = int(width), int(height)
        s, k = int(supersample), int(frame_subsample)
        if s != supersample or s < 1:
            raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
        if k != frame_subsample or k < 1 or (k > 1 and s > 1) or self.width % k or self.height % k:
            raise ValueError(f"frame_subsample must be an integer >= 1 dividing the image size {self.width}x"
                             f"{self.height} (> 1 only with supersample 1), got {frame_subsample!r}")
        self.supersample, self.frame_subsample = s, k
        # the frame's sampling grid: s times the image (supersampling) or 1/k of it (a coarse frame under windows)
        self.render_width, self.render_height = s * self.width // k, s * self.height // k
        rw, rh = self.render_width, self.render_height
        # the offscreen buffer: the frame's grid, and at least the image (larger draws are split into tiles)
        self.buffer_width, self.buffer_height = max(rw, self.width), max(rh, self.height)
        if self.buffer_width > model.vis.global_.offwidth or self.buffer_height > model.vis.global_.offheight:
            raise ValueError(f"render {rw}x{rh} (image {self.width}x{self.height}, supersample {s}) exceeds the "
                             f"model's offscreen buffer {model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        # The pieces mujoco.Renderer assembles (GL context, MjrContext on the offscreen buffer, MjvScene), kept here
        # to draw several viewports per read-back and to read the buffer in the GL's own format.
        try:
            self._gl = mujoco.GLContext(self.buffer_width, self.buffer_height)
            self._gl.make_current()
        except mujoco.FatalError as exc:
            raise RuntimeError(
                f"MuJoCo could not open an offscreen GL context ({exc}); rendering needs MUJOCO_GL=egl set before "
                "mujoco is imported: export it, or call twin.runtime.set_process_defaults() first (the twin command does)"
            ) from exc
        limit = gl_max_renderbuffer_px()
        if limit == 0:  # a context that cannot render (MuJoCo's GLFW default without a display)
            self._gl.free()
            raise RuntimeError("MuJoCo opened no usable offscreen GL context; rendering needs MUJOCO_GL=egl set before "
                               "mujoco is imported: export it, or call twin.runtime.set_process_defaults() first "
                               "(the twin command does)")
        if limit is not None and max(rw, rh) > limit:
            self._gl.free()
            raise ValueError(f"render {rw}x{rh} (image {self.width}x{self.height}, supersample {s}) exceeds this "
                             f"GL's largest offscreen buffer ({limit} px a side): lower render.supersample")
        try:
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        except mujoco.FatalError as exc:
            self._gl.free()
            raise RuntimeError(f"MuJoCo could not create its offscreen buffer of {rw}x{rh} px ({exc})") from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._scene = mujoco.MjvScene(model, maxgeom=10000)
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED.value
        self._read = _Reader(self._con, self.buffer_width, self.buffer_height)
        self._f32 = np.empty((rh, rw), dtype=np.float32)
        self._full = np.empty((self.height, self.width), dtype=np.float32)
        if s > 1 or k > 1:
            self._warped = np.empty((self.height // k * s, self.width // k * s), dtype=np.float32)
        self._noise = np.empty((self.height, self.width), dtype=np.int16)
        self._pool: np.ndarray | None = None
        self._pool_sigma = 0.0

    def _draw(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption,
              jobs: list[tuple[tuple[int, int, int, int], int, int]]) -> list[np.ndarray]:
        """The ideal pinhole renders of ``jobs``: each a box ``(x0, y0, x1, y1)`` (columns ``x0..x1-1``, rows
        ``y0..y1-1``, row 0 at the top) of an ideal sampling grid of ``gw x gh`` samples over the camera's whole
        view; ``(y1-y0, x1-x0)`` uint8 each, the same samples as the whole grid's render there (up to GL rounding).

        Off-axis frustum of the same camera: after ``mjv_updateScene`` the scene camera's near-plane window
        (``frustum_center``, ``frustum_bottom``, ``frustum_top``, half-width from the viewport's aspect when
        ``frustum_width`` is 0) is narrowed to the box's share of the whole grid's, and the box is drawn into a
        viewport of its own size, so each sample maps to the same ray as in the whole grid. The viewports of a
        batch are packed into the offscreen buffer (shelves, tallest first) and read back together; boxes larger
        than the buffer are drawn in tiles.
        """
        if self._con is None:
            raise RuntimeError("the image former was closed")
        bw, bh = self.buffer_width, self.buffer_height
        tiles = []  # (job, tile box)
        for j, (box, gw, gh) in enumerate(jobs):
            x0, y0, x1, y1 = box
            if not (0 <= x0 < x1 <= gw and 0 <= y0 < y1 <= gh):
                raise ValueError(f"box {box!r} is not inside the {gw}x{gh} sampling grid")
            for ty in range(y0, y1, bh):
                for tx in range(x0, x1, bw):
                    tiles.append((j, (tx, ty, min(tx + bw, x1), min(ty + bh, y1))))
        tiles.sort(key=lambda t: -(t[1][3] - t[1][1]))
        outs = [np.empty((y1 - y0, x1 - x0), dtype=np.uint8) for (x0, y0, x1, y1), _, _ in jobs]
        self._gl.make_current()
        self._cam.fixedcamid = int(camera_id)
        # mjv_updateScene fills the scene cameras (mjr_render draws their average in mono): narrow their frustum
        # after it and before mjr_render (the only window onto the projection MuJoCo offers)
        mujoco.mjv_updateScene(self.model, data, option, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL.value, self._scene)
        gl_cams = [self._scene.camera[0], self._scene.camera[1]]
        full = [(c.frustum_center, c.frustum_bottom, c.frustum_top) for c in gl_cams]
        culler = _FrustumCuller(self._scene, self.model, self._occluders)
        try:
            placed: list[tuple[int, tuple[int, int, int, int], int, int]] = []  # (job, tile, px, py)
            px = py = shelf = 0
            for j, tile in tiles:
                tx0, ty0, tx1, ty1 = tile
                w, h = tx1 - tx0, ty1 - ty0
                if px + w > bw:
                    px, py, shelf = 0, py + shelf, 0
                if py + h > bh:  # the buffer is full: read this batch back, start another
                    self._read_batch(placed, py + shelf, outs, jobs)
                    placed, px, py, shelf = [], 0, 0, 0
                _, gw, gh = jobs[j]
                for c, (cen, bot, top) in zip(gl_cams, full):
                    height = top - bot
                    half = 0.5 * gw / gh * height
                    left = cen - half + tx0 / gw * 2 * half
                    right = cen - half + tx1 / gw * 2 * half
                    c.frustum_center = 0.5 * (left + right)
                    c.frustum_width = 0.0  # half-width from the viewport aspect: (right - left) / 2
                    c.frustum_top = top - ty0 / gh * height
                    c.frustum_bottom = top - ty1 / gh * height
                c0 = gl_cams[0]
                half_w = 0.5 * w / h * (c0.frustum_top - c0.frustum_bottom)
                culler.cull(c0.frustum_center - half_w, c0.frustum_center + half_w, c0.frustum_bottom,
                            c0.frustum_top, c0.frustum_near)
                mujoco.mjr_render(mujoco.MjrRect(px, py, w, h), self._scene, self._con)
                placed.append((j, tile, px, py))
                px += w
                shelf = max(shelf, h)
            self._read_batch(placed, py + shelf, outs, jobs)
        finally:
            culler.restore()
            for c, (cen, bot, top) in zip(gl_cams, full):
                c.frustum_center, c.frustum_bottom, c.frustum_top = cen, bot, top
        return outs

    def _read_batch(self, placed, rows: int, outs: list[np.ndarray], jobs) -> None:
        """Read the drawn rows of the buffer and copy each placed tile into its job's image (flipped: GL rows
        run bottom first)."""
        if not placed:
            return
        grey = self._read(rows)
        for j, (tx0, ty0, tx1, ty1), px, py in placed:
            x0, y0 = jobs[j][0][:2]
            w, h = tx1 - tx0, ty1 - ty0
            outs[j][ty0 - y0:ty1 - y0, tx0 - x0:tx1 - x0] = grey[py:py + h, px:px + w][::-1]

    def ideal_grey(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption) -> np.ndarray:
        """The ideal pinhole render ``(s*H/k, s*W/k)`` uint8 of the frame's sampling grid, row 0 at the top."""
        rw, rh = self.render_width, self.render_height
        return self._draw(data, camera_id, option, [((0, 0, rw, rh), rw, rh)])[0]

    def form(
        self,
        data: mujoco.MjData,
        camera_id: int,
        cam: CameraPipeline,
        option: mujoco.MjvOption,
        noise_sigma: float,
        noise_seed: int | None,
        image_effects: tuple[Callable[[np.ndarray], np.ndarray], ...] = (),
        *,
        analog: bool = False,
        windows: tuple[tuple[int, int, int, int], ...] = (),
        window_supersample: int = 4,
    ) -> np.ndarray:
        """The camera's image ``(H, W)`` uint8 (a new array): ideal render, image effects, distortion, pixel
        integration (supersampling), noise.

        Image effects get the ideal render of :meth:`ideal_grey` (uint8, on the sampling grid: ``s`` times the
        image size with supersampling) and must return the same shape and dtype. ``analog``: return the
        float32 image before noise and 8-bit rounding (diagnostics).

        ``windows``: image rectangles ``(u0, v0, u1, v1)`` [px] formed at ``window_supersample`` x
        ``window_supersample`` samples per pixel (:meth:`CameraPipeline.window_tables`) and pasted into the frame's
        noise-free image before the noise, so that the result is one whole image; the frame and the windows'
        boxes are drawn in one batch. Ignored when image effects are given (they work on the whole ideal render of
        one sampling grid): the image is the full frame's.
        """
        if cam.supersample != self.supersample or cam.frame_subsample != self.frame_subsample:
            raise ValueError(f"camera {cam.name!r} was built for supersample {cam.supersample} / frame_subsample "
                             f"{cam.frame_subsample}, the renderer samples {self.supersample} / {self.frame_subsample}")
        if image_effects and self.frame_subsample > 1:
            raise ValueError("image effects need the frame at full resolution: frame_subsample must be 1 with "
                             "image effects")
        windows = tuple(windows) if not image_effects else ()
        rw, rh = self.render_width, self.render_height
        jobs = [((0, 0, rw, rh), rw, rh)]
        tables, groups, group_boxes = None, [], []
        if windows:
            ws = int(window_supersample)
            if ws < 1:
                raise ValueError(f"window_supersample must be an integer >= 1, got {window_supersample!r}")
            tables = cam.window_tables(list(windows), ws)
            # Why merge only boxes whose union adds few samples: a draw costs about _DRAW_COST_SAMPLES rasterised
            # samples, and a ring of arcs merged into one box would rasterise the sphere's whole disc.
            groups = _merge_boxes(tables.boxes)
            group_boxes = [(min(tables.boxes[i][0] for i in g), min(tables.boxes[i][1] for i in g),
                            max(tables.boxes[i][2] for i in g), max(tables.boxes[i][3] for i in g)) for g in groups]
            jobs += [(b, *tables.grid) for b in group_boxes]
        drawn = self._draw(data, camera_id, option, jobs)
        img = drawn[0]
        shape = (rh, rw)
        for fx in image_effects:
            img = fx(img)
            if img.shape != shape or img.dtype != np.uint8:
                raise ValueError(f"an image effect returned {img.shape} {img.dtype}, expected {shape} uint8 "
                                 f"(the ideal render on the sampling grid, supersample {self.supersample})")
        if cam.maps is None and self.supersample == 1 and self.frame_subsample == 1 and not windows:
            if analog:
                return img.astype(np.float32)
            out = img.copy()
            if noise_sigma > 0:
                self._seed(noise_seed)
                cv2.randn(self._noise, 0.0, float(noise_sigma))  # integer noise: img is integer already
                cv2.add(out, self._noise, dst=out, dtype=cv2.CV_8U)
            return out
        analog_img = self._frame_analog(img, cam)
        if windows:
            for g, (gx0, gy0, _, _), ideal in zip(groups, group_boxes, drawn[1:]):
                ideal = ideal.astype(np.float32)
                for i in g:
                    u0, v0, u1, v1 = tables.rects[i]
                    x0, y0, x1, y1 = tables.boxes[i]
                    if cam.ideal:
                        samples = ideal[y0 - gy0:y1 - gy0, x0 - gx0:x1 - gx0]
                    else:
                        # from the window's own source box on: every sample and its bilinear neighbours lie in
                        # the box (the replicated border only where the box meets the grid's, as in a frame)
                        mx, my = tables.maps(i)
                        samples = cv2.remap(ideal[y0 - gy0:, x0 - gx0:], mx, my, _REMAP_INTERPOLATION,
                                            borderMode=cv2.BORDER_REPLICATE)
                    analog_img[v0:v1, u0:u1] = cv2.resize(samples, (u1 - u0, v1 - v0), interpolation=cv2.INTER_AREA)
        if analog:
            return analog_img.copy()
        if noise_sigma <= 0:
            return cv2.add(analog_img, 0.0, dtype=cv2.CV_8U)  # rounds to nearest and saturates to 0..255
        # adds the noise, rounds to nearest and saturates to 0..255 in one pass
        return cv2.add(analog_img, self._noise_image(float(noise_sigma), noise_seed), dtype=cv2.CV_8U)

    def _frame_analog(self, img: np.ndarray, cam: CameraPipeline) -> np.ndarray:
        """The frame's noise-free image ``(H, W)`` float32 (an internal buffer) from its ideal render ``img``:
        distortion on the frame's grid, then block means (supersampling) or a bilinear resize (a coarse frame)."""
        np.copyto(self._f32, img)
        k, s = self.frame_subsample, self.supersample
        if k == 1 and s == 1:
            if cam.maps is None:
                np.copyto(self._full, self._f32)
            else:
                cv2.remap(self._f32, cam.maps[0], cam.maps[1], _REMAP_INTERPOLATION, dst=self._full,
                          borderMode=cv2.BORDER_REPLICATE)
            return self._full
        warped = self._f32
        if cam.maps is not None:
            warped = cv2.remap(self._f32, cam.maps[0], cam.maps[1], _REMAP_INTERPOLATION, dst=self._warped,
                               borderMode=cv2.BORDER_REPLICATE)
        # s > 1: each output pixel the mean of its s x s samples (INTER_AREA with an integer factor, exact in
        # float32); k > 1: the coarse image resized bilinearly (pixel u at (u + 0.5)/k - 0.5 of the coarse grid)
        cv2.resize(warped, (self.width, self.height), dst=self._full,
                   interpolation=cv2.INTER_AREA if s > 1 else cv2.INTER_LINEAR)
        return self._full

    def _noise_image(self, sigma: float, noise_seed: int | None) -> np.ndarray:
        """Sensor noise ``(H, W)`` float32 (a view), N(0, ``sigma``^2) i.i.d. over the pixels: rows of one long stream
        of Gaussian samples (generated once per image former, the same in every process), read from an offset and
        with a row pitch (``W`` to ``W`` + :data:`_NOISE_PITCHES` - 1) both drawn from ``noise_seed`` (random
        without one).

        Why a stream and not ``cv2.randn`` per image: a 5-Mpx image of Gaussian samples costs ~11 ms, a sixth of
        a windowed image. Within an image the samples are distinct draws of the stream, as independent as
        before. Two images share samples only at a shear of each other (another pitch) or at a shift of their
        offsets' difference (the same pitch, 1 in 1024): a pixel's noise lands under an unrelated pixel of the
        other image; two images read the very same samples with a chance of 1 in 4e9."""
        w, h = self.width, self.height
        if self._pool is None or self._pool_sigma != sigma:
            self._pool = np.empty(h * (w + _NOISE_PITCHES) + _NOISE_OFFSETS, dtype=np.float32)
            cv2.setRNGSeed(0x5EED)
            cv2.randn(self._pool, 0.0, sigma)
            self._pool_sigma = sigma
        rng = np.random.default_rng(None if noise_seed is None else int(noise_seed) & 0xFFFFFFFF)
        offset, pitch = int(rng.integers(_NOISE_OFFSETS)), w + int(rng.integers(_NOISE_PITCHES))
        return self._pool[offset:offset + h * pitch].reshape(h, pitch)[:, :w]

    @staticmethod
    def _seed(noise_seed: int | None) -> None:
        if noise_seed is not None:
            cv2.setRNGSeed(int(noise_seed) & 0x7FFFFFFF)

    def close(self) -> None:
        """Free the GL resources (the MjrContext first, while its context is current)."""
        if self._con is not None:
            self._gl.make_current()
            self._con.free()
            self._con = None
            self._gl.free()


class _Reader:
    """Reads the first ``rows`` rows of the offscreen buffer as greyscale ``(rows, width)`` uint8 (GL row order:
    bottom first). RGBA is the GL's native read format here (a copy; RGB goes through a slower conversion);
    with a multisampled buffer MuJoCo's own ``mjr_readPixels`` (which resolves it) is used."""

    def __init__(self, con: mujoco.MjrContext, width: int, height: int):
        self._con, self.width = con, width
        self._gl = None
        if not con.offSamples:
            try:
                from OpenGL import GL  # PyOpenGL: a dependency of mujoco's own GL back ends

                self._gl = GL
            except ImportError:  # pragma: no cover - depends on the installation
                self._gl = None
        self._buf = np.empty((height, width, 4 if self._gl is not None else 3), dtype=np.uint8)
        self._grey = np.empty((height, width), dtype=np.uint8)

    def __call__(self, rows: int) -> np.ndarray:
        buf = self._buf[:rows]
        if self._gl is not None:
            GL = self._gl
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._con.offFBO)
            GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
            GL.glReadPixels(0, 0, self.width, rows, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, buf)
            return cv2.cvtColor(buf, cv2.COLOR_RGBA2GRAY, dst=self._grey[:rows])
        mujoco.mjr_readPixels(buf, None, mujoco.MjrRect(0, 0, self.width, rows), self._con)
        return cv2.cvtColor(buf, cv2.COLOR_RGB2GRAY, dst=self._grey[:rows])


__all__ += ["ImageFormer", "gl_max_renderbuffer_px"]
