"""Depth for a stream of posed views: keyframes, the sweep against them, the temporal filter
and the geometric check, frame after frame (no ROS).

Every frame (:meth:`MvsStream.process`) is a reference: it is swept against the most
recent keyframes that are at least ``min_baseline`` of the scene's median depth away from
it and turned at most ``max_view_angle_deg`` from it, with ``delay`` also against the
frames that came after it (sources from both sides, interleaved, ``max_sources`` at most),
and against the views given with it (a rig's other cameras, same stamp: first, whatever
their distance and angle; a sweep takes 16 views at most). Its estimate is checked against
the keyframes' depth maps (a pixel that some checked view contradicts and none confirms is
not fused into an estimate the filter has, and its confidence is halved), then fused with
the filter's state moved into it from the previous frame. The frame becomes a keyframe
when it is ``keyframe_baseline`` of the median depth from the last keyframe, or turned by
``keyframe_angle_deg``. The planes shift by a fraction of a step from frame to frame
(``dither``), so the filter averages the sub-plane refinement's bias away.

A frame gives no depth, with its reason (:class:`NoDepth`), when no keyframe is far enough
and turned little enough (``no_baseline``: nothing is estimated from it; it may become the
first keyframe), or when its image, camera or pose do not fit (``size_mismatch``,
``bad_pose``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.mvs.consistency import consistency
from depth_nodes.core.mvs.cost import MAX_SOURCES
from depth_nodes.core.mvs.fusion import (
    FilterSettings,
    FilterState,
    converged,
    fuse,
    warp_state,
)
from depth_nodes.core.mvs.matcher import MultiViewMatcher, MvsParams, MvsResult, SourceView
from depth_nodes.core.settings import check_settings, setting
from depth_nodes.errors import ArgumentError

__all__ = ['Frame', 'MvsStream', 'NoDepth', 'StreamDepth', 'StreamParams']

F32 = NDArray[np.float32]
LABEL = 'multi-view stream parameter'
FILTER_CHOICES = ('kalman', 'gauss_uniform', 'none')
#: The planes' offset advances by this fraction of a step per frame (a low-discrepancy
#: sequence: the offsets of any few frames in a row spread over the step).
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class StreamParams:
    """Keyframes, filter and check settings (the sweep's are :class:`MvsParams`)."""

    max_sources: int = setting(4, 'Keyframes (and, with delay, later frames) a frame is '
                               'swept against, the most recent', low=1, high=16)
    max_keyframes: int = setting(8, 'Keyframes kept', low=1, high=64)
    min_baseline: float = setting(0.01, 'Least distance of a source keyframe, as a fraction '
                                  "of the scene's median depth", low=0.0, high=10.0)
    keyframe_baseline: float = setting(0.02, 'Distance from the last keyframe that makes a '
                                       "new one, as a fraction of the scene's median depth",
                                       low=0.0, high=10.0)
    max_view_angle_deg: float = setting(30.0, 'Largest rotation between a frame and a '
                                        'source, degrees: from wider angles its surfaces '
                                        'look too foreshortened to match', low=0.0,
                                        high=180.0)
    keyframe_angle_deg: float = setting(10.0, 'Rotation from the last keyframe that makes a '
                                        'new one, degrees', low=0.0, high=180.0)
    delay: int = setting(0, 'Frames the depth of a view waits for: its sweep then also '
                         'uses the views that came after it (points hidden from one side '
                         'are seen from the other), at that latency', low=0, high=16)
    temporal_filter: str = setting('kalman', 'kalman (inverse-depth Kalman filter with '
                                   'outlier gate), gauss_uniform (Vogiatzis-Hernandez / '
                                   'REMODE) or none (each frame alone)',
                                   choices=FILTER_CHOICES)
    process_sigma: float = setting(0.002, 'Relative inverse-depth noise added when the '
                                   'filter state moves to the next frame', low=0.0, high=0.5)
    correlation: float = setting(0.5, 'Share of a new estimate\'s variance added to the '
                                 'filter\'s before they are fused (successive frames share '
                                 'keyframes: their errors are not independent)', low=0.0,
                                 high=10.0)
    converge_sigma: float = setting(0.02, 'Largest relative depth standard deviation of a '
                                    'converged pixel', low=1e-4, high=1.0)
    dither: bool = setting(True, 'Shift the planes by a different fraction of a step in '
                           'every frame, so that the filter averages out the sub-plane '
                           "refinement's bias")
    check_px: float = setting(1.0, 'Geometric check against the keyframes\' depths: largest '
                              'round-trip distance, px (0: no check); a contradicted estimate '
                              'is not fused into one the filter has, and its confidence is '
                              'halved', low=0.0, high=100.0)
    check_relative: float = setting(0.05, 'Geometric check: largest relative depth '
                                    'difference', low=0.0, high=1.0)

    def validate(self) -> StreamParams:
        """Raises ArgumentError naming the first invalid field; returns self."""
        return check_settings(self, LABEL)

    def filter_settings(self, rho_range: float) -> FilterSettings:
        """The filter's settings (``rho_range``: the sweep's inverse-depth span)."""
        method = 'kalman' if self.temporal_filter == 'none' else self.temporal_filter
        return FilterSettings(method=method, process_sigma=self.process_sigma,
                              correlation=self.correlation,
                              converge_sigma=self.converge_sigma, rho_range=rho_range)


@dataclass(frozen=True)
class Frame:
    """One posed view.

    Attributes:
        image: (H, W) grey image (uint8, uint16 or float).
        camera: Its pinhole camera (the image's size).
        pose: Its optical frame in the world.
        stamp_ns: Its stamp.
        context: What the caller wants back with the frame's depth (a node: the frame's
            header and CameraInfo); the stream never reads it.
    """

    image: NDArray[Any]
    camera: Intrinsics
    pose: Pose
    stamp_ns: int = 0
    context: Any = None


@dataclass
class StreamDepth:
    """A frame's depth (arrays are the frame's own).

    Attributes:
        depth: (H, W) float32 Z, metres, NaN where none.
        sigma: (H, W) float32 standard deviation of Z, metres.
        confidence: (H, W) float32 in [0, 1].
        converged: (H, W) bool: the filter's estimate has converged there.
        sources: How many views the frame was swept against.
        measurement: The frame's own sweep, before the filter.
        frame: The reference view these belong to.
    """

    depth: F32
    sigma: F32
    confidence: F32
    converged: NDArray[np.bool_]
    sources: int
    measurement: MvsResult
    frame: Frame


@dataclass(frozen=True)
class NoDepth:
    """Why a frame gave no depth: a short stable ``reason``, a sentence, and the frame."""

    reason: str
    detail: str
    frame: Frame | None = None


def _interleave(first: list[SourceView], second: list[SourceView]) -> list[SourceView]:
    """first[0], second[0], first[1], second[1], ...: sources from both sides of a view
    while there are both."""
    out: list[SourceView] = []
    for i in range(max(len(first), len(second))):
        out += first[i:i + 1] + second[i:i + 1]
    return out


@dataclass
class _Keyframe:
    image: NDArray[Any]
    camera: Intrinsics
    pose: Pose
    census: NDArray[Any] | None
    depth: F32 | None = None


@dataclass
class _Previous:
    """The last processed frame's filter state and view."""

    state: FilterState
    camera: Intrinsics
    pose: Pose


@dataclass
class MvsStream:
    """Keyframes, sweeps and the filter for one camera (see the module notes).

    Args:
        params: The sweep's settings.
        stream: Keyframes, filter and check settings.
    """

    params: MvsParams = field(default_factory=MvsParams)
    stream: StreamParams = field(default_factory=StreamParams)

    def __post_init__(self) -> None:
        self.params.validate()
        self.stream.validate()
        self.matcher = MultiViewMatcher(self.params)
        self.keyframes: deque[_Keyframe] = deque(maxlen=self.stream.max_keyframes)
        self._previous: _Previous | None = None
        self._median_depth = math.sqrt(self.params.min_depth * self.params.max_depth)
        self._frames = 0
        self._pending: deque[tuple[Frame, list[Frame]]] = deque()

    def set_params(self, params: MvsParams, stream: StreamParams) -> None:
        """New settings from the next frame on; a change of the sweep's range or of the
        filter starts the filter over."""
        params.validate()
        stream.validate()
        if (params.min_depth, params.max_depth) != (self.params.min_depth,
                                                    self.params.max_depth) or \
                stream.temporal_filter != self.stream.temporal_filter:
            self._previous = None
        self.params, self.stream = params, stream
        self.matcher.set_params(params)
        if self.keyframes.maxlen != stream.max_keyframes:
            self.keyframes = deque(self.keyframes, maxlen=stream.max_keyframes)

    def reset_filter(self) -> None:
        """Forget the filter's state (the keyframes stay)."""
        self._previous = None

    def reset(self) -> None:
        """Forget the keyframes, the frames waiting and the filter (a time jump, a new
        map)."""
        self.keyframes.clear()
        self._pending.clear()
        self._previous = None

    @property
    def median_depth(self) -> float:
        """The scene's median depth as last measured (the sweep's middle before that)."""
        return self._median_depth

    def sources_for(self, frame: Frame) -> list[_Keyframe]:
        """The keyframes ``frame`` would be swept against, most recent first (those of its
        size: a camera that changed its resolution starts its keyframes over)."""
        least = self.stream.min_baseline * self._median_depth
        shape = np.asarray(frame.image).shape
        chosen = [k for k in reversed(self.keyframes)
                  if k.pose.distance_to(frame.pose) >= max(least, 1e-9) and
                  k.image.shape == shape and
                  k.pose.angle_to(frame.pose) <= self.stream.max_view_angle_deg]
        return chosen[:self.stream.max_sources]

    def process(self, frame: Frame, rig: list[Frame] | None = None
                ) -> StreamDepth | NoDepth | None:
        """Take ``frame``; returns the depth of the frame ``delay`` frames before it (of
        ``frame`` itself with no delay), or why that frame has none, or None while fewer
        than ``delay`` frames have come after the first one.

        Args:
            frame: The newest view.
            rig: Other views taken at the same time as ``frame`` (a rig's other cameras),
                swept against as sources whatever their distance.
        """
        problem = self._check(frame, np.asarray(frame.image), rig or [])
        if problem is not None:
            return problem
        self._pending.append((frame, list(rig or [])))
        if len(self._pending) <= self.stream.delay:
            return None
        return self._reference()

    def flush(self) -> list[StreamDepth | NoDepth]:
        """The depth of the frames still waiting for later ones (the stream ended), each
        swept against the later frames there are."""
        out = []
        while self._pending:
            out.append(self._reference())
        return out

    @property
    def waiting(self) -> int:
        """Frames taken whose depth has not been returned yet (``delay`` at most)."""
        return len(self._pending)

    def _reference(self) -> StreamDepth | NoDepth:
        """Sweep the oldest pending frame against keyframes before it and pending frames
        after it."""
        frame, rig = self._pending.popleft()
        image = np.asarray(frame.image)
        keyframes = self.sources_for(frame)
        later = self._later_sources(frame)
        past: list[SourceView] = [SourceView(k.image, k.camera, frame.pose.relative_to(k.pose),
                                             k.census) for k in keyframes]
        # the rig's views first: a sweep takes at most MAX_SOURCES views
        sources = [SourceView(np.asarray(v.image), v.camera, frame.pose.relative_to(v.pose))
                   for v in rig][:MAX_SOURCES]
        sources += _interleave(past, later)[:min(self.stream.max_sources,
                                                 MAX_SOURCES - len(sources))]
        if not sources:
            self._maybe_keyframe(frame, image, None, None)
            return NoDepth('no_baseline', 'no keyframe (or later frame, with delay) of '
                           'this size is both far enough from this view (at least '
                           f'{self.stream.min_baseline:g} x the median depth '
                           f'{self._median_depth:.2f} m) and turned at most '
                           f'{self.stream.max_view_angle_deg:g} degrees from it', frame)
        self._frames += 1
        offset = (self._frames * GOLDEN) % 1.0 if self.stream.dither else 0.0
        result = self.matcher.match(image, frame.camera, sources, offset=offset)
        contradicted = self._contradicted(frame, keyframes, result) \
            if self.stream.check_px > 0 else None
        depth = self._filtered(frame, result, contradicted)
        self._maybe_keyframe(frame, image, result, depth.depth)
        depth.sources = len(sources)
        finite = depth.depth[np.isfinite(depth.depth)]
        if finite.size:
            self._median_depth = float(np.median(finite))
        return depth

    def _later_sources(self, frame: Frame) -> list[SourceView]:
        """The pending frames after ``frame`` (of its size) far enough from it, the newest
        first."""
        least = max(self.stream.min_baseline * self._median_depth, 1e-9)
        shape = np.asarray(frame.image).shape
        return [SourceView(np.asarray(f.image), f.camera, frame.pose.relative_to(f.pose))
                for f, _ in reversed(self._pending)
                if f.pose.distance_to(frame.pose) >= least and np.asarray(f.image).shape == shape
                and f.pose.angle_to(frame.pose) <= self.stream.max_view_angle_deg]

    def _check(self, frame: Frame, image: NDArray[Any], rig: list[Frame]) -> NoDepth | None:
        if image.ndim != 2 or min(image.shape) < 2:
            return NoDepth('size_mismatch', f'the image must be grey (H, W), at least 2 x 2, '
                           f'got {image.shape}', frame)
        for view in (frame, *rig):
            shape = np.asarray(view.image).shape
            if shape != image.shape or (view.camera.height, view.camera.width) != shape:
                return NoDepth('size_mismatch', f'image {shape[1::-1]} and camera '
                               f'{view.camera.width}x{view.camera.height} and reference '
                               f'{image.shape[1]}x{image.shape[0]} must agree', frame)
            try:
                view.pose.validate()
            except ArgumentError as exc:
                return NoDepth('bad_pose', str(exc), frame)
        if image.shape[1] <= self.params.planes:
            return NoDepth('size_mismatch', f'the image is {image.shape[1]} px wide: planes '
                           f'({self.params.planes}) must be fewer', frame)
        return None

    def _contradicted(self, frame: Frame, keyframes: list[_Keyframe],
                      result: MvsResult) -> NDArray[np.bool_] | None:
        """The pixels whose new depth the keyframes' depths contradict, none confirming."""
        others = [(k.depth, k.camera.matrix, frame.pose.relative_to(k.pose))
                  for k in keyframes if k.depth is not None]
        if not others:
            return None
        checked, agreed = consistency(result.depth, frame.camera.matrix, others,
                                      max_px=self.stream.check_px,
                                      max_relative=self.stream.check_relative)
        out: NDArray[np.bool_] = (checked > 0) & (agreed == 0)
        return out

    def _filtered(self, frame: Frame, result: MvsResult,
                  contradicted: NDArray[np.bool_] | None) -> StreamDepth:
        """Fuse the frame's estimate into the state moved from the previous frame; a
        contradicted estimate is not fused where the state has one, and its confidence is
        halved."""
        planes = self.params.planes_of()
        settings = self.stream.filter_settings(
            planes.inverse_depths()[-1] - planes.inverse_depths()[0])
        shape = result.rho.shape
        previous = self._previous
        if self.stream.temporal_filter == 'none' or previous is None:
            state = FilterState.empty(shape)
        else:
            state = warp_state(previous.state, previous.camera, frame.camera,
                               previous.pose.relative_to(frame.pose),
                               process_sigma=settings.process_sigma)
        rho = result.rho
        if contradicted is not None:
            rho = rho.copy()
            rho[contradicted & np.isfinite(state.rho)] = np.nan
        fuse(state, rho, result.rho_var, settings)
        self._previous = _Previous(state, frame.camera, frame.pose)
        depth = state.depth()
        sigma = state.depth_sigma()
        done = converged(state, settings) if self.stream.temporal_filter != 'none' else \
            np.zeros(shape, bool)
        confidence = np.where(np.isfinite(depth), result.confidence, 0.0).astype(np.float32)
        confidence[np.isfinite(depth) & ~np.isfinite(rho)] = 0.5  # the filter's alone
        if contradicted is not None:
            confidence[contradicted] *= 0.5
        return StreamDepth(depth, sigma, confidence, done, 0, result, frame)

    def _maybe_keyframe(self, frame: Frame, image: NDArray[Any], result: MvsResult | None,
                        depth: F32 | None) -> None:
        last = self.keyframes[-1] if self.keyframes else None
        if last is not None:
            far = last.pose.distance_to(frame.pose) >= \
                self.stream.keyframe_baseline * self._median_depth
            turned = last.pose.angle_to(frame.pose) >= self.stream.keyframe_angle_deg
            if not (far or turned):
                return
        census = None if result is None else result.inputs.ref_census.reshape(image.shape)
        self.keyframes.append(_Keyframe(image.copy(), frame.camera, frame.pose, census,
                                        None if depth is None else depth.copy()))
