"""convert_metric node: a 16UC1 millimetre depth image -> 32FC1 metres (depth_image_proc's
ConvertMetricNode, same topics and parameter).

Subscribes ``image_raw`` (16UC1 mm, 0 unknown; a 32FC1 image is passed on with its
unknown pixels, zero or not finite, made NaN; ``image_transport`` raw or compressedDepth)
and publishes ``image``: 32FC1 metres, NaN unknown (REP 118), with the input's header.

Outputs are computed only while subscribed (lazy), or always offline.

Frames without output are counted and logged: ``unsupported_encoding`` and the decoding
reasons (``malformed_image``: also a depth image with no pixel).
"""

from __future__ import annotations

from typing import Any

from sensor_msgs.msg import Image

from depth_nodes.nodes.depth_common import DepthImageNode, depth_transport
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.params import NodeParameters

PARAMETERS = [depth_transport('image_transport')]


class ConvertMetricNode(DepthImageNode):
    """``image_raw`` (mm) -> ``image`` (m)."""

    def __init__(self, node_name: str = 'convert_metric', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS)
        self.pub_image = self.add_output(Image, 'image')
        self.add_input(Image, 'image_raw', self.on_frame,
                       transport=self.params.values['image_transport'])

    def on_frame(self, msg: Any) -> None:
        """Convert one depth image (while ``image`` is wanted)."""
        if self.skip_unwanted(self.pub_image.wanted):
            return
        read = self.read_depth(msg, 'image_raw')
        if read is not None:
            self.pub_image.publish(array_to_image(read[0], '32FC1', msg.header))
