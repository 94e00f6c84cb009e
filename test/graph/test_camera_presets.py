"""Camera presets (config/cameras, depth_nodes.graph.presets): each one's disparity range
is the disparity at its stated nearest depth; each one runs, through `process --camera`,
on a bundled bag rewritten by `depth-nodes convert` into its driver's topic layout; the
launch files take ``camera:=NAME``; a wrong name or a clash is a one-line error."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from helpers import REPO, run_cli

from depth_nodes.errors import ConfigError
from depth_nodes.graph.launching import launch_nodes
from depth_nodes.graph.presets import camera_names, disparity_range, load_camera

CONFIG = REPO / 'config'
PRESETS = camera_names(CONFIG)
#: How `convert` rewrites the bundled stereo bag (/stereo/{left,right}/image_raw) into each
#: stereo driver's layout, and the disparity topic the graph then publishes.
STEREO_LAYOUTS = {
    'realsense_d435': (['--namespace', '/camera/camera', '--rename', 'left=infra1',
                        '--rename', 'right=infra2', '--rename', 'image_raw=image_rect_raw'],
                       '/camera/camera/disparity_checked'),
    'zed2i': (['--namespace', '/zed/zed_node', '--rename', 'left=left_raw', '--rename',
               'right=right_raw', '--rename', 'image_raw=image_raw_color'],
              '/zed/zed_node/disparity_checked'),
    'oakd': (['--namespace', '/oak'], '/oak/disparity_checked'),
    'generic_stereo': (['--namespace', '/camera'], '/camera/disparity_checked'),
}
#: The bundled depth camera's bag (/camera/depth/image_rect_raw) in each depth driver's
#: layout, and the filtered depth the graph then publishes.
DEPTH_LAYOUTS = {
    'realsense_d435': (['--namespace', '/camera/camera'],
                       '/camera/camera/filtered/image_rect'),
    'zed2i': (['--namespace', '/zed/zed_node', '--rename', 'image_rect_raw=depth_registered'],
              '/zed/zed_node/filtered/image_rect'),
    'oakd': (['--namespace', '/oak', '--rename', 'depth=stereo', '--rename',
              'image_rect_raw=image_raw'], '/oak/filtered/image_rect'),
    'orbbec_femto': (['--rename', 'image_rect_raw=image_raw'], '/camera/filtered/image_rect'),
}


def test_the_shipped_presets() -> None:
    assert PRESETS == ['generic_stereo', 'oakd', 'orbbec_femto', 'realsense_d435',
                       'realsense_d455', 'zed2i']
    # every layout is run: realsense_d455 has the D435's (realsense-ros's) names
    assert set(STEREO_LAYOUTS) | {'orbbec_femto', 'realsense_d455'} == set(PRESETS)
    d435, d455 = (load_camera(n, CONFIG) for n in ('realsense_d435', 'realsense_d455'))
    assert [(s.name, s.namespace, s.remappings) for s in d455.config.nodes] == \
        [(s.name, s.namespace, s.remappings) for s in d435.config.nodes]


@pytest.mark.parametrize('name', PRESETS)
def test_each_preset_states_its_numbers_and_its_range_follows_from_them(name: str) -> None:
    preset = load_camera(name, CONFIG)
    text = (CONFIG / 'cameras' / f'{name}.yaml').read_text()
    assert preset.camera['description']
    # where the topics and numbers come from
    assert '# Topics' in text
    assert '# Numbers' in text
    stereo = next((s for s in preset.config.nodes if s.plugin == 'sgm_stereo'), None)
    if stereo is None:  # a depth camera: the depth filter only
        assert name == 'orbbec_femto'
        assert preset.config.nodes[0].plugin == 'depth_filter'
        return
    cam = preset.camera
    expected = disparity_range(cam['focal_px'], cam['baseline_m'], cam['nearest_m'])
    assert stereo.parameters['disparity_range'] == expected
    comments = ' '.join(line.lstrip('# ') for line in text.splitlines() if line.startswith('#'))
    assert f'multiple of 16: {expected}' in comments  # the arithmetic, written out


def test_the_disparity_range_is_the_nearest_disparity_rounded_up_to_16() -> None:
    assert disparity_range(446.8, 0.050, 0.28) == 80  # 79.8 px
    assert disparity_range(500.0, 0.120, 0.5) == 128  # 120 px
    assert disparity_range(400.0, 0.1, 0.5) == 80  # exactly 80: not rounded further


#: Every layout run: (preset, bundled bag, convert options, topic, messages at least).
RUNS = [(name, 'stereo_qvga_color', options, topic, 1)
        for name, (options, topic) in sorted(STEREO_LAYOUTS.items())] + \
       [(name, 'depth_moving_camera', options, topic, 12)
        for name, (options, topic) in sorted(DEPTH_LAYOUTS.items())]


@pytest.mark.slow
@pytest.mark.parametrize(('name', 'bag', 'options', 'topic', 'least'), RUNS,
                         ids=[f'{r[0]}-{r[1]}' for r in RUNS])
def test_a_preset_runs_on_its_driver_s_layout(name: str, bag: str, options: list[str],
                                              topic: str, least: int, tmp_path: Path) -> None:
    """The bundled bag rewritten into the driver's layout: the preset's graph publishes
    its output on the driver's names without a drop."""
    done = run_cli(['convert', str(REPO / 'bags' / bag), str(tmp_path / 'driver'), *options])
    assert done.returncode == 0, done.stderr
    done = run_cli(['process', str(tmp_path / 'driver'), str(tmp_path / 'out'), '--camera',
                    name])
    assert done.returncode == 0, done.stderr
    published = dict(re.findall(r'^\s+(/\S+)\s+(\d+)$', done.stdout, re.MULTILINE))
    assert int(published.get(topic, 0)) >= least, done.stdout
    assert 'dropped: 0' in done.stdout, done.stdout


def test_a_wrong_name_lists_the_presets_and_a_clash_is_refused(tmp_path: Path) -> None:
    done = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'), str(tmp_path / 'o'),
                    '--camera', 'kinect'])
    assert done.returncode == 1
    assert done.stderr.strip() == (
        "depth-nodes process: error: no camera preset 'kinect' (presets: "
        f'{", ".join(PRESETS)}; in {CONFIG / "cameras"})')
    done = run_cli(['process', str(REPO / 'bags' / 'stereo_qvga_color'), str(tmp_path / 'o'),
                    '--camera', 'oakd', '--config', 'config/stereo_pipeline.yaml'])
    assert done.returncode == 1
    assert done.stderr.strip() == ('depth-nodes process: error: --camera and --config: give '
                                   'one (a preset names its graph)')
    assert not (tmp_path / 'o').exists()


def test_the_launch_files_take_a_camera() -> None:
    nodes = launch_nodes(CONFIG / 'stereo_pipeline.yaml', camera='realsense_d435')
    by_name = {n['name']: n for n in nodes}
    assert by_name['sgm_stereo']['namespace'] == '/camera/camera'
    assert by_name['rectify_left']['namespace'] == '/camera/camera/infra1'
    assert by_name['sgm_stereo']['parameters'][0]['disparity_range'] == 80
    assert by_name['depth_filter']['parameters'][0]['stereo_baseline'] == 0.050
    with pytest.raises(ConfigError, match="no camera preset 'nope'"):
        launch_nodes(CONFIG / 'stereo_pipeline.yaml', camera='nope')


def test_convert_renames_levels_below_the_namespace_and_refuses_a_bad_pair(
        tmp_path: Path) -> None:
    done = run_cli(['convert', str(REPO / 'bags' / 'depth_moving_camera'), str(tmp_path / 'a'),
                    '--rename', 'depth'])
    assert done.returncode == 1
    assert done.stderr.strip() == ('depth-nodes convert: error: --rename depth: expected '
                                   'OLD=NEW, e.g. left=infra1')
    done = run_cli(['convert', str(REPO / 'bags' / 'depth_moving_camera'), str(tmp_path / 'b'),
                    '--rename', 'depth=stereo', '--rename', 'camera=cam'])
    assert done.returncode == 0, done.stderr
    topics = re.findall(r'^\s+(/\S+)\s+\d+$', done.stdout, re.MULTILINE)
    assert '/camera/stereo/image_rect_raw' in topics  # below the namespace only
    assert not any(t.startswith('/cam/') for t in topics)
