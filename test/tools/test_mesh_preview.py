"""The mesh preview (depth_nodes.tools.evaluation.mesh_preview): shapes whose picture is
known drawn through explicit cameras (the covered pixels against the analytic projection,
the z-buffer, Lambert's law), the kernels against a plain ray caster
(test/reference/mesh_preview.py), the automatic view, the errors, and `export-mesh
--preview` on a processed bag.

Tolerances: a covered pixel set matches the analytic one except within 1 pixel of its
border; grey levels match to 1 (rounding) where two formulas compute the same shade.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import REPO, kernel_size, run_cli
from reference.mesh_preview import (
    render_reference,
    vertex_normals_reference,
    visible_reference,
)

from depth_nodes.core.fusion.ply import read_ply
from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.errors import ArgumentError
from depth_nodes.tools.cli import export_mesh
from depth_nodes.tools.evaluation.mesh_preview import (
    AMBIENT,
    AUTO_ELEVATION_DEG,
    BACKGROUND,
    DIFFUSE,
    GREY,
    LIGHT,
    NEAR_M,
    _rasterise,
    _vertex_normals,
    auto_view,
    render_mesh,
)

W, H, F = 120, 90, 100.0
CAMERA = Intrinsics(F, F, (W - 1) / 2, (H - 1) / 2, W, H)
#: A camera at the origin of the world, looking along +z.
AT_ORIGIN = (Pose(), CAMERA)


def _quad(corners: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """Four corners in order around a quadrilateral, as two triangles."""
    return np.array(corners, np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def _square(centre: np.ndarray, normal: np.ndarray, half: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """A square of side ``2 half`` around ``centre``, facing ``normal``."""
    n = normal / np.linalg.norm(normal)
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    return _quad([list(centre + half * (sa * a + sb * b))
                  for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def _covered(image: np.ndarray) -> np.ndarray:
    return (image != np.array(BACKGROUND, np.uint8)).any(axis=2)


def _cube() -> tuple[np.ndarray, np.ndarray]:
    """The unit cube [0, 1]^3: 8 corners, 12 triangles."""
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)],
                       np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    faces = [tri for a, b, c, d in quads for tri in ((a, b, c), (a, c, d))]
    return corners, np.array(faces, np.int32)


def _look_at(position: np.ndarray, target: np.ndarray) -> Pose:
    """An optical camera at ``position`` looking at ``target``, z of the world up."""
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return Pose(np.column_stack([right, np.cross(forward, right), forward]), position)


def _project(points: np.ndarray, pose: Pose, camera: Intrinsics) -> np.ndarray:
    """(N, 3) world points -> (N, 3) pixel u, v and depth z."""
    local = (np.asarray(points, np.float64) - pose.position) @ pose.rotation
    return np.column_stack([camera.fx * local[:, 0] / local[:, 2] + camera.cx,
                            camera.fy * local[:, 1] / local[:, 2] + camera.cy, local[:, 2]])


class TestKnownShapes:
    def test_a_square_facing_the_camera_covers_its_projection(self) -> None:
        # the rectangle [-0.3, 0.7] x [-0.4, 0.2] at z = 2: pixels u in [44.5, 94.5],
        # v in [24.5, 54.5]
        v, f = _quad([[-0.3, -0.4, 2.0], [0.7, -0.4, 2.0], [0.7, 0.2, 2.0], [-0.3, 0.2, 2.0]])
        image = render_mesh(v, f, width=W, height=H, view=AT_ORIGIN)
        covered = _covered(image)
        u, w = np.arange(W)[None, :], np.arange(H)[:, None]
        left, right = CAMERA.cx + F * -0.3 / 2, CAMERA.cx + F * 0.7 / 2
        top, bottom = CAMERA.cy + F * -0.4 / 2, CAMERA.cy + F * 0.2 / 2
        inside = (u >= left + 1) & (u <= right - 1) & (w >= top + 1) & (w <= bottom - 1)
        outside = (u < left - 1) | (u > right + 1) | (w < top - 1) | (w > bottom + 1)
        assert covered[inside].all()
        assert not covered[outside].any()
        assert covered.sum() == 50 * 30  # the centres strictly inside: no tie on the border
        # one flat face: one shade, its normal (0, 0, -1) against the light
        expected = math.floor(GREY[0] * (AMBIENT + DIFFUSE * abs(LIGHT[2])) + 0.5)
        np.testing.assert_array_equal(np.unique(image[covered]), [expected])

    def test_a_cube_seen_from_a_corner_covers_the_hull_of_its_corners(self) -> None:
        v, f = _cube()
        pose = _look_at(np.array([3.1, -2.3, 2.2]), np.array([0.5, 0.4, 0.5]))
        image = render_mesh(v, f, width=W, height=H, view=(pose, CAMERA))
        covered = _covered(image)
        hull = cv2.convexHull(_project(v, pose, CAMERA)[:, :2].astype(np.float32))
        distance = np.array([[cv2.pointPolygonTest(hull, (float(x), float(y)), True)
                              for x in range(W)] for y in range(H)])
        assert covered[distance >= 1].all()
        assert not covered[distance <= -1].any()
        assert covered.sum() > 500
        # the same picture seen through the cube's faces wound the other way
        np.testing.assert_array_equal(
            render_mesh(v, f[:, ::-1], width=W, height=H, view=(pose, CAMERA)), image)

    @pytest.mark.parametrize('near_first', [True, False])
    def test_the_z_buffer_shows_the_nearer_of_two_squares(self, near_first: bool) -> None:
        near_v, near_f = _quad([[-0.5, -0.3, 2.0], [0.2, -0.3, 2.0], [0.2, 0.3, 2.0],
                                [-0.5, 0.3, 2.0]])
        far_v, far_f = _quad([[-0.2, -0.4, 2.5], [0.6, -0.4, 2.5], [0.6, 0.2, 2.5],
                              [-0.2, 0.2, 2.5]])
        red = np.tile(np.array([[230, 0, 0]], np.uint8), (4, 1))
        blue = np.tile(np.array([[0, 0, 230]], np.uint8), (4, 1))
        parts = [(near_v, near_f, red), (far_v, far_f, blue)]
        if not near_first:
            parts.reverse()
        v = np.concatenate([p[0] for p in parts])
        f = np.concatenate([parts[0][1], parts[1][1] + 4])
        c = np.concatenate([p[2] for p in parts])
        image = render_mesh(v, f, width=W, height=H, colors=c, view=AT_ORIGIN)
        # pixels both squares cover, 1 px in from their borders
        u_near = CAMERA.cx + F * np.array([-0.5, 0.2]) / 2.0
        u_far = CAMERA.cx + F * np.array([-0.2, 0.6]) / 2.5
        v_near = CAMERA.cy + F * np.array([-0.3, 0.3]) / 2.0
        v_far = CAMERA.cy + F * np.array([-0.4, 0.2]) / 2.5
        xs = np.arange(math.ceil(max(u_near[0], u_far[0]) + 1), math.floor(u_near[1] - 1) + 1)
        ys = np.arange(math.ceil(max(v_near[0], v_far[0]) + 1),
                       math.floor(min(v_near[1], v_far[1]) - 1) + 1)
        both = image[np.ix_(ys, xs)]
        assert both.size > 100
        assert (both[..., 0] > 0).all()
        assert (both[..., 2] == 0).all()
        # and the far one where it shows alone
        assert (image[ys[0]:ys[-1], math.ceil(u_near[1] + 1):math.floor(u_far[1] - 1), 2]
                > 0).all()

    @pytest.mark.parametrize('smooth', [True, False])
    def test_a_face_towards_the_light_is_brighter_than_a_grazing_one(self,
                                                                     smooth: bool) -> None:
        grazing = np.cross(LIGHT, [1.0, 0.0, 0.0])  # at right angles to the light
        shades = {}
        for name, normal in (('lit', LIGHT), ('grazing', grazing)):
            v, f = _square(np.array([0.0, 0.0, 3.0]), normal, 0.6)
            image = render_mesh(v, f, width=W, height=H, view=AT_ORIGIN, smooth=smooth)
            covered = _covered(image)
            assert covered.sum() > 200
            shades[name] = np.unique(image[covered])
        assert shades['lit'].min() > shades['grazing'].max()
        np.testing.assert_array_equal(shades['lit'], [GREY[0]])  # AMBIENT + DIFFUSE = 1
        assert np.abs(shades['grazing'].astype(int) - GREY[0] * AMBIENT).max() <= 1

    def test_triangles_with_a_vertex_not_finite_are_left_out(self) -> None:
        v, f = _cube()
        pose = _look_at(np.array([3.0, -2.0, 2.0]), np.array([0.5, 0.5, 0.5]))
        image = render_mesh(v, f, width=W, height=H, view=(pose, CAMERA))
        v_bad = np.concatenate([v, [[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0]]]).astype(np.float32)
        f_bad = np.concatenate([f, [[0, 8, 1], [2, 3, 9]]]).astype(np.int32)
        np.testing.assert_array_equal(
            render_mesh(v_bad, f_bad, width=W, height=H, view=(pose, CAMERA)), image)

    def test_a_mesh_without_area_draws_the_background(self) -> None:
        v = np.ones((3, 3), np.float32)
        image = render_mesh(v, np.array([[0, 1, 2]]), width=32, height=24)
        assert (image == np.array(BACKGROUND, np.uint8)).all()


@pytest.mark.kernels
class TestAgainstTheReference:
    """The rasteriser against the plain ray caster, on random triangles, some crossing the
    near plane."""

    @staticmethod
    def _mesh(seed: int, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``count`` random triangles over ``2 count`` vertices (shared, so that smooth
        normals are not face normals), a sixth of the vertices before the near plane or
        behind the camera."""
        rng = np.random.default_rng(seed)
        n = 2 * count
        vertices = np.column_stack([rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(0.5, 3.0, n)])
        vertices[rng.choice(n, n // 6, replace=False), 2] = rng.uniform(-1.0, 0.3, n // 6)
        faces = np.array([rng.choice(n, 3, replace=False) for _ in range(count)], np.int32)
        colors = rng.integers(0, 256, (n, 3), dtype=np.uint8)
        return vertices.astype(np.float32), faces, colors

    def test_the_z_buffer_equals_the_ray_caster(self) -> None:
        width, height, count = kernel_size((48, 36, 40), (20, 15, 12))
        camera = Intrinsics(20.0, 22.0, (width - 1) / 2 + 0.3, (height - 1) / 2 - 0.2,
                            width, height)
        for seed in range(kernel_size(3, 1)):
            v, f, _ = self._mesh(seed, count)
            points = v.astype(np.float64)
            inv_depth = np.zeros((height, width))
            index = np.full((height, width), -1, np.int32)
            _rasterise(points, f, camera.fx, camera.fy, camera.cx, camera.cy, NEAR_M,
                       inv_depth, index, np.empty((7, 3)))
            want_depth, want_index = visible_reference(points, f, camera, NEAR_M)
            np.testing.assert_array_equal(index, want_index)
            np.testing.assert_allclose(inv_depth, want_depth, rtol=1e-9, atol=0)
            assert (index >= 0).mean() > 0.3

    def test_vertex_normals_equal_the_reference(self) -> None:
        v, f = _cube()
        points = v.astype(np.float64) * [1.0, 2.0, 0.5]
        normals, facing = np.zeros_like(points), np.zeros(4)
        _vertex_normals(points, f, normals, facing)
        np.testing.assert_allclose(normals, vertex_normals_reference(points, f), atol=1e-12)
        np.testing.assert_allclose(facing[:3], 0.0, atol=1e-12)  # a closed surface
        assert facing[3] == pytest.approx(2 * 2 * (2 * 0.5 + 1 * 0.5 + 1 * 2))

    @pytest.mark.parametrize(('smooth', 'coloured'), [(True, False), (True, True),
                                                      (False, True)])
    def test_the_picture_equals_the_reference(self, smooth: bool, coloured: bool) -> None:
        width, height, count = kernel_size((40, 30, 30), (16, 12, 10))
        pose = _look_at(np.array([0.2, -0.3, -0.4]), np.array([0.0, 0.0, 2.0]))
        camera = Intrinsics(18.0, 18.0, (width - 1) / 2, (height - 1) / 2, width, height)
        v, f, c = self._mesh(7, count)
        colors = c if coloured else None
        got = render_mesh(v, f, width=width, height=height, colors=colors,
                          view=(pose, camera), smooth=smooth)
        want = render_reference(v, f, pose, camera, NEAR_M, colors=colors, smooth=smooth)
        assert np.abs(got.astype(int) - want).max() <= 1
        assert (got != want).any(axis=2).mean() < 0.05
        assert _covered(got).mean() > 0.2


class TestAutomaticView:
    @pytest.mark.parametrize(('size', 'up', 'scale'), [
        ((960, 720), (0.0, 0.0, 1.0), (10.0, 1.0, 0.2)),
        ((200, 600), (0.0, -1.0, 0.0), (1.0, 3.0, 0.5)),
        ((640, 480), (1.0, 0.0, 0.0), (0.05, 0.02, 0.01)),
        ((64, 48), (0.3, 0.2, 1.0), (2.0, 2.0, 2.0)),
    ])
    def test_every_vertex_is_inside_the_image(self, size: tuple[int, int],
                                              up: tuple[float, float, float],
                                              scale: tuple[float, float, float]) -> None:
        rng = np.random.default_rng(3)
        v = (rng.normal(size=(300, 3)) * scale + [5.0, -2.0, 1.0]).astype(np.float32)
        f = np.concatenate([rng.permutation(len(v)).reshape(-1, 3),  # every vertex used
                            rng.integers(0, len(v), (100, 3))]).astype(np.int32)
        width, height = size
        pose, camera = auto_view(v, f, width=width, height=height, up=up)
        assert (camera.width, camera.height) == size
        uvz = _project(v, pose, camera)
        assert (uvz[:, 2] > 0).all()
        assert (uvz[:, 0] >= 0).all()
        assert (uvz[:, 0] <= width - 1).all()
        assert (uvz[:, 1] >= 0).all()
        assert (uvz[:, 1] <= height - 1).all()
        # from above: the camera's direction from the centre rises AUTO_ELEVATION_DEG
        centre = (v.min(axis=0).astype(float) + v.max(axis=0)) / 2.0
        towards = (pose.position - centre) / np.linalg.norm(pose.position - centre)
        rise = math.degrees(math.asin(towards @ (np.array(up) / np.linalg.norm(up))))
        assert rise == pytest.approx(AUTO_ELEVATION_DEG, abs=1e-6)
        image = render_mesh(v, f, width=width, height=height, up=up)
        np.testing.assert_array_equal(image, render_mesh(v, f, width=width, height=height,
                                                         view=(pose, camera)))
        covered = _covered(image)
        assert covered.any()
        assert not (covered[0].any())
        assert not (covered[-1].any())
        assert not (covered[:, 0].any())
        assert not (covered[:, -1].any())

    @pytest.mark.parametrize('side', [-1.0, 1.0])
    def test_it_looks_from_the_side_the_mesh_faces(self, side: float) -> None:
        v, f = _square(np.array([2.0, 1.0, 0.5]), np.array([side, 0.0, 0.0]), 1.0)
        pose, _ = auto_view(v, f)
        assert np.sign(pose.position[0] - 2.0) == side


@pytest.mark.parametrize(('call', 'message'), [
    (lambda v, f: render_mesh(v[:, :2], f), r'^vertices must be \(N, 3\) numbers, got shape'),
    (lambda v, f: render_mesh(v.astype(str), f), r'^vertices must be \(N, 3\) numbers'),
    (lambda v, f: render_mesh(v, f[:, :2]), r'^faces must be \(M, 3\) integers, got shape '
                                            r'\(12, 2\)'),
    (lambda v, f: render_mesh(v, f.astype(np.float32)), r'^faces must be \(M, 3\) integers'),
    (lambda v, f: render_mesh(v, f[:0]), r'^the mesh has no triangle to render$'),
    (lambda v, f: render_mesh(v, np.where(f == 7, 8, f)),
     r'^faces: index 8 is outside the 8 vertices$'),
    (lambda v, f: render_mesh(v, np.where(f == 7, -1, f)),
     r'^faces: index -1 is outside the 8 vertices$'),
    (lambda v, f: render_mesh(np.full_like(v, np.nan), f),
     r'^every one of the 12 triangles has a vertex that is not finite$'),
    (lambda v, f: render_mesh(v, f, colors=np.zeros((8, 3))),
     r'^colors must be \(8, 3\) uint8 like the vertices, got \(8, 3\) float64$'),
    (lambda v, f: render_mesh(v, f, colors=np.zeros((7, 3), np.uint8)),
     r'^colors must be \(8, 3\) uint8'),
    (lambda v, f: render_mesh(v, f, width=0), r'^width must be an integer from 1 to 16384, '
                                              r'got 0$'),
    (lambda v, f: render_mesh(v, f, height=2.5), r'^height must be an integer from 1'),
    (lambda v, f: render_mesh(v, f, up=(0, 0, 0)), r'^up must be 3 finite numbers'),
    (lambda v, f: render_mesh(v, f, view=np.eye(4)),
     r'^view must be None or \(Pose, Intrinsics\), got ndarray$'),
    (lambda v, f: render_mesh(v, f, view=AT_ORIGIN),
     r"^view: the camera's image is 120x90, the picture 960x720 \(pass width and height"),
    (lambda v, f: render_mesh(v, f, width=W, height=H,
                              view=(Pose(), Intrinsics(0.0, F, 1.0, 1.0, W, H))),
     r'^view: the focal lengths must be positive and every value finite'),
    (lambda v, f: render_mesh(v, f, width=W, height=H,
                              view=(Pose(2 * np.eye(3), np.zeros(3)), CAMERA)),
     r"^a pose's rotation is not a rotation matrix"),
    (lambda v, f: auto_view(v, f, width=-3), r'^width must be an integer'),
])
def test_errors_say_what_is_wrong(call: object, message: str) -> None:
    v, f = _cube()
    with pytest.raises(ArgumentError, match=message) as caught:
        call(v, f)  # type: ignore[operator]
    assert '\n' not in str(caught.value)


@pytest.fixture(scope='module')
def processed_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """bags/depth_moving_camera through config/fusion_pipeline.yaml."""
    out = tmp_path_factory.mktemp('fused') / 'bag'
    result = run_cli(['process', str(REPO / 'bags' / 'depth_moving_camera'), str(out),
                      '--config', str(REPO / 'config' / 'fusion_pipeline.yaml')])
    assert result.returncode == 0, result.stderr[-2000:]
    return out


@pytest.mark.slow
class TestExportMeshPreview:
    def test_it_writes_the_picture_of_the_exported_mesh(self, processed_bag: Path,
                                                        tmp_path: Path) -> None:
        ply, png = tmp_path / 'mesh.ply', tmp_path / 'mesh.png'
        result = run_cli(['export-mesh', str(processed_bag), str(ply), '--preview', str(png)])
        assert result.returncode == 0, result.stderr
        assert f'{png}: preview 960x720, up -y' in result.stdout  # a simulator's bag: y down
        vertices, faces, colors = read_ply(ply)
        picture = cv2.imread(str(png), cv2.IMREAD_COLOR)
        assert picture is not None
        np.testing.assert_array_equal(  # RGB written as BGR
            picture[:, :, ::-1],
            render_mesh(vertices, faces, colors=colors, up=(0.0, -1.0, 0.0)))
        assert 0.05 < _covered(picture).mean() < 0.9

    def test_errors_are_one_line_and_write_nothing(self, processed_bag: Path,
                                                   tmp_path: Path) -> None:
        ply = tmp_path / 'mesh.ply'
        (tmp_path / 'old.png').write_bytes(b'')
        (tmp_path / 'folder.png').mkdir()
        for preview, message in (
                (tmp_path / 'missing' / 'p.png', f'{tmp_path / "missing"} is not a folder'),
                (tmp_path / 'old.png', f'{tmp_path / "old.png"} exists (--force replaces it)'),
                (tmp_path / 'folder.png', f'{tmp_path / "folder.png"} is a folder'),
                (tmp_path / 'p.xyz', f'--preview {tmp_path / "p.xyz"}: OpenCV writes no such '
                                     'image (name it .png)')):
            result = run_cli(['export-mesh', str(processed_bag), str(ply),
                              '--preview', str(preview)])
            assert result.returncode == 1
            assert result.stderr == f'depth-nodes export-mesh: error: {message}\n'
            assert not ply.exists()

    def test_a_picture_that_cannot_be_written_is_a_one_line_error(
            self, processed_bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
            capsys: pytest.CaptureFixture[str]) -> None:
        monkeypatch.setattr(cv2, 'imwrite', lambda *_: False)  # a full disk, say
        args = argparse.Namespace(bag=str(processed_bag), out=str(tmp_path / 'm.ply'),
                                  topic=None, preview=str(tmp_path / 'p.png'),
                                  preview_up='z', force=False)
        with pytest.raises(ArgumentError, match=f'^cannot write {tmp_path / "p.png"}$'):
            export_mesh.run(args)
        assert (tmp_path / 'm.ply').exists()  # the mesh itself was written
        assert 'm.ply: ' in capsys.readouterr().out
