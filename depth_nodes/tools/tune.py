"""`depth-nodes tune`: sgm_stereo's settings searched on a user's own stereo frames, scored
without ground truth.

The frames: up to ``frames`` rectified pairs, in runs of two consecutive frames spread
over the bag (read as `train-cost --adapt` reads them; a camera preset's driver topics
with ``camera``). The start: the shipped
stereo graph's settings (config/stereo_pipeline.yaml, what `process` runs), or the
preset's. Each trial is those settings with some changed at random (seeded): ``P1``,
``P2``, ``uniqueness_ratio``, ``paths``, ``matching_cost`` and ``learned_weight``.
``disparity_range`` is not searched: it belongs to the camera (its baseline, focal length
and nearest depth: a camera preset's), and a search could shrink it below the nearest
object. cross_check's thresholds are not searched: without ground truth a looser check
always scores better (more pixels pass, and a wrong match on a plain surface fits
photometrically). A trial's score, lower is better, needs no ground truth;
per pixel of the left image:

* where the left-right check passes (the left disparity and the right one it lands on
  within cross_check's ``disp12_max_diff``): the photometric error, |left - right warped by the
  disparity| in grey levels, the right image's brightness matched to the left's first;
* elsewhere (no disparity, or the check fails): :data:`MISSING_COST` grey levels, the
  typical error of a wrong match, so that density after the check counts as much as
  the photometric fit, and a setting cannot win by answering only where it is sure;

plus, between the two consecutive frames of a run, :data:`TEMPORAL_WEIGHT` grey levels
per pixel of median disparity change where both are checked (a still camera's disparity should
not flicker; a moving one's changes with the motion, the same for every setting). The
score of a trial is the mean over the frames. The best trial's settings are written as a
ROS 2 parameter file for sgm_stereo; with ground truth in the bag
(``<ns>/left/disparity_gt``) the true error (dense bad-2 of the raw disparity) of the start
and of the best is reported too.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from depth_nodes.core.metrics import disparity_errors
from depth_nodes.core.sgm import SgmMatcher, SgmParams
from depth_nodes.core.sgm.brightness import matched_brightness
from depth_nodes.core.stamps import stamp_ns
from depth_nodes.errors import ConfigError
from depth_nodes.graph.description import load_graph_config
from depth_nodes.graph.presets import load_camera
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.process import default_config_path
from depth_nodes.tools.train.adapt import Pair, stereo_pairs

__all__ = ['MISSING_COST', 'SPACE', 'TEMPORAL_WEIGHT', 'Trial', 'TuneResult', 'score_pairs',
           'search', 'tune', 'write_params']

F32 = NDArray[np.float32]
#: Grey levels a pixel without a checked disparity costs.
MISSING_COST = 20.0
#: Grey levels per pixel of median disparity change between consecutive frames.
TEMPORAL_WEIGHT = 1.0
#: sgm_stereo's parameters of type double (stereo_image_proc's types) among those searched:
#: a parameter file must give them as floats.
NODE_DOUBLES = frozenset({'P1', 'P2', 'uniqueness_ratio'})
#: What a trial may change, and the values it picks from.
SPACE: dict[str, tuple[Any, ...]] = {
    'P1': (8, 12, 18, 24, 32),
    'P2': (120, 160, 220, 300, 400),
    'uniqueness_ratio': (5.0, 10.0, 15.0),
    'paths': (5, 8),
    'matching_cost': ('census', 'census+learned'),
    'learned_weight': (10, 20, 40),
}


@dataclass
class Trial:
    """One setting tried: what it changed from the start, its score and its parts."""

    changes: dict[str, Any]
    score: float
    density: float
    photometric: float
    temporal: float
    bad2: float | None = None


@dataclass
class TuneResult:
    """The start, every trial in order, and the best."""

    start: Trial
    trials: list[Trial] = field(default_factory=list)
    pairs: int = 0
    interrupted: bool = False
    seconds: float = 0.0

    @property
    def best(self) -> Trial:
        return min([self.start, *self.trials], key=lambda t: t.score)


def _shipped_settings() -> dict[str, Any]:
    """sgm_stereo's and cross_check's parameters in the shipped stereo graph, over their
    defaults: what `process` runs."""
    config = load_graph_config(default_config_path())
    out: dict[str, Any] = {'check_diff': 1.0}
    for spec in config.nodes:
        if spec.plugin == 'sgm_stereo':
            out.update(spec.parameters)
        elif spec.plugin == 'cross_check':
            out['check_diff'] = float(spec.parameters.get('disp12_max_diff', 1.0))
    return out


def _preset(name: str) -> tuple[dict[str, Any], dict[str, str]]:
    """A stereo camera preset's sgm_stereo settings and its driver's topics, as the names
    :func:`stereo_pairs` reads.

    Raises:
        ConfigError: No such preset, or one without a stereo pair.
    """
    preset = load_camera(name, default_config_path().parent)
    stereo = next((s for s in preset.config.nodes if s.plugin == 'sgm_stereo'), None)
    if stereo is None:
        raise ConfigError(f'camera preset {name} has no stereo pair to tune')
    cam = preset.camera
    ns = str(cam.get('namespace', '/stereo')).rstrip('/')
    image = str(cam.get('image', 'image_raw'))
    rename = {}
    for side in ('left', 'right'):
        driver = f'{ns}/{cam.get(side, side)}'
        rename[f'{driver}/{image}'] = f'{ns}/{side}/image_raw'
        rename[f'{driver}/{image}/compressed'] = f'{ns}/{side}/image_raw/compressed'
        rename[f'{driver}/camera_info'] = f'{ns}/{side}/camera_info'
    settings = {**_shipped_settings(), **stereo.parameters}
    return settings, rename


def _params(settings: dict[str, Any]) -> SgmParams:
    names = set(asdict(SgmParams()))
    values = {k: v for k, v in settings.items() if k in names}
    if values.get('P2', 0) < values.get('P1', 0):
        values['P2'] = values['P1']
    return SgmParams(**values).validate()


def _check(result: Any, max_diff: float) -> NDArray[np.bool_]:
    """Pixels whose left disparity passes the left-right check."""
    d = result.disparity
    h, w = d.shape
    ok = np.isfinite(d)
    xr = np.rint(np.arange(w)[None, :] - np.where(ok, d, 0)).astype(np.int64)
    inside = ok & (xr >= 0) & (xr < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    back = np.full(d.shape, np.nan, np.float32)
    back[inside] = result.disparity_right[rows[inside], xr[inside]]
    checked: NDArray[np.bool_] = inside & (np.abs(back - d) <= max_diff)
    return checked


def _photometric(pair: Pair, d: F32) -> F32:
    """|left - right warped by d| per pixel, grey levels (NaN where d is)."""
    h, w = d.shape
    right = matched_brightness(pair.left, pair.right).astype(np.float32)
    xf = np.arange(w)[None, :] - np.where(np.isfinite(d), d, 0)
    x0 = np.clip(np.floor(xf).astype(np.int64), 0, w - 1)
    x1 = np.clip(x0 + 1, 0, w - 1)
    frac = (xf - np.floor(xf)).astype(np.float32)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    warped = right[rows, x0] * (1 - frac) + right[rows, x1] * frac
    out: F32 = np.abs(pair.left.astype(np.float32) - warped)
    return out


def score_pairs(pairs: list[Pair], settings: dict[str, Any],
                truth: dict[int, F32] | None = None) -> Trial:
    """Score ``settings`` on ``pairs`` (see the module notes); with ``truth`` (by stamp),
    also the raw disparity's dense bad-2 over the pairs that have it."""
    matcher = SgmMatcher(_params(settings))
    max_diff = float(settings.get('check_diff', 1.0))
    scores, densities, photos, temporal, bad = [], [], [], [], []
    previous: F32 | None = None
    source = None
    for pair in pairs:
        result = matcher.match(pair.left, pair.right)
        checked = _check(result, max_diff)
        photo = _photometric(pair, result.disparity)
        cost = np.where(checked, np.minimum(photo, MISSING_COST), MISSING_COST)
        scores.append(float(cost.mean()))
        densities.append(float(checked.mean()))
        photos.append(float(photo[checked].mean()) if checked.any() else math.nan)
        d = np.where(checked, result.disparity, np.nan).astype(np.float32)
        if previous is not None and source == pair.source and previous.shape == d.shape:
            both = np.isfinite(d) & np.isfinite(previous)
            if both.any():
                temporal.append(float(np.median(np.abs(d[both] - previous[both]))))
        previous, source = d, pair.source
        if truth is not None and pair.stamp in truth:
            bad.append(float(disparity_errors(result.disparity, truth[pair.stamp],
                                              n=2.0).bad_dense))
    change = float(np.mean(temporal)) if temporal else 0.0
    return Trial({}, float(np.mean(scores)) + TEMPORAL_WEIGHT * change,
                 float(np.mean(densities)), float(np.nanmean(photos)), change,
                 float(np.mean(bad)) if bad else None)


def ground_truth(bag: str | Path) -> dict[int, F32]:
    """The bag's left ``disparity_gt`` by stamp (empty: none)."""
    with BagReader(bag) as reader:
        # the left camera's (a driver's layout may name it otherwise, e.g. infra1)
        topics = sorted(t for t, kind in reader.topics.items()
                        if t.endswith('/disparity_gt') and kind.endswith('DisparityImage')
                        and '/right/' not in t)
        out: dict[int, F32] = {}
        if not topics:
            return out
        for msg in reader.messages(topics[:1]):
            parsed = msg.deserialize()
            d = read_disparity(parsed).disparity
            out[stamp_ns(parsed.header)] = np.where(d > 0, d, np.nan).astype(np.float32)
    return out


def tune(bag: str | Path, *, frames: int = 4, trials: int = 24, seed: int = 0,
         camera: str | None = None, log: Callable[[str], None] = lambda _: None,
         stop: Callable[[], bool] = lambda: False,
         on_best: Callable[[TuneResult], None] = lambda _: None) -> TuneResult:
    """Search the settings on the bag's frames (see the module notes). ``on_best`` gets
    the result each time the best changes (a checkpoint); ``stop`` ends the search between
    trials.

    Raises:
        BagError: The bag has no stereo pair.
        ConfigError: ``frames`` below 1 or ``trials`` below 0.
    """
    if frames < 1 or trials < 0:
        raise ConfigError(f'--frames must be at least 1 and --trials at least 0, got {frames} '
                          f'and {trials}')
    base, rename = _shipped_settings(), None
    if camera is not None:
        base, rename = _preset(camera)
    pairs = list(stereo_pairs(bag, frames, rename=rename, run=2))
    return search(pairs, base, trials=trials, seed=seed,
                  truth=ground_truth(bag) or None, log=log, stop=stop, on_best=on_best)


def search(pairs: list[Pair], base: dict[str, Any], *, trials: int, seed: int,
           truth: dict[int, F32] | None = None, space: dict[str, tuple[Any, ...]] = SPACE,
           log: Callable[[str], None] = lambda _: None,
           stop: Callable[[], bool] = lambda: False,
           on_best: Callable[[TuneResult], None] = lambda _: None) -> TuneResult:
    """Random search from ``base`` over ``space`` on ``pairs`` (see the module notes)."""
    started = time.monotonic()
    result = TuneResult(score_pairs(pairs, base, truth), pairs=len(pairs))
    log(f'{len(pairs)} pair(s); the shipped settings score {result.start.score:.2f}')
    on_best(result)
    rng = np.random.default_rng(seed)
    tried: set[frozenset[tuple[str, Any]]] = {frozenset()}
    for k in range(trials):
        if stop():
            result.interrupted = True
            break
        changes = _draw(rng, base, space, tried)
        if changes is None:
            log('every setting of the space was tried')
            break
        trial = replace(score_pairs(pairs, {**base, **changes}, truth), changes=changes)
        best = result.best
        result.trials.append(trial)
        mark = ' (best so far)' if trial.score < best.score else ''
        log(f'trial {k + 1}/{trials}: {trial.score:.2f}{mark} {_describe(changes)}')
        if mark:
            on_best(result)
    result.seconds = time.monotonic() - started
    return result


def _draw(rng: np.random.Generator, base: dict[str, Any], space: dict[str, tuple[Any, ...]],
          tried: set[frozenset[tuple[str, Any]]]) -> dict[str, Any] | None:
    """Settings not tried yet: each of the space's changed with probability one half to
    one of its values (the learned weight only with the learned cost), the start's own
    values left out; None when 1,000 draws found nothing new."""
    for _ in range(1000):
        picked = {name: values[int(rng.integers(len(values)))]
                  for name, values in space.items() if rng.random() < 0.5}
        if picked.get('matching_cost', base.get('matching_cost', 'census')) == 'census':
            picked.pop('learned_weight', None)
        changes = {k: v for k, v in picked.items() if base.get(k, _default(k)) != v}
        key = frozenset(changes.items())
        if key not in tried:
            tried.add(key)
            return changes
    return None


def _default(name: str) -> Any:
    """A setting's default when the shipped graph does not set it."""
    return asdict(SgmParams()).get(name)


def _describe(changes: dict[str, Any]) -> str:
    return ', '.join(f'{k} {v}' for k, v in changes.items()) or 'the shipped settings'


def write_params(result: TuneResult, out: Path, bag: str | Path) -> None:
    """The best settings as a ROS 2 parameter file (sgm_stereo's), written atomically."""
    best = result.best
    doc: dict[str, Any] = {}
    if best.changes:
        doc['sgm_stereo'] = {'ros__parameters': {
            k: float(v) if k in NODE_DOUBLES else v for k, v in best.changes.items()}}
    header = (f'# depth-nodes tune {bag}: {result.pairs} pair(s), '
              f'{len(result.trials)} trial(s); score {best.score:.2f} against the shipped '
              f'settings\' {result.start.score:.2f} (lower is better)\n')
    if not doc:
        header += '# the shipped settings scored best: nothing to change\n'
    tmp = out.with_name(out.name + '.partial')
    tmp.write_text(header + (yaml.safe_dump(doc, sort_keys=False) if doc else '{}\n'))
    tmp.replace(out)
