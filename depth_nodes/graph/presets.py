"""Camera presets (``config/cameras/NAME.yaml``): a shipped graph moved to one camera
driver's topic names, with the nodes and settings that camera needs. ``--camera NAME`` of
`process` and `pipeline`, and ``camera:=NAME`` of the launch files, pick one.

A preset file::

    camera:                       # the camera: what the graph is moved to, and its numbers
      description: Intel RealSense D435, realsense-ros 4.x
      graph: stereo_pipeline.yaml # a graph of config/
      namespace: /camera/camera   # as --namespace, --left, --right, --image
      left: infra1
      right: infra2
      image: image_rect_raw
      image_transport: raw        # how the driver's images arrive (optional)
      width: 848                  # the numbers the disparity range comes from
      focal_px: 446.8
      baseline_m: 0.050
      nearest_m: 0.28
    nodes: [...]                  # more nodes, as in a graph file (absolute namespaces)
    remappings: {node: {...}}     # per node name, over the graph's
    parameters: {node: {...}}     # per node name, over the graph's

Its comments say where each number comes from. ``disparity_range`` is the disparity at
the nearest depth, ``f B / Z_min``, rounded up to a multiple of 16
(:func:`disparity_range`); the presets' tests check that each file's value is that.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from depth_nodes.errors import ConfigError
from depth_nodes.graph.cameras import rename_cameras
from depth_nodes.graph.schema import GraphConfig, _node_spec, load_graph_config, load_yaml

__all__ = ['CameraPreset', 'camera_names', 'disparity_range', 'load_camera']

#: The keys of a preset's ``camera:`` mapping.
CAMERA_KEYS = frozenset({'description', 'graph', 'namespace', 'left', 'right', 'image',
                         'image_transport', 'width', 'height', 'focal_px', 'baseline_m',
                         'nearest_m'})
PRESET_KEYS = frozenset({'camera', 'nodes', 'remappings', 'parameters'})


@dataclass
class CameraPreset:
    """A preset loaded: its graph under the camera's names, and the camera's facts."""

    name: str
    config: GraphConfig
    camera: dict[str, Any]

    @property
    def image_transport(self) -> str | None:
        transport = self.camera.get('image_transport')
        return None if transport is None else str(transport)


def camera_names(config_dir: Path) -> list[str]:
    """The presets in ``config_dir/cameras``, sorted."""
    return sorted(p.stem for p in (config_dir / 'cameras').glob('*.yaml'))


def disparity_range(focal_px: float, baseline_m: float, nearest_m: float) -> int:
    """The disparity at the nearest depth, rounded up to a multiple of 16 pixels."""
    return 16 * math.ceil(focal_px * baseline_m / nearest_m / 16.0)


def load_camera(name: str, config_dir: Path) -> CameraPreset:
    """The preset ``name`` of ``config_dir/cameras``.

    Raises:
        ConfigError: No such preset (the message lists them), or a malformed one.
    """
    path = config_dir / 'cameras' / f'{name}.yaml'
    if '/' in name or not path.is_file():
        names = camera_names(config_dir)
        raise ConfigError(f'no camera preset {name!r} (presets: {", ".join(names) or "none"};'
                          f' in {config_dir / "cameras"})')
    doc = load_yaml(path, 'camera preset')
    where = f'camera preset {path}'
    if not isinstance(doc, dict) or not isinstance(doc.get('camera'), dict):
        raise ConfigError(f'{where} needs a top-level "camera:" mapping')
    if unknown := set(doc) - PRESET_KEYS:
        raise ConfigError(f'{where}: unknown keys {sorted(unknown)}')
    camera = doc['camera']
    if unknown := set(camera) - CAMERA_KEYS:
        raise ConfigError(f'{where}: unknown camera keys {sorted(unknown)}')
    if not isinstance(camera.get('graph'), str):
        raise ConfigError(f'{where}: camera.graph must name a graph of {config_dir}')
    base = load_graph_config(config_dir / camera['graph'])
    moved = rename_cameras(base, namespace=camera.get('namespace'), left=camera.get('left'),
                           right=camera.get('right'), image=camera.get('image'))
    extra = [_node_spec(entry, path, i) for i, entry in enumerate(doc.get('nodes') or [])]
    nodes = [*moved.nodes, *extra]
    by_name = {spec.name: spec for spec in nodes}
    if len(by_name) != len(nodes):
        raise ConfigError(f'{where}: its nodes and the graph\'s share a name')
    for field in ('remappings', 'parameters'):
        table = doc.get(field) or {}
        if not isinstance(table, dict):
            raise ConfigError(f'{where}: "{field}" must map node names to mappings')
        for node, values in table.items():
            if node not in by_name:
                raise ConfigError(f'{where}: {field} for {node!r}, which is not a node of the '
                                  f'graph ({", ".join(by_name)})')
            if not isinstance(values, dict):
                raise ConfigError(f'{where}: {field}.{node} must be a mapping')
            spec = by_name[node]
            if field == 'remappings':
                remaps = {**spec.remappings, **{str(k): str(v) for k, v in values.items()}}
                by_name[node] = dataclasses.replace(spec, remappings=remaps)
            else:
                params = {**spec.parameters, **{str(k): v for k, v in values.items()}}
                by_name[node] = dataclasses.replace(spec, parameters=params)
    config = GraphConfig(f'{base.name} ({name})', [by_name[spec.name] for spec in nodes],
                         str(path))
    return CameraPreset(name, config, dict(camera))
