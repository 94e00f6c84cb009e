"""The committed bags: present, small, complete, consistent, and regenerable from their seeds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import REPO

from depth_nodes.core.rectify import rectify_image
from depth_nodes.ros.camera_info import camera_info_to_model
from depth_nodes.ros.image import image_to_array, to_gray
from depth_nodes.tools.bags.generate import PRESETS, config_from_bag_metadata, write_stereo_bag
from depth_nodes.tools.bags.io import BagReader

pytestmark = pytest.mark.slow

BAGS = REPO / 'bags'
MAX_BAG_MB = 8.0
MAX_TOTAL_MB = 24.0  # every bag in bags/, the structured-light and ToF ones included (20 MB)


def _size_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.iterdir()) / 1e6


def test_bags_are_small() -> None:
    sizes = {path.name: _size_mb(path) for path in BAGS.iterdir() if path.is_dir()}
    assert set(PRESETS) < set(sizes)
    assert all(size < MAX_BAG_MB for size in sizes.values()), sizes
    assert sum(sizes.values()) < MAX_TOTAL_MB, sizes
    assert PRESETS['stereo_vga'].width == 640


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_bag_matches_its_preset(name: str) -> None:
    config = PRESETS[name]
    with BagReader(BAGS / name) as reader:
        assert config_from_bag_metadata(reader.custom_data) == config
        assert len(reader.topics) == 9
        assert set(reader.counts.values()) == {config.n_frames}
        assert (BAGS / name / 'metadata.yaml').is_file()
        assert next((BAGS / name).glob('*.mcap')).is_file()


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_raw_images_rectify_onto_the_ground_truth(name: str) -> None:
    """CameraInfo, raw images and rectified renders agree (what the rectifier must achieve).

    Tolerance: mean |rectified raw - rectified render| under 2.5 grey levels inside a 16 px
    margin (measured 1.3-1.8); the raw images carry noise of sigma 2.
    """
    with BagReader(BAGS / name) as reader:
        topics = [f'/stereo/{s}/{k}' for s in ('left', 'right')
                  for k in ('image_raw', 'camera_info', 'image_rect_gt')]
        msgs: dict[str, list[object]] = {}
        for m in reader.messages(topics):
            msgs.setdefault(m.topic, []).append(m.deserialize())
    for side in ('left', 'right'):
        raw = msgs[f'/stereo/{side}/image_raw'][0]
        truth = msgs[f'/stereo/{side}/image_rect_gt'][0]
        model = camera_info_to_model(msgs[f'/stereo/{side}/camera_info'][0])
        rectified = rectify_image(to_gray(image_to_array(raw), raw.encoding), model)
        expected = to_gray(image_to_array(truth), truth.encoding)
        diff = np.abs(rectified.astype(np.float32) - expected)[16:-16, 16:-16]
        assert diff.mean() < 2.5, (name, side, diff.mean())
        # and the check can fail: without R the images do not line up
        model.R = np.eye(3)
        unrotated = rectify_image(to_gray(image_to_array(raw), raw.encoding), model)
        assert np.abs(unrotated.astype(np.float32) - expected)[16:-16, 16:-16].mean() > 5.0


def test_the_smallest_bag_regenerates_identically(tmp_path: Path) -> None:
    name = 'stereo_qvga_fisheye'
    write_stereo_bag(tmp_path / name, PRESETS[name])
    with BagReader(BAGS / name) as committed, BagReader(tmp_path / name) as fresh:
        old = list(committed.messages())
        new = list(fresh.messages())
    assert [(m.topic, m.timestamp) for m in old] == [(m.topic, m.timestamp) for m in new]
    for a, b in zip(old, new, strict=True):
        msg_a, msg_b = a.deserialize(), b.deserialize()
        if a.msgtype == 'sensor_msgs/msg/Image':
            np.testing.assert_array_equal(image_to_array(msg_a), image_to_array(msg_b))
        elif a.msgtype == 'sensor_msgs/msg/CameraInfo':
            for field in ('k', 'd', 'r', 'p'):
                np.testing.assert_array_equal(getattr(msg_a, field), getattr(msg_b, field))
        else:
            np.testing.assert_array_equal(image_to_array(msg_a.image),
                                          image_to_array(msg_b.image))
            assert (msg_a.f, msg_a.t) == (msg_b.f, msg_b.t)
