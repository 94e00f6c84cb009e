"""One raw frame to REP 118 depth, amplitude, confidence and flags on the rectified grid
(:class:`ToFDecoder`, :func:`decode_tof`): the phasors, the unwrapping, the masks and the
lens correction (see the package notes)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.rectify import rectification_maps
from depth_nodes.core.tof.flying import remove_flying_pixels
from depth_nodes.core.tof.params import ToFParams, check_frequencies, unambiguous_range
from depth_nodes.core.tof.phase import check_samples, phasors, unwrap
from depth_nodes.errors import ArgumentError

#: Flags of :attr:`ToFResult.flags`.
SATURATED, LOW_AMPLITUDE, FLYING, OUT_OF_RANGE = 1, 2, 4, 8

F32 = NDArray[np.float32]


@dataclass
class ToFResult:
    """One decoded frame, on the rectified grid of the CameraInfo's ``P``.

    Attributes:
        depth: (H, W) float32 Z, metres, NaN where not published.
        amplitude: (H, W) float32 modulation amplitude (the strongest frequency's).
        confidence: (H, W) float32 in [0, 1].
        flags: (H, W) uint8: :data:`SATURATED`, :data:`LOW_AMPLITUDE`, :data:`FLYING`,
            :data:`OUT_OF_RANGE` (bits; 0 where the depth is published or only the
            confidence was too low).
        range_raw: (H, W) float32 range along the rays on the raw grid, before any mask.
    """

    depth: F32
    amplitude: F32
    confidence: F32
    flags: NDArray[np.uint8]
    range_raw: F32


class ToFDecoder:
    """Decodes frames of one camera: keeps the rectification maps of its calibration."""

    def __init__(self) -> None:
        self._key: Any = None
        self._maps: tuple[NDArray[Any], NDArray[Any]] | None = None
        self._ray_norm: F32 | None = None

    def _geometry(self, camera: CameraModel) -> tuple[NDArray[Any], NDArray[Any], F32]:
        key = (camera.width, camera.height, camera.distortion_model,
               *(np.asarray(m, np.float64).tobytes() for m in (camera.K, camera.D, camera.R,
                                                              camera.P)))
        if key != self._key or self._maps is None or self._ray_norm is None:
            map_x, map_y = rectification_maps(camera, fixed_point=False)
            P = camera.binned().projection
            h, w = map_x.shape
            u = (np.arange(w) - P[0, 2]) / P[0, 0]
            v = (np.arange(h) - P[1, 2]) / P[1, 1]
            self._ray_norm = np.sqrt(u[None, :] ** 2 + v[:, None] ** 2 + 1).astype(np.float32)
            self._maps = (map_x, map_y)
            self._key = key
        return self._maps[0], self._maps[1], self._ray_norm

    def decode(self, samples: NDArray[Any], camera: CameraModel, frequencies_mhz: Any,
               params: ToFParams) -> ToFResult:
        """Decode one frame: see :func:`decode_tof`."""
        freqs = check_frequencies(frequencies_mhz)
        params.validate()
        steps = params.phase_steps
        arr = check_samples(samples, len(freqs) * steps)
        model = camera.binned()
        if arr.shape[1:] != (model.height, model.width):
            raise ArgumentError(f'samples are {arr.shape[2]}x{arr.shape[1]} but the camera is '
                                f'{model.width}x{model.height}')
        phase, amplitude, offset, saturated = phasors(arr, len(freqs), steps,
                                                      params.saturation_level)
        range_m, sigma, chi2 = unwrap(phase, amplitude, offset, freqs, steps,
                                      params.electrons_per_count)
        low = (amplitude < params.min_amplitude).all(axis=0)
        flags = np.zeros(range_m.shape, np.uint8)
        flags[saturated] |= SATURATED
        flags[low] |= LOW_AMPLITUDE
        judged = np.where(flags == 0, range_m, np.nan).astype(np.float32)
        flags[remove_flying_pixels(judged, params.flying_pixel_threshold,
                                   params.jump_edge_threshold, sigma)] |= FLYING
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            relative = sigma / (params.noise_reference * range_m)
            agreement = np.exp(-chi2 / (16.0 * max(len(freqs) - 1, 1)))
            confidence = np.where(flags == 0, agreement / (1.0 + relative * relative), 0.0)
        confidence = np.nan_to_num(confidence.astype(np.float32), nan=0.0)
        strongest = amplitude.max(axis=0)
        map_x, map_y, ray_norm = self._geometry(camera)

        def rect(image: NDArray[Any]) -> NDArray[Any]:
            return cv2.remap(image, map_x, map_y, cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)

        r_rect = cv2.remap(range_m, map_x, map_y, cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=float('nan'))
        conf_rect = rect(confidence)
        flags_rect = rect(flags)
        depth = (r_rect / ray_norm).astype(np.float32)
        far = params.depth_max or unambiguous_range(freqs)
        with np.errstate(invalid='ignore'):
            outside = ~((depth >= params.depth_min) & (depth <= far))
        flags_rect[outside & (flags_rect == 0)] |= OUT_OF_RANGE
        keep = (flags_rect == 0) & (conf_rect >= params.min_confidence) & np.isfinite(depth)
        return ToFResult(depth=np.where(keep, depth, np.nan).astype(np.float32),
                         amplitude=rect(strongest), confidence=conf_rect, flags=flags_rect,
                         range_raw=range_m)


def decode_tof(samples: NDArray[Any], camera: CameraModel, frequencies_mhz: Any,
               params: ToFParams | None = None) -> ToFResult:
    """Decode one raw frame into depth, amplitude and confidence on the rectified grid.

    Args:
        samples: (n_freq * phase_steps, H, W) correlation samples, frequency-major.
        camera: The raw camera (its ``K``, ``D``, ``R``, ``P``: the depth is on ``P``'s grid).
        frequencies_mhz: The modulation frequencies, in the order of the planes.
        params: Decoding settings (default :class:`ToFParams`).

    Raises:
        ArgumentError: Samples of the wrong shape, bad frequencies or settings.
    """
    return ToFDecoder().decode(samples, camera, frequencies_mhz, params or ToFParams())
