"""`depth-nodes import-views`: real images with known cameras as a bag the multiview_stereo
node runs on.

Two formats of known cameras:

* **Middlebury multi-view** (``name_par.txt``, Seitz et al. 2006): the first line is the
  number of views, then one line per image, ``name k11 .. k33 r11 .. r33 t1 t2 t3``, the
  projection ``K [R | t]`` taking world points to pixels. Views listed but absent from the
  folder are skipped, and said so.
* **COLMAP's text model** (``cameras.txt`` + ``images.txt`` of a sparse model, with the
  images folder): ``images.txt`` holds per image ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID
  NAME`` (world to camera) and a line of 2-D points; ``cameras.txt`` the cameras. PINHOLE and
  SIMPLE_PINHOLE are taken as they are; SIMPLE_RADIAL, RADIAL and OPENCV images are
  undistorted first (their pinhole part kept).

The bag (namespace ``/views`` by default; views ``1 / rate`` seconds apart, in the order of
the file) holds ``image_rect`` (the image as it is: mono8, rgb8 or mono16), ``camera_info``
(the pinhole camera: D zero, P = [K | 0]), ``pose`` (geometry_msgs/PoseStamped: the camera's
optical frame in the world) and ``odom`` (the same as nav_msgs/Odometry). Its metadata
(:data:`VIEWS_KEY`) records the view names and the object's bounding box, if given, for
`depth-nodes eval`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.geometry import Intrinsics, Pose
from depth_nodes.core.stamps import NS_PER_S
from depth_nodes.errors import BagError, ConfigError
from depth_nodes.ros.camera_info import model_to_camera_info
from depth_nodes.ros.image import array_to_image
from depth_nodes.tools.bags.io import BagWriter
from depth_nodes.tools.bags.multiview import (
    camera_model,
    odometry_message,
    pose_message,
)
from depth_nodes.tools.signals import stop_requested

VIEWS_KEY = 'depth_nodes.import_views'
FORMATS = ('middlebury', 'colmap')
START_NS = 1_700_000_000_000_000_000
FRAME_ID = 'camera_optical'
#: COLMAP camera models taken, with their parameters' names.
COLMAP_MODELS = {'SIMPLE_PINHOLE': 3, 'PINHOLE': 4, 'SIMPLE_RADIAL': 4, 'RADIAL': 5,
                 'OPENCV': 8}


@dataclass(frozen=True)
class View:
    """One image with its camera.

    Attributes:
        name: The file name.
        path: Where the image is.
        camera: The pinhole camera (after undistortion).
        pose: The camera's optical frame in the world.
        distortion: OpenCV distortion coefficients to remove first (empty: none).
    """

    name: str
    path: Path
    camera: Intrinsics
    pose: Pose
    distortion: tuple[float, ...] = ()


@dataclass(frozen=True)
class ViewsInfo:
    """What import-views recorded in a bag's metadata."""

    names: list[str]
    bbox: tuple[float, ...] | None
    namespace: str

    @property
    def image_topic(self) -> str:
        """The images' topic."""
        return f'{self.namespace}/image_rect'

    @property
    def camera_info_topic(self) -> str:
        """The cameras' topic."""
        return f'{self.namespace}/camera_info'

    @property
    def pose_topic(self) -> str:
        """The poses' topic."""
        return f'{self.namespace}/pose'


def _pose_from_projection(rotation: NDArray[np.float64],
                          translation: NDArray[np.float64]) -> Pose:
    """The camera pose of ``x = K (R X + t)``: camera -> world is ``R^T``, centre ``-R^T t``."""
    r = np.asarray(rotation, np.float64)
    # the files give R to about 1e-8: make it exactly orthonormal
    u, _, vt = np.linalg.svd(r)
    r = u @ vt
    return Pose(r.T, -r.T @ np.asarray(translation, np.float64)).validate()


def read_middlebury(par_file: str | Path) -> tuple[list[View], list[str]]:
    """The views of a Middlebury ``*_par.txt`` that exist beside it, and the names of those
    that do not.

    Raises:
        ConfigError: The file is missing or malformed (the line is named).
    """
    path = Path(par_file)
    if not path.is_file():
        raise ConfigError(f'{path}: no such file (a Middlebury name_par.txt)')
    lines = [line.split() for line in path.read_text().splitlines() if line.strip()]
    if not lines or len(lines[0]) != 1 or not lines[0][0].isdigit():
        raise ConfigError(f'{path}: the first line must be the number of views')
    views, missing = [], []
    for number, parts in enumerate(lines[1:], start=2):
        if len(parts) != 22:
            raise ConfigError(f'{path} line {number}: expected a name and 21 numbers '
                              f'(K, R, t), got {len(parts)} fields')
        try:
            values = np.array([float(v) for v in parts[1:]])
        except ValueError:
            raise ConfigError(f'{path} line {number}: not a number in {parts[1:]}') from None
        if not np.isfinite(values).all():
            raise ConfigError(f'{path} line {number}: the numbers must be finite')
        k = values[:9].reshape(3, 3)
        image = path.parent / parts[0]
        if not image.is_file():
            missing.append(parts[0])
            continue
        size = _image_size(image)
        camera = Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], size[0], size[1])
        try:
            pose = _pose_from_projection(values[9:18].reshape(3, 3), values[18:21])
        except Exception as exc:
            raise ConfigError(f'{path} line {number}: R is not a rotation ({exc})') from None
        views.append(View(parts[0], image, camera, pose))
    return views, missing


def read_colmap(model: str | Path, images: str | Path) -> tuple[list[View], list[str]]:
    """The views of a COLMAP text model (``cameras.txt``, ``images.txt`` in ``model``)
    whose image is in ``images``, and the names of those that are not.

    Raises:
        ConfigError: A file missing or malformed, or a camera model not taken.
    """
    folder, image_dir = Path(model), Path(images)
    cameras: dict[int, tuple[str, int, int, list[float]]] = {}
    for number, parts in _records(folder / 'cameras.txt'):
        if len(parts) < 4:
            raise ConfigError(f'{folder / "cameras.txt"} line {number}: expected CAMERA_ID '
                              'MODEL WIDTH HEIGHT PARAMS')
        model_name = parts[1]
        if model_name not in COLMAP_MODELS:
            raise ConfigError(f'{folder / "cameras.txt"} line {number}: camera model '
                              f'{model_name} is not one of {", ".join(COLMAP_MODELS)} (run '
                              "COLMAP's image_undistorter for the others)")
        try:
            cameras[int(parts[0])] = (model_name, int(parts[2]), int(parts[3]),
                                      [float(v) for v in parts[4:]])
        except ValueError:
            raise ConfigError(f'{folder / "cameras.txt"} line {number}: not a number') from None
        if len(cameras[int(parts[0])][3]) != COLMAP_MODELS[model_name]:
            raise ConfigError(f'{folder / "cameras.txt"} line {number}: {model_name} takes '
                              f'{COLMAP_MODELS[model_name]} parameters')
    records = _records(folder / 'images.txt', keep_empty=True)
    views, missing = [], []
    for (number, parts), _ in zip(records[::2], records[1::2], strict=False):
        if len(parts) < 10:
            raise ConfigError(f'{folder / "images.txt"} line {number}: expected IMAGE_ID QW QX '
                              'QY QZ TX TY TZ CAMERA_ID NAME')
        try:
            qw, qx, qy, qz, tx, ty, tz = (float(v) for v in parts[1:8])
            camera_id = int(parts[8])
        except ValueError:
            raise ConfigError(f'{folder / "images.txt"} line {number}: not a number') from None
        if camera_id not in cameras:
            raise ConfigError(f'{folder / "images.txt"} line {number}: camera {camera_id} is '
                              'not in cameras.txt')
        name = ' '.join(parts[9:])
        path = image_dir / name
        if not path.is_file():
            missing.append(name)
            continue
        model_name, width, height, params = cameras[camera_id]
        camera, distortion = _colmap_camera(model_name, width, height, params)
        world_to_camera = Pose.from_quaternion((0, 0, 0), (qx, qy, qz, qw)).rotation
        pose = _pose_from_projection(world_to_camera, np.array([tx, ty, tz]))
        views.append(View(name, path, camera, pose, distortion))
    return views, missing


def _records(path: Path, *, keep_empty: bool = False) -> list[tuple[int, list[str]]]:
    """(line number, fields) of a COLMAP text file, comments left out."""
    if not path.is_file():
        raise ConfigError(f'{path}: no such file (a COLMAP text model)')
    out = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.startswith('#') or (not line.strip() and not keep_empty):
            continue
        out.append((number, line.split()))
    return out


def _colmap_camera(model: str, width: int, height: int,
                   p: list[float]) -> tuple[Intrinsics, tuple[float, ...]]:
    if model == 'SIMPLE_PINHOLE':
        return Intrinsics(p[0], p[0], p[1], p[2], width, height), ()
    if model == 'PINHOLE':
        return Intrinsics(p[0], p[1], p[2], p[3], width, height), ()
    if model == 'SIMPLE_RADIAL':
        return Intrinsics(p[0], p[0], p[1], p[2], width, height), (p[3], 0.0, 0.0, 0.0)
    if model == 'RADIAL':
        return Intrinsics(p[0], p[0], p[1], p[2], width, height), (p[3], p[4], 0.0, 0.0)
    return Intrinsics(p[0], p[1], p[2], p[3], width, height), tuple(p[4:8])  # OPENCV


def _image_size(path: Path) -> tuple[int, int]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ConfigError(f'{path}: not an image OpenCV can read')
    return int(image.shape[1]), int(image.shape[0])


def _load(view: View) -> tuple[NDArray[np.generic], str]:
    """The view's pixels (undistorted if needed) and their encoding."""
    image = cv2.imread(str(view.path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ConfigError(f'{view.path}: not an image OpenCV can read')
    if (image.shape[1], image.shape[0]) != (view.camera.width, view.camera.height):
        raise ConfigError(f'{view.path} is {image.shape[1]}x{image.shape[0]}, its camera '
                          f'{view.camera.width}x{view.camera.height}')
    if view.distortion:
        c = view.camera
        k = np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]])
        image = cv2.undistort(image, k, np.array(view.distortion))
    if image.ndim == 3:
        rgb = cv2.cvtColor(image[:, :, :3], cv2.COLOR_BGR2RGB)
        return (rgb, 'rgb8') if rgb.dtype == np.uint8 else (rgb, 'rgb16')
    return image, ('mono16' if image.dtype == np.uint16 else 'mono8')


def write_views_bag(views: list[View], out: str | Path, *, namespace: str = '/views',
                    rate: float = 10.0, bbox: tuple[float, ...] | None = None,
                    overwrite: bool = False) -> int:
    """Write ``views`` into a bag; returns the number of messages.

    Raises:
        ConfigError: No views, a bad rate or bounding box, an unreadable image.
        BagError: ``out`` exists and ``overwrite`` is False.
    """
    if not views:
        raise ConfigError('no view to import (none of the listed images is there)')
    if not (rate > 0 and math.isfinite(rate)):
        raise ConfigError(f'--rate must be positive, got {rate}')
    if bbox is not None and (len(bbox) != 6 or not all(math.isfinite(v) for v in bbox) or
                             not all(bbox[i] < bbox[i + 3] for i in range(3))):
        raise ConfigError('--bbox takes xmin ymin zmin xmax ymax zmax, each min below its '
                          f'max, got {list(bbox)}')
    info = {'names': [v.name for v in views], 'bbox': list(bbox) if bbox else None,
            'namespace': namespace}
    count = 0
    writer = BagWriter(out, overwrite=overwrite)
    try:
        with writer:
            writer.set_custom_data(VIEWS_KEY, json.dumps(info))
            for index, view in enumerate(views):
                if stop_requested():
                    break
                stamp = START_NS + round(index * NS_PER_S / rate)
                pixels, encoding = _load(view)
                header = pose_message(view.pose, stamp).header
                header.frame_id = FRAME_ID
                for topic, msg in (
                        ('image_rect', array_to_image(np.ascontiguousarray(pixels),
                                                      encoding, header)),
                        ('camera_info', model_to_camera_info(camera_model(view.camera,
                                                                          FRAME_ID), header)),
                        ('pose', pose_message(view.pose, stamp)),
                        ('odom', odometry_message(view.pose, stamp, FRAME_ID))):
                    writer.write(f'{namespace}/{topic}', msg, stamp)
                    count += 1
    except ConfigError:
        writer.discard()
        raise
    return count


def views_info(custom_data: dict[str, str], path: str | Path) -> ViewsInfo:
    """What import-views recorded in a bag's metadata.

    Raises:
        BagError: Not such a bag, or the metadata does not parse.
    """
    if VIEWS_KEY not in custom_data:
        raise BagError(f'{path} was not written by depth-nodes import-views')
    try:
        doc = json.loads(custom_data[VIEWS_KEY])
        bbox = tuple(float(v) for v in doc['bbox']) if doc.get('bbox') else None
        return ViewsInfo([str(n) for n in doc['names']], bbox, str(doc['namespace']))
    except (ValueError, TypeError, KeyError) as exc:
        raise BagError(f'{path}: malformed {VIEWS_KEY} metadata: {exc}') from None
