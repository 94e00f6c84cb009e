"""Sequence framing: a sequence is emitted only when complete and in order; every broken
sequence is dropped with its reason and the assembler resynchronises on the next start."""

from __future__ import annotations

import pytest

from depth_nodes.core.structured_light.framing import SequenceAssembler, parse_tag
from depth_nodes.errors import MessageError


def _feed(tags: list[str], count: int = 3) -> tuple[list[list[str]], list[str]]:
    assembler = SequenceAssembler()
    done, reasons = [], []
    for text in tags:
        frames, drops = assembler.add(parse_tag(text), text, count)
        reasons += [d.reason for d in drops]
        if frames is not None:
            done.append(frames)
    return done, reasons


def test_complete_sequences() -> None:
    done, reasons = _feed(['1:0/3', '1:1/3', '1:2/3', '2:0/3', '2:1/3', '2:2/3'])
    assert done == [['1:0/3', '1:1/3', '1:2/3'], ['2:0/3', '2:1/3', '2:2/3']]
    assert reasons == []


@pytest.mark.parametrize(('tags', 'reasons'), [
    (['1:0/3', '1:2/3'], ['sequence_missing_frame']),
    (['1:0/3', '1:1/3', '1:1/3', '1:2/3'], ['sequence_repeated_frame', 'sequence_resync']),
    (['1:0/3', '1:2/3', '1:1/3'], ['sequence_missing_frame', 'sequence_resync']),
    (['1:0/3', '1:1/3', '1:0/3', '1:2/3'], ['sequence_incomplete', 'sequence_missing_frame']),
    (['1:0/3', '2:1/3', '2:2/3'], ['sequence_mixed', 'sequence_resync', 'sequence_resync']),
    (['1:1/3', '1:2/3'], ['sequence_missing_frame', 'sequence_resync']),
    (['1:0/4', '1:1/4'], ['pattern_count_mismatch', 'sequence_resync']),
])
def test_broken_sequence_is_dropped_then_the_next_one_decodes(tags: list[str],
                                                              reasons: list[str]) -> None:
    done, got = _feed([*tags, '9:0/3', '9:1/3', '9:2/3'])
    assert got == reasons
    assert done == [['9:0/3', '9:1/3', '9:2/3']]


def test_a_frame_from_further_back_drops_the_sequence() -> None:
    """Frame 1 again after frames 0, 1, 2 of four (not the one just before: that is a
    repeat): out of order; the rest of the sequence is skipped until the next start."""
    done, reasons = _feed(['1:0/4', '1:1/4', '1:2/4', '1:1/4', '1:3/4',
                           '2:0/4', '2:1/4', '2:2/4', '2:3/4'], count=4)
    assert reasons == ['sequence_out_of_order', 'sequence_resync']
    assert done == [['2:0/4', '2:1/4', '2:2/4', '2:3/4']]


def test_out_of_order_frames_never_mix() -> None:
    done, reasons = _feed(['1:0/3', '1:1/3', '2:0/3', '1:2/3', '2:1/3', '2:2/3'])
    assert done == []
    assert reasons[0] == 'sequence_incomplete'
    assert 'sequence_mixed' in reasons


def test_tail_of_one_sequence_and_head_of_the_next_do_not_make_one() -> None:
    # sequence 1 loses its last frame, sequence 2 its first: indices 0, 1, (2 lost), ...
    done, reasons = _feed(['1:0/3', '1:1/3', '2:2/3'])
    assert done == []
    assert reasons == ['sequence_mixed', 'sequence_resync']


@pytest.mark.parametrize(('text', 'message'), [
    ('camera_optical_frame', 'is not "<sequence>:<index>/<count>"'),
    ('1:3/3', 'index must be < count'),
    ('1:0/0', 'index must be < count and count >= 1'),
    ('-1:0/3', 'is not'),
])
def test_bad_tags(text: str, message: str) -> None:
    with pytest.raises(MessageError, match=message):
        parse_tag(text)


def test_tag_pairer_pairs_whichever_comes_first_and_counts_the_rest() -> None:
    from depth_nodes.core.structured_light.framing import TagPairer

    pairer = TagPairer(queue_size=2)
    assert pairer.add_frame(10, 'f10') == (None, [])
    assert pairer.add_tag(10, 't10') == ('f10', [])  # the frame came first
    assert pairer.add_tag(20, 't20') == (None, [])
    assert pairer.add_frame(20, 'f20') == ('t20', [])  # the tag came first
    pairer.add_frame(30, 'f30')
    frame, drops = pairer.add_tag(40, 't40')
    assert frame is None
    assert drops == []
    pairer.add_frame(50, 'f50')
    frame, drops = pairer.add_tag(50, 't50')  # 30 never got its tag, a later frame did
    assert frame == 'f50'
    assert [(d.reason, d.count) for d in drops] == [('pattern_tag_missing', 1)]
    for stamp in (60, 70, 80, 90):  # four more tags: five wait, one more than 2 x 2
        _, drops = pairer.add_tag(stamp, f't{stamp}')
    assert [d.reason for d in drops] == ['pattern_tag_unmatched']
    pairer.add_frame(100, 'f100')
    assert [(d.reason, d.count) for d in pairer.finish()] == [
        ('pattern_tag_missing', 1), ('pattern_tag_unmatched', 4)]
    assert pairer.finish() == []
