"""Training of the learned confidence (``core/learned/confidence.py``) with JAX.

Each training pair (simulated scenes and photograph planes, augmented as for the matching
cost) goes through the shipped graph's matcher and cross_check settings; every pixel with
a raw disparity and a true one gives its signals and a label: is the raw disparity within
``threshold`` px of the truth (what ``eval``'s AUC ranks). The model is fitted with the
logistic loss, Adam, a fixed seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.cross_check import CrossCheckParams, cross_check, lr_threshold
from depth_nodes.core.learned.confidence import SIGNALS, ConfidenceModel, confidence_signals
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.tools.train.cost import adam_state, adam_step, load_jax
from depth_nodes.tools.train.data import augment, split
from depth_nodes.tools.train.photos import load_photos, photo_scene
from depth_nodes.tools.train.scenes import Scene, sim_scene

F32 = NDArray[np.float32]
#: The shipped graph's matcher settings (config/stereo_pipeline.yaml) that change results.
GRAPH_SGM = SgmParams(paths=5, census_width=5, census_height=5, intensity_weight=1,
                      match_brightness=True, border_cost=3.5, border_extrapolation=0.25)
#: The shipped graph's cross_check settings.
GRAPH_CHECK = CrossCheckParams(disp12_max_diff=1.0, fill_holes=True, median_size=5,
                               confidence_window=9)


@dataclass(frozen=True)
class ConfidenceConfig:
    """The training set and the fit.

    Attributes:
        scenes: Simulated scenes (the matching cost's, rendered or cached alike).
        photo_scenes: Photograph pairs.
        seed: Seed of everything.
        pixels_per_scene: Pixels sampled from each pair.
        threshold: A raw disparity within this many px of the truth is right.
        hidden: Units of the two hidden layers.
        steps: Optimiser steps.
        batch: Pixels per step.
        learning_rate: Adam's step size.
        validation: Share of each kind of scene held out.
    """

    scenes: int = 160
    photo_scenes: int = 160
    seed: int = 0
    pixels_per_scene: int = 6000
    threshold: float = 2.0
    hidden: int = 16
    steps: int = 6000
    batch: int = 2048
    learning_rate: float = 3e-3
    validation: float = 0.1


def scene_pixels(scene: Scene, config: ConfidenceConfig,
                 rng: np.random.Generator) -> tuple[F32, F32]:
    """Signals (N, len(SIGNALS)) and labels (N,) of one augmented pair."""
    left, right = augment(scene, rng)
    width = left.shape[1]
    top = float(np.nanmax(scene.disparity)) if np.isfinite(scene.disparity).any() else 0.0
    n_disp = int(min(width - 1, max(16, 16 * np.ceil((top + 8) / 16))))
    result = SgmMatcher(replace(GRAPH_SGM, disparity_range=n_disp)).match(left, right)
    checked = cross_check(result.disparity, result.disparity_right, result.cost_ratio,
                          **GRAPH_CHECK.arguments())
    signals = confidence_signals(result.disparity, result.cost_ratio, checked.difference,
                                 checked.labels, checked.filled,
                                 lr_threshold(GRAPH_CHECK.disp12_max_diff))
    has = np.isfinite(result.disparity) & np.isfinite(scene.disparity) & \
        (scene.disparity > 0)
    ys, xs = np.nonzero(has)
    pick = rng.choice(ys.size, size=min(config.pixels_per_scene, ys.size), replace=False)
    ys, xs = ys[pick], xs[pick]
    right_px = np.abs(result.disparity[ys, xs] - scene.disparity[ys, xs]) <= config.threshold
    return signals[ys, xs], right_px.astype(np.float32)


def pixel_set(config: ConfidenceConfig, scenes: list[tuple[str, int]], *,
              cache: Path | None = None) -> tuple[F32, F32]:
    """The signals and labels of the given (kind, index) scenes."""
    photos = load_photos() if any(kind == 'photo' for kind, _ in scenes) else []
    xs, ys = [], []
    for kind, index in scenes:
        rng = np.random.default_rng([config.seed, index, 7 if kind == 'sim' else 8])
        scene = sim_scene(config.seed, index, cache) if kind == 'sim' else \
            photo_scene(photos, config.seed, index)
        x, y = scene_pixels(scene, config, rng)
        xs.append(x)
        ys.append(y)
    return np.concatenate(xs), np.concatenate(ys)


def train_confidence(config: ConfidenceConfig, *, cache: Path | None = None,
                     log: Callable[[str], None] = print) -> ConfidenceModel:
    """Match the scenes, fit the model, return it with its recipe.

    Raises:
        ConfigError: JAX (or scikit-image, for photograph pairs) is missing.
    """
    jax = load_jax()
    jnp = jax.numpy
    start = time.monotonic()
    train_scenes, held = split(config.scenes, config.photo_scenes, config.validation)
    x_train, y_train = pixel_set(config, train_scenes, cache=cache)
    x_val, y_val = pixel_set(config, held, cache=cache)
    log(f'{x_train.shape[0]} training pixels ({100 * y_train.mean():.1f} % right), '
        f'{x_val.shape[0]} validation, {time.monotonic() - start:.0f} s')
    rng = np.random.default_rng([config.seed, 9])
    sizes = [len(SIGNALS), config.hidden, config.hidden, 1]
    params = [(jnp.asarray(rng.normal(0, np.sqrt(2.0 / a), (a, b)).astype(np.float32)),
               jnp.zeros(b, jnp.float32)) for a, b in pairwise(sizes)]

    def logits(p: Any, x: Any) -> Any:
        for i, (m, b) in enumerate(p):
            x = x @ m + b
            if i < len(p) - 1:
                x = jax.nn.relu(x)
        return x[:, 0]

    def loss(p: Any, x: Any, y: Any) -> Any:
        z = logits(p, x)
        return jnp.mean(jnp.maximum(z, 0) - z * y + jnp.log1p(jnp.exp(-jnp.abs(z))))

    means, variances = adam_state(jax, params)
    step = adam_step(jax, loss)
    evaluate = jax.jit(loss)
    for t in range(1, config.steps + 1):
        idx = rng.integers(0, x_train.shape[0], config.batch)
        params, means, variances, value = step(params, means, variances, float(t),
                                               config.learning_rate,
                                               x_train[idx], y_train[idx])
        if t % 1000 == 0 or t == config.steps:
            log(f'step {t}: train loss {float(value):.4f}, validation loss '
                f'{float(evaluate(params, x_val, y_val)):.4f}')
    recipe = {'command': 'depth-nodes train-confidence', 'config': asdict(config),
              'seconds': round(time.monotonic() - start, 1),
              'validation_loss': float(evaluate(params, x_val, y_val)),
              'jax': jax.__version__}
    return ConfidenceModel(tuple(np.asarray(m, np.float32) for m, _ in params),
                           tuple(np.asarray(b, np.float32) for _, b in params), recipe)
