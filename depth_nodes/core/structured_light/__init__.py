"""Structured light: pattern sets, decoding, triangulation and single-shot speckle depth.

Arrays only (numpy / OpenCV), no ROS: the public Python API of the structured-light node.
"""

from depth_nodes.core.structured_light.decode import DecodeResult, decode_sequence, wrapped_phase
from depth_nodes.core.structured_light.patterns import (
    AXES,
    MODES,
    Frame,
    PatternSet,
    generate_patterns,
    gray_code,
    gray_to_binary,
    speckle_pattern,
)
from depth_nodes.core.structured_light.speckle import (
    SpeckleMatcher,
    match_speckle,
    shift_range,
    shift_to_depth,
    speckle_depth,
)
from depth_nodes.core.structured_light.triangulate import (
    ProjectorGeometry,
    camera_rays,
    epipolar_distance,
    pixel_rays,
    points_on_rays,
    triangulate_columns,
    triangulate_pixels,
)

__all__ = [
    'AXES',
    'MODES',
    'DecodeResult',
    'Frame',
    'PatternSet',
    'ProjectorGeometry',
    'SpeckleMatcher',
    'camera_rays',
    'decode_sequence',
    'epipolar_distance',
    'generate_patterns',
    'gray_code',
    'gray_to_binary',
    'match_speckle',
    'pixel_rays',
    'points_on_rays',
    'shift_range',
    'shift_to_depth',
    'speckle_depth',
    'speckle_pattern',
    'triangulate_columns',
    'triangulate_pixels',
    'wrapped_phase',
]
