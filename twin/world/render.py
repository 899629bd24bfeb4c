"""Image formation: MuJoCo's ideal pinhole render -> greyscale -> lens distortion -> pixel integration -> noise.

One ``mujoco.Renderer`` per image size, created once and reused (start-up costs ~0.5 s). Each camera
keeps preallocated buffers and its remap tables, so the work around the renderer per image is a colour
conversion, one ``cv2.remap`` (only when the true camera differs from the ideal pinhole), with
supersampling one ``cv2.resize`` (block means), and one ``cv2.randn`` + saturating ``cv2.add``, which also
rounds to 8 bits once, at the end.

Supersampling (``render.supersample`` = ``s``): MuJoCo samples each pixel once, so outlines are staircases
whose low-frequency error moves a fitted sphere centre by ~0.04 px. With ``s`` > 1 the renderer draws
``s x s`` samples per pixel (``s`` times the width and height, the same field of view), the distortion is
applied to every sample (remap tables on the sampling grid, :func:`sampling_intrinsics`), and each output
pixel is the mean of its block, as a sensor pixel integrates light. Averaging first and distorting the
averaged image afterwards was measured too: the bilinear remap at output resolution puts 0.03 px of centre
error back (0.033 px against 0.011 px RMS).

Target windows (``render.window_supersample`` = ``S``): the frame at ``s`` samples per pixel, and windows
``(u0, v0, u1, v1)`` of the output image at ``S x S``: their samples lie on the whole ``S``-grid (the tables
of :meth:`CameraPipeline.window_maps`, the same dither), MuJoCo draws only their source box through an
off-axis frustum of the same camera (:meth:`ImageFormer.ideal_windows`), and their block means replace the
frame's noise-free pixels before the noise: one whole image, equal inside each window to the full ``S x S``
render up to GL rounding.

Sub-pixel fidelity: resampling an 8-bit image to 8 bits loses shifts smaller than ~1/30 px (each pixel
changes by less than half a grey level and rounds back), and ``cv2.remap`` quantizes source positions to
1/32 px, which biases every feature the same way. So the resampling runs in float32 and its tables carry
a fixed uniform dither of one quantum (+-1/64 px), which makes the quantization error zero-mean from
pixel to pixel (a hash of the sample's position, so that windows get the frame's dither); the sensor noise
then dithers the final rounding. Measured: the image of a known point
agrees with the camera model to about 0.001 px (``tests/test_world_render.py``).

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

from ..camera import CameraIntrinsics, undistort_normalized
from scipy.interpolate import RectBivariateSpline

from .rig import check_distortion_monotonic, distortion_maps, render_focal_px

__all__ = ["CameraPipeline", "scene_option", "sampling_intrinsics"]
# Bilinear on the sampling grid. Measured (6 poses, both cameras, the instrument's sphere centres against the
# true projections): with 2x2 samples, bilinear 0.011 px RMS, bicubic 0.013 px; with one sample bicubic would
# cut 0.042 px to 0.032 px and Lanczos-4 to 0.023 px (at 7x the remap time), see docs/world.md.
_REMAP_INTERPOLATION = cv2.INTER_LINEAR


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


def _hash_dither(seed: int, x0: int, y0: int, shape: tuple[int, int]) -> np.ndarray:
    """A fixed uniform dither in ``[-1/64, 1/64)`` px ``shape`` float32 for the samples ``x0 + j``, ``y0 + i`` of
    a sampling grid: a hash of (seed, column, row), so that any window of the grid gets the whole grid's values."""
    ys = np.arange(y0, y0 + shape[0], dtype=np.uint32)[:, None]
    xs = np.arange(x0, x0 + shape[1], dtype=np.uint32)[None, :]
    with np.errstate(over="ignore"):
        h = xs * np.uint32(0x9E3779B1) ^ ys * np.uint32(0x85EBCA77) ^ np.uint32(seed * 0xC2B2AE3D & 0xFFFFFFFF)
        h ^= h >> np.uint32(16)  # murmur3's finalizer: every input bit reaches every output bit
        h *= np.uint32(0x85EBCA6B)
        h ^= h >> np.uint32(13)
        h *= np.uint32(0xC2B2AE35)
        h ^= h >> np.uint32(16)
    return ((h >> np.uint32(8)).astype(np.float32) * np.float32(2.0**-24) - np.float32(0.5)) * np.float32(1.0 / 32.0)


def _dithered_fixed_point(name: str, map_x: np.ndarray, map_y: np.ndarray, x0: int, y0: int,
                          shift: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap``'s fixed-point tables (``CV_16SC2``) of the float32 maps of the samples from ``(x0, y0)`` on,
    each moved by the camera's fixed dither of one quantum and by ``-shift`` (a source box's origin) [px]."""
    seed = sum(map(ord, name))
    mx = map_x + _hash_dither(2 * seed, x0, y0, map_x.shape)
    my = map_y + _hash_dither(2 * seed + 1, x0, y0, map_y.shape)
    if shift != (0, 0):
        mx -= np.float32(shift[0])
        my -= np.float32(shift[1])
    return cv2.convertMaps(mx, my, cv2.CV_16SC2)


def _overlap_groups(boxes: list[tuple[int, int, int, int]]) -> list[list[int]]:
    """Indices of ``boxes`` ``(x0, y0, x1, y1)`` grouped into connected sets of overlapping (or touching) boxes."""
    parent = list(range(len(boxes)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, a in enumerate(boxes):
        for j in range(i + 1, len(boxes)):
            b = boxes[j]
            if a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]:
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(len(boxes)):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


@dataclass
class CameraPipeline:
    """One camera's image formation: its true intrinsics, ideal render focal length, samples per pixel along
    each axis and the remap tables on the sampling grid (``None``: the true camera is the ideal one)."""

    name: str
    intr: CameraIntrinsics
    f_render: float
    maps: tuple[np.ndarray, np.ndarray] | None
    supersample: int = 1
    frame_subsample: int = 1
    ideal: bool = False  # the true camera is the ideal pinhole (no distortion, centred, focal f_r)

    @classmethod
    def build(cls, name: str, intr: CameraIntrinsics, supersample: int = 1,
              frame_subsample: int = 1) -> "CameraPipeline":
        """``frame_subsample`` ``k`` > 1 (only with ``supersample`` 1): the frame's ideal render has ``W/k x H/k``
        samples (the same field of view) and the tables map each output pixel into that coarser grid."""
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
        # the ideal render on the sampling grid has focal length s * f_r: the same field of view
        maps = distortion_maps(sampling_intrinsics(intr, s), s * f_r)
        ideal = maps is None
        if k > 1:
            if maps is None:
                mx, my = np.meshgrid(np.arange(intr.width, dtype=np.float32), np.arange(intr.height, dtype=np.float32))
                maps = (mx, my)
            # a full-resolution ideal pixel x lies at (x + 0.5) / k - 0.5 in the k-times coarser ideal grid
            maps = tuple(((m + np.float32(0.5)) / np.float32(k) - np.float32(0.5)).astype(np.float32) for m in maps)
        if maps is not None:
            # Dither of one quantum (cv2.remap works in 1/32 px), fixed per camera and sample (a hash of the
            # sample's position, so that target windows get the same dither), then fixed-point tables.
            maps = _dithered_fixed_point(name, maps[0], maps[1], 0, 0)
        return cls(name, intr, f_r, maps, s, k, ideal)

    def window_maps(self, rect: tuple[int, int, int, int], s: int) -> tuple[np.ndarray, np.ndarray]:
        """Where each sample of the output window ``rect`` = ``(u0, v0, u1, v1)`` [px] lies in the ideal render's
        sampling grid at ``s x s`` samples per pixel: two float32 ``(s*(v1-v0), s*(u1-u0))`` maps in that grid's
        pixel coordinates (the whole grid: ``s*W x s*H``, focal ``s*f_r``, centre ``s*W/2 - 0.5``).

        The same construction as the full-frame tables (:func:`twin.world.rig.distortion_maps`): the inverse
        distortion solved on the whole grid's coarse lattice (every 16 samples, padded by two nodes) and the
        same bicubic spline (:meth:`_lattice_splines`, built once), evaluated at the window's samples, or, in a
        small window with ``s > 1``, at one sample per output pixel with linear interpolation between them.
        """
        u0, v0, u1, v1 = rect
        xs = np.arange(s * u0, s * u1, dtype=float)
        ys = np.arange(s * v0, s * v1, dtype=float)
        if self.ideal:  # the true camera is the ideal one: the window's samples are the ideal grid's
            mx, my = np.meshgrid(xs, ys)
            return mx.astype(np.float32), my.astype(np.float32)
        ccx, ccy = s * self.intr.width / 2 - 0.5, s * self.intr.height / 2 - 0.5
        fr = s * self.f_render
        sx, sy = self._lattice_splines(s)
        if s == 1 or len(xs) * len(ys) > 250_000:
            return ((sx(ys, xs) * fr + ccx).astype(np.float32), (sy(ys, xs) * fr + ccy).astype(np.float32))
        # Why not the spline at every sample of a small window: fitpack's per-call cost makes it ~40 ms per
        # stereo pair over a ring of windows. The spline at every s-th sample (one per output pixel, plus the
        # far edge) and linear in between, in float64: the map's curvature over one pixel leaves < 1e-4 sample,
        # far below the tables' 1/32-sample fixed point (large windows keep the spline: the gathers grow faster).
        xc, yc = xs[::s], ys[::s]
        xc, yc = np.append(xc, xc[-1] + s), np.append(yc, yc[-1] + s)
        tx, ty = np.arange(len(xs)), np.arange(len(ys))
        ix, iy = tx // s, ty // s
        wx, wy = (tx % s) / s, ((ty % s) / s)[:, None]
        out = []
        for spline, cc in ((sx, ccx), (sy, ccy)):
            m = spline(yc, xc) * fr + cc
            m = m[:, ix] + (m[:, ix + 1] - m[:, ix]) * wx  # (len(yc), len(xs))
            out.append((m[iy] + (m[iy + 1] - m[iy]) * wy).astype(np.float32))
        return out[0], out[1]

    def _lattice_splines(self, s: int) -> tuple[RectBivariateSpline, RectBivariateSpline]:
        """The normalized ray ``(x, y)`` of every sample of the ``s``-grid as two bicubic splines on the coarse
        lattice of :func:`twin.world.rig.distortion_maps` (nodes every 16 samples from -32 on), cached."""
        cache = self.__dict__.setdefault("_splines", {})
        if s not in cache:
            si = sampling_intrinsics(self.intr, s)
            step = 16
            us = np.arange(-2 * step, si.width + 2 * step + 1, step, dtype=float)
            vs = np.arange(-2 * step, si.height + 2 * step + 1, step, dtype=float)
            U, V = np.meshgrid(us, vs)
            xy = undistort_normalized(np.stack([(U - si.cx) / si.fx, (V - si.cy) / si.fy], axis=-1), si.dist)
            cache[s] = tuple(RectBivariateSpline(vs, us, xy[..., c], kx=3, ky=3) for c in (0, 1))
        return cache[s]

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view of the ideal render [deg]."""
        return float(np.rad2deg(2.0 * np.arctan(0.5 * self.intr.height / self.f_render)))


def gl_max_renderbuffer_px() -> int | None:
    """The current GL context's largest renderbuffer side [px] (``GL_MAX_RENDERBUFFER_SIZE``; 16384 on Mesa's
    llvmpipe here), or ``None`` when it cannot be queried. Needs a current context."""
    try:
        from OpenGL import GL  # PyOpenGL: a dependency of mujoco's own GL back ends

        return int(GL.glGetIntegerv(GL.GL_MAX_RENDERBUFFER_SIZE))
    except Exception:  # noqa: BLE001 - no PyOpenGL or no context: MuJoCo's own check still applies
        return None


class _FrustumCuller:
    """Leaves out of a window's draw the scene geoms whose bounding sphere lies wholly outside its frustum.

    Why: ``mjr_render`` sends every scene geom down the pipeline whatever the viewport shows, and on llvmpipe a
    primitive sphere at ``quality numslices=128`` costs ~0.5 ms per draw against ~0.1 ms for the rest of a
    small window; a geom outside the frustum produces no fragment (no shadows, no reflections here), so
    leaving it out changes no pixel. A left-out geom gets ``mjGEOM_NONE``, which ``mjr_render`` skips;
    :meth:`restore` puts the types back. Geoms without a model bounding radius (planes, decor) are always drawn.
    """

    _NONE = int(mujoco.mjtGeom.mjGEOM_NONE)

    def __init__(self, scene: mujoco.MjvScene):
        self._scene = scene
        n = int(scene.ngeom)
        self._types = np.array([scene.geoms[i].type for i in range(n)], dtype=int)
        self._pos = np.array([scene.geoms[i].pos for i in range(n)], dtype=float).reshape(n, 3)
        self._rbound = np.array([scene.geoms[i].modelrbound for i in range(n)], dtype=float)
        # mono rendering draws from the average of the two eye cameras (mjv_updateScene places them +-ipd/2 apart)
        cams = (scene.camera[0], scene.camera[1])
        fwd = np.mean([np.array(c.forward, dtype=float) for c in cams], axis=0)
        up = np.mean([np.array(c.up, dtype=float) for c in cams], axis=0)
        d = self._pos - np.mean([np.array(c.pos, dtype=float) for c in cams], axis=0)
        # camera coordinates: x right, y up, z along the view direction (depth)
        self._xyz = np.stack([d @ np.cross(fwd, up), d @ up, d @ fwd], axis=1)
        self._culled = np.zeros(n, dtype=bool)

    def cull(self, left: float, right: float, bottom: float, top: float, near: float) -> None:
        """Draw only the geoms that may reach the frustum of the near-plane window ``[left, right] x [bottom,
        top]`` at depth ``near`` (scene camera units)."""
        x, y, z = self._xyz.T
        r = self._rbound

        def outside(a: float, coord: np.ndarray, sign: float) -> np.ndarray:
            # plane coord = a z through the eye: signed distance (inside > 0) below -r
            return sign * (coord - a * z) / np.sqrt(1.0 + a * a) < -r

        out = ((z + r < near) | outside(left / near, x, 1.0) | outside(right / near, x, -1.0)
               | outside(bottom / near, y, 1.0) | outside(top / near, y, -1.0)) & (r > 0)
        for i in np.flatnonzero(out != self._culled):
            self._scene.geoms[i].type = self._NONE if out[i] else int(self._types[i])
        self._culled = out

    def restore(self) -> None:
        for i in np.flatnonzero(self._culled):
            self._scene.geoms[i].type = int(self._types[i])
        self._culled[:] = False


class ImageFormer:
    """Turns a scene into 8-bit greyscale images for a set of cameras, reusing one renderer.

    ``supersample`` ``s``: MuJoCo renders ``s*width x s*height`` samples with the same field of view; lens
    distortion is applied on that sampling grid (each sample's ray goes through the lens model,
    :func:`sampling_intrinsics`), and every output pixel is the mean of its ``s x s`` samples
    (``cv2.INTER_AREA`` with an integer factor, float32: exact), as a sensor pixel integrates the light
    falling on it; then noise and 8-bit rounding as with one sample.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, supersample: int = 1,
                 frame_subsample: int = 1):
        self.model = model
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
        # the offscreen buffer: the frame's grid, and at least the image (windows are drawn in buffer-sized tiles)
        self.buffer_width, self.buffer_height = max(rw, self.width), max(rh, self.height)
        if self.buffer_width > model.vis.global_.offwidth or self.buffer_height > model.vis.global_.offheight:
            raise ValueError(f"render {rw}x{rh} (image {self.width}x{self.height}, supersample {s}) exceeds the "
                             f"model's offscreen buffer {model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        # The same pieces mujoco.Renderer assembles (GL context, MjrContext on the offscreen buffer, MjvScene),
        # kept here so that the pixels can be read without Renderer.render()'s extra flip of the RGB frame:
        # the flip is done once on the 8-bit grey image instead.
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
        self._rect = mujoco.MjrRect(0, 0, rw, rh)
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED.value
        self._rgb = np.empty((rh, rw, 3), dtype=np.uint8)
        self._grey_flipped = np.empty((rh, rw), dtype=np.uint8)
        self._grey = np.empty((rh, rw), dtype=np.uint8)
        self._f32 = np.empty((rh, rw), dtype=np.float32)
        if s > 1:
            self._warped = np.empty((rh, rw), dtype=np.float32)
            self._mean = np.empty((self.height, self.width), dtype=np.float32)
        elif k > 1:
            self._warped = np.empty((self.height, self.width), dtype=np.float32)
        self._noise = np.empty((self.height, self.width), dtype=np.int16)
        self._noise_f = np.empty((self.height, self.width), dtype=np.float32)

    def ideal_grey(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption) -> np.ndarray:
        """The ideal pinhole render ``(s*H, s*W)`` uint8 on the sampling grid, row 0 at the top (a view into an
        internal buffer)."""
        if self._con is None:
            raise RuntimeError("the image former was closed")
        self._gl.make_current()
        self._cam.fixedcamid = int(camera_id)
        mujoco.mjv_updateScene(self.model, data, option, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL.value, self._scene)
        mujoco.mjr_render(self._rect, self._scene, self._con)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)  # OpenGL rows: bottom row first
        cv2.cvtColor(self._rgb, cv2.COLOR_RGB2GRAY, dst=self._grey_flipped)
        cv2.flip(self._grey_flipped, 0, dst=self._grey)
        return self._grey

    def ideal_windows(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption,
                      boxes: list[tuple[int, int, int, int]], s: int) -> list[np.ndarray]:
        """The ideal pinhole renders of the boxes ``(x0, y0, x1, y1)`` (columns ``x0..x1-1``, rows ``y0..y1-1``, row
        0 at the top) of the ideal sampling grid at ``s x s`` samples per pixel (``s*W x s*H``): ``(y1-y0, x1-x0)``
        uint8 each, the same samples as the whole grid's render there (up to GL rounding).

        Off-axis frustum of the same camera: after ``mjv_updateScene`` the scene camera's near-plane window
        (``frustum_center``, ``frustum_bottom``, ``frustum_top``, half-width from the viewport's aspect when
        ``frustum_width`` is 0) is narrowed to the box's share of the whole grid's, and the box is drawn into a
        viewport of its own size, so each pixel centre maps to the same ray as in the whole grid. Boxes larger
        than the offscreen buffer are drawn in tiles.
        """
        if self._con is None:
            raise RuntimeError("the image former was closed")
        gw, gh = s * self.width, s * self.height
        for box in boxes:
            x0, y0, x1, y1 = box
            if not (0 <= x0 < x1 <= gw and 0 <= y0 < y1 <= gh):
                raise ValueError(f"box {box!r} is not inside the {gw}x{gh} sampling grid")
        self._gl.make_current()
        self._cam.fixedcamid = int(camera_id)
        # mjv_updateScene fills the scene cameras (mjr_render draws their average in mono): narrow their frustum
        # after it and before mjr_render (the only window onto the projection MuJoCo offers)
        mujoco.mjv_updateScene(self.model, data, option, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL.value, self._scene)
        gl_cams = [self._scene.camera[0], self._scene.camera[1]]
        full = [(c.frustum_center, c.frustum_bottom, c.frustum_top) for c in gl_cams]
        bw, bh = self.buffer_width, self.buffer_height  # the offscreen buffer
        culler = _FrustumCuller(self._scene)
        outs = []
        try:
            for x0, y0, x1, y1 in boxes:
                out = np.empty((y1 - y0, x1 - x0), dtype=np.uint8)
                outs.append(out)
                for ty in range(y0, y1, bh):
                    for tx in range(x0, x1, bw):
                        w, h = min(bw, x1 - tx), min(bh, y1 - ty)
                        for c, (cen, bot, top) in zip(gl_cams, full):
                            height = top - bot
                            half = 0.5 * gw / gh * height
                            left = cen - half + tx / gw * 2 * half
                            right = cen - half + (tx + w) / gw * 2 * half
                            c.frustum_center = 0.5 * (left + right)
                            c.frustum_width = 0.0  # half-width from the viewport aspect: (right - left) / 2
                            c.frustum_top = top - ty / gh * height
                            c.frustum_bottom = top - (ty + h) / gh * height
                        rect = mujoco.MjrRect(0, 0, w, h)
                        c0 = gl_cams[0]
                        half_w = 0.5 * w / h * (c0.frustum_top - c0.frustum_bottom)
                        culler.cull(c0.frustum_center - half_w, c0.frustum_center + half_w, c0.frustum_bottom,
                                    c0.frustum_top, c0.frustum_near)
                        mujoco.mjr_render(rect, self._scene, self._con)
                        rgb = np.empty((h, w, 3), dtype=np.uint8)
                        mujoco.mjr_readPixels(rgb, None, rect, self._con)  # bottom row first
                        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
                        out[ty - y0:ty - y0 + h, tx - x0:tx - x0 + w] = grey[::-1]
        finally:
            culler.restore()
            for c, (cen, bot, top) in zip(gl_cams, full):
                c.frustum_center, c.frustum_bottom, c.frustum_top = cen, bot, top
        return outs

    def windows_analog(self, data: mujoco.MjData, camera_id: int, cam: CameraPipeline, option: mujoco.MjvOption,
                       rects: list[tuple[int, int, int, int]], s: int) -> list[np.ndarray]:
        """The noise-free output pixels ``(v1-v0, u1-u0)`` float32 of each image window ``(u0, v0, u1, v1)`` at
        ``s x s`` samples per pixel: the ideal render of the samples' source box, distortion on the sampling
        grid (the same dithered bilinear remap as the full frame), block means."""
        gw, gh = s * self.width, s * self.height
        maps, boxes = [], []
        for rect in rects:
            mx, my = cam.window_maps(rect, s)
            # the source box: every bilinear neighbour of every sample (clipped to the grid: BORDER_REPLICATE
            # there, as in the full frame)
            x0 = int(np.clip(np.floor(mx.min()) - 1, 0, gw - 1))
            y0 = int(np.clip(np.floor(my.min()) - 1, 0, gh - 1))
            x1 = int(np.clip(np.ceil(mx.max()) + 2, x0 + 1, gw))
            y1 = int(np.clip(np.ceil(my.max()) + 2, y0 + 1, gh))
            maps.append((mx, my))
            boxes.append((x0, y0, x1, y1))
        # Why one draw per group of overlapping source boxes (a sphere's ring of windows, say) and not one per
        # window: each mjr_render sends the target's whole tessellated sphere through llvmpipe (~0.5 ms) while
        # the extra samples inside the group's bounding box cost ~5 ns each; the same frustum gives each sample
        # the same ray either way.
        groups = _overlap_groups(boxes)
        group_boxes = [(min(boxes[i][0] for i in g), min(boxes[i][1] for i in g),
                        max(boxes[i][2] for i in g), max(boxes[i][3] for i in g)) for g in groups]
        drawn = self.ideal_windows(data, camera_id, option, group_boxes, s)
        ideals: list[np.ndarray] = [np.empty(0)] * len(boxes)
        for g, (gx0, gy0, _, _), img in zip(groups, group_boxes, drawn):
            for i in g:
                x0, y0, x1, y1 = boxes[i]
                ideals[i] = img[y0 - gy0:y1 - gy0, x0 - gx0:x1 - gx0]
        out = []
        for (u0, v0, u1, v1), (mx, my), (x0, y0, _, _), ideal in zip(rects, maps, boxes, ideals):
            ideal = ideal.astype(np.float32)
            if cam.ideal:
                samples = ideal[s * v0 - y0:s * v1 - y0, s * u0 - x0:s * u1 - x0]
            else:
                # the full frame's dither at these samples, then the source box's origin
                m1, m2 = _dithered_fixed_point(cam.name, mx, my, s * u0, s * v0, shift=(x0, y0))
                samples = cv2.remap(ideal, m1, m2, _REMAP_INTERPOLATION, borderMode=cv2.BORDER_REPLICATE)
            out.append(cv2.resize(samples, (u1 - u0, v1 - v0), interpolation=cv2.INTER_AREA))
        return out

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
        ``window_supersample`` samples per pixel (:meth:`window_analog`) and pasted into the full frame's
        noise-free image before the noise, so that the result is one whole image. Ignored when image effects
        are given (they work on the whole ideal render of one sampling grid): the image is the full frame's.
        """
        if cam.supersample != self.supersample or cam.frame_subsample != self.frame_subsample:
            raise ValueError(f"camera {cam.name!r} was built for supersample {cam.supersample} / frame_subsample "
                             f"{cam.frame_subsample}, the renderer samples {self.supersample} / {self.frame_subsample}")
        if image_effects and self.frame_subsample > 1:
            raise ValueError("image effects need the frame at full resolution: frame_subsample must be 1 with "
                             "image effects")
        img = self.ideal_grey(data, camera_id, option)
        shape = (self.render_height, self.render_width)
        for fx in image_effects:
            img = fx(img)
            if img.shape != shape or img.dtype != np.uint8:
                raise ValueError(f"an image effect returned {img.shape} {img.dtype}, expected {shape} uint8 "
                                 f"(the ideal render on the sampling grid, supersample {self.supersample})")
        windows = tuple(windows) if not image_effects else ()
        if cam.maps is None and self.supersample == 1 and not windows:
            if analog:
                return img.astype(np.float32)
            out = img.copy()
            if noise_sigma > 0:
                self._seed(noise_seed)
                cv2.randn(self._noise, 0.0, float(noise_sigma))  # integer noise: img is integer already
                cv2.add(out, self._noise, dst=out, dtype=cv2.CV_8U)
            return out
        np.copyto(self._f32, img)
        analog_img = self._f32
        if cam.maps is not None:
            dst = self._warped if (self.supersample > 1 or self.frame_subsample > 1) else None
            analog_img = cv2.remap(self._f32, cam.maps[0], cam.maps[1], _REMAP_INTERPOLATION, dst=dst,
                                   borderMode=cv2.BORDER_REPLICATE)
        if self.supersample > 1:
            # each output pixel: the mean of its s x s samples (INTER_AREA with an integer factor, exact in float32)
            cv2.resize(analog_img, (self.width, self.height), dst=self._mean, interpolation=cv2.INTER_AREA)
            analog_img = self._mean
        if windows:
            ws = int(window_supersample)
            if ws < 1:
                raise ValueError(f"window_supersample must be an integer >= 1, got {window_supersample!r}")
            for (u0, v0, u1, v1), win in zip(windows, self.windows_analog(data, camera_id, cam, option,
                                                                          list(windows), ws)):
                analog_img[v0:v1, u0:u1] = win
        if analog:
            return analog_img.copy()
        if noise_sigma > 0:
            self._seed(noise_seed)
            cv2.randn(self._noise_f, 0.0, float(noise_sigma))
        else:
            self._noise_f.fill(0.0)
        # adds the noise, rounds to nearest and saturates to 0..255 in one pass
        return cv2.add(analog_img, self._noise_f, dtype=cv2.CV_8U)

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


__all__ += ["ImageFormer", "gl_max_renderbuffer_px"]
