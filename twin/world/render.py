"""Image formation: MuJoCo's ideal pinhole render -> greyscale -> lens distortion -> sensor noise.

One ``mujoco.Renderer`` per image size, created once and reused (start-up costs ~0.5 s). Each camera
keeps preallocated buffers and its remap tables, so the work around the renderer per image is a colour
conversion, one ``cv2.remap`` (only when the true camera differs from the ideal pinhole) and one
``cv2.randn`` + saturating ``cv2.add``.

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
            # Fixed-point tables: cv2.remap's fastest path (it quantizes to 1/32 px either way).
            maps = cv2.convertMaps(maps[0], maps[1], cv2.CV_16SC2)
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
        self.renderer = mujoco.Renderer(model, self.height, self.width)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self._grey = np.empty((self.height, self.width), dtype=np.uint8)
        self._noise = np.empty((self.height, self.width), dtype=np.int16)

    def ideal_grey(self, data: mujoco.MjData, camera_id: int, option: mujoco.MjvOption) -> np.ndarray:
        """The ideal pinhole image ``(H, W)`` uint8 (a view into an internal buffer: copy to keep)."""
        self.renderer.update_scene(data, camera=camera_id, scene_option=option)
        self.renderer.render(out=self._rgb)
        cv2.cvtColor(self._rgb, cv2.COLOR_RGB2GRAY, dst=self._grey)
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
    ) -> np.ndarray:
        """The camera's image ``(H, W)`` uint8: ideal render, image effects, distortion, noise (a new array)."""
        img = self.ideal_grey(data, camera_id, option)
        for fx in image_effects:
            img = fx(img)
            if img.shape != (self.height, self.width) or img.dtype != np.uint8:
                raise ValueError(f"an image effect returned {img.shape} {img.dtype}, expected ({self.height}, {self.width}) uint8")
        if cam.maps is not None:
            out = cv2.remap(img, cam.maps[0], cam.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        else:
            out = img.copy()
        if noise_sigma > 0:
            if noise_seed is not None:
                cv2.setRNGSeed(int(noise_seed) & 0x7FFFFFFF)
            cv2.randn(self._noise, 0.0, float(noise_sigma))
            cv2.add(out, self._noise, dst=out, dtype=cv2.CV_8U)
        return out

    def close(self) -> None:
        self.renderer.close()


__all__.append("ImageFormer")
