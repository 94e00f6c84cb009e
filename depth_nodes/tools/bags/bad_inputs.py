"""The bad-input campaign's bag (`depth-nodes generate --preset bad_inputs`): malformed and
hostile stereo messages between good frames.

Built from the raw frames of a stereo bag (the bundled stereo_vga by default): every case
of :data:`CASES` is one stamp, 0.5 s after the previous one, of the four raw topics under
``/stereo`` (left/right image_raw and camera_info), with something wrong in it, and good
frames sit between the cases. What each case must cause (which node drops it first, under
which reason) is the test's to judge: test/campaign.py, used by
test/live/test_bad_input_campaign.py, which replays the bag into the stereo graph.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from sensor_msgs.msg import Image

from depth_nodes.core.stamps import NS_PER_S, stamp_parts
from depth_nodes.errors import ArgumentError
from depth_nodes.tools.bags.io import BagWriter
from depth_nodes.tools.live.processes import StereoFrame, load_stereo_frames

NS = '/stereo'
TOPICS = (f'{NS}/left/image_raw', f'{NS}/left/camera_info', f'{NS}/right/image_raw',
          f'{NS}/right/camera_info')
#: Seconds between two stamps of the campaign (more than a frame takes to go through).
STEP_S = 0.5
#: Stamp of the first campaign frame.
START_NS = 100 * NS_PER_S
#: Good frames before START_NS. A player's first messages can reach a subscriber that has
#: not yet matched the new publisher (DDS matches the two ends one after the other), so the
#: campaign proper starts once these have gone through.
LEAD_IN = 2

#: Which messages of a case are written: all four, or only one side.
Keep = tuple[bool, bool, bool, bool]
ALL: Keep = (True, True, True, True)


@dataclass(frozen=True)
class Case:
    """One hostile stamp.

    Attributes:
        name: What is wrong.
        spoil: Changes the (copied) frame in place.
        keep: Which of the four messages are written.
        stamp_offset_s: Added to the case's stamp (negative: out of order).
    """

    name: str
    spoil: Callable[[StereoFrame], None]
    keep: Keep = ALL
    stamp_offset_s: float = 0.0


def _left_image(change: Callable[[Image], None]) -> Callable[[StereoFrame], None]:
    """A case that spoils the left image."""
    return lambda frame: change(frame[0])


def _unknown_encoding(image: Image) -> None:
    image.encoding = 'yuv_sideways'


def _mono_as_rgb(image: Image) -> None:
    image.encoding = 'rgb8'  # 1 byte a pixel of data, 3 declared


def _step_disagrees(image: Image) -> None:
    image.step = image.width + 7


def _empty_data(image: Image) -> None:
    image.data = []


def _huge(image: Image) -> None:
    image.width = image.height = 1_000_000
    image.step = 1_000_000
    image.data = bytes(64)


def _zero_k(frame: StereoFrame) -> None:
    frame[1].k = [0.0] * 9


def _nan_calibration(frame: StereoFrame) -> None:
    d = list(frame[3].d)
    d[0] = float('nan')
    frame[3].d = d


def _half_size_right(frame: StereoFrame) -> None:
    """A consistent right camera at half resolution (2x2 binning): the rectifier takes it,
    the matcher must refuse a 640x480 / 320x240 pair."""
    image, info = frame[2], frame[3]
    rows = bytes(image.data)
    width, height = image.width, image.height
    image.data = b''.join(rows[y * image.step:y * image.step + width:2]
                          for y in range(0, height, 2))
    image.width, image.height, image.step = width // 2, height // 2, width // 2
    info.binning_x = info.binning_y = 2


def _nothing(frame: StereoFrame) -> None:
    return None


CASES: tuple[Case, ...] = (
    Case('unknown encoding', _left_image(_unknown_encoding)),
    Case('mono data declared rgb8', _left_image(_mono_as_rgb)),
    Case('step and data length disagree', _left_image(_step_disagrees)),
    Case('empty data', _left_image(_empty_data)),
    Case('huge declared size, 64 bytes of data', _left_image(_huge)),
    Case('zero calibration (K all zero)', _zero_k),
    Case('NaN in the distortion', _nan_calibration),
    Case('left / right size mismatch', _half_size_right),
    Case('stamp older than the previous frame', _nothing, stamp_offset_s=-0.75),
    Case('unpaired left frame', _nothing, keep=(True, True, False, False)),
    Case('unpaired right frame', _nothing, keep=(False, False, True, True)),
)


@dataclass
class Campaign:
    """What was written: stamps of the lead-in frames, the good frames and each case."""

    good: list[int]
    cases: list[tuple[int, Case]]
    lead_in: list[int] = field(default_factory=list)


def write_bad_input_bag(path: str | Path, source: str | Path, *,
                        overwrite: bool = False) -> Campaign:
    """Write the campaign bag at ``path`` from the raw frames of ``source``.

    Good frames (alternating the source's frames) come first, last and between every two
    cases. Returns the stamps written.
    """
    frames = load_stereo_frames(source, NS)
    if not frames:
        raise ArgumentError(f'{source} has no complete raw stereo frame under {NS}')
    campaign = Campaign([], [])
    step = round(STEP_S * NS_PER_S)
    stamp = START_NS - LEAD_IN * step
    with BagWriter(path, overwrite=overwrite) as writer:
        def put(frame: StereoFrame, at: int, keep: Keep = ALL) -> None:
            sec, nanosec = stamp_parts(at)
            for topic, msg, wanted in zip(TOPICS, frame, keep, strict=True):
                if wanted:
                    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
                    writer.write(topic, msg, stamp)

        for index in range(LEAD_IN):
            put(copy.deepcopy(frames[index % len(frames)]), stamp)
            campaign.lead_in.append(stamp)
            stamp += step
        for index, case in enumerate(CASES):
            put(copy.deepcopy(frames[index % len(frames)]), stamp)
            campaign.good.append(stamp)
            stamp += step
            frame = copy.deepcopy(frames[index % len(frames)])
            case.spoil(frame)
            at = stamp + round(case.stamp_offset_s * NS_PER_S)
            put(frame, at, case.keep)
            campaign.cases.append((at, case))
            stamp += step
        put(copy.deepcopy(frames[0]), stamp)
        campaign.good.append(stamp)
    return campaign
