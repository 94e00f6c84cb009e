"""What a `process` run reports: its counts (:class:`ProcessReport`) and its progress on a
terminal (:class:`Progress`)."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import TextIO


@dataclass
class ProcessReport:
    """What went in, what came out, and what nodes dropped, by reason."""

    nodes: list[str] = field(default_factory=list)
    consumed: Counter[str] = field(default_factory=Counter)
    copied: Counter[str] = field(default_factory=Counter)
    published: Counter[str] = field(default_factory=Counter)
    drops: dict[str, Counter[str]] = field(default_factory=dict)
    shadowed: list[str] = field(default_factory=list)
    unfed: list[str] = field(default_factory=list)
    #: Nodes switched to a compressed transport because the bag holds only that.
    transports: dict[str, str] = field(default_factory=dict)
    #: What the command line could say instead, when the bag holds the missing inputs
    #: elsewhere (e.g. ``--namespace /camera``).
    suggestions: list[str] = field(default_factory=list)
    #: Parameter-file entries that address no node (rclpy would ignore them).
    unmatched_params: list[str] = field(default_factory=list)
    #: Input messages handled, of ``total`` in the bag.
    done: int = 0
    total: int = 0
    #: True when a SIGINT / SIGTERM stopped the run (the output holds what was done).
    interrupted: bool = False
    #: The input topic whose messages count as frames (the most frequent one the graph
    #: consumes), frames done and the run's wall-clock seconds.
    frame_topic: str = ''
    frames: int = 0
    seconds: float = 0.0
    workers: int = 1
    engine: str = ''

    def summary(self) -> str:
        """One line: frames, messages, time, rate."""
        rate = self.frames / self.seconds if self.seconds > 0 else 0.0
        how = f'{self.workers} worker{"s" * (self.workers != 1)}'
        if self.engine:
            how += f' on {self.engine}'
        return (f'processed {self.frames} frames ({self.done} of {self.total} messages) in '
                f'{self.seconds:.1f} s: {rate:.2f} frames/s, {how}')

    def format(self) -> str:
        """A plain-text summary for the terminal."""
        lines = [f'nodes: {", ".join(self.nodes) or "none"}']
        lines.append('in:')
        for topic in sorted(self.copied):
            use = f'  -> {self.consumed[topic]} consumed' if self.consumed[topic] else ''
            lines.append(f'  {topic:<40} {self.copied[topic]:>6}{use}')
        lines.append('out:')
        for topic in sorted(self.published) or ['(nothing published)']:
            count = f'{self.published[topic]:>6}' if topic in self.published else ''
            lines.append(f'  {topic:<40} {count}')
        total_drops = sum(sum(c.values()) for c in self.drops.values())
        lines.append(f'dropped: {total_drops}')
        for node, counter in sorted(self.drops.items()):
            for reason, n in sorted(counter.items()):
                lines.append(f'  {node:<30} {reason:<28} {n:>6}')
        for topic in self.shadowed:
            lines.append(f'note: input topic {topic} is also published by a node; '
                         'only the node output was written')
        for node, transport in sorted(self.transports.items()):
            lines.append(f'note: {node} reads its images with image_transport {transport} '
                         '(the bag holds no raw ones)')
        for topic in self.unfed:
            lines.append(f'note: {topic} is subscribed but neither in the bag nor published')
        return '\n'.join(lines)

    def nothing_published(self) -> str:
        """Why a run published nothing, for the one-line error."""
        if not self.unfed:
            return 'the graph published nothing (see the drops above)'
        hint = ''
        if self.suggestions:
            hint = '; try ' + ' or '.join(self.suggestions)
        return (f'the graph published nothing: its inputs {", ".join(self.unfed)} are not in '
                f'the bag{hint}')


class Progress:
    """A one-line progress display on a terminal (frames done, frames/s, ETA); silent
    otherwise (the summary line says it all at the end)."""

    def __init__(self, total_frames: int, stream: TextIO) -> None:
        self.total = max(total_frames, 1)
        self.stream = stream
        self.enabled = stream.isatty()
        self.start = time.monotonic()
        self._shown = -1.0

    def update(self, frames: int, *, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._shown < 0.25:
            return
        self._shown = now
        elapsed = now - self.start
        rate = frames / elapsed if elapsed > 0 else 0.0
        eta = f'{(self.total - frames) / rate:.0f} s' if rate > 0 else '?'
        percent = min(frames * 100 // self.total, 100)
        bar = '#' * (percent // 4)
        self.stream.write(f'\r[{bar:<25}] {percent:3d}% {frames}/{self.total} frames, '
                          f'{rate:.2f} frames/s, ETA {eta}   ')
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write('\n')
            self.stream.flush()
