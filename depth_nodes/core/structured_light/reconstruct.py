"""Captured sequence -> depth: decode, triangulate, keep depths in range."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.structured_light.decode import DecodeResult, decode_sequence
from depth_nodes.core.structured_light.patterns import PatternSet
from depth_nodes.core.structured_light.triangulate import (
    ProjectorGeometry,
    camera_rays,
    epipolar_distance,
    triangulate_columns,
    triangulate_pixels,
)
from depth_nodes.errors import ConfigError

F32 = NDArray[np.float32]


@dataclass
class Reconstruction:
    """Depth (metres, NaN unknown), confidence in [0, 1], the decoded coordinates and how
    many decoded pixels the epipolar check rejected (0 with columns only)."""

    depth: F32
    confidence: F32
    decoded: DecodeResult
    epipolar_rejected: int = 0


def reconstruct(images: NDArray[np.generic], pattern_set: PatternSet,
                geometry: ProjectorGeometry, *, rays: NDArray[np.float64] | None = None,
                shadow_threshold: float = 12.0, min_modulation: float = 4.0,
                depth_min: float = 0.1, depth_max: float = 10.0,
                epipolar_tolerance: float = 0.0) -> Reconstruction:
    """Decode ``images`` and triangulate: ray-plane when only columns are coded, ray-ray
    when rows are too (and then, with ``epipolar_tolerance``, codes farther than that many
    projector pixels from their camera pixel's epipolar line are rejected: see
    :func:`~depth_nodes.core.structured_light.triangulate.epipolar_distance`).

    Args:
        images: (F, H, W) grey frames in the order of ``pattern_set.frames``.
        pattern_set: The projected set (its size must be the projector's).
        geometry: Camera and projector calibration.
        rays: Cached :func:`camera_rays` of ``geometry.camera`` (computed when None).
        shadow_threshold: See :func:`decode_sequence`.
        min_modulation: See :func:`decode_sequence`.
        depth_min: Depths below this (metres) become NaN.
        depth_max: Depths above this become NaN.
        epipolar_tolerance: Projector pixels; 0 turns the check off.

    Raises:
        ConfigError: Frames, pattern set and calibration sizes disagree.
        CalibrationError: Columns only with a distorted projector.
    """
    cam, proj = geometry.camera, geometry.projector
    if (pattern_set.width, pattern_set.height) != (proj.width, proj.height):
        raise ConfigError(f'pattern set is {pattern_set.width}x{pattern_set.height} but the '
                          f'projector is {proj.width}x{proj.height}')
    if np.shape(images)[1:] != (cam.height, cam.width):
        raise ConfigError(f'images are {np.shape(images)[1:]} (H, W) but the camera is '
                          f'{cam.width}x{cam.height}')
    decoded = decode_sequence(images, pattern_set, shadow_threshold=shadow_threshold,
                              min_modulation=min_modulation)
    rays = camera_rays(cam) if rays is None else rays
    rejected = 0
    if decoded.v is None:
        depth = triangulate_columns(rays, decoded.u, geometry)
    else:
        depth = triangulate_pixels(rays, decoded.u, decoded.v, geometry)
        if epipolar_tolerance > 0:
            with np.errstate(invalid='ignore'):
                off = epipolar_distance(rays, decoded.u, decoded.v, geometry) > \
                    epipolar_tolerance
            rejected = int(off.sum())
            depth[off] = np.nan
    with np.errstate(invalid='ignore'):
        depth[(depth < depth_min) | (depth > depth_max)] = np.nan
    confidence = np.where(np.isfinite(depth), decoded.confidence, 0).astype(np.float32)
    return Reconstruction(depth, confidence, decoded, rejected)
