"""Census Semi-Global Matching (Hirschmueller 2008) in numba: the public API.

``SgmMatcher(SgmParams(...)).match(left, right)`` returns the left disparity, the
right-view disparity and a cost-ratio map; see :mod:`depth_nodes.core.sgm.matcher`.
"""

from depth_nodes.core.sgm.matcher import SgmMatcher, SgmParams, SgmResult, sgm_match

__all__ = ['SgmMatcher', 'SgmParams', 'SgmResult', 'sgm_match']
