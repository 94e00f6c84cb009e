"""What the bad-input campaign must cause: for each hostile case of the campaign bag
(depth_nodes/tools/bags/bad_inputs.py), which node of the stereo graph must drop it first
and under which reason. test/live/test_bad_input_campaign.py replays the bag into the graph
and judges what the nodes counted against :func:`expected_drops`.
"""

from __future__ import annotations

from collections import Counter

from depth_nodes.tools.bags.bad_inputs import NS, Campaign

RECTIFY_LEFT, RECTIFY_RIGHT = f'{NS}/left/rectify_left', f'{NS}/right/rectify_right'
SGM, POINT_CLOUD = f'{NS}/sgm_stereo', f'{NS}/point_cloud'

#: Per case name: ``{node: {reason: count}}`` that the first node(s) seeing it must count.
#: The unpaired frames are dropped by no node under a reason of their own: they never
#: complete a set (``sync_unmatched`` downstream, checked apart).
DROPS: dict[str, dict[str, dict[str, int]]] = {
    'unknown encoding': {RECTIFY_LEFT: {'unsupported_encoding': 1}},
    'mono data declared rgb8': {RECTIFY_LEFT: {'malformed_image': 1}},
    'step and data length disagree': {RECTIFY_LEFT: {'malformed_image': 1}},
    'empty data': {RECTIFY_LEFT: {'malformed_image': 1}},
    'huge declared size, 64 bytes of data': {RECTIFY_LEFT: {'size_mismatch': 1}},
    'zero calibration (K all zero)': {RECTIFY_LEFT: {'uncalibrated': 1}},
    'NaN in the distortion': {RECTIFY_RIGHT: {'bad_calibration': 1}},
    'left / right size mismatch': {SGM: {'size_mismatch': 1}},
    'stamp older than the previous frame': {
        RECTIFY_LEFT: {'stamp_out_of_order': 2}, RECTIFY_RIGHT: {'stamp_out_of_order': 2},
        SGM: {'stamp_out_of_order': 2}, POINT_CLOUD: {'stamp_out_of_order': 2}},
    'unpaired left frame': {},
    'unpaired right frame': {},
}


def expected_drops(campaign: Campaign) -> dict[str, Counter[str]]:
    """Per node, the drops the cases written in ``campaign`` must cause at the first node
    seeing them.

    Raises:
        KeyError: A case that :data:`DROPS` does not judge.
    """
    out: dict[str, Counter[str]] = {}
    for _, case in campaign.cases:
        for node, reasons in DROPS[case.name].items():
            out.setdefault(node, Counter()).update(reasons)
    return out
