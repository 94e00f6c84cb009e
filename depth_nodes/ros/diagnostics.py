"""A node's diagnostic_msgs/DiagnosticStatus over one period of its counts.

Every node publishes one every ``diagnostics_period`` seconds on :data:`DIAGNOSTICS_TOPIC`
(the diagnostic_aggregator's input; ``depth-nodes diag`` shows them as a table). Values:
per input and output topic its rate over the period and its total; the frames processed
and skipped (no subscriber) in the period; the processing time per frame (mean and max over
the period); the drops in total and per reason. Level WARN when frames were dropped during
the period, else OK.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from depth_nodes.ros.accounting import Window

#: Topic of the diagnostics every node publishes (the diagnostic_aggregator's input).
DIAGNOSTICS_TOPIC = '/diagnostics'
#: The key of the frames skipped because no output was wanted (lazy outputs).
SKIPPED_KEY = 'frames skipped (no subscriber)'


def node_status(name: str, window: Window, now: float, *, inputs: Iterable[str],
                received: Mapping[str, int], outputs: Iterable[str],
                published: Mapping[str, int], drops: Mapping[str, int]) -> DiagnosticStatus:
    """The status of node ``name`` over ``window``, which ends at ``now``.

    Args:
        name: The node's fully qualified name (also the hardware id).
        window: The period's counts.
        now: The end of the period (monotonic seconds, as ``window.start``).
        inputs: The node's input topics, in the order they were declared.
        received: Messages received since the start, by input topic.
        outputs: The node's output topics, in the order they were declared.
        published: Messages published since the start, by output topic.
        drops: Frames dropped since the start, by reason.
    """
    span = max(now - window.start, 1e-9)
    values = []
    for topic in inputs:
        values += [KeyValue(key=f'input {topic} rate (Hz)',
                            value=f'{window.inputs[topic] / span:.2f}'),
                   KeyValue(key=f'input {topic} total', value=str(received[topic]))]
    for topic in outputs:
        values += [KeyValue(key=f'output {topic} rate (Hz)',
                            value=f'{window.outputs[topic] / span:.2f}'),
                   KeyValue(key=f'output {topic} total', value=str(published[topic]))]
    times = window.frame_times
    values += [
        KeyValue(key='frames processed', value=str(len(times))),
        KeyValue(key=SKIPPED_KEY, value=str(window.skipped)),
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
        message = (f'{len(times) / span:.1f} frames/s' if sum(received.values())
                   else 'waiting for input')
        if window.skipped:
            message += f', {window.skipped} skipped (no subscriber)'
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=name,
                            values=values)
