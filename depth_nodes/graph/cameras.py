"""A graph moved to a camera driver's names (``--namespace``, ``--left``, ``--right``,
``--image`` of the commands, the launch files' arguments of the same names), and the checks
of those names.
"""

from __future__ import annotations

from depth_nodes.errors import ConfigError
from depth_nodes.graph.schema import GraphConfig, NodeSpec

#: Topic names of one camera that the graphs use below its namespace (renamed with it).
CAMERA_TOPICS = ('image_raw', 'camera_info', 'image_rect', 'image_rect_color', 'image_mono',
                 'image_color')


def root_namespace(config: GraphConfig) -> str:
    """The namespace every node of ``config`` lives in (``/stereo`` for the stereo graph:
    its nodes are in /stereo, /stereo/left and /stereo/right)."""
    parts = [n.namespace.strip('/').split('/') for n in config.nodes]
    common: list[str] = []
    for level in zip(*parts, strict=False):
        if len(set(level)) != 1:
            break
        common.append(level[0])
    return '/' + '/'.join(p for p in common if p)


def rename_cameras(config: GraphConfig, *, namespace: str | None = None,
                   left: str | None = None, right: str | None = None,
                   image: str | None = None) -> GraphConfig:
    """The graph moved to a camera driver's names.

    Args:
        config: The graph (e.g. config/stereo_pipeline.yaml, under /stereo).
        namespace: Replaces the graph's root namespace (``/camera`` for a driver that
            publishes ``/camera/left/image_raw``).
        left: Replaces the left camera's name below it (``left``), e.g. ``infra1``.
        right: Replaces the right camera's name (``right``), e.g. ``infra2``.
        image: Replaces the raw image's name (``image_raw``), e.g. ``image_rect_raw``.

    Nodes move with their namespace; a node at the root keeps its relative topic names
    (``left/image_rect``) and gets remappings to the new side names; a remapping that
    pointed at a renamed topic points at its new name. A moved node keeps its old full
    name as an alias, so a parameter file written for the graph's own names (e.g.
    ``/stereo/sgm_stereo``) still reaches it.

    Raises:
        ConfigError: A name that is empty, relative where it must be absolute, or has
            characters ROS does not allow.
    """
    root = root_namespace(config)
    new_root = root if namespace is None else checked_namespace(namespace)
    sides = {k: checked_name(v, f'--{k}') for k, v in (('left', left), ('right', right))
             if v is not None and v != k}
    new_image = None if image is None or image == 'image_raw' else checked_name(image,
                                                                                  '--image')

    def move(name: str) -> str:
        """A topic or namespace name, relative or absolute, under the new names."""
        absolute = name.startswith('/')
        if absolute:
            if name != root and not name.startswith(root.rstrip('/') + '/'):
                return name
            rest = name[len(root):].strip('/')
        else:
            rest = name
        parts = rest.split('/') if rest else []
        if parts and parts[0] in sides:
            parts[0] = sides[parts[0]]
        if new_image is not None and parts and parts[-1] == 'image_raw':
            parts[-1] = new_image
        rest = '/'.join(parts)
        if not absolute:
            return rest
        return '/' + '/'.join(p for p in (new_root.strip('/'), rest) if p)

    nodes = []
    for spec in config.nodes:
        remaps = {src: move(dst) for src, dst in spec.remappings.items()}
        in_root = spec.namespace.rstrip('/') == root.rstrip('/')
        # the relative camera names this node may use, where they moved (a node at the
        # root reaches them through left/ and right/, one in a side's namespace directly)
        prefixes = ('left/', 'right/') if in_root else ('',)
        for name in (f'{prefix}{topic}' for prefix in prefixes for topic in CAMERA_TOPICS):
            if move(name) != name:
                remaps.setdefault(name, move(name))
        namespace = move(spec.namespace) or '/'
        aliases = list(spec.aliases)
        if namespace != spec.namespace:  # a parameter file written for the graph's names
            aliases.append(spec.fully_qualified_name)
        nodes.append(NodeSpec(spec.name, spec.plugin, namespace, dict(spec.parameters),
                              remaps, aliases))
    return GraphConfig(config.name, nodes, config.source)


def checked_name(value: str, what: str) -> str:
    """``value`` if it is a relative ROS name, else ConfigError naming ``what``."""
    if not value or not all(part and (part[0].isalpha() or part[0] == '_') and
                            all(c.isalnum() or c == '_' for c in part)
                            for part in value.split('/')):
        raise ConfigError(f'{what} {value!r} is not a ROS name (parts of letters, digits '
                          'and _, each starting with a letter or _, joined by single /)')
    return value


def checked_namespace(value: str, what: str = '--namespace') -> str:
    """``value`` as an absolute namespace (``/camera``), else ConfigError."""
    if not value.startswith('/'):
        raise ConfigError(f'{what} {value!r} must be absolute (start with /)')
    if value.strip('/'):
        checked_name(value.strip('/'), what)
    return '/' + value.strip('/')
