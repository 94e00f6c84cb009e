"""Depth post-processing for any depth camera (the depth_filter node's core): decimation,
flying pixels, edge-preserving spatial smoothing, motion-compensated temporal smoothing and
hole filling, in librealsense's order, with every filled pixel marked and the per-pixel
standard deviation carried through. No ROS here.
"""

from depth_nodes.core.depth_filter.chain import DepthFilter, FilterResult, warm_up
from depth_nodes.core.depth_filter.noise import NOISE_MODELS, stereo_sigma, tof_sigma
from depth_nodes.core.depth_filter.params import DepthFilterParams

__all__ = ['NOISE_MODELS', 'DepthFilter', 'DepthFilterParams', 'FilterResult',
           'stereo_sigma', 'tof_sigma', 'warm_up']
