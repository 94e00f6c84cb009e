"""Exact depth and colour images of a scene seen by a pinhole camera placed anywhere.

The ground truth of depth_image_proc's nodes: a depth camera and a colour camera at
different places, sizes and focal lengths, looking at the stereo simulator's scenes
(:func:`~depth_nodes.sim.layout.build_scene`). Rays go through the pixel centres; Z,
the ray length and the 3-D points are exact (float64 until the images are made).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.sim.scene import Scene

FloatArray = NDArray[np.float64]

__all__ = ['DepthView', 'render_view']


@dataclass
class DepthView:
    """What one camera sees.

    Attributes:
        depth: (H, W) float32 Z in metres, NaN where no surface is hit.
        ray_length: (H, W) float32 distance from the camera centre, NaN where none.
        points: (H, W, 3) float64 points in the camera's optical frame, NaN where none.
        labels: (H, W) int32 index of the primitive hit, -1 for none.
        colour: (H, W, 3) uint8 RGB (linear radiance scaled by ``gain``), or None.
    """

    depth: NDArray[np.float32]
    ray_length: NDArray[np.float32]
    points: FloatArray
    labels: NDArray[np.int32]
    colour: NDArray[np.uint8] | None


def render_view(scene: Scene, camera: Intrinsics, pose: Pose | None = None, *,
                colour: bool = False, gain: float = 255.0) -> DepthView:
    """Cast one ray per pixel centre of ``camera`` placed at ``pose``.

    Args:
        scene: The surfaces.
        camera: The camera's pinhole intrinsics and size.
        pose: Its pose in the scene (default: at the origin, looking along +z).
        colour: Also shade the hits (the scene's light) into an RGB image.
        gain: Radiance to 8-bit scale of the colour image.
    """
    pose = pose or Pose()
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64),
                       np.arange(camera.height, dtype=np.float64))
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy,
                     np.ones_like(u)], axis=-1).reshape(-1, 3)
    dirs = rays @ pose.rotation.T
    t, labels = scene.cast(pose.position, dirs)  # the camera-frame ray has z = 1: t is Z
    hit = np.isfinite(t)
    shape = (camera.height, camera.width)
    points = np.where(hit[:, None], rays * t[:, None], np.nan).reshape(*shape, 3)
    image = None
    if colour:
        rgb = scene.shade(pose.position, dirs, t, labels).reshape(*shape, 3)
        image = np.clip(np.rint(rgb * gain), 0, 255).astype(np.uint8)
    return DepthView(
        depth=np.where(hit, t, np.nan).reshape(shape).astype(np.float32),
        ray_length=np.linalg.norm(points, axis=-1).astype(np.float32),
        points=points,
        labels=labels.reshape(shape),
        colour=image,
    )
