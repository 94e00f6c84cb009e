"""`depth-nodes convert`: a bag rewritten the way a camera driver records one.

Field bags rarely hold raw ``sensor_msgs/Image``: drivers publish Bayer mosaics, and
recordings keep image_transport's ``compressed`` topics (JPEG or PNG) under the driver's
own namespace. This turns a bag with raw camera images (any ``.../image_raw`` topic of
type sensor_msgs/Image) into such a bag, every other message copied, so the graph, the
harness and ``eval`` can be checked on what real bags hold, and what the compression costs
can be measured against the raw original (README, "Compressed and Bayer input"):

* ``bayer``: colour images sampled on a Bayer tile (ROS's naming, top-left first), stored
  as ``bayer_<order>8`` / ``16``: what the camera sent before any demosaicing;
* ``codec``: ``jpeg`` (``quality``) or ``png``: the images move to ``<topic>/compressed``
  as sensor_msgs/CompressedImage, in image_transport's format;
* ``namespace``: the first namespace of every topic (``/stereo``) replaced, e.g. by
  ``/camera``;
* ``rename``: below it, names replaced (``left`` -> ``infra1``, ``image_raw`` ->
  ``image_rect_raw``): a driver's layout, as a camera preset (config/cameras) reads it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from depth_nodes.errors import BagError, ConfigError, DepthNodesError
from depth_nodes.graph.description import checked_name, checked_namespace
from depth_nodes.ros.image import array_to_image, image_to_array, to_rgb8
from depth_nodes.ros.transport import compress_image
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.signals import stop_requested

IMAGE = 'sensor_msgs/msg/Image'
BAYER_ORDERS = ('rggb', 'bggr', 'gbrg', 'grbg')


@dataclass(frozen=True)
class ConvertOptions:
    """How to rewrite the bag (see the module notes)."""

    namespace: str | None = None
    codec: str | None = None
    quality: int = 90
    bayer: str | None = None
    #: (old, new) names of topic levels below the first namespace.
    rename: tuple[tuple[str, str], ...] = ()

    def check(self) -> ConvertOptions:
        """Raises ConfigError on values no driver would produce."""
        if self.codec not in (None, 'jpeg', 'png'):
            raise ConfigError(f'--compress must be jpeg or png, got {self.codec!r}')
        if not 1 <= self.quality <= 100:
            raise ConfigError(f'--quality must be in 1..100, got {self.quality}')
        if self.bayer not in (None, *BAYER_ORDERS):
            raise ConfigError(f'--bayer must be one of {", ".join(BAYER_ORDERS)}, got '
                              f'{self.bayer!r}')
        if self.namespace is not None:
            checked_namespace(self.namespace)
        for old, new in self.rename:
            for name in (old, new):
                checked_name(name, '--rename')
                if '/' in name:
                    raise ConfigError(f'--rename {old}={new}: one level of a topic name on '
                                      'each side, e.g. left=infra1')
        if self.codec is None and self.bayer is None and self.namespace is None and \
                not self.rename:
            raise ConfigError('nothing to convert: give --compress, --bayer, --namespace or '
                              '--rename')
        if self.quality != 90 and self.codec != 'jpeg':
            raise ConfigError('--quality applies to --compress jpeg only')
        return self


def mosaic(rgb: np.ndarray, order: str) -> np.ndarray:
    """An (H, W, 3) RGB image sampled on a Bayer tile named top-left first ('rggb': R G /
    G B); H and W even."""
    out = np.empty(rgb.shape[:2], rgb.dtype)
    for i, colour in enumerate(order):
        dy, dx = divmod(i, 2)
        out[dy::2, dx::2] = rgb[dy::2, dx::2, 'rgb'.index(colour)]
    return out


def _renamed(topic: str, namespace: str | None,
             rename: tuple[tuple[str, str], ...] = ()) -> str:
    """``topic`` with its first namespace replaced and the levels below it renamed; a
    topic without a namespace (/tf, /clock, /diagnostics) stays where it is."""
    parts = topic.strip('/').split('/')
    if len(parts) < 2:
        return topic
    names = dict(rename)
    rest = [names.get(p, p) for p in parts[1:]]
    first = parts[0] if namespace is None else namespace.strip('/')
    return '/' + '/'.join(p for p in (first, *rest) if p)


def _camera_image(msg: Any, options: ConvertOptions) -> tuple[str, Any]:
    """(topic suffix, message) of one raw camera image as the driver would record it."""
    pixels, encoding = image_to_array(msg), str(msg.encoding)
    if options.bayer is not None:
        if pixels.ndim != 3:
            raise BagError(f'--bayer needs colour images; this one is {encoding}')
        if pixels.shape[0] % 2 or pixels.shape[1] % 2:
            raise BagError(f'--bayer needs an even image size, not {pixels.shape[1]}x'
                           f'{pixels.shape[0]}')
        if encoding in ('rgb8', 'rgb16'):
            rgb = pixels
        elif encoding == 'bgr16':
            rgb = pixels[:, :, ::-1]
        else:
            rgb = to_rgb8(pixels, encoding)
        encoding = f'bayer_{options.bayer}{16 if rgb.dtype == np.uint16 else 8}'
        pixels = mosaic(np.ascontiguousarray(rgb), options.bayer)
    if options.codec is None:
        return '', array_to_image(pixels, encoding, msg.header)
    return '/compressed', compress_image(pixels, encoding, codec=options.codec,
                                         quality=options.quality, header=msg.header)


def convert_bag(in_bag: str | Path, out_bag: str | Path, options: ConvertOptions, *,
                overwrite: bool = False) -> dict[str, int]:
    """Write ``out_bag`` from ``in_bag`` (see the module notes).

    Returns:
        Messages written per output topic.

    Raises:
        BagError: Unreadable input, existing output, or nothing to convert.
        ConfigError: Invalid options.
    """
    options.check()
    with BagReader(in_bag) as reader:
        cameras = [t for t, kind in reader.topics.items()
                   if kind == IMAGE and t.endswith('/image_raw')]
        if (options.codec or options.bayer) and not cameras:
            raise BagError(f'{in_bag} has no camera images to convert (no sensor_msgs/Image '
                           'topic ending in /image_raw)')
        writer = BagWriter(out_bag, overwrite=overwrite)
        for key, value in reader.custom_data.items():  # e.g. the simulator's settings
            writer.set_custom_data(key, value)
        try:
            with writer:
                for bag_msg in reader.messages():
                    if stop_requested():
                        break
                    topic = _renamed(bag_msg.topic, options.namespace, options.rename)
                    if bag_msg.topic in cameras and (options.codec or options.bayer):
                        suffix, msg = _camera_image(bag_msg.deserialize(), options)
                        writer.write(topic + suffix, msg, bag_msg.timestamp)
                    else:
                        writer.write(topic, bag_msg.data, bag_msg.timestamp, bag_msg.msgtype,
                                     qos=reader.qos.get(bag_msg.topic, ()))
        except DepthNodesError as exc:  # nothing half-written is left behind
            writer.discard()
            where = '' if writer.failed else f'{in_bag}: '  # the output's own error names it
            raise BagError(f'{where}{exc}; {out_bag} not written') from None
        return dict(writer.counts)
