"""Cross-check node: left-right consistency, speckle removal, hole filling and confidence.

Subscribes ``disparity`` (stereo_msgs/DisparityImage, left view), ``disparity_right``
(DisparityImage in the right view: x_left = x_right + d) and ``cost_ratio``
(sensor_msgs/Image 32FC1, best / second-best aggregated cost of the left winner), the three
outputs of the sgm_stereo node, matched by exact stamp (``approximate_sync`` for the
ApproximateTime policy). Publishes, with the left disparity's header:

* ``disparity_checked``: DisparityImage with the input's ``f``, ``t``, ``min_disparity``,
  ``max_disparity``, ``delta_d`` and ``valid_window``; pixels that fail the left-right
  check or belong to a speckle are invalid (stored below ``min_disparity``), unless
  ``fill_holes`` fills them (``fill_mode``); ``median_size`` smooths the result. A pixel
  whose match lies outside the right image (the matcher extrapolated it) is kept with a
  confidence that falls with the distance (``keep_extrapolated``).
* ``confidence``: 32FC1 in [0, 1], same size and header (:mod:`depth_nodes.core.confidence`):
  pooled cost distinctiveness, left-right agreement, support and smoothness; 0 on invalid
  pixels, low on filled ones. An all-NaN ``cost_ratio`` (the sgm_stereo node running one
  of OpenCV's algorithms, which give no matching cost) leaves the distinctiveness out.

The algorithm lives in :mod:`depth_nodes.core.cross_check`. Parameters (all but the
synchronisation ones change at runtime and apply from the next frame): ``disp12_max_diff``
(0 counts as 1 px, as in OpenCV's StereoSGBM; -1: no left-right check),
``speckle_size``, ``speckle_range``, ``fill_holes``, ``fill_mode``, ``median_size``,
``keep_extrapolated``, ``confidence_window``, ``filled_confidence``, ``confidence_model``
(``handmade`` or ``learned``: the shipped network over the same signals, read once).

Outputs are computed only while subscribed (lazy), or always offline (the check yields
both at once: an output nobody wants is not built).

Frames without output are counted and logged with a reason: ``disparity_encoding`` (a
DisparityImage not 32FC1), ``unsupported_encoding`` (cost_ratio not 32FC1),
``malformed_image``, ``size_mismatch`` (the three inputs differ in size),
``range_mismatch`` (the two views' disparity windows differ), ``no_weights`` (the learned
confidence's weights cannot be read), ``sync_*``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np
from sensor_msgs.msg import Image
from stereo_msgs.msg import DisparityImage

from depth_nodes.core.cross_check import CrossCheckParams, cross_check
from depth_nodes.core.learned.confidence import ConfidenceModel, shipped_confidence
from depth_nodes.core.learned.network import WeightsError
from depth_nodes.errors import MessageError
from depth_nodes.ros.disparity import build_disparity, read_disparity
from depth_nodes.ros.image import array_to_image
from depth_nodes.ros.node import DepthNode
from depth_nodes.ros.params import THREADS, NodeParameters, specs_from, synchroniser_specs
from depth_nodes.ros.workers import use_threads

#: The parameters of the algorithm, declared from CrossCheckParams' settings.
PARAMETER_NAMES = tuple(f.name for f in fields(CrossCheckParams))

PARAMETERS = [
    *synchroniser_specs('the three inputs', qos=False),
    *specs_from(CrossCheckParams, PARAMETER_NAMES),
    THREADS,
]


def _check_values(values: Mapping[str, Any]) -> str | None:
    """A ``confidence_weights`` file that cannot be read is refused with the reason."""
    path = values['confidence_weights']
    if path and values['confidence_model'] == 'learned':
        try:
            ConfidenceModel.load(path)
        except WeightsError as exc:
            return f'confidence_weights: {exc}'
    return None


def _disparity(msg: Any, name: str, node: DepthNode) -> Any:
    if msg.image.encoding != '32FC1':
        node.drop('disparity_encoding', f'{name} image encoding must be 32FC1, got '
                  f'{msg.image.encoding!r}')
        return None
    try:
        return read_disparity(msg)
    except MessageError as exc:
        node.drop('malformed_image', f'{name}: {exc}')
        return None


class CrossCheckNode(DepthNode):
    """Left-right check of SGM's two views; publishes ``disparity_checked`` and
    ``confidence``."""

    def __init__(self, node_name: str = 'cross_check', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.params = NodeParameters(self, PARAMETERS, check_values=_check_values)
        values = self.params.values
        self._models: dict[str, ConfidenceModel] = {}
        self.pub_disparity = self.add_output(DisparityImage, 'disparity_checked')
        self.pub_confidence = self.add_output(Image, 'confidence')
        tolerance = values['approximate_sync_tolerance_seconds']
        self.add_synced_inputs(
            [(DisparityImage, 'disparity'), (DisparityImage, 'disparity_right'),
             (Image, 'cost_ratio')],
            self.on_frame, queue_size=values['queue_size'],
            approximate=values['approximate_sync'], max_interval=tolerance or None)

    def _model(self, path: str) -> ConfidenceModel:
        """The learned confidence of ``confidence_weights`` (read once per path).

        Raises:
            WeightsError: It cannot be read.
        """
        if path not in self._models:
            self._models[path] = ConfidenceModel.load(path) if path else shipped_confidence()
        return self._models[path]

    def on_frame(self, disparity_msg: DisparityImage, right_msg: DisparityImage,
                 cost_msg: Image) -> None:
        """Check one synchronised set and publish ``disparity_checked`` and ``confidence``
        (those wanted)."""
        want_disparity, want_confidence = self.pub_disparity.wanted, self.pub_confidence.wanted
        if self.skip_unwanted(want_disparity, want_confidence):
            return
        values: Mapping[str, Any] = self.params.values
        use_threads(values['threads'])
        left = _disparity(disparity_msg, 'disparity', self)
        if left is None:
            return
        right = _disparity(right_msg, 'disparity_right', self)
        if right is None:
            return
        shape = left.disparity.shape
        if right.disparity.shape != shape:
            self.drop('size_mismatch', f'disparity_right is {right.disparity.shape[1]}x'
                      f'{right.disparity.shape[0]}, disparity {shape[1]}x{shape[0]}')
            return
        if (right.min_disparity, right.max_disparity) != (left.min_disparity,
                                                          left.max_disparity):
            self.drop('range_mismatch', f'disparity_right searched {right.min_disparity:g}..'
                      f'{right.max_disparity:g}, disparity {left.min_disparity:g}..'
                      f'{left.max_disparity:g}')
            return
        cost = self.frame_image(cost_msg, 'cost_ratio', shape, ('32FC1',))
        if cost is None:
            return
        ratio = cost[0]
        if np.isnan(ratio).all():  # no matching cost (OpenCV): leave distinctiveness out
            ratio = np.zeros_like(ratio)
        params = CrossCheckParams(**{name: values[name] for name in PARAMETER_NAMES})
        model = None
        if params.confidence_model == 'learned':
            try:
                model = self._model(params.confidence_weights)
            except WeightsError as exc:
                self.drop('no_weights', str(exc))
                return
        result = cross_check(left.disparity, right.disparity, ratio, **params.arguments(),
                             model=model)
        header = disparity_msg.header
        if want_disparity:
            self.pub_disparity.publish(build_disparity(
                result.disparity, header, focal=left.focal, baseline=left.baseline,
                min_disparity=left.min_disparity, max_disparity=left.max_disparity,
                delta_d=left.delta_d, valid_window=left.valid_window))
        if want_confidence:
            self.pub_confidence.publish(array_to_image(
                np.ascontiguousarray(result.confidence, np.float32), '32FC1', header))
