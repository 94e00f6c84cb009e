"""The base class of every depth_nodes node.

It adds to ``rclpy.node.Node`` what every node here shares (the offline bag harness relies
on the first three):

* inputs and outputs are declared through :meth:`DepthNode.add_input` and
  :meth:`DepthNode.add_output`, so a harness can see which topics a node consumes and can
  route its published messages directly (no DDS) while the live path is unchanged;
* QoS follows REP 2003 (sensor-data subscriptions, reliable publishers) and both can be
  overridden with ``qos_overrides`` parameters;
* a frame that produces no output is never lost silently: :meth:`DepthNode.drop` counts it
  by reason and logs a throttled warning naming the reason;
* no message can stop a node: an exception a callback did not expect is counted as an
  ``internal_error`` drop, its traceback logged once per kind, and the node goes on;
* every input message is counted and its stamp checked (a stamp with ``nanosec`` of 1e9
  or more is dropped as ``bad_stamp``; a message not newer than the last one on its topic
  as ``stamp_out_of_order``, unless the stamps jumped back by :data:`STAMP_RESET_S` or
  more, as when a bag loops, which starts the topic over);
* every ``diagnostics_period`` seconds the node publishes a diagnostic_msgs/DiagnosticArray
  on ``/diagnostics``: input and output rates, processing time per frame, drops by reason;
* ``frame_id`` (empty by default) replaces the frame of every output's header, for a
  driver whose frame names do not fit the robot's TF tree.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.utilities import ok, try_shutdown
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from depth_nodes.core.camera import StereoModel
from depth_nodes.errors import (
    CalibrationError,
    DecodeError,
    DepthNodesError,
    EncodingError,
    MessageError,
    UncalibratedError,
    UnsupportedFormatError,
)
from depth_nodes.ros.camera_info import StereoInfoCache
from depth_nodes.ros.dds import use_large_message_profile
from depth_nodes.ros.image import CAMERA_ENCODINGS
from depth_nodes.ros.memory import keep_freed_memory
from depth_nodes.ros.sync import ApproximateTimeSynchronizer, ExactTimeSynchronizer
from depth_nodes.ros.transport import (
    decode_image,
    gray_image,
    image_pixels,
    transport_topic,
    transport_type,
)

#: Publishers keep this many messages by default (reliable, volatile).
PUBLISHER_DEPTH = 10
#: Seconds between two warnings for the same drop reason.
DROP_LOG_PERIOD_S = 5.0
#: A stamp this many seconds or more older than the last one on its topic starts the topic
#: over (a looping bag, a restarted driver) instead of being dropped as out of order.
STAMP_RESET_S = 1.0
#: Topic of the diagnostics every node publishes (the diagnostic_aggregator's input).
DIAGNOSTICS_TOPIC = '/diagnostics'
NS_PER_S = 1_000_000_000

Sink = Callable[[str, Any], None]


@dataclass(frozen=True)
class InputSpec:
    """One subscription: fully resolved topic, message class and callback."""

    topic: str
    msg_type: type
    callback: Callable[[Any], None]


@dataclass
class _Window:
    """Counts of one diagnostics period (reset when it is published)."""

    start: float
    inputs: Counter[str] = field(default_factory=Counter)
    outputs: Counter[str] = field(default_factory=Counter)
    drops: Counter[str] = field(default_factory=Counter)
    frame_times: list[float] = field(default_factory=list)


def _set_frame(msg: Any, frame: str) -> None:
    for holder in (msg, getattr(msg, 'image', None)):
        header = getattr(holder, 'header', None)
        if holder is not None and header is not None:
            holder.header = Header(stamp=header.stamp, frame_id=frame)


class Output:
    """A publisher that the offline harness can redirect.

    Live, :meth:`publish` publishes over DDS; with a sink installed on its node (the bag
    harness does that) the message goes to the sink instead.
    """

    def __init__(self, node: DepthNode, publisher: Any) -> None:
        self._node = node
        self._publisher = publisher
        self.topic: str = publisher.topic_name
        self.count = 0

    def publish(self, msg: Any) -> None:
        """Publish ``msg`` (or hand it to the harness sink); callable from any thread. With
        the node's ``frame_id`` parameter set, the message's header (and a DisparityImage's
        image header) get that frame, on a copy: the input's header is left alone."""
        if self._node.stopping:  # the run is over: nothing can be sent any more
            return
        frame = self._node.frame_override
        if frame:
            _set_frame(msg, frame)
        with self._node._counting:
            self.count += 1
            self._node._window.outputs[self.topic] += 1
        sink = self._node.sink
        if sink is None:
            self._publisher.publish(msg)
        else:
            sink(self.topic, msg)

    @property
    def qos_profile(self) -> QoSProfile:
        """The publisher's QoS (after ``qos_overrides``)."""
        return self._publisher.qos_profile  # type: ignore[no-any-return]


class DepthNode(Node):
    """Base class: declared inputs/outputs, REP 2003 QoS, counted drops.

    Args:
        node_name: Default node name (remappable with ``__node``).
        **kwargs: Passed to ``rclpy.node.Node`` (namespace, context, parameter_overrides,
            cli_args, ...).
    """

    #: The node reads images straight from a camera driver (its ``image_transport`` is
    #: the driver's): the launch files' ``image_transport`` argument sets it.
    reads_camera_images = False

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.inputs: list[InputSpec] = []
        self.outputs: dict[str, Output] = {}
        self.drops: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self.sink: Sink | None = None
        self._last_drop_log: dict[str, float] = {}
        self._logged_errors: set[tuple[str, str]] = set()
        self._last_stamp: dict[str, int] = {}
        self._syncs: list[tuple[Any, Counter[str]]] = []
        self._stereo_cache: StereoInfoCache | None = None
        self._window = _Window(time.monotonic())
        # counters may be touched by worker threads (see ros/workers.py) as well
        self._counting = threading.Lock()
        #: The time a callback spends when it publishes is the frame's processing time.
        #: A node that publishes from worker threads sets this False and calls
        #: :meth:`record_frame_time` itself.
        self.callback_is_frame_time = True
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

    def add_input(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], None],
        *,
        qos: QoSProfile | int | None = None,
        check_stamps: bool = True,
        transport: str = 'raw',
    ) -> str:
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
        node then starts over: see :meth:`_start_over`). The time spent in
        ``callback`` when it publishes is the frame's processing time in the diagnostics.

        Returns:
            The fully resolved topic name (after namespace and remapping).
        """
        resolved = self.resolve_topic_name(topic)
        if transport != 'raw' and msg_type is Image:
            msg_type = transport_type(transport)
            resolved = topic = transport_topic(resolved, transport)

        def on_message(msg: Any) -> None:
            self.received[resolved] += 1
            self._window.inputs[resolved] += 1
            if not self._stamp_valid(resolved, msg):
                return
            if check_stamps and not self._stamp_in_order(resolved, msg):
                return
            if not self.callback_is_frame_time:  # workers may be publishing meanwhile
                self.guarded(callback, msg, where=resolved)
                return
            published = sum(self._window.outputs.values())
            start = time.perf_counter()
            self.guarded(callback, msg, where=resolved)
            if sum(self._window.outputs.values()) > published:
                self.record_frame_time(time.perf_counter() - start)

        sub = self.create_subscription(
            msg_type,
            topic,
            on_message,
            qos if qos is not None else qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self.inputs.append(InputSpec(sub.topic_name, msg_type, on_message))
        return str(sub.topic_name)

    def record_frame_time(self, seconds: float) -> None:
        """Add one frame's processing time to the diagnostics (any thread)."""
        with self._counting:
            self._window.frame_times.append(seconds)

    def guarded(self, callback: Callable[..., None], *args: Any, where: str) -> None:
        """Run ``callback(*args)``; an exception it did not expect becomes a counted
        ``internal_error`` drop (its traceback logged once per exception type and place)
        instead of ending the node. Used for every input callback and timer."""
        try:
            callback(*args)
        except Exception as exc:  # the last line of defence: the node must go on
            if self.stopping:  # a publish after Ctrl-C / SIGTERM shut the context down
                return
            self.internal_error(exc, where)

    @property
    def stopping(self) -> bool:
        """True once the node's context is shut down (Ctrl-C, SIGTERM): a frame still in
        flight then cannot be published, which is the end of the run, not an error."""
        return not self.context.ok()

    def internal_error(self, exc: BaseException, where: str) -> None:
        """Count an unexpected exception as an ``internal_error`` drop; log its traceback
        the first time this type of exception happens at ``where``."""
        key = (where, type(exc).__name__)
        with self._counting:
            first = key not in self._logged_errors
            self._logged_errors.add(key)
        if first:
            self.get_logger().error(
                f'unexpected {type(exc).__name__} handling {where}; the frame is dropped and '
                f'the node goes on (logged once per kind):\n'
                + ''.join(traceback.format_exception(exc)).rstrip())
        self.drop('internal_error', f'{where}: {type(exc).__name__}: {exc}')

    def _stamp_valid(self, topic: str, msg: Any) -> bool:
        """False (after counting a ``bad_stamp`` drop) for a header stamp that is not a
        time: ``nanosec`` must be below 1e9 (builtin_interfaces/Time)."""
        header = getattr(msg, 'header', None)
        stamp = getattr(header, 'stamp', None) if header is not None else getattr(
            msg, 'stamp', None)  # std_msgs/Header itself
        if stamp is None:
            return True
        if not 0 <= stamp.nanosec < NS_PER_S:
            self.drop('bad_stamp', f'{topic}: stamp nanosec {stamp.nanosec} is not below 1e9 '
                      f'(sec {stamp.sec}): not a valid time')
            return False
        return True

    def _stamp_in_order(self, topic: str, msg: Any) -> bool:
        header = getattr(msg, 'header', None)
        if header is None:
            return True
        stamp = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
        last = self._last_stamp.get(topic)
        self._last_stamp[topic] = stamp if last is None else max(stamp, last)
        if last is None or stamp > last:
            return True
        if last - stamp >= STAMP_RESET_S * 1e9:
            self.get_logger().info(f'{topic}: stamps jumped back by {(last - stamp) / 1e9:.3f} '
                                   's (a looping bag or a restarted source): starting over')
            self._start_over()
            self._last_stamp[topic] = stamp
            return True
        self.drop('stamp_out_of_order', f'{topic}: stamp {stamp / 1e9:.9f} s is not newer '
                  f'than the last one, {last / 1e9:.9f} s')
        return False

    def add_output(
        self, msg_type: type, topic: str, *, qos: QoSProfile | int | None = None
    ) -> Output:
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

    def add_synced_inputs(
        self,
        inputs: Sequence[tuple[Any, ...]],
        callback: Callable[..., None],
        *,
        queue_size: int,
        approximate: bool = False,
        max_interval: float | None = None,
        qos: QoSProfile | int | None = None,
    ) -> ExactTimeSynchronizer | ApproximateTimeSynchronizer:
        """Subscribe to several topics and call ``callback(*msgs)`` for each matched set.

        Matching is by header stamp, exact or (``approximate``) by the ApproximateTime
        policy; ``qos`` as :meth:`add_input`'s (default sensor data). An entry
        ``(Image, topic, transport)`` subscribes that image through a
        transport (see :meth:`add_input`). Messages the synchroniser discards are counted
        as drops with the reason ``sync_<why>`` (``sync_unmatched``, ``sync_queue_full``,
        ...), so an image that never found its camera_info is not lost silently.
        """
        if approximate:
            sync: ExactTimeSynchronizer | ApproximateTimeSynchronizer = (
                ApproximateTimeSynchronizer(len(inputs), callback, queue_size=queue_size,
                                            max_interval=max_interval))
        else:
            sync = ExactTimeSynchronizer(len(inputs), callback, queue_size=queue_size)
        seen: Counter[str] = Counter()
        topics: list[str] = []
        self._syncs.append((sync, seen))

        def feed(index: int) -> Callable[[Any], None]:
            def on_message(msg: Any) -> None:
                try:
                    sync.add(index, msg)
                finally:  # also when the set's callback raised: the losses stand
                    for why, count in list(sync.lost_frames.items()):
                        if count > seen[why]:
                            self.drop(f'sync_{why}', f'{count - seen[why]} frame(s) of '
                                      f'{", ".join(topics)} could not be matched by stamp '
                                      f'({why})', count=count - seen[why])
                            seen[why] = count
            return on_message

        for index, (msg_type, topic, *transport) in enumerate(inputs):
            topics.append(self.add_input(msg_type, topic, feed(index), qos=qos,
                                         transport=transport[0] if transport else 'raw'))
        return sync

    def _start_over(self) -> None:
        """Forget every input's stamp history and what the synchronisers hold (counted as
        ``time_jump`` drops), so the inputs can be matched again from the new stamps on."""
        self._last_stamp.clear()
        for sync, seen in self._syncs:
            if sync.queued_frames:
                self.drop('time_jump', f'{sync.queued_frames} frame(s) waiting for their '
                          'partners were discarded when the stamps jumped back',
                          count=sync.queued_frames)
            sync.reset()
            seen.clear()

    def holds_input(self) -> bool:
        """True while a message waits for its partners (in a synchroniser, or in a node's
        own state: nodes with state of their own extend it). `process` on several workers
        hands a segment over only where no node holds anything."""
        return any(sync.queued for sync, _ in self._syncs)

    def finish_stream(self) -> None:
        """The input stream ended (the offline harness calls this after the last message):
        count what the node still holds, which no later message can complete, as
        ``stream_ended`` drops. Nodes with state of their own extend it."""
        for sync, _ in self._syncs:
            if sync.queued_frames:
                self.drop('stream_ended', f'{sync.queued_frames} frame(s) still waiting for '
                          'their partners when the stream ended', count=sync.queued_frames)
            sync.reset()
        for _, seen in self._syncs:
            seen.clear()

    def frame_image(self, msg: Any, what: str, shape: tuple[int, ...],
                    encodings: tuple[str, ...], *, camera: bool = False) -> Any:
        """The pixels of an input image (raw or compressed) that must fit the frame being
        processed.

        Args:
            msg: An Image or CompressedImage.
            what: How the logs name it.
            shape: The frame's (height, width).
            encodings: The encodings accepted.
            camera: Decode camera encodings (Bayer, YUV) to bgr8 / bgr16 first; the
                encodings are then those of the decoded pixels.

        Returns:
            ``(pixels, encoding)``, or None after counting the drop: the decoding's reason
            (see :meth:`decoding_failed`), ``unsupported_encoding`` (not one of
            ``encodings``) or ``size_mismatch`` (not ``shape``).
        """
        declared = getattr(msg, 'encoding', None)  # a raw Image says before it is read
        if declared is not None and declared not in encodings and not (
                camera and declared in CAMERA_ENCODINGS):
            encoding = declared
        else:
            try:
                pixels, encoding = image_pixels(msg) if camera else decode_image(msg)
            except MessageError as exc:
                self.decoding_failed(exc, what)
                return None
        if encoding not in encodings:
            self.drop('unsupported_encoding', f'{what} encoding {encoding!r} is not '
                      f'{" or ".join(encodings)}')
            return None
        if pixels.shape[:2] != tuple(shape[:2]):
            self.drop('size_mismatch', f'{what} is {pixels.shape[1]}x{pixels.shape[0]}, the '
                      f'frame {shape[1]}x{shape[0]}')
            return None
        return pixels, encoding

    def decoding_failed(self, exc: MessageError, what: str) -> None:
        """Count an image that could not be read: ``unsupported_format`` (a compressed
        format or transport not known), ``unsupported_encoding``, ``decode_failed`` (damaged
        compressed data) or ``malformed_image`` (fields that disagree, odd Bayer sizes)."""
        if isinstance(exc, UnsupportedFormatError):
            reason = 'unsupported_format'
        elif isinstance(exc, EncodingError):
            reason = 'unsupported_encoding'
        elif isinstance(exc, DecodeError):
            reason = 'decode_failed'
        else:
            reason = 'malformed_image'
        self.drop(reason, f'{what}: {exc}')

    def gray_image(self, msg: Any, what: str) -> Any:
        """A camera image (raw or compressed, any camera encoding) as one grey channel, or
        None after counting the drop (see :meth:`decoding_failed`)."""
        try:
            return gray_image(msg)
        except MessageError as exc:
            self.decoding_failed(exc, what)
        return None

    def stereo_model(self, left_info: Any, right_info: Any) -> StereoModel | None:
        """The stereo geometry of a CameraInfo pair (converted again only when one changes),
        or None after counting the drop: ``uncalibrated`` (a K all zero) or
        ``bad_calibration`` (anything else unusable)."""
        if self._stereo_cache is None:
            self._stereo_cache = StereoInfoCache()
        try:
            return self._stereo_cache.model(left_info, right_info)
        except UncalibratedError as exc:
            self.drop('uncalibrated', str(exc))
        except CalibrationError as exc:
            self.drop('bad_calibration', f'camera_info unusable: {exc}')
        return None

    def drop(self, reason: str, detail: str, count: int = 1) -> None:
        """Count frames that produced no output, and log why (throttled per reason).

        Args:
            reason: A short stable key, e.g. ``size_mismatch``; the counter's key.
            detail: The human-readable explanation, e.g. the sizes that disagreed.
            count: How many frames were lost for this reason at once.
        """
        with self._counting:
            self.drops[reason] += count
            self._window.drops[reason] += count
            now = time.monotonic()
            last = self._last_drop_log.get(reason)
            log = (last is None or now - last >= DROP_LOG_PERIOD_S) and not self.stopping
            if log:
                self._last_drop_log[reason] = now
        if log:
            self.get_logger().warning(
                f'dropped frame ({reason}, {self.drops[reason]} so far): {detail}'
            )


    def diagnostics(self) -> DiagnosticStatus:
        """The node's status since the last call (which starts a new period).

        Values: per input and output topic its rate over the period and its total; the
        processing time per frame (mean and max over the period); per drop reason its
        total. Level WARN when frames were dropped during the period, else OK.
        """
        now = time.monotonic()
        with self._counting:
            window, self._window = self._window, _Window(now)
            drops = Counter(self.drops)
            totals = {topic: out.count for topic, out in self.outputs.items()}
        span = max(now - window.start, 1e-9)
        values = []
        for spec in self.inputs:
            values += [KeyValue(key=f'input {spec.topic} rate (Hz)',
                                value=f'{window.inputs[spec.topic] / span:.2f}'),
                       KeyValue(key=f'input {spec.topic} total',
                                value=str(self.received[spec.topic]))]
        for topic, total in totals.items():
            values += [KeyValue(key=f'output {topic} rate (Hz)',
                                value=f'{window.outputs[topic] / span:.2f}'),
                       KeyValue(key=f'output {topic} total', value=str(total))]
        times = window.frame_times
        values += [
            KeyValue(key='frames processed', value=str(len(times))),
            KeyValue(key='processing time mean (ms)',
                     value=f'{1e3 * sum(times) / len(times):.2f}' if times else 'nan'),
            KeyValue(key='processing time max (ms)',
                     value=f'{1e3 * max(times):.2f}' if times else 'nan'),
            KeyValue(key='drops total', value=str(sum(drops.values()))),
        ]
        values += [KeyValue(key=f'drops {reason}', value=str(count))
                   for reason, count in sorted(drops.items())]
        if window.drops:
            level = DiagnosticStatus.WARN
            message = f'dropped {sum(window.drops.values())} in {span:.1f} s: ' + ', '.join(
                f'{reason} {count}' for reason, count in sorted(window.drops.items()))
        else:
            level = DiagnosticStatus.OK
            message = (f'{len(times) / span:.1f} frames/s' if sum(self.received.values())
                       else 'waiting for input')
        name = self.get_fully_qualified_name()
        return DiagnosticStatus(level=level, name=name, message=message, hardware_id=name,
                                values=values)

    def publish_diagnostics(self) -> None:
        """Publish :meth:`diagnostics` on ``/diagnostics`` (the timer's callback)."""
        if self._diagnostics_pub is None:
            return
        array = DiagnosticArray(status=[self.diagnostics()])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(array)


def run_node(node_class: Callable[[], DepthNode], args: list[str] | None = None) -> int:
    """Run one node until Ctrl-C: the body of every node's console script ``main``.

    ``-h`` / ``--help`` before any ``--ros-args`` prints the node's module notes (topics,
    parameters, drop reasons) instead.

    Returns:
        The process exit status: 0, or 1 when the node could not start (bad parameters).
    """
    argv = sys.argv[1:] if args is None else list(args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    name = node_class.__name__
    if '-h' in own or '--help' in own:
        doc = sys.modules[node_class.__module__].__doc__ or ''
        try:
            print(f'{doc.strip()}\n\nusage: {Path(sys.argv[0]).name} [--ros-args -p '
                  'NAME:=VALUE -r FROM:=TO --params-file FILE ...]\n(ros2 param list / '
                  'describe on the running node, or depth-nodes param, show every parameter)')
            sys.stdout.flush()
        except BrokenPipeError:  # `| head`: the reader has what it wanted
            sys.stdout = open(os.devnull, 'w')  # noqa: SIM115 (stays open until exit)
        return 0
    use_large_message_profile()
    keep_freed_memory()
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:  # rclpy's UnknownROSArgsError, RCLError: bad --ros-args
        print(f'{name}: error: bad --ros-args: {str(exc).splitlines()[0]}', file=sys.stderr)
        return 1
    node = None
    try:
        node = node_class()
        rclpy.spin(node)
    except DepthNodesError as exc:
        print(f'{name}: error: {exc}', file=sys.stderr)
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        try:
            try_shutdown()
        except Exception:  # rclpy's signal handler shut the context down meanwhile: fine
            if ok():
                raise
    return 0
