"""Image formation: MuJoCo's ideal pinhole render -> greyscale -> lens distortion -> sensor noise.

One ``mujoco.Renderer`` per image size, created once and reused (start-up costs ~0.5 s). Each camera
keeps preallocated buffers and its remap tables, so the work around the renderer per image is a colour
conversion, one ``cv2.remap`` (only when the true camera differs from the ideal pinhole) and one
``cv2.randn`` + saturating ``cv2.add``, which also rounds to 8 bits once, at the end.

Sub-pixel fidelity: resampling an 8-bit image to 8 bits loses shifts smaller than ~1/30 px (each pixel
changes by less than half a grey level and rounds back), and ``cv2.remap`` quantizes source positions to
1/32 px, which biases every feature the same way. So the resampling runs in float32 and its tables carry
a fixed uniform dither of one quantum (+-1/64 px), which makes the quantization error zero-mean from
pixel to pixel; the sensor noise then dithers the final rounding. Measured: the image of a known point
agrees with the camera model to about 0.001 px (``tests/test_world_render.py``).

The distortion is applied by resampling: a true pixel ``(u, v)`` has normalized distorted coordinates
``((u - cx)/fx, (v - cy)/fy)``; undistorting them gives the ray, which the ideal render (focal length
``f_r``, centred principal point) shows at ``f_r * x + (W/2 - 0.5)``. ``cv2.remap`` interpolates there
bilinearly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import mujoco
import numpy as np

from ..camera import CameraIntrinsics
from .rig import check_distortion_monotonic, distortion_maps, render_focal_px

__all__ = ["CameraPipeline", "scene_option"]


def scene_option(groups: tuple[int, ...]) -> mujoco.MjvOption:
    """A MuJoCo scene option showing only the geom ``groups``."""
    opt = mujoco.MjvOption()
    for g in range(len(opt.geomgroup)):
        opt.geomgroup[g] = 1 if g in groups else 0
    # sites and joints are never drawn in images
    for g in range(len(opt.sitegroup)):
        opt.sitegroup[g] = 0
    return opt


@dataclass
class CameraPipeline:
    """One camera's image formation: its true intrinsics, ideal render focal length, remap tables."""

    name: str
    intr: CameraIntrinsics
    f_render: float
    maps: tuple[np.ndarray, np.ndarray] | None

    @classmethod
    def build(cls, name: str, intr: CameraIntrinsics) -> "CameraPipeline":
        check_distortion_monotonic(intr)
        f_r = render_focal_px(intr)
        maps = distortion_maps(intr, f_r)
        if maps is not None:
            # Dither of one quantum (cv2.remap works in 1/32 px), fixed per camera, then fixed-point tables.
            rng = np.random.default_rng(sum(map(ord, name)))
            dither = rng.uniform(-1.0 / 64.0, 1.0 / 64.0, size=(2,) + maps[0].shape).astype(np.float32)
            maps = cv2.convertMaps(maps[0] + dither[0], maps[1] + dither[1], cv2.CV_16SC2)
        return cls(name, intr, f_r, maps)

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view of the ideal render [deg]."""
        return float(np.rad2deg(2.0 * np.arctan(0.5 * self.intr.height / self.f_render)))


class ImageFormer:
    """Turns a scene into 8-bit greyscale images for a set of cameras, reusing one renderer."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int):
        self.model = model
        self.width, self.height = int(width), int(height)
        if self.width > model.vis.global_.offwidth or self.height > model.vis.global_.offheight:
            raise ValueError(f"image {self.width}x{self.height} exceeds the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        # The same pieces mujoco.Renderer assembles (GL context, MjrContext on the offscreen buffer, MjvScene),
        # kept here so that the pixels can be read without Renderer.render()'s extra flip of the RGB frame:
        # the flip is done once on the 8-bit grey image instead.
        try:
            self._gl = mujoco.GLContext(self.width, self.height)
            self._gl.make_current()
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        except mujoco.FatalError as exc:
            raise RuntimeError(
                f"MuJoCo could not open an offscreen GL context ({exc}); rendering needs MUJOCO_GL=egl, which "
                "twin sets only if it is imported before mujoco: import twin first or export MUJOCO_GL=egl"
            ) from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._scene = mujoco.MjvScene(model, maxgeom=10000)
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED.value
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self._grey_flipped = np.empty((self.height, self.width), dtype=np.uint8)
        self._grey = np.empty((self.height, self.width), dtype=np.uint8)
        self._noise = np.empty((self.height, self.width), dtype=np.int16)
        self._noise_f = np.empty((self.height, self.width), dtype=np.float32)
        self._f32 = np.empty((self.height, self.width), dtype=np.float32)

    def ideal_grey(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption) -> np.ndarray:
        """The ideal pinhole image ``(H, W)`` uint8, row 0 at the top (a view into an internal buffer)."""
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
        """The camera's image ``(H, W)`` uint8 (a new array): ideal render, image effects, distortion, noise.

        ``analog``: return the float32 image before noise and 8-bit rounding (diagnostics).
        """
        img = self.ideal_grey(data, camera_id, option)
        for fx in image_effects:
            img = fx(img)
            if img.shape != (self.height, self.width) or img.dtype != np.uint8:
                raise ValueError(f"an image effect returned {img.shape} {img.dtype}, expected ({self.height}, {self.width}) uint8")
        if cam.maps is None:
            if analog:
                return img.astype(np.float32)
            out = img.copy()
            if noise_sigma > 0:
                self._seed(noise_seed)
                cv2.randn(self._noise, 0.0, float(noise_sigma))  # integer noise: img is integer already
                cv2.add(out, self._noise, dst=out, dtype=cv2.CV_8U)
            return out
        np.copyto(self._f32, img)
        warped = cv2.remap(self._f32, cam.maps[0], cam.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if analog:
            return warped
        if noise_sigma > 0:
            self._seed(noise_seed)
            cv2.randn(self._noise_f, 0.0, float(noise_sigma))
        else:
            self._noise_f.fill(0.0)
        # adds the noise, rounds to nearest and saturates to 0..255 in one pass
        return cv2.add(warped, self._noise_f, dtype=cv2.CV_8U)

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


__all__.append("ImageFormer")
