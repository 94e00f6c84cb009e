"""The simulator's scenes as training pairs: colour renders, the true disparity and
where it is visible (optionally cached on disk: a scene takes seconds to render)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from depth_nodes.sim.stereo import StereoSimConfig, simulate_stereo

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class Scene:
    """A training pair: colour (H, W, 3) renders, the true left disparity and where it is
    visible in the right view."""

    left: U8
    right: U8
    disparity: F32
    visible: NDArray[np.bool_]


def render_scene(seed: int, index: int) -> Scene:
    """Scene ``index`` of a training set seeded ``seed``: a random size, baseline and focal
    length, so that disparities from a few to about 60 px occur."""
    rng = np.random.default_rng([seed, index, 1])
    width = int(rng.choice([320, 384, 448]))
    config = StereoSimConfig(width=width, height=width * 3 // 4, n_frames=1,
                             seed=int(rng.integers(10_000, 2**31)),
                             baseline_m=float(rng.uniform(0.06, 0.3)),
                             focal_px=float(rng.uniform(0.6, 1.1) * width), colour=True,
                             supersample=2)
    frame = next(iter(simulate_stereo(config)))
    visible = (frame.occlusion_gt == 0) & np.isfinite(frame.disparity_gt)
    return Scene(frame.left_rect_gt, frame.right_rect_gt, frame.disparity_gt, visible)


def sim_scene(seed: int, index: int, cache: Path | None) -> Scene:
    """:func:`render_scene`, read from ``cache`` when an earlier run rendered it there."""
    if cache is None:
        return render_scene(seed, index)
    path = cache / f'sim_{seed}_{index}.npz'
    if path.exists():
        with np.load(path) as data:
            return Scene(data['left'], data['right'], data['disparity'], data['visible'])
    scene = render_scene(seed, index)
    np.savez(path, left=scene.left, right=scene.right, disparity=scene.disparity,
             visible=scene.visible)
    return scene
