"""SimulatedBag (depth_nodes.tools.bags.simulated), what every simulated kind of bag is
written and read with: the configuration in the metadata, whole frames (or whole groups of
frames) up to a signal, a file beside a complete bag only, and its errors."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.tools import signals
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.simulated import Frame, SimulatedBag, stamped_header


@dataclass(frozen=True)
class _Config:
    size: int = 3
    name: str = 'toy'


def _parse(doc: dict[str, Any]) -> _Config:
    config = _Config(**doc)
    if config.size < 1:
        raise ConfigError(f'size must be >= 1, got {config.size}')
    return config


BAG = SimulatedBag('test.toy', 'a toy bag', 'the toy maker', _parse)


def _frame(stamp: int, value: int) -> Frame:
    image = array_to_image(np.full((2, 3), value, np.uint8), 'mono8',
                           stamped_header(stamp, 'toy'))
    return stamp, [('/toy/image', image), ('/toy/again', image)]


def _values(path: Path, topic: str = '/toy/image') -> dict[int, int]:
    with BagReader(path) as reader:
        return {m.timestamp: int(image_to_array(m.deserialize())[0, 0])
                for m in reader.messages([topic])}


def test_frames_and_the_configuration_round_trip(tmp_path: Path) -> None:
    config = _Config(size=5, name='five')
    count = BAG.write(tmp_path / 'bag', config, (_frame(10 + i, i) for i in range(3)))
    assert count == 6
    assert _values(tmp_path / 'bag') == {10: 0, 11: 1, 12: 2}
    read, found = BAG.read(tmp_path / 'bag', ['/toy/image', '/toy/none'],
                           optional=('/toy/none',))
    assert read == config
    assert sorted(found['/toy/image']) == [10, 11, 12]
    assert found['/toy/none'] == {}
    msg = found['/toy/image'][11]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (
        0, 11, 'toy')
    with BagReader(tmp_path / 'bag') as reader:
        assert BAG.config(dict(reader.custom_data), tmp_path / 'bag') == config


def test_a_signal_stops_between_groups_and_leaves_nothing_beside(tmp_path: Path) -> None:
    simulated: list[int] = []
    beside: list[Path] = []

    def group(first: int) -> Iterator[Frame]:
        for stamp in (first, first + 1):
            simulated.append(stamp)
            yield _frame(stamp, stamp)
        if first == 0:
            signals.STOP.set()  # as the first SIGINT does, inside the first group

    with signals.graceful():
        count = BAG.write_groups(tmp_path / 'bag', _Config(),
                                 (group(first) for first in (0, 10, 20)),
                                 on_complete=beside.append)
    assert signals.stop_requested()
    signals.STOP.clear()
    assert count == 4  # the whole first group, nothing of the next
    assert _values(tmp_path / 'bag') == {0: 0, 1: 1}
    assert simulated == [0, 1]  # the next group was not even simulated
    assert beside == []
    done = BAG.write_groups(tmp_path / 'full', _Config(), (group(f) for f in (10, 20)),
                            on_complete=beside.append)
    assert done == 8
    assert beside == [tmp_path / 'full']


def test_a_signal_stops_between_frames(tmp_path: Path) -> None:
    def frames() -> Iterator[Frame]:
        yield _frame(1, 1)
        signals.STOP.set()
        yield _frame(2, 2)

    with signals.graceful():
        assert BAG.write(tmp_path / 'bag', _Config(), frames()) == 2
    signals.STOP.clear()
    assert _values(tmp_path / 'bag') == {1: 1}


def test_errors_name_the_bag_and_the_maker(tmp_path: Path) -> None:
    BAG.write(tmp_path / 'bag', _Config(), [_frame(1, 1)])
    with pytest.raises(BagError, match='exists'):
        BAG.write(tmp_path / 'bag', _Config(), [_frame(1, 1)])
    assert BAG.write(tmp_path / 'bag', _Config(size=2), [_frame(3, 3)], overwrite=True) == 2
    other = SimulatedBag('test.other', 'another bag', 'another maker', _parse)
    with pytest.raises(BagError, match=r'bag is not another bag \(no test\.other metadata: '
                       r'made by another maker\)$'):
        other.read(tmp_path / 'bag', ['/toy/image'])
    with pytest.raises(BagError, match='topic /toy/none is not in'):
        BAG.read(tmp_path / 'bag', ['/toy/none'])
    bad = dataclasses.replace(BAG, parse=lambda doc: _parse({**doc, 'size': 0}))
    with pytest.raises(BagError, match=r'malformed test\.toy metadata: size must be >= 1, '
                       r'got 0$'):
        bad.read(tmp_path / 'bag', ['/toy/image'])
    with pytest.raises(BagError, match=r'malformed test\.toy metadata'):
        BAG.config({'test.toy': '{"size": 1, "colour": 2}'}, tmp_path / 'bag')
    with pytest.raises(BagError, match=r'malformed test\.toy metadata'):
        BAG.config({'test.toy': 'not json'}, tmp_path / 'bag')
