"""The mesh a bag's MarkerArray topic ends with: its messages replayed as a viewer draws
them (a TRIANGLE_LIST marker added or replaced by namespace and id, a DELETE removing one,
a DELETEALL clearing its namespace), for `depth-nodes export-mesh` and `eval`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from depth_nodes.core.fusion.mesh import weld
from depth_nodes.core.geometry import Pose
from depth_nodes.errors import BagError
from depth_nodes.ros.serialized import MARKER_ARRAY, TRIANGLE_LIST, read_marker_array
from depth_nodes.tools.bags.io import BagReader

__all__ = ['FinalMesh', 'final_mesh', 'mesh_topic']

F32 = NDArray[np.float32]
ADD, DELETE, DELETEALL = 0, 2, 3


@dataclass
class FinalMesh:
    """A bag's last mesh.

    Attributes:
        topic: The topic it was read from.
        vertices: (N, 3) float32, shared.
        faces: (M, 3) int32.
        colors: (N, 3) uint8 when the markers carry per-vertex colours, else None.
        messages: MarkerArray messages replayed.
        markers: Triangle-list markers in the end.
        stamp: Bag timestamp of the last message, ns.
    """

    topic: str
    vertices: F32
    faces: NDArray[np.int32]
    colors: NDArray[np.uint8] | None
    messages: int
    markers: int
    stamp: int


def mesh_topic(reader: BagReader, topic: str | None) -> str:
    """``topic``, or the bag's one MarkerArray topic.

    Raises:
        BagError: ``topic`` is not a MarkerArray topic of the bag, or the bag has none, or
            several (naming them).
    """
    meshes = sorted(t for t, kind in reader.topics.items() if kind == MARKER_ARRAY)
    if topic is not None:
        if reader.topics.get(topic) != MARKER_ARRAY:
            raise BagError(f'{reader.path}: no MarkerArray topic {topic} (it has: '
                           f'{", ".join(meshes) or "none"})')
        return topic
    if len(meshes) != 1:
        raise BagError(f'{reader.path}: ' + (
            'no MarkerArray topic (process the bag with a graph that has tsdf_fusion, e.g. '
            '--config config/fusion_pipeline.yaml)' if not meshes else
            f'several MarkerArray topics ({", ".join(meshes)}): choose one with --topic'))
    return meshes[0]


def final_mesh(bag: str | Path, topic: str | None = None) -> FinalMesh:
    """Replay ``topic`` (default: the bag's one MarkerArray topic) to its last mesh.

    Raises:
        BagError: No such topic, a message that is not a MarkerArray, no triangle left.
    """
    with BagReader(bag) as reader:
        topic = mesh_topic(reader, topic)
        drawn: dict[tuple[str, int], tuple[F32, F32 | None]] = {}
        messages = stamp = 0
        for msg in reader.messages([topic]):
            try:
                markers = read_marker_array(msg.data)
            except ValueError as exc:
                raise BagError(f'{topic} at t={msg.timestamp}: not a MarkerArray ({exc})'
                               ) from None
            messages += 1
            stamp = msg.timestamp
            for marker in markers:
                key = (marker.namespace, marker.id)
                if marker.action == DELETEALL:
                    for gone in [k for k in drawn if k[0] == marker.namespace]:
                        del drawn[gone]
                elif marker.action == DELETE:
                    drawn.pop(key, None)
                elif marker.action == ADD and marker.type == TRIANGLE_LIST:
                    pose = Pose.from_quaternion(marker.pose[:3], marker.pose[3:]) \
                        if any(marker.pose[3:]) else Pose()
                    points = marker.points @ pose.rotation.T + pose.position
                    usable = len(points) // 3 * 3
                    rgba = marker.colors[:usable] if len(marker.colors) == len(points) \
                        else None
                    drawn[key] = (points[:usable].astype(np.float32), rgba)
    if not drawn:
        raise BagError(f'{bag}: {topic} ends with no triangle ({messages} messages)')
    soup = np.concatenate([points for points, _ in drawn.values()])
    vertices, faces = weld(soup)
    colors: NDArray[np.uint8] | None = None
    if all(c is not None for _, c in drawn.values()):
        every = np.concatenate([c for _, c in drawn.values() if c is not None])
        # the colour of each welded vertex: that of one of the soup's rows at its position
        _, first = np.unique(np.ascontiguousarray(soup).view(np.dtype((np.void, 12))).ravel(),
                             return_index=True)
        colors = np.clip(every[first, :3] * 255 + 0.5, 0, 255).astype(np.uint8)
    return FinalMesh(topic, vertices, faces, colors, messages, len(drawn), stamp)
