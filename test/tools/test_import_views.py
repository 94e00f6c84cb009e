"""`depth-nodes import-views`: real images with known cameras (Middlebury's name_par.txt, a
COLMAP text model) as a bag; the cameras and poses it writes against the files' own
numbers and against the simulator's truth; the errors a user can make.

Tolerances: poses to 1e-9 of the file's (R is made exactly orthonormal, the files give it
to about 1e-8); a COLMAP model written from known poses is read back to 1e-6.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import REPO, run_cli

from depth_nodes.core.geometry import Pose, quaternion_from_rpy, quaternion_of, rotation_matrix
from depth_nodes.errors import ConfigError
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.views import (
    read_colmap,
    read_middlebury,
    views_info,
    write_views_bag,
)

TEMPLE = REPO / 'test' / 'data' / 'middlebury_mvs' / 'templeSparseRing'
PAR = TEMPLE / 'templeSR_par.txt'
BBOX = (-0.073568, 0.021728, -0.012445, 0.028855, 0.181892, 0.062736)


def test_middlebury_cameras_are_read_as_the_file_states_them() -> None:
    views, missing = read_middlebury(PAR)
    assert len(views) == 16
    assert missing == []
    first = PAR.read_text().splitlines()[1].split()
    k = np.array([float(v) for v in first[1:10]]).reshape(3, 3)
    r = np.array([float(v) for v in first[10:19]]).reshape(3, 3)
    t = np.array([float(v) for v in first[19:22]])
    view = views[0]
    assert view.name == 'templeSR0001.png'
    assert (view.camera.fx, view.camera.fy, view.camera.cx, view.camera.cy) == (
        k[0, 0], k[1, 1], k[0, 2], k[1, 2])
    assert (view.camera.width, view.camera.height) == (640, 480)
    # the pose inverts x = K (R X + t): the camera centre is -R^T t, its axes R's rows
    np.testing.assert_allclose(view.pose.position, -r.T @ t, atol=1e-7)
    np.testing.assert_allclose(view.pose.rotation, r.T, atol=1e-7)
    # every camera looks at the object: the bounding box's centre is in front of it
    centre = (np.array(BBOX[:3]) + np.array(BBOX[3:])) / 2
    for v in views:
        local = v.pose.rotation.T @ (centre - v.pose.position)
        assert local[2] > 0.3


def test_missing_images_are_skipped_and_named(tmp_path: Path) -> None:
    lines = PAR.read_text().splitlines()
    par = tmp_path / 'x_par.txt'
    par.write_text('\n'.join([lines[0], lines[1], lines[2].replace('templeSR0002',
                                                                   'nothere')]) + '\n')
    image = cv2.imread(str(TEMPLE / 'templeSR0001.png'))
    cv2.imwrite(str(tmp_path / 'templeSR0001.png'), image)
    views, missing = read_middlebury(par)
    assert [v.name for v in views] == ['templeSR0001.png']
    assert missing == ['nothere.png']


@pytest.mark.parametrize(('content', 'message'), [
    ('', 'the first line must be the number of views'),
    ('2\nname 1 2 3\n', 'line 2: expected a name and 21 numbers'),
    ('1\nname ' + ' '.join(['x'] * 21) + '\n', 'line 2: not a number'),
    ('1\nname ' + ' '.join(['nan'] * 21) + '\n', 'line 2: the numbers must be finite'),
])
def test_a_malformed_par_file_is_one_line_naming_the_line(tmp_path: Path, content: str,
                                                           message: str) -> None:
    par = tmp_path / 'bad_par.txt'
    par.write_text(content)
    with pytest.raises(ConfigError, match=message):
        read_middlebury(par)


def _colmap_model(folder: Path, poses: list[Pose], model: str = 'PINHOLE') -> None:
    """A COLMAP text model of 64 x 48 views at ``poses`` (world -> camera as COLMAP
    stores it), with their images."""
    (folder / 'sparse').mkdir(parents=True)
    (folder / 'images').mkdir()
    params = {'PINHOLE': '50 51 31.5 23.5', 'SIMPLE_PINHOLE': '50 31.5 23.5',
              'OPENCV': '50 51 31.5 23.5 0.01 -0.002 0 0'}[model]
    (folder / 'sparse' / 'cameras.txt').write_text(
        f'# Camera list\n1 {model} 64 48 {params}\n')
    lines = ['# Image list', '#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME']
    rng = np.random.default_rng(1)
    for i, pose in enumerate(poses):
        world_to_camera = pose.inverse()
        qx, qy, qz, qw = quaternion_of(world_to_camera.rotation)
        t = world_to_camera.position
        lines.append(f'{i + 1} {qw} {qx} {qy} {qz} {t[0]} {t[1]} {t[2]} 1 view{i}.png')
        lines.append('')  # its 2-D points: none
        cv2.imwrite(str(folder / 'images' / f'view{i}.png'),
                    rng.integers(0, 255, (48, 64), np.uint8))
    (folder / 'sparse' / 'images.txt').write_text('\n'.join(lines) + '\n')


def test_a_colmap_model_gives_back_its_poses(tmp_path: Path) -> None:
    poses = [Pose(rotation_matrix(quaternion_from_rpy(0.1 * i, -0.05 * i, 0.2)),
                  np.array([0.3 * i, -0.1, 1.0 + i])) for i in range(3)]
    _colmap_model(tmp_path, poses)
    views, missing = read_colmap(tmp_path / 'sparse', tmp_path / 'images')
    assert missing == []
    assert [v.name for v in views] == ['view0.png', 'view1.png', 'view2.png']
    for view, pose in zip(views, poses, strict=True):
        np.testing.assert_allclose(view.pose.rotation, pose.rotation, atol=1e-6)
        np.testing.assert_allclose(view.pose.position, pose.position, atol=1e-6)
        assert (view.camera.fx, view.camera.fy, view.camera.cx) == (50.0, 51.0, 31.5)


def test_a_colmap_camera_with_distortion_is_undistorted_and_unknown_models_refused(
        tmp_path: Path) -> None:
    _colmap_model(tmp_path / 'a', [Pose()], model='OPENCV')
    views, _ = read_colmap(tmp_path / 'a' / 'sparse', tmp_path / 'a' / 'images')
    assert views[0].distortion == (0.01, -0.002, 0.0, 0.0)
    (tmp_path / 'b' / 'sparse').mkdir(parents=True)
    (tmp_path / 'b' / 'sparse' / 'cameras.txt').write_text('1 FISHEYE 64 48 1 2 3 4\n')
    (tmp_path / 'b' / 'sparse' / 'images.txt').write_text('')
    with pytest.raises(ConfigError, match=r"FISHEYE is not one of .* image_undistorter"):
        read_colmap(tmp_path / 'b' / 'sparse', tmp_path / 'b')


def test_the_bag_holds_images_cameras_and_poses(tmp_path: Path) -> None:
    views, _ = read_middlebury(PAR)
    count = write_views_bag(views[:3], tmp_path / 'bag', bbox=BBOX)
    assert count == 12
    with BagReader(tmp_path / 'bag') as reader:
        info = views_info(dict(reader.custom_data), tmp_path / 'bag')
        assert info.names == [v.name for v in views[:3]]
        assert info.bbox == BBOX
        assert set(reader.topics) == {'/views/image_rect', '/views/camera_info',
                                      '/views/pose', '/views/odom'}
        poses = [m.deserialize() for m in reader.messages(['/views/pose'])]
    for msg, view in zip(poses, views[:3], strict=True):
        p = msg.pose
        got = Pose.from_quaternion((p.position.x, p.position.y, p.position.z),
                                   (p.orientation.x, p.orientation.y, p.orientation.z,
                                    p.orientation.w))
        np.testing.assert_allclose(got.rotation, view.pose.rotation, atol=1e-9)
        np.testing.assert_allclose(got.position, view.pose.position, atol=1e-12)


def test_the_command_line_says_what_it_did_and_refuses_a_bad_box(tmp_path: Path) -> None:
    done = run_cli(['import-views', str(PAR), str(tmp_path / 'bag'), '--bbox', *map(str, BBOX)])
    assert done.returncode == 0, done.stderr
    assert '16 views from the Middlebury cameras' in done.stdout
    bad = run_cli(['import-views', str(PAR), str(tmp_path / 'bag2'), '--bbox', '1', '0', '0',
                   '0', '1', '1'])
    assert bad.returncode == 1
    assert bad.stderr.strip() == ('depth-nodes import-views: error: --bbox takes xmin ymin '
                                  'zmin xmax ymax zmax, each min below its max, got [1.0, 0.0, '
                                  '0.0, 0.0, 1.0, 1.0]')
    assert not (tmp_path / 'bag2').exists()
    missing = run_cli(['import-views', str(tmp_path / 'none.txt'), str(tmp_path / 'bag3')])
    assert missing.returncode == 1
    assert 'no such file' in missing.stderr
