"""Multi-view stereo in numba (no ROS): a plane sweep over a reference view and K source
views with known cameras, SGM over the planes, and depth over time.

``MultiViewMatcher(MvsParams(...)).match(reference, camera, sources)`` gives one view's
inverse depth, standard deviation and confidence (:mod:`.matcher`, over the costs of
:mod:`.cost`); ``MvsStream`` runs a stream of posed views: keyframes, the geometric check
(:mod:`.consistency`) and the depth filter (:mod:`.fusion`). Poses: :mod:`.geometry`,
over time :mod:`.poses`.
"""

from depth_nodes.core.geometry import Pose
from depth_nodes.core.mvs.matcher import MultiViewMatcher, MvsParams, MvsResult, SourceView
from depth_nodes.core.mvs.planes import SweepPlanes
from depth_nodes.core.mvs.stream import Frame, MvsStream, NoDepth, StreamDepth, StreamParams

__all__ = ['Frame', 'MultiViewMatcher', 'MvsParams', 'MvsResult', 'MvsStream', 'NoDepth',
           'Pose', 'SourceView', 'StreamDepth', 'StreamParams', 'SweepPlanes']
