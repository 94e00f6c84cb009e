"""What depth_image_proc's nodes here share: their parameters, reading a depth image and
a single camera's CameraInfo, with every failure counted as a drop.

Not a node itself; :mod:`depth_nodes.nodes.point_cloud_xyz`, ``point_cloud_xyzrgb``,
``register_depth``, ``convert_metric`` and ``depth_disparity`` build on :class:`DepthImageNode`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.depth_image import DEPTH_ENCODINGS, to_metres
from depth_nodes.errors import MessageError
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import ParamSpec, one_of
from depth_nodes.ros.transport import decode_image

#: Transports a depth image can arrive by (image_transport's raw and compressedDepth).
DEPTH_TRANSPORTS = ('raw', 'compressedDepth')


def depth_transport(name: str) -> ParamSpec:
    """The transport parameter of a depth input, under depth_image_proc's name for it
    (``depth_image_transport``, or ``image_transport`` where the depth is the only image)."""
    return ParamSpec(name, 'raw', 'How the depth image arrives: raw, or compressedDepth '
                     '(<topic>/compressedDepth, PNG or RVL)', read_only=True,
                     check=one_of(DEPTH_TRANSPORTS))


#: depth_image_proc's synchroniser queue.
QUEUE_SIZE = ParamSpec('queue_size', 5, 'Messages held per input while waiting for their '
                       'partners', 1, 1000, read_only=True)

#: depth_image_proc's ``invalid_depth`` of its point cloud nodes.
INVALID_DEPTH = ParamSpec('invalid_depth', 0.0, 'Depth, metres, given to the points of '
                          'pixels with no depth (0: they are NaN points)', 0.0, 1.0e6)


class DepthImageNode(DepthNode):
    """A DepthNode with helpers for depth images and single-camera CameraInfos."""

    def read_depth(self, msg: Any, what: str) -> tuple[NDArray[np.float32], str] | None:
        """A depth image (raw or compressedDepth) as float32 metres, NaN unknown, with its
        encoding; or None after counting the drop (``unsupported_encoding``: not 16UC1 or
        32FC1; ``malformed_image``: no pixel; the decoding's reasons, see
        :meth:`DepthNode.decoding_failed`)."""
        declared = getattr(msg, 'encoding', None)
        if declared is not None and declared not in DEPTH_ENCODINGS:
            self.drop('unsupported_encoding', f'{what} encoding {declared!r} is not a depth '
                      f'encoding ({" or ".join(DEPTH_ENCODINGS)}, REP 118)')
            return None
        try:
            pixels, encoding = decode_image(msg)
        except MessageError as exc:
            self.decoding_failed(exc, what)
            return None
        if encoding not in DEPTH_ENCODINGS or pixels.ndim != 2:
            self.drop('unsupported_encoding', f'{what} encoding {encoding!r} is not a depth '
                      f'encoding ({" or ".join(DEPTH_ENCODINGS)}, REP 118)')
            return None
        if not self.has_pixels(pixels, what):
            return None
        return to_metres(pixels, encoding), encoding

    def has_pixels(self, pixels: NDArray[Any], what: str) -> bool:
        """True for an image with at least one pixel; else False after counting the drop
        (``malformed_image``): an image 0 pixels wide or high gives no output, never an
        empty one."""
        if pixels.shape[0] and pixels.shape[1]:
            return True
        self.drop('malformed_image', f'{what} is empty ({pixels.shape[1]}x{pixels.shape[0]})')
        return False

    def camera_model(self, info: Any, what: str) -> CameraModel:
        """The validated camera model of a CameraInfo (built again only when its content
        changes): :meth:`FrameReader.camera_model
        <depth_nodes.ros.frames.FrameReader.camera_model>`.

        Raises:
            UncalibratedError: K and P all zero.
            CalibrationError: Anything else unusable.
        """
        return self.frame_reader.camera_model(info, what)
