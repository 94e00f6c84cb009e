"""Which scorer a bag needs, told by what it holds.

A bag made by `depth-nodes generate` or `import-views` carries its maker's configuration in
its metadata (``custom_data``), which `process` and `convert` keep: that key tells its kind.
A stereo pair of no simulator (`import-pair`, a user's own bag with ground truth) is told
by its ground-truth topic, ``…/left/disparity_gt`` (a stereo_msgs/DisparityImage). A bag
with a mesh (a visualization_msgs/MarkerArray topic: tsdf_fusion's output) is scored as a
fused bag whatever its maker. Then the metadata: a multi-view rig's bag holds a stereo
pair's ground truth too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from depth_nodes.ros.serialized import MARKER_ARRAY
from depth_nodes.tools.bags import depth_filter, generate, multiview, structured_light, tof
from depth_nodes.tools.bags.io import BagReader
from depth_nodes.tools.bags.views import VIEWS_KEY
from depth_nodes.tools.evaluation.evaluate import DISPARITY, GT_SUFFIX


@dataclass(frozen=True)
class Kind:
    """A kind of bag that `eval` scores.

    Attributes:
        name: Its name in messages and option help (``time-of-flight``).
        what: What such a bag is, for errors (``a time-of-flight bag``).
        key: The metadata key that tells it.
    """

    name: str
    what: str
    key: str


MULTIVIEW = Kind('multi-view', 'a multi-view sequence bag', multiview.CONFIG_KEY)
VIEWS = Kind('imported-views', 'an imported-views bag', VIEWS_KEY)
STRUCTURED_LIGHT = Kind('structured-light', 'a structured-light bag', structured_light.CONFIG_KEY)
TOF = Kind('time-of-flight', 'a time-of-flight bag', tof.CONFIG_KEY)
DEPTH_FILTER = Kind('depth-filter', 'a depth-filter bag', depth_filter.CONFIG_KEY)
STEREO = Kind('stereo', 'a stereo bag', generate.CONFIG_KEY)
#: Told by its mesh topic, not by a key.
FUSION = Kind('fusion', 'a fused bag (tsdf_fusion\'s mesh)', MARKER_ARRAY)
#: Every kind, in the order their metadata is looked for.
KINDS = (FUSION, MULTIVIEW, VIEWS, STRUCTURED_LIGHT, TOF, DEPTH_FILTER, STEREO)


def bag_kind(path: str | Path) -> Kind | None:
    """The kind of the bag at ``path``; None when it has neither a kind's metadata nor a
    stereo ground-truth topic.

    Raises:
        BagError: The bag is missing or unreadable.
    """
    with BagReader(Path(path)) as reader:
        if MARKER_ARRAY in reader.topics.values():
            return FUSION
        for kind in KINDS[1:]:
            if kind.key in reader.custom_data:
                return kind
        if any(topic.endswith(GT_SUFFIX) and msgtype == DISPARITY
               for topic, msgtype in reader.topics.items()):
            return STEREO
    return None


def looked_for() -> str:
    """What :func:`bag_kind` looks for, for the error of a bag of no kind."""
    keys = ', '.join(f'{kind.key}: {kind.name}' for kind in KINDS[1:])
    return (f'a stereo ground truth, …{GT_SUFFIX} of type {DISPARITY}, and the metadata '
            f'of a generated or imported bag, {keys}, and a mesh ({MARKER_ARRAY})')
