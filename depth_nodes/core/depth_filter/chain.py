"""The depth filter: the stages of :mod:`depth_nodes.core.depth_filter` in librealsense's
order (decimation, flying pixels, spatial, temporal, hole filling) over a stream of depth
frames, with the per-pixel variance carried through and every filled pixel marked.

The temporal stage remembers the last output. Given the camera's pose with each frame, it
moves that memory with the camera before using it (motion compensation); it starts over
when the frame's size or camera changes (:attr:`FilterResult.reset` says why).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.depth_filter.decimate import decimate, decimated_camera
from depth_nodes.core.depth_filter.domain import from_domain, to_domain
from depth_nodes.core.depth_filter.holes import fill_depth_holes, fill_spread
from depth_nodes.core.depth_filter.params import SPATIAL_HOLES, DepthFilterParams
from depth_nodes.core.depth_filter.spatial import noise_factor, scale_smoothed, spatial_smooth
from depth_nodes.core.depth_filter.temporal import (
    TemporalState,
    fresh_state,
    temporal_step,
    warp_state,
)
from depth_nodes.core.geometry import Intrinsics, Motion, Pose, Splat
from depth_nodes.core.tof.flying import remove_flying_pixels
from depth_nodes.errors import ArgumentError

F32 = NDArray[np.float32]
B = NDArray[np.bool_]
#: Flying pixels: the share of its neighbours' gap a depth must lie from each of them
#: (:func:`~depth_nodes.core.tof.flying.remove_flying_pixels`): the surface pixel next to
#: a mixed one lies between its neighbours by its noise alone.
FLYING_MARGIN = 0.1
#: Motion below which the memory is not moved (rotation, rad; translation, m).
STILL = (1e-9, 1e-9)


@dataclass
class FilterResult:
    """One filtered frame.

    Attributes:
        depth: Z, metres, NaN unknown, on ``camera``'s grid.
        filled: True where the depth was filled (spatial hole fill, temporal persistence,
            hole filling), not measured in this frame.
        sigma: Standard deviation of Z, metres (None without a per-pixel input noise);
            NaN where unknown (a hole filled at the image's border).
        camera: The output's intrinsics (decimated).
        times: Seconds each stage took.
        reset: Why the temporal memory started over at this frame, if it did.
    """

    depth: F32
    filled: B
    sigma: F32 | None
    camera: Intrinsics
    times: dict[str, float] = field(default_factory=dict)
    reset: str | None = None


class DepthFilter:
    """A stream of depth frames -> filtered frames (see the module notes)."""

    def __init__(self) -> None:
        self.state: TemporalState | None = None
        self.pose: Pose | None = None
        self._spare: TemporalState | None = None  # the state the warp writes next
        self._disparity = True  # the domain of the memory's values
        self._landed: Splat | None = None  # the warp's z-buffer, reused

    def reset(self) -> None:
        """Forget the past frames (a time jump, a gap)."""
        self.state = None
        self.pose = None

    def process(self, depth: F32, camera: Intrinsics, params: DepthFilterParams, *,
                sigma: F32 | None = None, pose: Pose | None = None) -> FilterResult:
        """Filter one frame.

        Args:
            depth: (H, W) Z, metres; NaN, infinite, zero or negative values are unknown.
            camera: The depth image's intrinsics (its size is the image's).
            params: The settings (validated here).
            sigma: (H, W) standard deviation of Z, metres, if known.
            pose: The camera's optical frame in the world at this frame, if known.

        Raises:
            ArgumentError: A setting out of range, or shapes that do not fit.
        """
        params.validate()
        raw = np.asarray(depth)
        if raw.ndim != 2 or raw.shape != (camera.height, camera.width):
            raise ArgumentError(f'depth {raw.shape[1::-1]} does not fit the camera\'s '
                                f'{camera.width}x{camera.height}')
        if sigma is not None and np.shape(sigma) != raw.shape:
            raise ArgumentError(f'sigma {np.shape(sigma)[1::-1]} does not fit the depth\'s '
                                f'{raw.shape[1::-1]}')
        times: dict[str, float] = {}
        disparity = params.filter_domain == 'disparity'
        start = time.perf_counter()
        if params.decimation > 1:
            var = None if sigma is None else np.square(np.asarray(sigma, np.float32))
            raw, var = decimate(raw, params.decimation, var)
            camera = decimated_camera(camera, params.decimation)
            sigma = None if sigma is None else np.sqrt(var)
        # a NaN sigma (unknown) stays NaN through the stages
        z, v, var_v = to_domain(raw, sigma, disparity)
        times['decimation'] = time.perf_counter() - start

        start = time.perf_counter()
        if params.flying_gap > 0 or params.flying_jump > 0:
            flying = remove_flying_pixels(z, params.flying_gap, params.flying_jump, sigma,
                                          margin=FLYING_MARGIN, spikes=True)
            v[flying] = np.nan
            var_v[flying] = np.nan
        times['flying'] = time.perf_counter() - start

        filled = np.zeros(v.shape, np.bool_)
        start = time.perf_counter()
        if params.spatial:
            before = v
            v, filled_s = spatial_smooth(v, params.spatial_alpha, params.spatial_delta,
                                         params.spatial_iterations,
                                         SPATIAL_HOLES[params.spatial_holes_fill])
            if sigma is not None:
                scale_smoothed(before, var_v, params.spatial_delta,
                               noise_factor(params.spatial_alpha, params.spatial_iterations))
            if filled_s.any():
                var_v[filled_s] = np.square(fill_spread(before, filled_s)[filled_s] / 2)
                filled |= filled_s
        times['spatial'] = time.perf_counter() - start

        start = time.perf_counter()
        reset = None
        if params.temporal:
            reset = self._prepare(camera, pose, disparity)
            assert self.state is not None
            v, var_v, kept = temporal_step(v, var_v, self.state, params.temporal_alpha,
                                           params.temporal_delta, params.temporal_persistence)
            filled |= kept
            self.pose = pose
        else:
            self.reset()
        times['temporal'] = time.perf_counter() - start

        start = time.perf_counter()
        z, out_sigma = from_domain(v, var_v, disparity)
        if params.hole_filling != 'off':
            measured = z
            z, filled_h = fill_depth_holes(z, params.hole_filling)
            if filled_h.any():
                out_sigma[filled_h] = fill_spread(measured, filled_h)[filled_h] / 2
                filled |= filled_h
        times['hole_filling'] = time.perf_counter() - start
        return FilterResult(z, filled, None if sigma is None else out_sigma, camera, times,
                            reset)

    def _prepare(self, camera: Intrinsics, pose: Pose | None, disparity: bool) -> str | None:
        """Bring the temporal memory onto this frame's grid; why it started over, if it
        did."""
        reset = None
        if self.state is not None and disparity != self._disparity:
            reset = 'filter_domain changed: the memory holds values of the other domain'
            self.state = None
        self._disparity = disparity
        if self.state is not None and (self.state.camera.width, self.state.camera.height) != \
                (camera.width, camera.height):
            reset = (f'the frame size changed from {self.state.camera.width}x'
                     f'{self.state.camera.height} to {camera.width}x{camera.height}')
            self.state = None
        if self.state is None:
            self.state = fresh_state(camera)
            return reset
        if pose is not None and self.pose is not None:
            rotation, translation = self.pose.relative_to(pose)
            angle = np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))
            if angle > STILL[0] or np.linalg.norm(translation) > STILL[1] or \
                    self.state.camera != camera:
                self._warp(camera, (rotation, translation), disparity)
        elif self.state.camera != camera:
            self._warp(camera, (np.eye(3), np.zeros(3)), disparity)
        return reset

    def _warp(self, camera: Intrinsics, motion: Motion, disparity: bool) -> None:
        """Move the memory with the camera, into the spare buffers (double buffering)."""
        assert self.state is not None
        shape = (camera.height, camera.width)
        if self._landed is None or self._landed.depth.shape != shape:
            self._landed = Splat.empty(shape)
        moved = warp_state(self.state, camera, motion, disparity, spare=self._spare,
                           landed=self._landed)
        self._spare, self.state = self.state, moved


def warm_up() -> None:
    """Run every kernel once on a small frame (all stages on, a camera that moves): numba
    loads or compiles them now rather than on a live camera's first frame, which would
    otherwise take about half a second while the frames after it overflow the input
    queue."""
    camera = Intrinsics(8.0, 8.0, 7.5, 5.5, 16, 12)
    depth = np.full((12, 16), 2.0, np.float32)
    depth[4:8, 6:10] = np.nan
    params = DepthFilterParams(decimation=2, spatial_holes_fill=2,
                               hole_filling='farthest_from_around')
    filt = DepthFilter()
    for step in range(2):
        pose = Pose(np.eye(3), np.array([0.01 * step, 0.0, 0.0]))
        filt.process(depth, camera, params, sigma=np.full_like(depth, 0.01), pose=pose)
