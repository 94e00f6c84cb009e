"""The fusion graphs end to end: config/fusion_pipeline.yaml on a depth camera's bag, then
`eval` of the fused bag against the simulator's exact surface and `export-mesh`; the one
commented line that adds tsdf_fusion after the stereo graph and after the multi-view graph,
uncommented, on their bags.

The bags are small (160 x 120, a few frames) so that the graphs run in seconds; the
tolerances are those of the noisy depth at that size and are stated where used.
"""

from __future__ import annotations

import dataclasses
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from helpers import REPO, run_cli

from depth_nodes.graph.description import load_graph_config
from depth_nodes.sim.depth_sequence import DepthSequenceConfig, scene_at
from depth_nodes.sim.sequence import SequenceConfig
from depth_nodes.tools.bags.depth_filter import write_depth_bag
from depth_nodes.tools.bags.fusion_stereo import FusionStereoConfig, write_fusion_stereo_bag
from depth_nodes.tools.bags.multiview import write_sequence_bag
from depth_nodes.tools.bags.process import process_bag
from depth_nodes.tools.evaluation.fusion import evaluate_fusion_bag

pytestmark = pytest.mark.slow

CONFIG = REPO / 'config'
#: A depth camera circling the orbit scene: 160 x 120, 6 frames over 20 degrees.
ORBIT = DepthSequenceConfig(kind='orbit', width=160, height=120, n_frames=6, orbit_deg=20.0,
                            baseline_m=0.05, disparity_sigma=0.0384, supersample=2, seed=4)


def _drops(report: object) -> int:
    return sum(sum(c.values()) for c in report.drops.values())  # type: ignore[attr-defined]


@pytest.fixture(scope='module')
def fused_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp('fusion_graph')
    write_depth_bag(root / 'bag', ORBIT)
    report = process_bag(root / 'bag', root / 'out',
                         config=load_graph_config(CONFIG / 'fusion_pipeline.yaml'))
    assert _drops(report) == 0
    assert report.published['/camera/mesh'] >= 1
    assert report.published['/camera/filtered/image_rect'] == ORBIT.n_frames
    return root / 'out'


def test_the_fused_bag_lies_on_the_exact_surface(fused_bag: Path) -> None:
    """At 2 cm voxels and these few noisy 160 x 120 frames (depth 2 - 7 m, the noise
    0.0015 Z^2 and the filter's smoothing), vertices lie a median under a voxel from the
    exact surface (measured 0.33 voxel), over 90 % of the surface seen within 5 m is within
    two voxels of the mesh (measured 98.2 %), and the distance slice is a median under 2.5
    voxels off (measured 11.3 mm)."""
    report = evaluate_fusion_bag(fused_bag, voxel=0.02, truncation=4.0)
    (row,) = report.rows
    assert row.vertices > 1000
    assert row.median < 0.02, row
    assert row.completeness > 0.9, row
    (label, cells, median, _) = report.slice_rows[0]
    assert label == '/camera/esdf_slice'
    assert cells > 100
    assert median < 0.05, report.slice_rows


def test_export_mesh_writes_the_final_mesh_of_the_bag(fused_bag: Path, tmp_path: Path) -> None:
    ply = tmp_path / 'mesh.ply'
    done = run_cli(['export-mesh', str(fused_bag), str(ply)])
    assert done.returncode == 0, done.stderr
    counts = re.match(rf'{re.escape(str(ply))}: (\d+) vertices, (\d+) triangles', done.stdout)
    assert counts is not None, done.stdout
    vertices, faces = int(counts.group(1)), int(counts.group(2))
    data = ply.read_bytes()
    head, body = data.split(b'end_header\n', 1)
    assert f'element vertex {vertices}'.encode() in head
    assert f'element face {faces}'.encode() in head
    xyz = np.frombuffer(body[:12 * vertices], '<f4').reshape(-1, 3).astype(np.float64)
    error = scene_at(ORBIT, ORBIT.n_frames - 1).distance(xyz)
    assert np.median(error) < 0.02
    (first_count,) = struct.unpack_from('<B', body, 12 * vertices)
    assert first_count == 3  # faces are triangles


def _uncommented(name: str, tmp_path: Path) -> Path:
    """The graph file with its commented tsdf_fusion line made live."""
    text = (CONFIG / name).read_text()
    line = re.search(r'^(\s*)# (- \{name: tsdf_fusion.*)$', text, re.MULTILINE)
    assert line is not None, f'{name}: no tsdf_fusion line to uncomment'
    path = tmp_path / name
    path.write_text(text.replace(line.group(0), line.group(1) + line.group(2)))
    return path


def test_one_line_adds_fusion_to_the_stereo_graph(tmp_path: Path) -> None:
    """The stereo graph on a moving 320 x 240 pair with odometry, fused by confidence:
    every frame fused without a drop, the mesh's vertices a median under 3 voxels (15 cm)
    from the exact surface (measured 119 mm: the depth of a 320-pixel pair at 2 - 7 m, a
    median 81 mm off per pixel, and a mesh that samples the far, noisier walls by their
    area, not by their pixels)."""
    sequence = DepthSequenceConfig(kind='orbit', width=320, height=240, n_frames=3, seed=2,
                                   orbit_deg=20.0, baseline_m=0.12)
    write_fusion_stereo_bag(tmp_path / 'bag', FusionStereoConfig(sequence))
    graph = load_graph_config(_uncommented('stereo_pipeline.yaml', tmp_path))
    report = process_bag(tmp_path / 'bag', tmp_path / 'out', config=graph)
    assert not report.drops['/stereo/tsdf_fusion']
    assert report.published['/stereo/depth'] == 3
    assert report.published['/stereo/mesh'] >= 1
    assert report.published['/stereo/surface_points'] >= 1
    fused = evaluate_fusion_bag(tmp_path / 'out', voxel=0.05, truncation=4.0, max_depth=8.0)
    assert fused.rows[0].median < 0.15, fused.rows


def test_one_line_adds_fusion_to_the_multiview_graph(tmp_path: Path) -> None:
    """The multi-view graph's depth (once its filter has converged) fused by its sigma:
    the mesh is published and every depth frame the graph gave is fused without a drop."""
    write_sequence_bag(tmp_path / 'bag', dataclasses.replace(
        SequenceConfig(motion='sideways', n_frames=8), width=160, height=120))
    graph = load_graph_config(_uncommented('multiview_pipeline.yaml', tmp_path))
    report = process_bag(tmp_path / 'bag', tmp_path / 'out', config=graph)
    assert report.published['/mvs/depth'] >= 4
    assert not report.drops['/mvs/tsdf_fusion']
    assert report.published['/mvs/mesh'] >= 1


def test_real_views_fused_stay_in_the_temple_s_box(tmp_path: Path) -> None:
    """Middlebury's templeSparseRing (16 real views with known cameras, test/data): the
    multi-view graph with its tsdf_fusion line, from the command line. With min_weight 30
    (a voxel meshed once the views' evidence, (voxel / sigma)^2 summed, reaches 30), over
    98 % of the mesh's vertices lie inside the temple's bounding box (measured 99.6 % of
    2,871); with the default min_weight the stray depth of the dark background makes
    surface too (measured 69.5 % of 34,498)."""
    temple = REPO / 'test' / 'data' / 'middlebury_mvs' / 'templeSparseRing'
    views = tmp_path / 'temple'
    done = run_cli(['import-views', str(temple / 'templeSR_par.txt'), str(views), '--bbox',
                    '-0.073568', '0.021728', '-0.012445', '0.028855', '0.181892', '0.062736'])
    assert done.returncode == 0, done.stderr
    params = tmp_path / 'temple.yaml'
    params.write_text(
        'multiview_stereo:\n  ros__parameters: {min_depth: 0.45, max_depth: 0.8, planes: 128, '
        'delay: 1, uniqueness_ratio: 15.0}\n'
        'tsdf_fusion:\n  ros__parameters: {voxel_size: 0.002, min_integration_distance: 0.3, '
        'max_integration_distance: 0.8, min_weight: 30.0, esdf_rate_hz: 0.0}\n')
    done = run_cli(['process', str(views), str(tmp_path / 'out'), '--config',
                    str(_uncommented('multiview_pipeline.yaml', tmp_path)), '--namespace',
                    '/views', '--params', str(params)])
    assert done.returncode == 0, done.stderr
    done = run_cli(['eval', str(tmp_path / 'out')])
    assert done.returncode == 0, done.stderr
    found = re.search(r'inside the object\'s bounding box: (\d+) of (\d+)', done.stdout)
    assert found is not None, done.stdout
    inside, total = int(found.group(1)), int(found.group(2))
    assert total > 1000
    assert inside / total >= 0.98
