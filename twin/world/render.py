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

Sub-pixel fidelity: resampling an 8-bit image to 8 bits loses shifts smaller than ~1/30 px (each pixel
changes by less than half a grey level and rounds back), and ``cv2.remap`` quantizes source positions to
1/32 px, which biases every feature the same way. So the resampling runs in float32 and its tables carry
a fixed uniform dither of one quantum (+-1/64 px), which makes the quantization error zero-mean from
pixel to pixel; the sensor noise then dithers the final rounding. Measured: the image of a known point
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

from ..camera import CameraIntrinsics
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


@dataclass
class CameraPipeline:
    """One camera's image formation: its true intrinsics, ideal render focal length, samples per pixel along
    each axis and the remap tables on the sampling grid (``None``: the true camera is the ideal one)."""

    name: str
    intr: CameraIntrinsics
    f_render: float
    maps: tuple[np.ndarray, np.ndarray] | None
    supersample: int = 1

    @classmethod
    def build(cls, name: str, intr: CameraIntrinsics, supersample: int = 1) -> "CameraPipeline":
        check_distortion_monotonic(intr)
        s = int(supersample)
        if s != supersample or s < 1:
            raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
        f_r = render_focal_px(intr)
        # the ideal render on the sampling grid has focal length s * f_r: the same field of view
        maps = distortion_maps(sampling_intrinsics(intr, s), s * f_r)
        if maps is not None:
            # Dither of one quantum (cv2.remap works in 1/32 px), fixed per camera, then fixed-point tables.
            rng = np.random.default_rng(sum(map(ord, name)))
            for m in maps:
                m += rng.uniform(-1.0 / 64.0, 1.0 / 64.0, size=m.shape).astype(np.float32)
            maps = cv2.convertMaps(maps[0], maps[1], cv2.CV_16SC2)
        return cls(name, intr, f_r, maps, s)

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


class ImageFormer:
    """Turns a scene into 8-bit greyscale images for a set of cameras, reusing one renderer.

    ``supersample`` ``s``: MuJoCo renders ``s*width x s*height`` samples with the same field of view; lens
    distortion is applied on that sampling grid (each sample's ray goes through the lens model,
    :func:`sampling_intrinsics`), and every output pixel is the mean of its ``s x s`` samples
    (``cv2.INTER_AREA`` with an integer factor, float32: exact), as a sensor pixel integrates the light
    falling on it; then noise and 8-bit rounding as with one sample.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, supersample: int = 1):
        self.model = model
        self.width, self.height = int(width), int(height)
        s = int(supersample)
        if s != supersample or s < 1:
            raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
        self.supersample = s
        self.render_width, self.render_height = s * self.width, s * self.height
        rw, rh = self.render_width, self.render_height
        if rw > model.vis.global_.offwidth or rh > model.vis.global_.offheight:
            raise ValueError(f"render {rw}x{rh} (image {self.width}x{self.height}, supersample {s}) exceeds the "
                             f"model's offscreen buffer {model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        # The same pieces mujoco.Renderer assembles (GL context, MjrContext on the offscreen buffer, MjvScene),
        # kept here so that the pixels can be read without Renderer.render()'s extra flip of the RGB frame:
        # the flip is done once on the 8-bit grey image instead.
        try:
            self._gl = mujoco.GLContext(rw, rh)
            self._gl.make_current()
        except mujoco.FatalError as exc:
            raise RuntimeError(
                f"MuJoCo could not open an offscreen GL context ({exc}); rendering needs MUJOCO_GL=egl, which "
                "twin sets only if it is imported before mujoco: import twin first or export MUJOCO_GL=egl"
            ) from exc
        limit = gl_max_renderbuffer_px()
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
    ) -> np.ndarray:
        """The camera's image ``(H, W)`` uint8 (a new array): ideal render, image effects, distortion, pixel
        integration (supersampling), noise.

        Image effects get the ideal render of :meth:`ideal_grey` (uint8, on the sampling grid: ``s`` times the
        image size with supersampling) and must return the same shape and dtype. ``analog``: return the
        float32 image before noise and 8-bit rounding (diagnostics).
        """
        if cam.supersample != self.supersample:
            raise ValueError(f"camera {cam.name!r} was built for supersample {cam.supersample}, the renderer "
                             f"samples {self.supersample}")
        img = self.ideal_grey(data, camera_id, option)
        shape = (self.render_height, self.render_width)
        for fx in image_effects:
            img = fx(img)
            if img.shape != shape or img.dtype != np.uint8:
                raise ValueError(f"an image effect returned {img.shape} {img.dtype}, expected {shape} uint8 "
                                 f"(the ideal render on the sampling grid, supersample {self.supersample})")
        if cam.maps is None and self.supersample == 1:
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
            dst = self._warped if self.supersample > 1 else None
            analog_img = cv2.remap(self._f32, cam.maps[0], cam.maps[1], _REMAP_INTERPOLATION, dst=dst,
                                   borderMode=cv2.BORDER_REPLICATE)
        if self.supersample > 1:
            # each output pixel: the mean of its s x s samples (INTER_AREA with an integer factor, exact in float32)
            cv2.resize(analog_img, (self.width, self.height), dst=self._mean, interpolation=cv2.INTER_AREA)
            analog_img = self._mean
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
