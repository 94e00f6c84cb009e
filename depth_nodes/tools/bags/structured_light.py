"""Structured-light bags: write them from the projector-camera simulator, read them back.

Topics (namespace ``/sl``; one stamp per camera frame, frames ``1 / frame_rate_hz`` apart;
the bag timestamp equals the header stamp):

====================================  =========================  ===============================
topic                                 type                       content
====================================  =========================  ===============================
/sl/image_raw                         sensor_msgs/Image mono8    the pattern sequence(s)
/sl/camera_info                       sensor_msgs/CameraInfo     the camera (every frame)
/sl/pattern                           std_msgs/Header            ``"<seq>:<index>/<count>"``
/sl/projector/camera_info             sensor_msgs/CameraInfo     projector, ``P = K_p [R | t]``
/sl/depth_gt                          sensor_msgs/Image 32FC1    Z (m), at each sequence's
                                                                 first stamp
/sl/projector_u_gt, /sl/projector_v_gt  sensor_msgs/Image 32FC1  exact projector column / row
/sl/shadow_gt                         sensor_msgs/Image mono8    0 lit, 255 projector shadow,
                                                                 128 outside the projector
/sl/speckle/image_raw                 sensor_msgs/Image mono8    single-shot dot pattern images
/sl/speckle/camera_info               sensor_msgs/CameraInfo     the camera
====================================  =========================  ===============================

The scene is static, so the ground truth of a sequence also holds for the speckle images.
The speckle reference (the dot pattern on a plane at ``reference_depth`` m, seen by the
camera widened by :data:`REFERENCE_MARGIN` columns on each side) is written beside the bag
as ``speckle_reference.png``; the configuration is stored in the bag's
metadata (``custom_data``, key :data:`CONFIG_KEY`).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.camera import CameraModel
from depth_nodes.core.structured_light import PatternSet, generate_patterns, speckle_pattern
from depth_nodes.core.structured_light.framing import parse_tag
from depth_nodes.errors import BagError, ConfigError, DepthNodesError
from depth_nodes.ros.camera_info import camera_info_to_model, model_to_camera_info
from depth_nodes.ros.image import array_to_image, image_to_array
from depth_nodes.sim.projector import ProjectorCameraSim, ProjectorSimConfig, reference_plane_scene
from depth_nodes.tools.bags.simulated import Frame, SimulatedBag, stamped_header

NAMESPACE = '/sl'
CONFIG_KEY = 'depth_nodes.sim.structured_light'
REFERENCE_FILE = 'speckle_reference.png'
#: Extra columns of the speckle reference on each side of the camera's width.
REFERENCE_MARGIN = 64
#: The four topics every sequence frame has.
SEQUENCE_TOPICS = ('image_raw', 'pattern', 'camera_info', 'projector/camera_info')
#: The ground truth, at each sequence's first stamp.
GT_TOPICS = ('depth_gt', 'projector_u_gt', 'projector_v_gt', 'shadow_gt')


@dataclass(frozen=True)
class StructuredLightBagConfig:
    """What a structured-light bag holds.

    Attributes:
        sim: The projector-camera simulator.
        mode: Pattern set of the sequences (gray, phase or opencv).
        axes: Coded axes (columns or both).
        steps: Phase steps.
        period: Phase period, projector pixels.
        sequences: Number of sequences (each with its own camera noise).
        speckle_frames: Number of speckle images.
        reference_depth: Depth of the speckle reference plane, metres.
        frame_rate_hz: Camera frame rate.
        start_stamp_ns: Stamp of the first frame.
    """

    sim: ProjectorSimConfig = field(default_factory=ProjectorSimConfig)
    mode: str = 'phase'
    axes: str = 'columns'
    steps: int = 6
    period: float = 12.0
    sequences: int = 1
    speckle_frames: int = 1
    reference_depth: float = 1.0
    frame_rate_hz: float = 60.0
    start_stamp_ns: int = 1_700_000_000_000_000_000

    @property
    def pattern_set(self) -> PatternSet:
        """The projected pattern set."""
        return PatternSet(self.mode, self.sim.projector_width, self.sim.projector_height,
                          self.axes, self.steps, self.period)

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> StructuredLightBagConfig:
        """Inverse of :func:`dataclasses.asdict` (the bag metadata's JSON document)."""
        sim = doc.pop('sim')
        for key in ('camera_distortion', 'projector_distortion'):
            sim[key] = tuple(sim[key])
        return cls(sim=ProjectorSimConfig(**sim), **doc)


#: The committed bag.
PRESETS: dict[str, StructuredLightBagConfig] = {
    'structured_light_vga': StructuredLightBagConfig(sim=ProjectorSimConfig(seed=7)),
}


BAG: SimulatedBag[StructuredLightBagConfig] = SimulatedBag(
    CONFIG_KEY, 'a structured-light bag', 'depth-nodes generate --preset '
    'structured_light_vga', StructuredLightBagConfig.from_dict)


def write_structured_light_bag(path: str | Path, config: StructuredLightBagConfig, *,
                               overwrite: bool = False) -> int:
    """Simulate ``config`` and write the bag (and its speckle reference) at ``path``.

    A signal stops between whole sequences and between speckle frames; the reference is
    written beside a complete bag only.

    Returns:
        The number of messages written.

    Raises:
        ConfigError: An invalid configuration.
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    pattern_set = config.pattern_set
    if config.mode == 'speckle' or config.sequences < 0 or config.speckle_frames < 0:
        raise ConfigError('sequences need mode gray, phase or opencv, and counts >= 0')
    sim = ProjectorCameraSim(config.sim)
    patterns = generate_patterns(pattern_set)
    dots = speckle_pattern(sim.projector.width, sim.projector.height, seed=config.sim.seed,
                           density=config.sim.speckle_density)[None]
    frame = itertools.count()
    period_ns = 1e9 / config.frame_rate_hz

    def next_stamp() -> int:
        return config.start_stamp_ns + round(next(frame) * period_ns)

    def groups() -> Iterator[Iterator[Frame]]:
        """Each sequence (its frames are of use only together), then each speckle frame;
        lazy: a group is simulated when it is written."""
        for seq in range(config.sequences):
            yield _sequence(sim, patterns, seq, pattern_set.count, next_stamp)
        for k in range(config.speckle_frames):
            yield _speckle(sim, dots, k, next_stamp)

    def reference(folder: Path) -> None:
        if config.speckle_frames:
            _write_reference(folder, config, dots)

    return BAG.write_groups(path, config, groups(), overwrite=overwrite, on_complete=reference)


def _sequence(sim: ProjectorCameraSim, patterns: NDArray[np.float32], seq: int, count: int,
              next_stamp: Callable[[], int]) -> Iterator[Frame]:
    """The frames of pattern sequence ``seq`` (camera noise seeded by it; tagged
    ``seq:index/count``), the ground truth with the first."""
    capture = sim.capture(patterns, noise_seed=seq)
    cam, proj = sim.camera, sim.projector
    for index, image in enumerate(capture.images):
        stamp = next_stamp()
        h = stamped_header(stamp, cam.frame_id)
        messages: list[tuple[str, Any]] = [
            ('image_raw', array_to_image(image, 'mono8', h)),
            ('camera_info', model_to_camera_info(cam, h)),
            ('pattern', stamped_header(stamp, f'{seq}:{index}/{count}')),
            ('projector/camera_info',
             model_to_camera_info(proj, stamped_header(stamp, proj.frame_id)))]
        if index == 0:
            messages += [(topic, array_to_image(arr, enc, h)) for topic, arr, enc in (
                ('depth_gt', capture.depth, '32FC1'), ('projector_u_gt', capture.u, '32FC1'),
                ('projector_v_gt', capture.v, '32FC1'), ('shadow_gt', capture.shadow, 'mono8'))]
        yield stamp, [(f'{NAMESPACE}/{topic}', msg) for topic, msg in messages]


def _speckle(sim: ProjectorCameraSim, dots: NDArray[np.float32], k: int,
             next_stamp: Callable[[], int]) -> Iterator[Frame]:
    """Speckle frame ``k``: the dot pattern seen by the camera (noise seeded by ``k``)."""
    stamp = next_stamp()
    cam, proj = sim.camera, sim.projector
    h = stamped_header(stamp, cam.frame_id)
    image = sim.render(dots, noise_seed=1000 + k)[0]
    yield stamp, [
        (f'{NAMESPACE}/speckle/image_raw', array_to_image(image, 'mono8', h)),
        (f'{NAMESPACE}/speckle/camera_info', model_to_camera_info(cam, h)),
        (f'{NAMESPACE}/projector/camera_info',
         model_to_camera_info(proj, stamped_header(stamp, proj.frame_id)))]


def _write_reference(folder: Path, config: StructuredLightBagConfig,
                     dots: NDArray[np.float32]) -> None:
    """The speckle reference beside the bag: wider than the camera's images
    (:data:`REFERENCE_MARGIN` columns each side, the same intrinsics otherwise), so the dots
    that near and far surfaces at the image's sides show are in it."""
    wide = dataclasses.replace(config.sim, width=config.sim.width + 2 * REFERENCE_MARGIN)
    ref_sim = ProjectorCameraSim(wide, reference_plane_scene(config.reference_depth))
    reference = ref_sim.render(dots, noise_seed=999, noise_sigma=config.sim.noise_sigma / 2)
    cv2.imwrite(str(folder / REFERENCE_FILE), reference[0])


@dataclass
class Sequence:
    """One complete captured sequence read from a bag, with its ground truth."""

    number: int
    stamp_ns: int
    images: NDArray[np.uint8]
    gt: dict[str, NDArray[Any]]


@dataclass
class StructuredLightBag:
    """Everything :func:`read_structured_light_bag` found."""

    config: StructuredLightBagConfig
    camera: CameraModel
    projector: CameraModel
    sequences: list[Sequence]
    speckle: list[NDArray[np.uint8]]
    reference: NDArray[np.uint8] | None
    reference_path: Path


def read_structured_light_bag(path: str | Path) -> StructuredLightBag:
    """Read a bag written by :func:`write_structured_light_bag`.

    Sequences are assembled from the ``pattern`` tags; incomplete ones are skipped.

    Raises:
        BagError: Missing bag, topic or metadata, or an unusable message.
    """
    path = Path(path)
    topics = [f'{NAMESPACE}/{t}' for t in (*SEQUENCE_TOPICS, *GT_TOPICS, 'speckle/image_raw')]
    config, found = BAG.read(path, topics, optional=tuple(topics[len(SEQUENCE_TOPICS):]))
    by_topic = {topic.removeprefix(NAMESPACE + '/'): messages
                for topic, messages in found.items()}
    try:
        camera = camera_info_to_model(next(iter(by_topic['camera_info'].values())))
        projector = camera_info_to_model(next(iter(by_topic['projector/camera_info'].values())))
        groups: dict[int, dict[int, tuple[int, NDArray[np.uint8]]]] = defaultdict(dict)
        for stamp, tag_msg in by_topic['pattern'].items():
            tag = parse_tag(tag_msg.frame_id)
            image = by_topic['image_raw'].get(stamp)
            if image is not None:
                groups[tag.sequence][tag.index] = (stamp, image_to_array(image))
                groups[tag.sequence][-1] = (tag.count, np.empty(0, np.uint8))
        sequences = []
        for number, frames in sorted(groups.items()):
            n = frames.pop(-1)[0]
            if sorted(frames) != list(range(n)):
                continue
            first = frames[0][0]
            gt = {k: image_to_array(by_topic[k][first]) for k in GT_TOPICS
                  if first in by_topic[k]}
            sequences.append(Sequence(number, first, np.stack([frames[i][1] for i in range(n)]),
                                      gt))
        speckle = [image_to_array(m) for _, m in sorted(by_topic['speckle/image_raw'].items())]
    except DepthNodesError as exc:
        raise BagError(f'{path}: {exc}') from None
    reference_path = path / REFERENCE_FILE
    ref = cv2.imread(str(reference_path), cv2.IMREAD_GRAYSCALE)
    reference = None if ref is None else np.asarray(ref, dtype=np.uint8)
    return StructuredLightBag(config, camera, projector, sequences, speckle, reference,
                              reference_path)
