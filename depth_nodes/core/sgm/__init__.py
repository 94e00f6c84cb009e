"""Census Semi-Global Matching (Hirschmueller 2008) in numba: the public API.

``SgmMatcher(SgmParams(...)).match(left, right)`` returns the left disparity, the
right-view disparity and a cost-ratio map; see :mod:`depth_nodes.core.sgm.matcher`.

The modules, by job: ``params`` (the settings), ``census`` and ``brightness`` and
``cost`` (the matching costs), ``learned_cost`` (the learned features' cost,
``matching_cost: learned``), ``border`` (the cells whose match lies outside the right
image), ``aggregate`` (the path recurrence), ``select`` (the paths fused with the
selection), ``check`` (the left-right rule), ``bands`` (bands of rows and the task
runner), ``workspace`` (the buffers kept between frames), ``schedule`` (a frame's tasks),
``ranged`` and ``coarse`` (the coarse-to-fine search), ``matcher`` (the matcher and its
post-filters). Other names are imported from the module that defines them.
"""

from depth_nodes.core.sgm.matcher import SgmMatcher, SgmResult, sgm_match
from depth_nodes.core.sgm.params import SgmParams

__all__ = ['SgmMatcher', 'SgmParams', 'SgmResult', 'sgm_match']
