"""Adaptation of the learned cost's feature network to a user's camera, without ground
truth: ``depth-nodes train-cost --adapt BAG ...``.

Proxy labels, as Tonioni et al. (2017, "Unsupervised adaptation for deep stereo") take
them from a conventional matcher: the shipped graph's census+learned SGM (with the
weights adapted) runs on each recorded pair, and a pixel becomes a label where its match
is both left-right consistent (the right view's disparity at the match agrees within
``lr_px``) and distinctive (the cost ratio, best over second best, at most
``max_cost_ratio``) and the right image's intensity at the match agrees with the left's
(a photometric check: |I_left - I_right(x - d)| at most ``max_photometric`` grey levels,
after the brightness of the two views is matched). Triplets are cut there as for the
supervised training (``data.py``): the left patch, the right patch at the label, one a
few or many pixels off (the uniqueness constraint of MC-CNN-WS: a pixel has one match).
The network is then fine-tuned from the weights it starts from, with a pull back towards
them (``anchor``) so that it adapts without forgetting, and the best checkpoint on the
held-out labels (every tenth pair, or a tenth of the labels of a single pair) is kept.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.learned.network import FeatureExtractor, FeatureNet, shipped_features
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.brightness import matched_brightness
from depth_nodes.core.sgm.cost import OUT_OF_RANGE_COST
from depth_nodes.core.sgm.learned_cost import learned_costs
from depth_nodes.errors import BagError
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.evaluation.evaluate import rectified_pair
from depth_nodes.tools.train.cost import TrainConfig, load_jax, optimise
from depth_nodes.tools.train.data import DataConfig, sample_triplets

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class AdaptConfig:
    """How the proxy labels are taken and the network fine-tuned.

    Attributes:
        frames: Pairs read from each bag, evenly spread over it (at most).
        proxy_cost: The proxy matcher's ``matching_cost``.
        disparity_range: Disparities the proxy matcher searches.
        learned_weight: The proxy matcher's ``learned_weight``.
        lr_px: Largest left-right disagreement of a label, px.
        max_cost_ratio: Largest best / second-best cost of a label.
        max_photometric: Largest |I_left - I_right(x - d)| of a label, grey levels.
        samples: Triplets per pair.
        hard_fraction: Share of the negatives taken where the network's own cost is
            lowest away from the label (its mistakes), the others a few or many pixels off.
        steps: Optimiser steps.
        learning_rate: Adam's step size.
        anchor: Weight of the pull back to the starting weights.
        seed: Seed of the sampling.
    """

    frames: int = 10
    proxy_cost: str = 'census'
    disparity_range: int = 64
    learned_weight: int = 20
    lr_px: float = 1.0
    max_cost_ratio: float = 0.7
    max_photometric: float = 12.0
    samples: int = 20000
    hard_fraction: float = 0.5
    steps: int = 2000
    learning_rate: float = 5e-4
    anchor: float = 0.05
    seed: int = 0


@dataclass
class Pair:
    """One recorded pair, rectified, grey."""

    source: str
    stamp: int
    left: U8
    right: U8


def stereo_pairs(bag: str | Path, frames: int, *, rename: dict[str, str] | None = None,
                 run: int = 1) -> Iterator[Pair]:
    """Up to ``frames`` rectified grey pairs of a stereo bag, spread over it: its
    ``<ns>/left|right/image_rect``, or ``image_raw`` (or ``/compressed``) with
    ``camera_info`` rectified here. ``rename``: a driver's topics read as those names
    (``/camera/camera/infra1/image_rect_raw`` as ``/camera/camera/left/image_raw``).
    ``run``: the pairs in runs of that many consecutive frames, each run its own
    ``source`` (``BAG#k``), the runs spread over the bag.

    Raises:
        BagError: The bag has no stereo pair (it says what it looked for).
    """
    rename = rename or {}
    back = {name: topic for topic, name in rename.items()}
    with BagReader(bag) as reader:
        topics = {rename.get(t, t) for t in reader.topics}
        namespaces = sorted({t.rsplit('/left/', 1)[0] for t in topics if '/left/' in t
                             and t.endswith(('/image_rect', '/image_raw',
                                             '/image_raw/compressed'))})
        ns = next((n for n in namespaces if any(t.startswith(f'{n}/right/') for t in topics)),
                  None)
        if ns is None:
            raise BagError(f'{bag}: no stereo pair (looked for <ns>/left/ and <ns>/right/ '
                           'image_rect, or image_raw with camera_info)')
        wanted = [f'{ns}/{side}/{name}' for side in ('left', 'right')
                  for name in ('image_rect', 'image_raw', 'image_raw/compressed',
                               'camera_info')]
        data: dict[str, dict[int, Any]] = {}
        for msg in reader.messages([back.get(t, t) for t in wanted if t in topics]):
            parsed = msg.deserialize()
            stamp = int(parsed.header.stamp.sec) * 10**9 + int(parsed.header.stamp.nanosec)
            data.setdefault(rename.get(msg.topic, msg.topic), {})[stamp] = parsed
    key = next((f'{ns}/left/{n}' for n in ('image_rect', 'image_raw', 'image_raw/compressed')
                if f'{ns}/left/{n}' in data), None)
    stamps = sorted(data[key]) if key else []
    runs, n = -(-frames // run), len(stamps)
    if runs * run < n:
        firsts = [round(i * (n - run) / max(runs - 1, 1)) for i in range(runs)]
    else:
        firsts = list(range(0, n, run))
    left_over = frames
    for k, first in enumerate(firsts):
        for stamp in stamps[first:first + min(run, left_over)]:
            left_over -= 1
            left, right = rectified_pair(data, ns, stamp)
            yield Pair(str(bag) if run == 1 else f'{bag}#{k}', stamp, left, right)


def proxy_labels(pair: Pair, matcher: SgmMatcher, config: AdaptConfig
                 ) -> tuple[F32, NDArray[np.bool_]]:
    """The matcher's disparity of a pair, and where it is a label (see the module
    notes)."""
    result = matcher.match(pair.left, pair.right)
    d = result.disparity
    h, w = d.shape
    ok = np.isfinite(d)
    xs = np.arange(w)[None, :]
    xr = np.rint(xs - np.where(ok, d, 0)).astype(np.int64)
    inside = ok & (xr >= 0) & (xr < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    back = np.full(d.shape, np.nan, np.float32)
    back[inside] = result.disparity_right[rows[inside], xr[inside]]
    consistent = inside & (np.abs(back - d) <= config.lr_px)
    distinct = result.cost_ratio <= config.max_cost_ratio
    right = matched_brightness(pair.left, pair.right).astype(np.float32)
    xf = xs - np.where(ok, d, 0)
    x0 = np.clip(np.floor(xf).astype(np.int64), 0, w - 1)
    x1 = np.clip(x0 + 1, 0, w - 1)
    frac = (xf - np.floor(xf)).astype(np.float32)
    warped = right[rows, x0] * (1 - frac) + right[rows, x1] * frac
    photometric = np.abs(pair.left.astype(np.float32) - warped) <= config.max_photometric
    return d, consistent & distinct & photometric


def mistakes(pair: Pair, labels: F32, extractor: FeatureExtractor,
             config: AdaptConfig) -> F32:
    """Per pixel, the disparity the network's own cost (winner takes all, no SGM) prefers
    more than 1.5 px from the label; NaN where the label is unknown or the image edge
    leaves no other candidate."""
    costs = learned_costs(extractor, pair.left, pair.right, min_disparity=0,
                          weight=config.learned_weight)
    h, w = pair.left.shape
    volume = np.empty((h, w, config.disparity_range), np.uint8)
    costs.rows(0, volume)
    ks = np.arange(config.disparity_range)[None, None, :]
    near = np.abs(ks - labels[:, :, None]) <= 1.5
    volume[near] = 255
    best = volume.argmin(axis=2).astype(np.float32)
    known = np.isfinite(labels) & (volume.min(axis=2) < OUT_OF_RANGE_COST)
    out: F32 = np.where(known, best, np.nan).astype(np.float32)
    return out


@dataclass
class AdaptResult:
    """The adapted network, what it learned from, its curves."""

    net: FeatureNet
    labels: int
    pairs: int
    best_step: int
    seconds: float


def adapt(bags: list[str | Path], config: AdaptConfig, *, weights: str = '',
          log: Callable[[str], None] = print,
          checkpoint: Callable[[FeatureNet], None] | None = None,
          stop: Callable[[], bool] = lambda: False) -> AdaptResult:
    """Fine-tune the network of ``weights`` (a file; empty: the shipped one) on the proxy
    labels of the bags' pairs (see the module notes); ``checkpoint`` gets each network
    that beats the ones before on the held-out labels; ``stop`` ends it early (the best so
    far is returned).

    Raises:
        ConfigError: JAX is missing; the weights cannot be read.
        BagError: A bag cannot be read or holds no stereo pair; no pair gave a label.
    """
    jax = load_jax()
    start = time.monotonic()
    base = FeatureNet.load(weights) if weights else shipped_features()
    params = SgmParams(disparity_range=config.disparity_range, matching_cost=config.proxy_cost,
                       learned_weight=config.learned_weight, learned_weights=weights)
    matcher = SgmMatcher(params)
    extractor = FeatureExtractor(base)
    data = DataConfig(radius=base.radius, window=base.window, seed=config.seed,
                      samples_per_scene=config.samples)
    rng = np.random.default_rng([config.seed, 11])
    parts: list[tuple[F32, F32, F32]] = []
    sources: list[str] = []
    labels = 0
    for bag in bags:
        for pair in stereo_pairs(bag, config.frames):
            if stop():
                break
            if pair.left.shape[1] <= config.disparity_range:
                raise BagError(f'{pair.source}: a {pair.left.shape[1]} px wide image is too '
                               f'narrow for {config.disparity_range} disparities')
            d, usable = proxy_labels(pair, matcher, config)
            labels += int(usable.sum())
            hard = mistakes(pair, d, extractor, config)
            parts.append(sample_triplets(pair.left, pair.right, d, usable, data, rng, hard,
                                         config.hard_fraction))
            sources.append(f'{Path(pair.source).name}@{pair.stamp}')
            log(f'{sources[-1]}: {usable.mean():.0%} of the pixels labelled '
                f'({int(usable.sum())}), {time.monotonic() - start:.0f} s')
    if not parts or not sum(p[0].shape[0] for p in parts):
        raise BagError('no pair gave a proxy label (nothing left-right consistent and '
                       'distinctive): is it a rectified stereo pair?')
    train_set, val_set = _split(parts, rng)
    log(f'{train_set[0].shape[0]} training triplets, {val_set[0].shape[0]} held out')
    initial = [(k, b) for k, b in zip(base.kernels, base.biases, strict=True)]
    train = TrainConfig(channels=base.channels, layers=len(base.kernels), steps=config.steps,
                        learning_rate=config.learning_rate)
    best: dict[str, Any] = {'loss': np.inf, 'step': 0, 'net': base}
    recipe = {'command': 'depth-nodes train-cost --adapt', 'adapted_on': sources,
              'adapt': asdict(config), 'base': base.recipe}

    def keep(net: FeatureNet, step: int, loss: float) -> None:
        if loss < best['loss']:
            best.update(loss=loss, step=step, net=FeatureNet(net.kernels, net.biases,
                                                             base.window, dict(recipe)))
            if checkpoint is not None:
                checkpoint(best['net'])

    optimise(jax, initial, train_set, val_set, train, seed=config.seed, window=base.window,
             log=log, log_every=max(1, config.steps // 10), start=start,
             anchor=config.anchor, checkpoint=keep, stop=stop)
    net: FeatureNet = best['net']
    net.recipe.update(best_step=best['step'], seconds=round(time.monotonic() - start, 1))
    return AdaptResult(net, labels, len(sources), best['step'], time.monotonic() - start)


def _split(parts: list[tuple[F32, F32, F32]], rng: np.random.Generator
           ) -> tuple[tuple[F32, F32, F32], tuple[F32, F32, F32]]:
    """Training and held-out triplets: every tenth pair held out, or, with fewer than
    ten pairs, a tenth of every pair's triplets."""
    if len(parts) >= 10:
        held = [p for i, p in enumerate(parts) if i % 10 == 9]
        kept = [p for i, p in enumerate(parts) if i % 10 != 9]
    else:
        held, kept = [], []
        for p in parts:
            order = rng.permutation(p[0].shape[0])
            cut = max(1, p[0].shape[0] // 10)
            held.append(tuple(a[order[:cut]] for a in p))  # type: ignore[arg-type]
            kept.append(tuple(a[order[cut:]] for a in p))  # type: ignore[arg-type]
    join = lambda group: tuple(np.concatenate([g[i] for g in group]) for i in range(3))  # noqa: E731
    return join(kept), join(held)  # type: ignore[return-value]


def write_atomically(net: FeatureNet, out: Path) -> None:
    """``net`` saved to ``out`` through a temporary file, so that ``out`` always holds a
    whole file (a Ctrl-C in the middle of a save leaves the last one)."""
    tmp = out.with_name(out.stem + '.partial.npz')
    net.save(tmp)
    os.replace(tmp, out)
