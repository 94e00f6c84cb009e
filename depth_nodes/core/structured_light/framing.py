"""Sequence framing: which pattern a frame shows, and when a sequence is complete.

Convention: every camera image of a pattern sequence has a companion ``std_msgs/Header``
on the ``pattern`` topic with the image's exact stamp and ``frame_id`` set to
``"<sequence>:<index>/<count>"``: ``sequence`` a number the projector driver increments
for every new sequence, ``index`` the 0-based position of the pattern in the sequence and
``count`` the number of patterns. The image's own header is untouched (its ``frame_id``
stays the camera's optical frame, which TF and every downstream node rely on).

Why a companion topic rather than stamps alone or a field of the image: stamps carry no
position (a dropped frame cannot be told from a late one), the image header's
``frame_id`` belongs to TF, and an explicit sequence number is the only way to see that
frames 0..k of one sequence and k+1..n of the next would otherwise look like one complete
sequence. The companion is matched to its image by exact stamp.

:class:`SequenceAssembler` accepts frames in arrival order and returns a sequence only
when frames ``0 .. count - 1`` of one sequence number arrived in order, each exactly once.
Anything else drops the partial sequence with a reason; frames are then skipped until the
next index 0 (resynchronisation). :class:`TagPairer` pairs each image with its tag before.
"""

from __future__ import annotations

import re
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from depth_nodes.errors import MessageError

_TAG = re.compile(r'^\s*(\d+):(\d+)/(\d+)\s*$')

#: Drop reasons the assembler reports.
INCOMPLETE = 'sequence_incomplete'
MIXED = 'sequence_mixed'
MISSING = 'sequence_missing_frame'
REPEATED = 'sequence_repeated_frame'
OUT_OF_ORDER = 'sequence_out_of_order'
COUNT_MISMATCH = 'pattern_count_mismatch'
RESYNC = 'sequence_resync'
#: Drop reasons the tag pairer reports.
TAG_MISSING = 'pattern_tag_missing'
TAG_UNMATCHED = 'pattern_tag_unmatched'


@dataclass(frozen=True)
class PatternTag:
    """The parsed companion tag of one frame."""

    sequence: int
    index: int
    count: int

    def __str__(self) -> str:
        return f'{self.sequence}:{self.index}/{self.count}'


def parse_tag(text: str) -> PatternTag:
    """Parse ``"<sequence>:<index>/<count>"``.

    Raises:
        MessageError: Malformed text, ``count`` 0 or ``index >= count``.
    """
    m = _TAG.match(text)
    if m is None:
        raise MessageError(f'pattern tag {text!r} is not "<sequence>:<index>/<count>"')
    tag = PatternTag(int(m[1]), int(m[2]), int(m[3]))
    if tag.count < 1 or tag.index >= tag.count:
        raise MessageError(f'pattern tag {text!r}: index must be < count and count >= 1')
    return tag


@dataclass
class Drop:
    """A reason to drop (a sequence or a skipped frame), its explanation and how many
    frames it stands for."""

    reason: str
    detail: str
    count: int = 1


class TagPairer:
    """Pairs camera frames with their pattern tags (the projector driver's
    std_msgs/Header with the frame's stamp), whichever arrives first.

    At most ``queue_size`` frames wait for their tag and ``2 * queue_size`` tags for their
    frame; what falls out is a drop (``pattern_tag_missing``, ``pattern_tag_unmatched``),
    as is a frame whose tag never came while a later frame's did.
    """

    def __init__(self, queue_size: int) -> None:
        self.queue_size = queue_size
        self._tags: OrderedDict[int, Any] = OrderedDict()
        self._frames: OrderedDict[int, Any] = OrderedDict()

    def add_tag(self, stamp: int, tag: Any) -> tuple[Any | None, list[Drop]]:
        """A tag at ``stamp`` (ns): its waiting frame, if any, and the drops it caused."""
        if stamp in self._frames:
            drops = [Drop(TAG_MISSING, f'frame at stamp {older} ns never got its pattern '
                          'tag (a later frame did)') for older in self._frames if older < stamp]
            for older in [s for s in self._frames if s < stamp]:
                del self._frames[older]
            return self._frames.pop(stamp), drops
        self._tags[stamp] = tag
        drops = []
        while len(self._tags) > 2 * self.queue_size:
            old, dropped = self._tags.popitem(last=False)
            drops.append(Drop(TAG_UNMATCHED, f'pattern tag {getattr(dropped, "frame_id", "")!r} '
                              f'at stamp {old} ns never got its image'))
        return None, drops

    def add_frame(self, stamp: int, frame: Any) -> tuple[Any | None, list[Drop]]:
        """A frame at ``stamp`` (ns): its tag, if it came first, and the drops it caused."""
        tag = self._tags.pop(stamp, None)
        if tag is not None:
            return tag, []
        self._frames[stamp] = frame
        drops = []
        while len(self._frames) > self.queue_size:
            old, _ = self._frames.popitem(last=False)
            drops.append(Drop(TAG_MISSING, f'frame at stamp {old} ns has no pattern tag (is '
                              'the projector driver publishing "pattern"?)'))
        return None, drops

    @property
    def held(self) -> int:
        """Frames and tags waiting for their partner."""
        return len(self._frames) + len(self._tags)

    def finish(self) -> list[Drop]:
        """The stream ended: what is still waiting, as drops; the pairer is empty after."""
        drops = []
        if self._frames:
            drops.append(Drop(TAG_MISSING, f'{len(self._frames)} frame(s) without their '
                              'pattern tag when the stream ended', len(self._frames)))
        if self._tags:
            drops.append(Drop(TAG_UNMATCHED, f'{len(self._tags)} pattern tag(s) without '
                              'their image when the stream ended', len(self._tags)))
        self._frames.clear()
        self._tags.clear()
        return drops


class SequenceAssembler:
    """Collects the frames of one sequence; see the module docstring.

    Not thread-safe; call from one callback group.
    """

    def __init__(self) -> None:
        self._sequence: int | None = None
        self._count = 0
        self._frames: list[Any] = []
        self._reported: int | None = None  # sequence whose broken start was reported

    @property
    def pending(self) -> int:
        """Frames held of the current, incomplete sequence."""
        return len(self._frames)

    def reset(self) -> None:
        """Forget the current sequence (e.g. the calibration changed)."""
        self._sequence, self._frames = None, []

    def add(self, tag: PatternTag, frame: Any, expected_count: int
            ) -> tuple[list[Any] | None, list[Drop]]:
        """Add one frame.

        Args:
            tag: Its parsed tag.
            frame: Any payload (kept, returned with the sequence).
            expected_count: The count the current pattern set needs.

        Returns:
            The complete sequence's payloads in index order (or None), and the drops this
            frame caused (at most two: the broken sequence and the skipped frame).
        """
        drops: list[Drop] = []
        current = self._sequence
        if current is not None and tag.index == 0:  # a new start before the end
            drops.append(self._abandon(INCOMPLETE, f'sequence {current} dropped after '
                                       f'{len(self._frames)} of {self._count} frames: {tag} '
                                       f'started a new one'))
        elif current is not None and tag.sequence != current:
            drops.append(self._abandon(MIXED, f'sequence {current} dropped: frame {tag} of '
                                       f'another sequence arrived after {len(self._frames)} '
                                       f'of {self._count} frames'))
        if self._sequence is None:
            if tag.index != 0:
                if drops or self._reported == tag.sequence:
                    self._reported = tag.sequence
                    drops.append(Drop(RESYNC, f'frame {tag} skipped: waiting for the start '
                                      f'(index 0) of the next sequence'))
                else:
                    self._reported = tag.sequence
                    drops.append(Drop(MISSING, f'sequence {tag.sequence} starts at frame '
                                      f'{tag}: frames 0..{tag.index - 1} missing'))
                return None, drops
            if tag.count != expected_count:
                self._reported = tag.sequence
                drops.append(Drop(COUNT_MISMATCH, f'sequence {tag.sequence} has {tag.count} '
                                  f'frames, the configured pattern set needs {expected_count}'))
                return None, drops
            self._sequence, self._count, self._frames = tag.sequence, tag.count, [frame]
        else:
            expected = len(self._frames)
            if tag.count != self._count:
                reason, what = MIXED, f'count changed to {tag.count} at frame {tag}'
            elif tag.index == expected:
                self._frames.append(frame)
                reason = ''
            elif tag.index == expected - 1:
                reason, what = REPEATED, f'frame {tag} arrived twice'
            elif tag.index < expected:
                reason, what = OUT_OF_ORDER, f'frame {tag} arrived after frame {expected - 1}'
            else:
                reason, what = MISSING, (f'frame {tag} arrived, frames {expected}..'
                                         f'{tag.index - 1} missing')
            if reason:
                self._reported = tag.sequence
                drops.append(self._abandon(reason, f'sequence {tag.sequence} dropped: {what}'))
                return None, drops
        if len(self._frames) == self._count:
            frames = self._frames
            self._reported = self._sequence
            self.reset()
            return frames, drops
        return None, drops

    def _abandon(self, reason: str, detail: str) -> Drop:
        self.reset()
        return Drop(reason, detail)
