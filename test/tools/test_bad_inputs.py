"""The bad-input campaign's bag (`generate --preset bad_inputs`, depth_nodes.tools.bags.bad_inputs):
what it holds stamp by stamp, and that test/campaign.py judges every case it writes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from campaign import DROPS, POINT_CLOUD, RECTIFY_LEFT, expected_drops
from helpers import REPO, run_cli
from sensor_msgs.msg import CameraInfo, Image

from depth_nodes.errors import ArgumentError
from depth_nodes.tools.bags.bad_inputs import (
    CASES,
    LEAD_IN,
    START_NS,
    STEP_S,
    TOPICS,
    Campaign,
    write_bad_input_bag,
)
from depth_nodes.tools.bags.io import BagReader, BagWriter

SOURCE = REPO / 'bags' / 'stereo_vga'
STEP_NS = round(STEP_S * 1e9)


@pytest.fixture(scope='module')
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Campaign]:
    path = tmp_path_factory.mktemp('bad') / 'bag'
    return path, write_bad_input_bag(path, SOURCE)


def _by_stamp(path: Path) -> dict[int, dict[str, Any]]:
    out: dict[int, dict[str, Any]] = {}
    with BagReader(path) as reader:
        for m in reader.messages():
            msg = m.deserialize()
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            out.setdefault(stamp, {})[m.topic] = msg
    return out


def test_the_oracle_judges_every_case_and_nothing_else() -> None:
    assert sorted(DROPS) == sorted(case.name for case in CASES)
    assert len({case.name for case in CASES}) == len(CASES)


def test_stamps_alternate_good_frames_and_cases(written: tuple[Path, Campaign]) -> None:
    path, campaign = written
    assert campaign.lead_in == [START_NS - (LEAD_IN - i) * STEP_NS for i in range(LEAD_IN)]
    assert len(campaign.good) == len(CASES) + 1
    assert [case for _, case in campaign.cases] == list(CASES)
    for i, (at, case) in enumerate(campaign.cases):
        assert campaign.good[i] == START_NS + 2 * i * STEP_NS
        assert at == campaign.good[i] + STEP_NS + round(case.stamp_offset_s * 1e9)
    frames = _by_stamp(path)
    for stamp in campaign.lead_in + campaign.good:
        assert sorted(frames[stamp]) == sorted(TOPICS)
    assert sorted(frames) == sorted(campaign.lead_in + campaign.good +
                                    [at for at, _ in campaign.cases])


def test_each_case_holds_what_it_says(written: tuple[Path, Campaign]) -> None:
    path, campaign = written
    frames = _by_stamp(path)
    case = {c.name: frames[at] for at, c in campaign.cases}
    left, left_info, right, right_info = TOPICS
    assert case['unknown encoding'][left].encoding == 'yuv_sideways'
    assert case['mono data declared rgb8'][left].encoding == 'rgb8'
    image = case['mono data declared rgb8'][left]
    assert len(image.data) == image.width * image.height  # one byte a pixel: too little
    image = case['step and data length disagree'][left]
    assert image.step == image.width + 7
    assert len(case['empty data'][left].data) == 0
    image = case['huge declared size, 64 bytes of data'][left]
    assert (image.width, image.height, len(image.data)) == (1_000_000, 1_000_000, 64)
    assert not any(case['zero calibration (K all zero)'][left_info].k)
    assert str(case['NaN in the distortion'][right_info].d[0]) == 'nan'
    half = case['left / right size mismatch']
    assert (half[right].width * 2, half[right].height * 2) == (half[left].width,
                                                               half[left].height)
    assert half[right_info].binning_x == half[right_info].binning_y == 2
    assert sorted(case['unpaired left frame']) == sorted([left, left_info])
    assert sorted(case['unpaired right frame']) == sorted([right, right_info])
    good = frames[campaign.good[0]]
    assert sorted(case['stamp older than the previous frame']) == sorted(good)


def test_expected_drops_add_up_over_the_cases(written: tuple[Path, Campaign]) -> None:
    _, campaign = written
    drops = expected_drops(campaign)
    assert drops[RECTIFY_LEFT] == {'unsupported_encoding': 1, 'malformed_image': 3,
                                   'size_mismatch': 1, 'uncalibrated': 1,
                                   'stamp_out_of_order': 2}
    assert drops[POINT_CLOUD] == {'stamp_out_of_order': 2}
    assert sum(sum(c.values()) for c in drops.values()) == 16


def test_generate_writes_it_and_refuses_a_bag_without_stereo_frames(tmp_path: Path) -> None:
    done = run_cli(['generate', str(tmp_path / 'bad'), '--preset', 'bad_inputs'])
    assert done.returncode == 0, done.stderr
    assert f'{tmp_path / "bad"}: bad_inputs from {SOURCE}: 12 good frames, 11 hostile ' \
           'cases' in done.stdout
    with BagWriter(tmp_path / 'apart') as writer:  # the four topics, never at one stamp
        for i, topic in enumerate(TOPICS):
            msg = Image() if topic.endswith('image_raw') else CameraInfo()
            msg.header.stamp.sec = i
            writer.write(topic, msg, i)
    with pytest.raises(ArgumentError, match='has no complete raw stereo frame under /stereo'):
        write_bad_input_bag(tmp_path / 'out', tmp_path / 'apart')
    for source, message in ((tmp_path / 'apart', 'has no complete raw stereo frame under '
                             '/stereo'), (REPO / 'bags' / 'tof_vga', 'topic /stereo/left/'
                             'image_raw is not in')):
        refused = run_cli(['generate', str(tmp_path / 'out2'), '--preset', 'bad_inputs',
                           '--source', str(source)])
        assert refused.returncode == 1
        (line,) = refused.stderr.strip().splitlines()
        assert line.startswith('depth-nodes generate: error: ')
        assert message in line
    assert not (tmp_path / 'out2').exists()

