"""librealsense's depth post-processing filters on our own depth frames, for comparison with
the ``depth_filter`` node stage by stage.

The frames go through a ``pyrealsense2.software_device``: one software sensor with a Z16
depth stream of the given intrinsics, the ``depth_units`` option and a ``stereo_baseline``
option (without the baseline the disparity transform silently passes depth through). Each
:meth:`RealsenseChain.process` call pushes one frame with the next frame number and
timestamp, reads it back from a frame queue and applies the filters in librealsense's
recommended order: decimation, depth->disparity, spatial, temporal, disparity->depth, hole
filling. Only the stages that are on run; the temporal filter keeps its state across calls,
so a new sequence needs a new chain.

Behaviour of librealsense 2.59.1 measured on crafted frames (not read from its source).
``delta`` is in depth units, or in 1/32 pixel of disparity (``32 fx B / Z``) when the
disparity domain is on:

* decimation: keeps ``floor(W / m) x floor(H / m)`` blocks from the top-left and pads the
  frame with zeros on the right and bottom to a multiple of 4 (at magnitude 1 too, so this
  chain skips it then); the lower median of a block's non-zero values for m 2 and 3, their
  truncated mean for m >= 4, 0 for an empty block; it reports ``fx / m``, ``ppx / m``
  (not ``(ppx + 0.5) / m - 0.5``) and the padded size.
* spatial: per iteration, every row left to right then right to left, then every column
  top to bottom then bottom to top; a pixel becomes ``alpha x + (1 - alpha) n``, n the
  neighbour just processed, when both are non-zero and close. In depth: "close" compares
  with n, at most ``delta`` along rows and below it along columns; the result is rounded
  half up; the left-to-right pass skips the last column. In disparity: "close" compares
  with n's value before the pass. Hole filling copies n into a hole along rows only,
  ``2**h - 1`` pixels from each side per pass (all with h = 5); in disparity a row's
  trailing hole is filled from the next row's first pixel (the last row's from whatever
  follows the frame in memory).
* temporal: ``alpha x + (1 - alpha) last`` (truncated in depth), ``last`` the pixel's last
  non-zero output, when they differ by less than ``delta``; otherwise ``x``, which also
  restarts the pixel's validity history. A 0 gets ``last`` when that history (frames
  before this one) holds: 8 of the last 8 valid (mode 1), 2 of 3 (2), 2 of 4 (3), 2 of 8
  (4), 1 of 2 (5), 1 of 5 (6), 1 of 8 (7), always (8); never in mode 0.
* hole filling: in place, row by row: mode 0 copies the left pixel (not in the first
  column); modes 1 and 2 take the largest / smallest non-zero of the up, up-left, left,
  down-left and down pixels (mode 2 keeps 0 when up is 0), from the second row to the last
  but one, from the second column.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import time
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import ArgumentError, CalibrationError, ConfigError

F32 = NDArray[np.float32]

#: The order of the stages, librealsense's recommended one.
STAGES = ('decimation', 'depth_to_disparity', 'spatial', 'temporal', 'disparity_to_depth',
          'hole_filling')
#: Frame rate stamped on the stream; it only spaces the timestamps.
FPS = 30
#: How long to wait for a pushed frame to come back, milliseconds.
TIMEOUT_MS = 2000


@dataclass(frozen=True)
class Camera:
    """The depth camera: image size, pinhole intrinsics in pixels, stereo baseline.

    Attributes:
        width: Image width in pixels.
        height: Image height in pixels.
        fx: Focal length along x, pixels.
        fy: Focal length along y, pixels.
        cx: Principal point x, pixels.
        cy: Principal point y, pixels.
        baseline: Stereo baseline in metres; sets the disparity domain's scale only.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float = 0.05

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise CalibrationError(f'camera size must be positive, got {self.width}x{self.height}')
        for name in ('fx', 'fy', 'cx', 'cy', 'baseline'):
            if not math.isfinite(getattr(self, name)):
                raise CalibrationError(f'camera {name} must be finite, got {getattr(self, name)}')
        if self.fx <= 0 or self.fy <= 0 or self.baseline <= 0:
            raise CalibrationError(f'camera fx, fy and baseline must be positive, got '
                                   f'{self.fx}, {self.fy}, {self.baseline}')


@dataclass(frozen=True)
class RealsenseSettings:
    """Which librealsense filters run and their options (librealsense's ranges and defaults).

    Attributes:
        decimation: Decimation magnitude, 1 (off) to 8.
        spatial: Run the spatial edge-preserving filter.
        spatial_alpha: Its smoothing weight of the current pixel, 0.25 to 1.
        spatial_delta: Its step threshold, 1 to 50 (see the module notes for the units).
        spatial_iterations: Its passes, 1 to 5 (librealsense's ``filter_magnitude``).
        spatial_holes_fill: Its hole filling, 0 (off) to 5 (unlimited).
        temporal: Run the temporal filter.
        temporal_alpha: Its weight of the current frame, 0 to 1.
        temporal_delta: Its step threshold, 1 to 100.
        temporal_persistence: Its persistence mode, 0 (off) to 8 (always).
        hole_filling: Hole-filling mode 0 (from the left), 1 (farthest around), 2 (nearest
            around), or None for off.
        disparity: Run spatial and temporal in the disparity domain.
        depth_units: Metres per depth unit of the Z16 frames.
    """

    decimation: int = 1
    spatial: bool = False
    spatial_alpha: float = 0.5
    spatial_delta: float = 20.0
    spatial_iterations: int = 2
    spatial_holes_fill: int = 0
    temporal: bool = False
    temporal_alpha: float = 0.4
    temporal_delta: float = 20.0
    temporal_persistence: int = 3
    hole_filling: int | None = None
    disparity: bool = False
    depth_units: float = 0.001

    def __post_init__(self) -> None:
        ranges: dict[str, tuple[float, float]] = {
            'decimation': (1, 8),
            'spatial_alpha': (0.25, 1.0), 'spatial_delta': (1, 50),
            'spatial_iterations': (1, 5), 'spatial_holes_fill': (0, 5),
            'temporal_alpha': (0.0, 1.0), 'temporal_delta': (1, 100),
            'temporal_persistence': (0, 8),
        }
        for name, (low, high) in ranges.items():
            value = getattr(self, name)
            if not low <= value <= high:
                raise ConfigError(f'{name} must be in [{low}, {high}], got {value}')
        if self.hole_filling not in (None, 0, 1, 2):
            raise ConfigError(f'hole_filling must be None, 0, 1 or 2, got {self.hole_filling!r}')
        if not 0 < self.depth_units <= 0.01:
            raise ConfigError(f'depth_units must be in (0, 0.01] metres, got {self.depth_units}')


@dataclass(frozen=True)
class Filtered:
    """One frame through the chain.

    Attributes:
        depth: (H', W') float32 depth in metres, NaN where librealsense gives 0; H', W' as
            librealsense reports them (decimation pads, see the module notes).
        seconds: Seconds of each stage's ``process`` call, by stage name, in chain order.
        camera: The output stream's size and intrinsics as librealsense reports them.
    """

    depth: F32
    seconds: dict[str, float]
    camera: Camera


def _preload_libusb() -> None:
    """Load libusb-package's libusb-1.0 (the realsense extra installs it) before
    pyrealsense2, whose native library needs ``libusb-1.0.so.0`` and finds it among the
    libraries already loaded: no system package is needed. Nothing happens without it (a
    system libusb then serves)."""
    try:
        import libusb_package
    except ImportError:
        return
    path = Path(libusb_package.__file__).parent / 'libusb-1.0.so'
    if path.is_file():
        with contextlib.suppress(OSError):
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


def load_pyrealsense() -> ModuleType:
    """Import pyrealsense2, or raise a one-line ConfigError saying how to get it.

    Raises:
        ConfigError: pyrealsense2 is not installed, or its native library cannot load.
    """
    _preload_libusb()
    try:
        import pyrealsense2
    except ModuleNotFoundError as exc:
        if exc.name != 'pyrealsense2':
            raise
        raise ConfigError('pyrealsense2 is not installed: pip install .[realsense] '
                          '(the optional extra for the librealsense comparison)') from None
    except ImportError as exc:
        raise ConfigError(f'pyrealsense2 cannot be loaded ({exc}); it needs libusb-1.0: '
                          f'pip install .[realsense] brings libusb-package') from None
    module: ModuleType = pyrealsense2
    return module


def depth_to_units(depth_m: F32, camera: Camera, depth_units: float) -> NDArray[np.uint16]:
    """Checked conversion of a depth image in metres to Z16 units (0 = unknown).

    Args:
        depth_m: (height, width) float32 depth in metres; NaN, inf and 0 mean unknown.
        camera: The camera, whose size the image must have.
        depth_units: Metres per unit.

    Returns:
        (height, width) uint16, rounded to the nearest unit.

    Raises:
        ArgumentError: Wrong type, dtype or shape, a negative depth, or one beyond Z16.
    """
    if not isinstance(depth_m, np.ndarray) or depth_m.dtype != np.float32:
        raise ArgumentError(f'depth_m must be a float32 array, got '
                            f'{getattr(depth_m, "dtype", type(depth_m).__name__)}')
    if depth_m.shape != (camera.height, camera.width):
        raise ArgumentError(f'depth_m must have the camera shape {(camera.height, camera.width)}, '
                            f'got {depth_m.shape}')
    known = np.isfinite(depth_m)
    values = np.where(known, depth_m, 0.0)
    if (values < 0).any():
        raise ArgumentError(f'depth_m must not be negative, got a minimum of {values.min()}')
    units = np.rint(values / depth_units)
    if (units > np.iinfo(np.uint16).max).any():
        raise ArgumentError(f'depth_m exceeds what Z16 holds at depth_units {depth_units} '
                            f'({65535 * depth_units:g} m): maximum {values.max()}')
    return units.astype(np.uint16)


class RealsenseChain:
    """librealsense's filters on a stream of depth frames (see the module notes).

    Args:
        settings: Which filters run and their options.
        camera: Size and intrinsics of the frames that :meth:`process` takes.

    Raises:
        ConfigError: pyrealsense2 is missing or cannot load.
    """

    def __init__(self, settings: RealsenseSettings, camera: Camera) -> None:
        self.settings = settings
        self.camera = camera
        self._rs = load_pyrealsense()
        self._device, self._sensor, self._profile = _software_sensor(self._rs, settings, camera)
        self._queue = self._rs.frame_queue(1)
        self._sensor.open(self._profile)
        self._sensor.start(self._queue)
        self._filters = _filters(self._rs, settings)
        self._frame_number = 0
        self._open = True

    def process(self, depth_m: F32) -> Filtered:
        """Run one frame through the filters that are on.

        Args:
            depth_m: (height, width) float32 depth in metres; NaN, inf or 0 = unknown.

        Returns:
            The filtered depth, the seconds of each stage and the output intrinsics.

        Raises:
            ArgumentError: ``depth_m`` is not a float32 image of the camera's size, or holds
                depths Z16 cannot (negative, beyond 65535 units).
            ConfigError: The chain was closed.
        """
        if not self._open:
            raise ConfigError('this RealsenseChain was closed; build a new one')
        frame = self._push(depth_to_units(depth_m, self.camera, self.settings.depth_units))
        seconds: dict[str, float] = {}
        for name, stage in self._filters:
            start = time.perf_counter()
            frame = stage.process(frame)
            seconds[name] = time.perf_counter() - start
        units = np.asanyarray(frame.get_data()).astype(np.float32)
        camera = _output_camera(frame, self.camera.baseline)
        del frame
        depth = units * np.float32(self.settings.depth_units)
        depth[units == 0] = np.nan
        return Filtered(depth, seconds, camera)

    def close(self) -> None:
        """Stop and close the software sensor (idempotent)."""
        if self._open:
            self._open = False
            self._sensor.stop()
            self._sensor.close()

    def __enter__(self) -> RealsenseChain:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _push(self, units: NDArray[np.uint16]) -> Any:
        """Inject one Z16 frame (pyrealsense2 copies the pixels) and return it as a frame."""
        self._frame_number += 1
        video = self._rs.software_video_frame()
        video.pixels = units
        video.stride = units.shape[1] * 2
        video.bpp = 2
        video.timestamp = self._frame_number * 1000.0 / FPS
        video.domain = self._rs.timestamp_domain.hardware_clock
        video.frame_number = self._frame_number
        video.profile = self._profile
        video.depth_units = self.settings.depth_units
        self._sensor.on_video_frame(video)
        return self._queue.wait_for_frame(TIMEOUT_MS)


def _software_sensor(rs: Any, settings: RealsenseSettings, camera: Camera) -> tuple[Any, ...]:
    """A software device with one Z16 depth sensor: (device, sensor, video stream profile)."""
    device = rs.software_device()
    sensor = device.add_sensor('Depth')
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = camera.width, camera.height
    intrinsics.fx, intrinsics.fy = camera.fx, camera.fy
    intrinsics.ppx, intrinsics.ppy = camera.cx, camera.cy
    intrinsics.model = rs.distortion.none
    intrinsics.coeffs = [0.0] * 5
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid = rs.stream.depth, 0, 0
    stream.width, stream.height, stream.fps = camera.width, camera.height, FPS
    stream.bpp, stream.fmt, stream.intrinsics = 2, rs.format.z16, intrinsics
    profile = sensor.add_video_stream(stream).as_video_stream_profile()
    sensor.add_read_only_option(rs.option.depth_units, settings.depth_units)
    # millimetres, as a RealSense depth sensor reports it; the disparity transform needs it
    sensor.add_read_only_option(rs.option.stereo_baseline, camera.baseline * 1000.0)
    return device, sensor, profile


def _filters(rs: Any, settings: RealsenseSettings) -> list[tuple[str, Any]]:
    """The filters that are on, as (stage name, filter), in :data:`STAGES` order."""
    s, option = settings, rs.option
    stages: dict[str, Any] = {}
    if s.decimation > 1:
        stages['decimation'] = _configured(rs.decimation_filter(), {
            option.filter_magnitude: s.decimation})
    if s.spatial:
        stages['spatial'] = _configured(rs.spatial_filter(), {
            option.filter_smooth_alpha: s.spatial_alpha,
            option.filter_smooth_delta: s.spatial_delta,
            option.filter_magnitude: s.spatial_iterations,
            option.holes_fill: s.spatial_holes_fill})
    if s.temporal:
        stages['temporal'] = _configured(rs.temporal_filter(), {
            option.filter_smooth_alpha: s.temporal_alpha,
            option.filter_smooth_delta: s.temporal_delta,
            option.holes_fill: s.temporal_persistence})
    if s.disparity and (s.spatial or s.temporal):
        stages['depth_to_disparity'] = rs.disparity_transform(True)
        stages['disparity_to_depth'] = rs.disparity_transform(False)
    if s.hole_filling is not None:
        stages['hole_filling'] = _configured(rs.hole_filling_filter(), {
            option.holes_fill: s.hole_filling})
    return [(name, stages[name]) for name in STAGES if name in stages]


def _configured(block: Any, options: dict[Any, float]) -> Any:
    """``block`` (a librealsense filter) with ``options`` set."""
    for option, value in options.items():
        block.set_option(option, float(value))
    return block


def _output_camera(frame: Any, baseline: float) -> Camera:
    """The size and intrinsics librealsense reports for ``frame``."""
    intr = frame.get_profile().as_video_stream_profile().get_intrinsics()
    return Camera(intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy, baseline)
