"""Small nodes used to test the bag harness (the package's real nodes land separately)."""

from __future__ import annotations

from typing import Any

import numpy as np
from sensor_msgs.msg import Image

from depth_nodes.errors import MessageError
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.ros.node import DepthNode


class InvertNode(DepthNode):
    """Publishes 255 - image for mono8 images on `image`; drops anything else."""

    def __init__(self, node_name: str = 'invert', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.declare_parameter('offset', 0)
        self.add_input(Image, 'image', self.on_image)
        self.out = self.add_output(Image, 'image_inverted')

    def on_image(self, msg: Image) -> None:
        if msg.encoding != 'mono8':
            self.drop('unsupported_encoding', f'expected mono8, got {msg.encoding}')
            return
        try:
            pixels = image_to_array(msg)
        except MessageError as exc:
            self.drop('malformed_image', str(exc))
            return
        offset = self.get_parameter('offset').value
        inverted = (255 - pixels.astype(np.int32) + offset).clip(0, 255).astype(np.uint8)
        self.out.publish(array_to_image(inverted, 'mono8', msg.header))


class RestoreNode(DepthNode):
    """Inverts `image_inverted` back (tests node-to-node chaining in the harness)."""

    def __init__(self, node_name: str = 'restore', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.add_input(Image, 'image_inverted', self.on_image)
        self.out = self.add_output(Image, 'image_restored')

    def on_image(self, msg: Image) -> None:
        pixels = image_to_array(msg)
        self.out.publish(array_to_image(255 - pixels, 'mono8', msg.header))


class RunningSumNode(DepthNode):
    """Publishes the running sum of the mono8 images on `image` (clipped to 255): every
    output depends on all the frames before it, so the node says ``keeps_state``."""

    keeps_state = True

    def __init__(self, node_name: str = 'running_sum', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.total: np.ndarray | None = None
        self.add_input(Image, 'image', self.on_image)
        self.out = self.add_output(Image, 'image_sum')

    def on_image(self, msg: Image) -> None:
        pixels = image_to_array(msg).astype(np.int64)
        if self.total is None or self.total.shape != pixels.shape:
            self.total = np.zeros_like(pixels)
        self.total += pixels
        self.out.publish(array_to_image(np.minimum(self.total, 255).astype(np.uint8), 'mono8',
                                        msg.header))
