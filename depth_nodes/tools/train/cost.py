"""Training of the learned matching cost's feature network, with JAX on the CPU (the
``train`` extra; only this package, ``depth_nodes.tools.train``, imports JAX).

The network is ``core/learned/network.py``'s, evaluated on patches (valid convolutions:
a (2 layers + 1)-square patch gives one feature vector). The loss is MC-CNN's hinge on
cosine similarities (Zbontar and LeCun, JMLR 2016): for each triplet,
``max(0, margin + s(left, negative) - s(left, positive))`` (or, with
``DataConfig.candidates``, a softmax over the true match and its nearest whole offsets:
tried, not shipped, docs/learned.md). Adam, a learning rate halved
in the last third, a batch drawn from a fixed shuffled order: the same seed gives the
same weights on the same machine.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.learned.network import FeatureNet
from depth_nodes.errors import ConfigError
from depth_nodes.tools.train.data import DataConfig, split, training_set

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class TrainConfig:
    """The network and the optimisation.

    Attributes:
        channels: Features per pixel (and per hidden layer).
        layers: 3x3 convolutions.
        steps: Optimiser steps.
        batch: Triplets per step.
        learning_rate: Adam's step size (halved for the last third of the steps).
        margin: The hinge's margin on cosine similarities.
        validation: Share of the scenes held out (the last ones) for the validation loss.
    """

    channels: int = 6
    layers: int = 3
    steps: int = 20000
    batch: int = 256
    learning_rate: float = 2e-3
    margin: float = 0.2
    validation: float = 0.1


def load_jax() -> Any:
    """The ``jax`` module.

    Raises:
        ConfigError: JAX is not installed (the ``train`` extra).
    """
    try:
        import jax  # optional: only training needs it
    except ImportError:
        raise ConfigError("training needs JAX: pip install 'depth_nodes[train]'") from None
    jax.config.update('jax_platforms', 'cpu')
    return jax


def init_params(config: TrainConfig, seed: int) -> list[tuple[F32, F32]]:
    """He-initialised (kernel, bias) per layer."""
    rng = np.random.default_rng([seed, 3])
    params = []
    c_in = 1
    for _ in range(config.layers):
        std = np.sqrt(2.0 / (9 * c_in))
        kernel = rng.normal(0.0, std, (3, 3, c_in, config.channels)).astype(np.float32)
        params.append((kernel, np.zeros(config.channels, np.float32)))
        c_in = config.channels
    return params


def forward(jax: Any, params: Any, patches: Any) -> Any:
    """Unit feature vectors (N, C) of (N, P, P) patches, P = 2 layers + 1."""
    jnp = jax.numpy
    x = patches[:, :, :, None]
    for i, (kernel, bias) in enumerate(params):
        x = jax.lax.conv_general_dilated(x, kernel, (1, 1), 'VALID',
                                         dimension_numbers=('NHWC', 'HWIO', 'NHWC')) + bias
        if i < len(params) - 1:
            x = jax.nn.relu(x)
    x = x[:, 0, 0, :]
    return x / jnp.maximum(jnp.sqrt((x * x).sum(axis=1, keepdims=True)), 1e-6)


#: Adam's moment decays and its epsilon.
ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8


def adam_state(jax: Any, params: Any) -> tuple[Any, Any]:
    """Adam's first and second moments of ``params``, zero."""
    zeros = jax.tree_util.tree_map(jax.numpy.zeros_like, params)
    return zeros, jax.tree_util.tree_map(jax.numpy.zeros_like, params)


def adam_step(jax: Any, loss: Callable[..., Any]) -> Any:
    """The compiled Adam step of ``loss(params, *batch)``: ``step(params, means,
    variances, t, learning_rate, *batch) -> (params, means, variances, loss)``, ``t``
    counting from 1 (both trainings use it)."""
    jnp, tree_map = jax.numpy, jax.tree_util.tree_map
    beta1, beta2 = ADAM_BETAS

    def update(p: Any, m: Any, v: Any, t: Any, lr: Any, *batch: Any) -> Any:
        value, grads = jax.value_and_grad(loss)(p, *batch)
        m = tree_map(lambda a, g: beta1 * a + (1 - beta1) * g, m, grads)
        v = tree_map(lambda a, g: beta2 * a + (1 - beta2) * g * g, v, grads)
        p = tree_map(lambda x, a, b: x - lr * (a / (1 - beta1 ** t))
                     / (jnp.sqrt(b / (1 - beta2 ** t)) + ADAM_EPS), p, m, v)
        return p, m, v, value

    return jax.jit(update)


def hinge_loss(jax: Any, params: Any, left: Any, positive: Any, negative: Any,
               margin: float) -> tuple[Any, Any]:
    """The mean hinge and the share of triplets ranked right (positive more similar).

    With (N, K, P, P) negatives (``DataConfig.candidates``), the loss is instead the
    softmax cross-entropy of the similarities over the true match and its K neighbours
    (temperature ``margin``), and a triplet is right when the true match beats them all.
    """
    jnp = jax.numpy
    fl, fp = forward(jax, params, left), forward(jax, params, positive)
    s_pos = (fl * fp).sum(axis=1)
    if negative.ndim == 4:
        n, k = negative.shape[:2]
        fn = forward(jax, params, negative.reshape((n * k, *negative.shape[2:])))
        s_neg = (fl[:, None, :] * fn.reshape(n, k, -1)).sum(axis=2)
        logits = jnp.concatenate([s_pos[:, None], s_neg], axis=1) / margin
        loss = jax.nn.logsumexp(logits, axis=1) - logits[:, 0]
        return loss.mean(), (s_pos > s_neg.max(axis=1)).mean()
    fn = forward(jax, params, negative)
    s_neg = (fl * fn).sum(axis=1)
    return jnp.maximum(0.0, margin + s_neg - s_pos).mean(), (s_pos > s_neg).mean()


@dataclass
class TrainResult:
    """The trained network and its curves (loss per logged step)."""

    net: FeatureNet
    steps: list[int]
    train_loss: list[float]
    validation_loss: list[float]
    validation_ranked: list[float]
    seconds: float


def train(data: DataConfig, config: TrainConfig, *, cache: Path | None = None,
          log: Callable[[str], None] = print, log_every: int = 1000) -> TrainResult:
    """Render the scenes, train, and return the network with its recipe.

    Raises:
        ConfigError: JAX is missing.
    """
    jax = load_jax()
    if data.radius != config.layers:
        data = DataConfig(**{**asdict(data), 'radius': config.layers})
    start = time.monotonic()
    train_scenes, held = split(data.scenes, data.photo_scenes, config.validation)
    log(f'rendering {data.scenes} simulated scenes and {data.photo_scenes} photograph '
        f'pairs ({len(held)} held out for validation)')
    train_set = training_set(data, train_scenes, cache=cache)
    val_set = training_set(data, held, cache=cache)
    log(f'{train_set[0].shape[0]} training triplets, {val_set[0].shape[0]} validation, '
        f'{time.monotonic() - start:.0f} s')
    result = optimise(jax, init_params(config, data.seed), train_set, val_set, config,
                      seed=data.seed, window=data.window, log=log, log_every=log_every,
                      start=start)
    recipe = {'command': 'depth-nodes train-cost', 'data': asdict(data),
              'train': asdict(config), 'seconds': round(result.seconds, 1),
              'validation_loss': result.validation_loss[-1] if result.validation_loss
              else None,
              'validation_ranked': result.validation_ranked[-1] if result.validation_ranked
              else None,
              'jax': jax.__version__}
    result.net = FeatureNet(result.net.kernels, result.net.biases, data.window, recipe)
    return result


def optimise(jax: Any, initial: list[tuple[F32, F32]], train_set: tuple[F32, F32, F32],
             val_set: tuple[F32, F32, F32], config: TrainConfig, *, seed: int, window: int,
             log: Callable[[str], None], log_every: int, start: float,
             anchor: float = 0.0,
             checkpoint: Callable[[FeatureNet, int, float], None] | None = None,
             stop: Callable[[], bool] = lambda: False) -> TrainResult:
    """Adam on the hinge loss from ``initial`` (kernel, bias) layers; every ``log_every``
    steps the losses are logged and ``checkpoint`` gets the network so far, the step and
    the validation loss. ``anchor`` adds ``anchor * sum((w - w_initial)^2)`` to the loss:
    a fine-tuning that stays near the weights it started from. ``stop`` ends the loop
    early (a Ctrl-C) after the step it is seen true."""
    jnp = jax.numpy
    params = [(jnp.asarray(k), jnp.asarray(b)) for k, b in initial]
    origin = [(jnp.asarray(k), jnp.asarray(b)) for k, b in initial]
    means, variances = adam_state(jax, params)

    def loss_only(p: Any, left: Any, pos: Any, neg: Any) -> Any:
        loss = hinge_loss(jax, p, left, pos, neg, config.margin)[0]
        if anchor:
            loss = loss + anchor * sum(((k - k0) ** 2).sum() + ((b - b0) ** 2).sum()
                                       for (k, b), (k0, b0) in zip(p, origin, strict=True))
        return loss

    step = adam_step(jax, loss_only)
    evaluate = jax.jit(lambda p, a, b, c: hinge_loss(jax, p, a, b, c, config.margin))
    rng = np.random.default_rng([seed, 4])
    n = train_set[0].shape[0]
    order = rng.permutation(n)
    cursor = 0
    steps, train_loss, val_loss, val_ranked = [], [], [], []
    running = []
    for t in range(1, config.steps + 1):
        if stop():
            break
        if cursor + config.batch > n:
            order, cursor = rng.permutation(n), 0
        idx = order[cursor:cursor + config.batch]
        cursor += config.batch
        lr = config.learning_rate * (0.5 if t > 2 * config.steps // 3 else 1.0)
        params, means, variances, loss = step(params, means, variances, float(t), lr,
                                               *(jnp.asarray(s[idx]) for s in train_set))
        running.append(float(loss))
        if t % log_every == 0 or t == config.steps:
            vl, vr = (float(v) for v in _batched(evaluate, params, val_set))
            steps.append(t)
            train_loss.append(float(np.mean(running)))
            val_loss.append(vl)
            val_ranked.append(vr)
            running = []
            log(f'step {t}: train loss {train_loss[-1]:.4f}, validation loss {vl:.4f}, '
                f'ranked right {100 * vr:.2f} %, {time.monotonic() - start:.0f} s')
            if checkpoint is not None:
                checkpoint(_net(params, window), t, vl)
    return TrainResult(_net(params, window), steps, train_loss, val_loss, val_ranked,
                       time.monotonic() - start)


def _net(params: Any, window: int) -> FeatureNet:
    """The layers as a FeatureNet (its recipe filled in by the caller)."""
    return FeatureNet(tuple(np.asarray(k, np.float32) for k, _ in params),
                      tuple(np.asarray(b, np.float32) for _, b in params), window, {})


def _batched(evaluate: Any, params: Any, sets: tuple[F32, F32, F32],
             size: int = 4096) -> tuple[float, float]:
    """The loss and ranked share over a whole set, in batches (weighted by size)."""
    n = sets[0].shape[0]
    loss = ranked = 0.0
    for i in range(0, n, size):
        part = [s[i:i + size] for s in sets]
        a, b = evaluate(params, *part)
        loss += float(a) * part[0].shape[0]
        ranked += float(b) * part[0].shape[0]
    return loss / max(n, 1), ranked / max(n, 1)
