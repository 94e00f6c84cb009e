"""Training pairs with the texture of real photographs: layers of slanted planes, each
covered with a photograph, seen by a rectified stereo pair (exact disparity, occlusions).

The simulator's textures are procedural (noise, stripes, checkers); real scenes are
photographs' textures. Here the geometry stays simple and exact: a background plane and a
few nearer planar patches (random polygons), each with disparity ``d = a + b x + c y`` in
the left view. A patch's photograph is attached to its surface, so the right view samples
it at the left-view point it sees: ``x = (x_r + a + c y) / (1 - b)``. Layers are drawn back
to front in both views; a left pixel is visible when the right view shows the same layer
at both neighbours of ``x - d``.

The photographs are scikit-image's data set (``train`` extra; public-domain and CC0
images: astronaut, brick, camera, coffee, ...). Its Middlebury motorcycle pair is a real
stereo pair and is never used here: ``eval`` keeps it for validation beside Teddy and
Cones, which are never used either.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ConfigError
from depth_nodes.tools.train.scenes import Scene

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
#: The photographs of scikit-image's data folder used as textures (natural images only).
PHOTOS = ('astronaut.png', 'brick.png', 'camera.png', 'cell.png', 'chelsea.png',
          'clock_motion.png', 'coffee.png', 'coins.png', 'grass.png', 'gravel.png',
          'hubble_deep_field.jpg', 'ihc.png', 'moon.png', 'page.png', 'retina.jpg',
          'rocket.jpg', 'text.png')


def photo_folder() -> Path:
    """scikit-image's data folder (found without importing scikit-image).

    Raises:
        ConfigError: scikit-image is not installed (the ``train`` extra).
    """
    spec = importlib.util.find_spec('skimage')
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError("the photographs come from scikit-image: pip install "
                          "'depth_nodes[train]'")
    return Path(next(iter(spec.submodule_search_locations))) / 'data'


def load_photos() -> list[U8]:
    """The photographs as (H, W, 3) uint8 RGB (grey ones repeated in three channels).

    Raises:
        ConfigError: scikit-image is missing, or a photograph is unreadable.
    """
    folder = photo_folder()
    photos = []
    for name in PHOTOS:
        image = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
        if image is None:
            raise ConfigError(f'cannot read the photograph {folder / name}')
        photos.append(np.ascontiguousarray(image[:, :, ::-1], dtype=np.uint8))
    return photos


def _polygon(rng: np.random.Generator, w: int, h: int) -> NDArray[np.int32]:
    """A random star-shaped polygon of 5 - 9 corners inside the image."""
    cx, cy = rng.uniform(0.15, 0.85) * w, rng.uniform(0.15, 0.85) * h
    size = rng.uniform(0.08, 0.3) * min(w, h) * 1.5
    n = int(rng.integers(5, 10))
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    radii = size * rng.uniform(0.5, 1.0, n)
    points = np.stack([cx + radii * np.cos(angles), cy + radii * np.sin(angles)], axis=1)
    return np.round(points).astype(np.int32)


def photo_scene(photos: list[U8], seed: int, index: int) -> Scene:
    """Pair ``index`` of a set seeded ``seed``: a background and 2 - 5 nearer patches."""
    rng = np.random.default_rng([seed, index, 5])
    w = int(rng.choice([320, 384, 448]))
    h = w * 3 // 4
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    left = np.zeros((h, w, 3), np.float32)
    right = np.zeros((h, w, 3), np.float32)
    disparity = np.zeros((h, w), np.float32)
    layer_left = np.zeros((h, w), np.int32)
    layer_right = np.zeros((h, w), np.int32)
    base = rng.uniform(2.0, 0.08 * w)
    n_layers = int(rng.integers(3, 7))
    for layer in range(n_layers):
        a = base + (0.0 if layer == 0 else rng.uniform(2.0, 0.1 * w) + 2.0 * layer)
        b, c = rng.uniform(-0.04, 0.04), rng.uniform(-0.04, 0.04)
        a -= b * w / 2 + c * h / 2  # ``a`` is the disparity at the image centre
        photo = photos[int(rng.integers(len(photos)))]
        scale = rng.uniform(0.35, 1.4)
        ox = rng.uniform(0, photo.shape[1])
        oy = rng.uniform(0, photo.shape[0])
        if layer == 0:
            mask = np.ones((h, w), np.uint8)
        else:
            mask = np.zeros((h, w), np.uint8)
            cv2.fillPoly(mask, [_polygon(rng, w, h)], 1)
        # left view: the texture at the left pixel; right view: at the left point it sees
        x_seen = (xs + a + c * ys) / (1.0 - b)
        for view, x_left, mask_view, layer_map in (
                (left, xs, mask, layer_left),
                (right, x_seen, cv2.remap(mask, x_seen, ys, cv2.INTER_NEAREST,
                                          borderValue=0), layer_right)):
            u = (x_left * scale + ox).astype(np.float32)
            v = (ys * scale + oy).astype(np.float32)
            texture = cv2.remap(photo, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            on = mask_view > 0
            view[on] = texture[on]
            layer_map[on] = layer
        disparity[mask > 0] = (a + b * xs + c * ys)[mask > 0]
    xr = xs - disparity
    x0 = np.floor(xr).astype(np.int64)
    inside = (x0 >= 0) & (x0 + 1 < w)
    rows = ys.astype(np.int64)
    seen = np.zeros((h, w), bool)
    seen[inside] = (layer_right[rows[inside], x0[inside]] == layer_left[inside]) & \
        (layer_right[rows[inside], x0[inside] + 1] == layer_left[inside])
    return Scene(np.clip(left, 0, 255).astype(np.uint8), np.clip(right, 0, 255).astype(np.uint8),
                 disparity, seen)
