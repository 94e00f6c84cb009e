"""Structured-light bags: written, read back, run through the node offline, scored; the
bundled bag meets the targets."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from helpers import REPO, small_sl_graph

from depth_nodes.errors import BagError
from depth_nodes.ros.image import image_to_array
from depth_nodes.sim.projector import ProjectorSimConfig
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.bags.structured_light import (
    PRESETS,
    REFERENCE_MARGIN,
    StructuredLightBagConfig,
    read_structured_light_bag,
    write_structured_light_bag,
)
from depth_nodes.tools.evaluation.structured_light import (
    evaluate_structured_light_bag,
    opencv_available,
)

BUNDLED = REPO / 'bags' / 'structured_light_vga'
SMALL = StructuredLightBagConfig(
    sim=ProjectorSimConfig(width=96, height=72, focal_px=84.0, projector_width=96,
                           projector_height=72, projector_focal_px=75.0, seed=5),
    steps=4, period=8.0, sequences=2, speckle_frames=1)


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('sl') / 'bag'
    count = write_structured_light_bag(path, SMALL)
    n = SMALL.pattern_set.count
    assert count == 2 * (4 * n + 4) + 3
    return path


def test_topics_stamps_and_tags(small_bag: Path) -> None:
    with BagReader(small_bag) as reader:
        assert reader.counts['/sl/image_raw'] == 2 * SMALL.pattern_set.count
        assert reader.topics['/sl/pattern'] == 'std_msgs/msg/Header'
        assert reader.topics['/sl/depth_gt'] == 'sensor_msgs/msg/Image'
        tags = [m.deserialize() for m in reader.messages(['/sl/pattern'])]
    n = SMALL.pattern_set.count
    assert [t.frame_id for t in tags] == [f'{s}:{k}/{n}' for s in range(2) for k in range(n)]
    bag = read_structured_light_bag(small_bag)
    assert bag.config == SMALL
    assert [s.number for s in bag.sequences] == [0, 1]
    assert bag.sequences[0].images.shape == (n, 72, 96)
    assert not np.array_equal(bag.sequences[0].images, bag.sequences[1].images)  # noise
    assert set(bag.sequences[0].gt) == {'depth_gt', 'projector_u_gt', 'projector_v_gt',
                                        'shadow_gt'}
    assert bag.reference is not None
    assert bag.reference.shape == (72, 96 + 2 * REFERENCE_MARGIN)  # wider: see the module
    np.testing.assert_allclose(bag.projector.P[0, 3] / bag.projector.K[0, 0], -0.1,
                               atol=1e-12)


def test_process_runs_the_node_on_every_sequence(small_bag: Path, tmp_path: Path) -> None:
    report = process_bag(small_bag, tmp_path / 'out', config=small_sl_graph(small_bag))
    assert report.published['/sl/depth'] == 2
    assert report.published['/sl/speckle/depth'] == 1
    assert sum(sum(c.values()) for c in report.drops.values()) == 0
    with BagReader(tmp_path / 'out') as reader:
        depth = [image_to_array(m.deserialize()) for m in reader.messages(['/sl/depth'])]
        gt = image_to_array(next(reader.messages(['/sl/depth_gt'])).deserialize())
    assert np.nanmedian(np.abs(depth[0] - gt)) < 0.03  # 96 px projector: coarse


def test_evaluate_reports_every_method(small_bag: Path) -> None:
    report = evaluate_structured_light_bag(small_bag)
    names = [r.method for r in report.rows]
    assert names[:3] == ['gray (this package)', 'phase N=4 P=8 (this package)',
                         'opencv GrayCodePattern']
    assert names[3].startswith('speckle')
    text = report.format()
    assert 'phase N=4 P=8' in text
    if not opencv_available():
        assert 'unavailable: cv2.structured_light needs the opencv-contrib wheel' in text


def test_bundled_bag_meets_the_targets() -> None:
    report = evaluate_structured_light_bag(BUNDLED, opencv=False)
    rows = {r.method.split(' ')[0]: r for r in report.rows}
    phase = rows['phase']
    assert phase.decoded is not None
    assert phase.decoded >= 0.99  # lit, unshadowed pixels decoded
    assert phase.rms is not None
    assert phase.rms < 0.1  # projector px, interior pixels
    assert phase.depth_rms_mm is not None
    assert phase.depth_rms_mm < 6.0
    assert rows['gray'].rms is not None
    assert 0.2 < rows['gray'].rms < 0.4  # integer columns: 1/sqrt(12) = 0.29 px
    # single-shot speckle, the targets: >= 95 % of lit pixels decoded (measured
    # 95.9 %), <= 1 % of shadowed ones given a depth (0.79 %); depth RMS 4.0 mm
    speckle = rows['speckle']
    assert speckle.decoded is not None
    assert speckle.decoded >= 0.95
    assert speckle.false is not None
    assert speckle.false <= 0.01
    assert speckle.depth_rms_mm is not None
    assert speckle.depth_rms_mm < 6.0


def test_bundled_bag_is_the_preset() -> None:
    assert read_structured_light_bag(BUNDLED).config == PRESETS['structured_light_vga']
    size = sum(f.stat().st_size for f in BUNDLED.iterdir())
    assert size < 8e6


@pytest.mark.parametrize(('make', 'message'), [
    (lambda p: p / 'missing', 'bag not found'),
    (lambda p: REPO / 'bags' / 'stereo_vga', 'is not a structured-light bag'),
])
def test_read_errors(tmp_path: Path, make: object, message: str) -> None:
    with pytest.raises(BagError, match=message):
        read_structured_light_bag(make(tmp_path))  # type: ignore[operator]


def test_write_refuses_speckle_sequences(tmp_path: Path) -> None:
    from depth_nodes.errors import ConfigError
    with pytest.raises(ConfigError, match='sequences need mode gray, phase or opencv'):
        write_structured_light_bag(tmp_path / 'b', dataclasses.replace(SMALL, mode='speckle'))


def test_shipped_pipeline_config_decodes_the_bundled_bag(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """config/structured_light_pipeline.yaml on bags/structured_light_vga: no drops, and the
    phase decoder's depth within 5 mm of the truth at the median (measured 1.7 mm)."""
    from helpers import REPO

    from depth_nodes.graph.description import load_graph_config

    monkeypatch.chdir(REPO)  # the config names the speckle reference relative to the repo
    config = load_graph_config(REPO / 'config' / 'structured_light_pipeline.yaml')
    report = process_bag(REPO / 'bags' / 'structured_light_vga', tmp_path / 'out',
                         config=config)
    assert sum(sum(c.values()) for c in report.drops.values()) == 0
    assert report.published['/sl/depth'] == 1
    assert report.published['/sl/speckle/depth'] >= 1
    with BagReader(tmp_path / 'out') as reader:
        depth = image_to_array(next(reader.messages(['/sl/depth'])).deserialize())
        gt = image_to_array(next(reader.messages(['/sl/depth_gt'])).deserialize())
    assert np.nanmedian(np.abs(depth - gt)) < 0.005
