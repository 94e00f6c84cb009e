"""Training data of the learned matching cost: the simulator's stereo scenes, made to
differ the way real cameras differ, cut into patch triplets.

A scene is a :func:`~depth_nodes.sim.stereo.simulate_stereo` frame (its noise-free
rectified renders and exact disparity). :func:`augment` gives each camera its own
response (gain, offset, gamma, vignetting), then blur, Bayer demosaicing, sensor noise and
JPEG, and shifts the right image vertically by a fraction of a pixel (a rectification
error). :func:`triplets` then samples, at visible pixels, a left patch, the right patch
at the true disparity (interpolated: the truth is sub-pixel) and a right patch off it by
a few pixels (a near negative) or many (a far one). All of it is numpy / OpenCV and
deterministic from a seed; the Middlebury pairs are never used.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.learned.network import normalise
from depth_nodes.tools.train.photos import load_photos, photo_scene
from depth_nodes.tools.train.scenes import Scene, sim_scene

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
#: ITU-R BT.601 luma of RGB.
_LUMA = np.array([0.299, 0.587, 0.114], np.float32)


@dataclass(frozen=True)
class DataConfig:
    """How the training set is made.

    Attributes:
        scenes: Simulated scenes (one stereo frame each).
        photo_scenes: Pairs of planes covered with photographs (``photos.py``).
        seed: Seed of the scenes, the augmentation and the sampling.
        samples_per_scene: Patch triplets drawn from each scene.
        radius: Patch radius (the network's receptive field: 2 radius + 1 square).
        window: Local normalisation window of the network input.
        near: (lo, hi) px of a near negative's offset from the true match.
        far: (lo, hi) px of a far negative's offset.
        far_fraction: Share of far negatives.
        candidates: 0: one negative per triplet; K > 0: the 2 K whole offsets within K px
            of the true match, all at once (for the softmax loss).
    """

    scenes: int = 160
    photo_scenes: int = 0
    seed: int = 0
    samples_per_scene: int = 2000
    radius: int = 4
    window: int = 9
    near: tuple[float, float] = (1.0, 6.0)
    far: tuple[float, float] = (6.0, 48.0)
    far_fraction: float = 0.25
    candidates: int = 0


def _camera_response(rgb: U8, rng: np.random.Generator) -> F32:
    """One camera's look of a colour render, as a grey float image: gain, offset, gamma,
    vignetting, blur, Bayer demosaicing (half the time) and noise."""
    img = rgb.astype(np.float32) / 255.0
    h, w = img.shape[:2]
    img = np.clip(img * rng.uniform(0.7, 1.3) + rng.uniform(-0.08, 0.08), 0.0, 1.0)
    img = img ** np.float32(rng.uniform(0.75, 1.35))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    cx, cy = w * rng.uniform(0.4, 0.6), h * rng.uniform(0.4, 0.6)
    r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / (0.25 * (w * w + h * h))
    img = img * (1.0 - rng.uniform(0.0, 0.35) * r2)[:, :, None]
    if rng.random() < 0.5:
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.3, 1.0))
    if rng.random() < 0.5:
        bgr = np.clip(img[:, :, ::-1] * 255.0, 0, 255).astype(np.uint8)
        mosaic = np.zeros((h, w), np.uint8)  # BGGR: OpenCV's older name is BayerRG
        mosaic[0::2, 0::2] = bgr[0::2, 0::2, 0]
        mosaic[0::2, 1::2] = bgr[0::2, 1::2, 1]
        mosaic[1::2, 0::2] = bgr[1::2, 0::2, 1]
        mosaic[1::2, 1::2] = bgr[1::2, 1::2, 2]
        grey = cv2.cvtColor(cv2.cvtColor(mosaic, cv2.COLOR_BayerRG2BGR),
                            cv2.COLOR_BGR2GRAY).astype(np.float32)
    else:
        grey = 255.0 * (img @ _LUMA)
    grey = grey + np.asarray(rng.normal(0.0, rng.uniform(0.5, 4.0), grey.shape), np.float32)
    out: F32 = np.clip(grey, 0, 255).astype(np.float32)
    return out


def augment(scene: Scene, rng: np.random.Generator) -> tuple[U8, U8]:
    """The pair as two different cameras would have taken it (uint8 grey), the right one
    shifted vertically by up to 0.4 px; JPEG-compressed a third of the time."""
    left = _camera_response(scene.left, rng)
    right = _camera_response(scene.right, rng)
    shift = np.array([[1, 0, 0], [0, 1, rng.uniform(-0.4, 0.4)]], np.float32)
    moved = cv2.warpAffine(right, shift, (right.shape[1], right.shape[0]),
                           flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    pair: list[U8] = []
    for img in (left, moved):
        grey = np.clip(np.round(img), 0, 255).astype(np.uint8)
        if rng.random() < 0.33:
            quality = int(rng.integers(50, 96))
            ok, jpeg = cv2.imencode('.jpg', grey, [cv2.IMWRITE_JPEG_QUALITY, quality])
            decoded = cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE) if ok else None
            grey = grey if decoded is None else np.asarray(decoded, np.uint8)
        pair.append(grey)
    return pair[0], pair[1]


def _patches(image: F32, ys: NDArray[np.float64], xs: NDArray[np.float64],
             radius: int) -> F32:
    """(N, 2 radius + 1, 2 radius + 1) patches centred on (ys, xs), bilinear in x (the
    rows are whole: ys are integers)."""
    h, w = image.shape
    offsets = np.arange(-radius, radius + 1)
    rows = ys.astype(np.int64)[:, None, None] + offsets[None, :, None]
    cols = xs[:, None, None] + offsets[None, None, :]
    x0 = np.floor(cols).astype(np.int64)
    frac = (cols - x0).astype(np.float32)
    rows = np.clip(rows, 0, h - 1)
    a = image[rows, np.clip(x0, 0, w - 1)]
    b = image[rows, np.clip(x0 + 1, 0, w - 1)]
    out: F32 = (a * (1 - frac) + b * frac).astype(np.float32)
    return out


def triplets(scene: Scene, config: DataConfig,
             rng: np.random.Generator) -> tuple[F32, F32, F32]:
    """(left, positive, negative) patch stacks of one augmented scene, each (N, P, P)
    float32 normalised like the network's input (fewer than ``samples_per_scene`` when
    the scene has few usable pixels)."""
    left, right = augment(scene, rng)
    return sample_triplets(left, right, scene.disparity, scene.visible, config, rng)


def sample_triplets(left: NDArray[np.generic], right: NDArray[np.generic],
                    disparity: NDArray[np.floating], usable: NDArray[np.bool_],
                    config: DataConfig, rng: np.random.Generator,
                    hard: NDArray[np.floating] | None = None,
                    hard_fraction: float = 0.0) -> tuple[F32, F32, F32]:
    """(left, positive, negative) patch stacks of a grey pair, at ``usable`` pixels whose
    match is ``disparity`` (the truth, or a proxy label): the left patch, the right patch
    at the match (interpolated: it may be sub-pixel) and one a few pixels off it (near)
    or many (far); each (N, P, P) float32 normalised like the network's input, at most
    ``samples_per_scene``. With ``hard`` (a disparity per pixel, NaN: none), that share
    ``hard_fraction`` of the negatives is taken there instead: a wrong match the current
    network prefers."""
    nl, nr = normalise(left, config.window), normalise(right, config.window)
    h, w = nl.shape
    r = config.radius
    ys, xs = np.nonzero(usable)
    d = disparity[ys, xs].astype(np.float64)
    xr = xs - d
    inside = (ys >= r) & (ys < h - r) & (xs >= r) & (xs < w - r) & (xr >= r) & \
        (xr <= w - 1 - r)
    ys, xs, xr = ys[inside], xs[inside], xr[inside]
    hard_x = None if hard is None else xs - hard[ys, xs].astype(np.float64)
    if ys.size == 0:
        empty = np.zeros((0, 2 * r + 1, 2 * r + 1), np.float32)
        shape = (0, 2 * config.candidates, 2 * r + 1, 2 * r + 1)
        return empty, empty, np.zeros(shape, np.float32) if config.candidates else empty
    pick = rng.choice(ys.size, size=min(config.samples_per_scene, ys.size), replace=False)
    ys, xs, xr = ys[pick], xs[pick], xr[pick]
    hard_x = None if hard_x is None else hard_x[pick]
    n = ys.size
    far = rng.random(n) < config.far_fraction
    lo = np.where(far, config.far[0], config.near[0])
    hi = np.where(far, config.far[1], config.near[1])
    offset = rng.uniform(lo, hi) * rng.choice([-1.0, 1.0], size=n)
    xn = xr + offset
    # a negative outside the image mirrors to the other side of the true match
    outside = (xn < r) | (xn > w - 1 - r)
    xn = np.where(outside, xr - offset, xn)
    xn = np.clip(xn, r, w - 1 - r)
    if hard_x is not None:
        use = (rng.random(n) < hard_fraction) & np.isfinite(hard_x) & (hard_x >= r) & \
            (hard_x <= w - 1 - r)
        xn = np.where(use, hard_x, xn)
    if config.candidates:
        # every whole offset +-1 .. +-candidates from the true match, clipped to the image
        offsets = np.concatenate([-np.arange(config.candidates, 0, -1),
                                  np.arange(1, config.candidates + 1)]).astype(np.float64)
        xc = np.clip(xr[:, None] + offsets[None, :], r, w - 1 - r)
        negatives = _patches(nr, np.repeat(ys, offsets.size), xc.ravel(), r)
        negatives = negatives.reshape(n, offsets.size, 2 * r + 1, 2 * r + 1)
        return (_patches(nl, ys, xs.astype(np.float64), r), _patches(nr, ys, xr, r),
                negatives)
    return (_patches(nl, ys, xs.astype(np.float64), r), _patches(nr, ys, xr, r),
            _patches(nr, ys, xn, r))


def split(sim: int, photo: int, validation: float) -> tuple[list[tuple[str, int]],
                                                           list[tuple[str, int]]]:
    """The (kind, index) of the training and the validation scenes among ``sim``
    simulated and ``photo`` photograph scenes: the last ``validation`` share of each kind
    (at least one of a kind with two or more) is held out."""
    train: list[tuple[str, int]] = []
    held: list[tuple[str, int]] = []
    for kind, count in (('sim', sim), ('photo', photo)):
        n_held = max(1, round(count * validation)) if count > 1 else 0
        train += [(kind, i) for i in range(count - n_held)]
        held += [(kind, i) for i in range(count - n_held, count)]
    return train, held


def training_set(config: DataConfig, scenes: list[tuple[str, int]], *,
                 cache: Path | None = None) -> tuple[F32, F32, F32]:
    """The triplets of the given (kind, index) scenes, kind ``sim`` or ``photo``."""
    parts: list[tuple[F32, F32, F32]] = []
    photos = load_photos() if any(kind == 'photo' for kind, _ in scenes) else []
    for kind, index in scenes:
        rng = np.random.default_rng([config.seed, index, 2 if kind == 'sim' else 6])
        scene = sim_scene(config.seed, index, cache) if kind == 'sim' else \
            photo_scene(photos, config.seed, index)
        parts.append(triplets(scene, config, rng))
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]
