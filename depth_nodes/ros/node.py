"""The base class of every depth_nodes node, composed of small parts.

It adds to ``rclpy.node.Node`` what every node here shares (the offline bag harness relies
on the first three):

* inputs and outputs are declared through :meth:`DepthNode.add_input` and
  :meth:`DepthNode.add_output`, so a harness can see which topics a node consumes and can
  route its published messages directly (no DDS) while the live path is unchanged
  (:mod:`~depth_nodes.ros.inputs`, :mod:`~depth_nodes.ros.outputs`);
* QoS follows REP 2003 (sensor-data subscriptions, reliable publishers) and both can be
  overridden with ``qos_overrides`` parameters;
* a frame that produces no output is never lost silently: :meth:`DepthNode.drop` counts it
  by reason and logs a throttled warning naming the reason; an exception a callback did
  not expect is counted as an ``internal_error`` drop (:mod:`~depth_nodes.ros.accounting`);
* every input message is counted and its stamp checked; stamps that jump back by
  :data:`~depth_nodes.core.stamps.STAMP_RESET_S` or more (a looping bag) start the inputs
  over and call :meth:`DepthNode.on_time_jump`;
* camera poses come through :meth:`DepthNode.add_pose_input` (odometry, PoseStamped or tf,
  the frames waiting for them, their drops and time jumps: :mod:`~depth_nodes.ros.poses`),
  transforms between frames through :meth:`DepthNode.add_tf_input`; a node never
  subscribes to poses itself;
* outputs are lazy, as image_pipeline's nodes: a node computes an output only while it is
  :attr:`Output.wanted <depth_nodes.ros.outputs.Output.wanted>` (subscribed, or always
  offline); a frame no output wants is skipped (:meth:`DepthNode.skip_unwanted`), counted
  in the diagnostics, not as a drop;
* every ``diagnostics_period`` seconds the node publishes a diagnostic_msgs/DiagnosticArray
  on ``/diagnostics`` (:mod:`~depth_nodes.ros.diagnostics`);
* ``frame_id`` (empty by default) replaces the frame of every output's header, for a
  driver whose frame names do not fit the robot's TF tree.

Hooks for a node with state of its own: :meth:`DepthNode.on_time_jump`,
:meth:`DepthNode.holds_input`, :meth:`DepthNode.finish_stream` and
:attr:`DepthNode.keeps_state`.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.qos_overriding_options import QoSOverridingOptions

from depth_nodes.core.camera import StereoModel
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.stamps import STAMP_RESET_S
from depth_nodes.errors import MessageError
from depth_nodes.ros.accounting import Accounting
from depth_nodes.ros.diagnostics import DIAGNOSTICS_TOPIC, node_status
from depth_nodes.ros.frames import FrameReader
from depth_nodes.ros.inputs import InputSet, InputSpec, Synchronizer
from depth_nodes.ros.outputs import PUBLISHER_DEPTH, Output, Sink
from depth_nodes.ros.poses import PoseInput, TfInput
from depth_nodes.ros.run import run_node

T = TypeVar('T')

__all__ = ['DIAGNOSTICS_TOPIC', 'PUBLISHER_DEPTH', 'STAMP_RESET_S', 'DepthNode', 'InputSpec',
           'Output', 'Sink', 'run_node']


class DepthNode(Node):
    """Base class: declared inputs/outputs, REP 2003 QoS, counted drops, lazy outputs.

    Args:
        node_name: Default node name (remappable with ``__node``).
        **kwargs: Passed to ``rclpy.node.Node`` (namespace, context, parameter_overrides,
            cli_args, ...).
    """

    #: True for a node whose output depends on frames before the current one beyond what
    #: :meth:`holds_input` reports (a temporal filter): such a node cannot be split across
    #: ``depth-nodes process --workers``, which hands each worker a segment of the bag.
    keeps_state: bool = False

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        #: The offline harness's sink: installed, every output goes to it, not to DDS.
        self.sink: Sink | None = None
        self.accounting = Accounting(lambda: self.get_logger(), lambda: self.stopping)
        self.input_set = InputSet(self, self.accounting, self._inputs_restarted)
        self.pose_inputs: list[PoseInput[Any]] = []
        self.frame_reader = FrameReader(self)
        self.inputs: list[InputSpec] = self.input_set.specs
        self.outputs: dict[str, Output] = {}
        #: Frames dropped since the start, by reason.
        self.drops: Counter[str] = self.accounting.drops
        #: Messages received since the start, by resolved input topic.
        self.received: Counter[str] = self.accounting.received
        period = self.declare_parameter(
            'diagnostics_period', 1.0, ParameterDescriptor(
                description=f'Seconds between two DiagnosticArray messages on '
                            f'{DIAGNOSTICS_TOPIC} (0 disables them)',
                read_only=True,
                floating_point_range=[FloatingPointRange(from_value=0.0, to_value=3600.0,
                                                         step=0.0)])).value
        self.frame_override: str = self.declare_parameter(
            'frame_id', '', ParameterDescriptor(
                description='Frame of every output\'s header (empty: the input\'s frame, '
                            'as the camera driver set it)', read_only=True)).value
        self._diagnostics_pub = None
        if period > 0:
            self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                                          PUBLISHER_DEPTH)
            self.create_timer(period, lambda: self.guarded(self.publish_diagnostics,
                                                           where='the diagnostics timer'))

    # ------------------------------------------------------------------ inputs, outputs

    def add_input(self, msg_type: type, topic: str, callback: Callable[[Any], None], *,
                  qos: QoSProfile | int | None = None, check_stamps: bool = True,
                  transport: str = 'raw') -> str:
        """Subscribe ``callback`` to ``topic`` with sensor-data QoS unless told otherwise.

        An Image input with another ``transport`` (``compressed``, ``compressedDepth``:
        the node's ``image_transport`` parameter) subscribes to a
        sensor_msgs/CompressedImage on ``<topic>/<transport>`` instead, as image_transport
        does; the callback gets the CompressedImage (decode it with :meth:`frame_image` or
        :meth:`gray_image`).

        Every message is counted. With ``check_stamps`` (the default; off for inputs where
        only the latest value matters, such as a fixed calibration), a message whose header
        stamp is not newer than the last on this topic is dropped (``stamp_out_of_order``)
        before ``callback`` sees it, unless it is :data:`STAMP_RESET_S` or more older (the
        node then starts over and calls :meth:`on_time_jump`). The time spent in
        ``callback`` when it publishes is the frame's processing time in the diagnostics.

        Returns:
            The fully resolved topic name (after namespace and remapping).
        """
        return self.input_set.add(msg_type, topic, callback, qos=qos,
                                  check_stamps=check_stamps, transport=transport)

    def add_synced_inputs(self, inputs: Sequence[tuple[Any, ...]],
                          callback: Callable[..., None], *, queue_size: int,
                          approximate: bool = False, max_interval: float | None = None,
                          qos: QoSProfile | int | None = None) -> Synchronizer:
        """Subscribe to several topics and call ``callback(*msgs)`` for each matched set.

        Matching is by header stamp, exact or (``approximate``) by the ApproximateTime
        policy; ``qos`` as :meth:`add_input`'s (default sensor data). An entry
        ``(Image, topic, transport)`` subscribes that image through a
        transport (see :meth:`add_input`). Messages the synchroniser discards are counted
        as drops with the reason ``sync_<why>`` (``sync_unmatched``, ``sync_queue_full``,
        ...), so an image that never found its camera_info is not lost silently.
        """
        return self.input_set.add_synced(inputs, callback, queue_size=queue_size,
                                         approximate=approximate, max_interval=max_interval,
                                         qos=qos)

    def add_output(self, msg_type: type, topic: str, *,
                   qos: QoSProfile | int | None = None) -> Output:
        """Create a reliable publisher on ``topic`` (depth :data:`PUBLISHER_DEPTH`)."""
        pub = self.create_publisher(
            msg_type,
            topic,
            qos if qos is not None else PUBLISHER_DEPTH,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        out = Output(self, pub)
        self.outputs[out.topic] = out
        return out

    def add_pose_input(self, process: Callable[[T, Pose | None], None], *,
                       allow_none: bool, default_source: str = 'odometry') -> PoseInput[T]:
        """The camera's poses: declares the pose parameters (``pose_source``,
        ``pose_tolerance``, ...), subscribes to the source, and calls ``process(item, pose)``
        for each frame handed to :meth:`PoseInput.submit <depth_nodes.ros.poses.PoseInput.submit>`
        once its pose is known, in stamp order (``pose`` None with ``pose_source: none``).
        Frames without a pose are counted drops; the waiting frames are dropped on a time
        jump and at the end of the stream, and forgotten while nobody listens
        (:meth:`PoseInput.clear <depth_nodes.ros.poses.PoseInput.clear>`).

        Raises:
            ConfigError: A start-up value refused, or ``pose_source: tf`` without tf2_msgs.
        """
        poses: PoseInput[T] = PoseInput(self, process, allow_none=allow_none,
                                        default_source=default_source)
        self.pose_inputs.append(poses)
        return poses

    def add_tf_input(self) -> TfInput:
        """``/tf`` and ``/tf_static`` in a transform tree (look up the transform between two
        frames with :meth:`TfInput.lookup <depth_nodes.ros.poses.TfInput.lookup>`).

        Raises:
            ConfigError: tf2_msgs is not installed (the PyPI wheels have none).
        """
        return TfInput(self)

    @property
    def callback_is_frame_time(self) -> bool:
        """The time a callback spends when it publishes is the frame's processing time. A
        node that publishes from worker threads sets this False and calls
        :meth:`record_frame_time` itself."""
        return self.input_set.callback_is_frame_time

    @callback_is_frame_time.setter
    def callback_is_frame_time(self, value: bool) -> None:
        self.input_set.callback_is_frame_time = value

    def skip_unwanted(self, *wanted: bool) -> bool:
        """True when none of ``wanted`` (the node's :attr:`Output.wanted`, read once per
        frame before the work) is set: the frame is then counted as skipped (no subscriber;
        not a drop, no warning) and the caller returns without computing it."""
        if any(wanted):
            return False
        self.accounting.skip()
        return True

    # ------------------------------------------------------------------ hooks

    def _inputs_restarted(self, stamp: int | None) -> None:
        for poses in self.pose_inputs:
            poses.on_time_jump(stamp)
        self.on_time_jump()

    def on_time_jump(self) -> None:
        """Hook: an input's stamps jumped back by :data:`STAMP_RESET_S` or more (a looping
        bag, a restarted driver), or a pose input's did. Called after the base class has
        forgotten its stamp history, emptied its synchronisers and dropped the frames
        waiting for a pose; a node with state of its own (a temporal filter) resets it
        here. The default does nothing."""

    def holds_input(self) -> bool:
        """Hook: True while a message waits for its partners (in a synchroniser, or in a
        node's own state). `process` on several workers hands a segment over only where no
        node holds anything. A node with state of its own extends it, calling super()."""
        return self.input_set.holds() or any(len(poses) for poses in self.pose_inputs)

    def finish_stream(self) -> None:
        """Hook: the input stream ended (the offline harness calls this after the last
        message): count what the node still holds, which no later message can complete, as
        ``stream_ended`` drops. A node with state of its own extends it, calling super()."""
        self.input_set.finish()
        for poses in self.pose_inputs:
            poses.discard('stream_ended', 'when the stream ended')

    # ------------------------------------------------------------------ accounting

    def drop(self, reason: str, detail: str, count: int = 1) -> None:
        """Count frames that produced no output, and log why (throttled per reason).

        Args:
            reason: A short stable key, e.g. ``size_mismatch``; the counter's key.
            detail: The human-readable explanation, e.g. the sizes that disagreed.
            count: How many frames were lost for this reason at once.
        """
        self.accounting.drop(reason, detail, count)

    def internal_error(self, exc: BaseException, where: str) -> None:
        """Count an unexpected exception as an ``internal_error`` drop; log its traceback
        the first time this type of exception happens at ``where``."""
        self.accounting.internal_error(exc, where)

    def guarded(self, callback: Callable[..., None], *args: Any, where: str) -> None:
        """Run ``callback(*args)``; an exception it did not expect becomes a counted
        ``internal_error`` drop (its traceback logged once per exception type and place)
        instead of ending the node. Used for every input callback and timer."""
        self.accounting.guarded(callback, *args, where=where)

    def record_frame_time(self, seconds: float) -> None:
        """Add one frame's processing time to the diagnostics (any thread)."""
        self.accounting.record_frame_time(seconds)

    @property
    def stopping(self) -> bool:
        """True once the node's context is shut down (Ctrl-C, SIGTERM): a frame still in
        flight then cannot be published, which is the end of the run, not an error."""
        return not self.context.ok()

    # ------------------------------------------------------------------ reading frames

    def frame_image(self, msg: Any, what: str, shape: tuple[int, ...],
                    encodings: tuple[str, ...], *, camera: bool = False) -> Any:
        """``(pixels, encoding)`` of an input image that must fit the frame, or None after
        counting the drop: see :meth:`FrameReader.frame_image
        <depth_nodes.ros.frames.FrameReader.frame_image>`."""
        return self.frame_reader.frame_image(msg, what, shape, encodings, camera=camera)

    def decoding_failed(self, exc: MessageError, what: str) -> None:
        """Count an image that could not be read: ``unsupported_format`` (a compressed
        format or transport not known), ``unsupported_encoding``, ``decode_failed`` (damaged
        compressed data) or ``malformed_image`` (fields that disagree, odd Bayer sizes)."""
        self.frame_reader.decoding_failed(exc, what)

    def gray_image(self, msg: Any, what: str) -> Any:
        """A camera image (raw or compressed, any camera encoding) as one grey channel, or
        None after counting the drop (see :meth:`decoding_failed`)."""
        return self.frame_reader.gray_image(msg, what)

    def camera(self, info: Any, what: str,
               shape: tuple[int, int] | None = None) -> Intrinsics | None:
        """The intrinsics a CameraInfo gives an image of ``shape``, or None after counting
        the drop: see :meth:`FrameReader.camera <depth_nodes.ros.frames.FrameReader.camera>`."""
        return self.frame_reader.camera(info, what, shape)

    def stereo_model(self, left_info: Any, right_info: Any) -> StereoModel | None:
        """The stereo geometry of a CameraInfo pair (converted again only when one changes),
        or None after counting the drop: ``uncalibrated`` (a K all zero) or
        ``bad_calibration`` (anything else unusable)."""
        return self.frame_reader.stereo_model(left_info, right_info)

    # ------------------------------------------------------------------ diagnostics

    def diagnostics(self) -> DiagnosticStatus:
        """The node's status since the last call (which starts a new period): see
        :func:`~depth_nodes.ros.diagnostics.node_status`."""
        now = time.monotonic()
        window, drops, published = self.accounting.new_window(now)
        return node_status(self.get_fully_qualified_name(), window, now,
                           inputs=[spec.topic for spec in self.inputs],
                           received=self.received, outputs=list(self.outputs),
                           published=published, drops=drops)

    def publish_diagnostics(self) -> None:
        """Publish :meth:`diagnostics` on ``/diagnostics`` (the timer's callback)."""
        if self._diagnostics_pub is None:
            return
        array = DiagnosticArray(status=[self.diagnostics()])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(array)
