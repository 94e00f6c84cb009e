"""A single wild pose costs at most its own frame: the bundled multi-view bag and the
depth-camera bag, each processed clean and with one odometry message gone wrong (stamped an
hour ahead, or 100 m off), through the shipped graphs.

What must hold: the stream carries on without starting over (no ``time_jump``, the filter
keeps its memory); a wild pose *added* to the stream changes no output byte and is one
``bad_pose``; a frame's own pose gone wrong loses that frame (``no_pose``) and no other:
every output is byte for byte what the stream gives with that odometry message missing.
(Before, one hour-ahead stamp lost the next 4 multi-view frames and restarted the filter:
the depth after it was 1.2 - 3.5 % off the clean run's.)"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import REPO

from depth_nodes.core.depth_image import to_metres
from depth_nodes.core.stamps import NS_PER_S, stamp_ns
from depth_nodes.graph.description import load_graph_config
from depth_nodes.ros.image import image_to_array
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.bags.process import ProcessReport, process_bag

pytestmark = pytest.mark.slow

#: bag, its graph, its odometry topic, its output depth topic
CASES = {
    'multiview': (REPO / 'bags' / 'mvs_sideways', 'multiview_pipeline.yaml', '/mvs/odom',
                  '/mvs/depth'),
    'depth_filter': (REPO / 'bags' / 'depth_moving_camera', 'depth_filter_pipeline.yaml',
                     '/camera/odom', '/camera/filtered/image_rect'),
}
#: the odometry message that goes wrong: the sixth
SPOILED = 5

Spoil = Callable[[Any], list[Any]]


def _hour_ahead(odom: Any) -> list[Any]:
    """The message, then a copy of it stamped an hour later."""
    wild = copy.deepcopy(odom)
    wild.header.stamp.sec += 3600
    return [odom, wild]


def _jump_between(odom: Any) -> list[Any]:
    """The message, then one 50 ms later and 100 m away."""
    wild = copy.deepcopy(odom)
    wild.header.stamp.nanosec += 50_000_000
    if wild.header.stamp.nanosec >= NS_PER_S:
        wild.header.stamp.sec += 1
        wild.header.stamp.nanosec -= NS_PER_S
    wild.pose.pose.position.x += 100.0
    return [odom, wild]


def _jump_in_place(odom: Any) -> list[Any]:
    """The message itself 100 m away."""
    wild = copy.deepcopy(odom)
    wild.pose.pose.position.x += 100.0
    return [wild]


def _missing(odom: Any) -> list[Any]:
    """No message at all: the frame has no pose."""
    return []


def _rewrite(bag: Path, out: Path, topic: str, spoil: Spoil | None) -> Path:
    seen = 0
    with BagReader(bag) as reader, BagWriter(out) as writer:
        for msg in reader.messages():
            if msg.topic != topic or spoil is None:
                writer.write(msg.topic, msg.data, msg.timestamp, msg.msgtype)
                continue
            parsed = [msg.deserialize()]
            if seen == SPOILED:
                parsed = spoil(parsed[0])
            seen += 1
            for item in parsed:
                writer.write(msg.topic, item, msg.timestamp)
    return out


def _run(tmp: Path, case: str, spoil: Spoil | None, name: str
         ) -> tuple[ProcessReport, dict[int, np.ndarray]]:
    bag, config, odom, depth = CASES[case]
    source = _rewrite(bag, tmp / f'{name}_in', odom, spoil)
    report = process_bag(source, tmp / f'{name}_out',
                         config=load_graph_config(REPO / 'config' / config))
    with BagReader(tmp / f'{name}_out') as reader:
        depths = {}
        for msg in reader.messages([depth]):
            image = msg.deserialize()
            depths[stamp_ns(image)] = to_metres(image_to_array(image), image.encoding)
    return report, depths


def _drops(report: ProcessReport) -> dict[str, int]:
    total: dict[str, int] = {}
    for counts in report.drops.values():
        for reason, n in counts.items():
            total[reason] = total.get(reason, 0) + n
    return total


@pytest.fixture(scope='module')
def clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp('clean')
    return {case: _run(tmp, case, None, case) for case in CASES}


@pytest.mark.parametrize('case', sorted(CASES))
@pytest.mark.parametrize('spoil', [_hour_ahead, _jump_between], ids=['hour_ahead', 'jump'])
def test_a_wild_pose_added_changes_nothing(tmp_path: Path, clean: dict[str, Any], case: str,
                                           spoil: Spoil) -> None:
    base_report, base = clean[case]
    report, depths = _run(tmp_path, case, spoil, 'wild')
    assert _drops(report) == {**_drops(base_report), 'bad_pose': 1}
    assert sorted(depths) == sorted(base)
    for stamp, depth in base.items():
        np.testing.assert_array_equal(depths[stamp], depth, err_msg=f'{stamp}')


@pytest.mark.parametrize('case', sorted(CASES))
def test_a_frame_whose_pose_jumps_is_the_only_one_lost(tmp_path: Path, clean: dict[str, Any],
                                                      case: str) -> None:
    base_report, base = clean[case]
    report, depths = _run(tmp_path, case, _jump_in_place, 'jump')
    missing_report, missing = _run(tmp_path, case, _missing, 'missing')
    drops = _drops(report)
    assert drops.pop('bad_pose') == 1
    assert drops == _drops(missing_report)
    assert drops.pop('no_pose') == 1
    assert 'time_jump' not in drops
    assert drops == _drops(base_report)
    lost = sorted(set(base) - set(depths))
    assert len(lost) == 1
    assert set(depths) <= set(base)
    assert any(stamp > lost[0] for stamp in depths)  # the stream carried on
    assert sorted(depths) == sorted(missing)
    for stamp, depth in missing.items():
        np.testing.assert_array_equal(depths[stamp], depth, err_msg=f'{stamp}')
