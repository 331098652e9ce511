"""Joining captured stroke fragments (pure numpy, no Blender)."""

from __future__ import annotations

import numpy as np

from render.join import join_fragments


def frag(*pts):
    return (np.array(pts, float), ["silhouette"] * len(pts))


def test_collinear_fragments_with_small_gaps_become_one_stroke():
    # a line cut into 3 pieces with 0.4 px gaps, listed out of order and one reversed
    a = frag([0, 0], [5, 0])
    b = frag([10, 0], [5.4, 0])  # reversed
    c = frag([10.3, 0], [15, 0], [20, 0])
    out = join_fragments([b, c, a], gap_px=1.0)
    assert len(out) == 1
    xs = out[0][0][:, 0]
    assert np.all(np.diff(xs) > 0) or np.all(np.diff(xs) < 0), "not chained end to end"
    assert len(out[0][0]) == len(out[0][1]) == 7  # no point lost, types stay aligned


def test_no_join_across_large_gap_or_sharp_turn():
    a = frag([0, 0], [5, 0])
    far = frag([7, 0], [12, 0])  # 2 px gap
    turn = frag([5.2, 0], [5.2, -5])  # continues at a right angle
    assert len(join_fragments([a, far], gap_px=1.0)) == 2
    assert len(join_fragments([a, turn], gap_px=1.0)) == 2
    assert len(join_fragments([a, far], gap_px=0.0)) == 2


def test_shared_endpoint_not_duplicated_and_deterministic():
    a = frag([0, 0], [5, 0])
    b = frag([5, 0], [9, 1])
    out1 = join_fragments([a, b], gap_px=1.0)
    out2 = join_fragments([a, b], gap_px=1.0)
    assert len(out1) == 1 and len(out1[0][0]) == 3
    assert np.array_equal(out1[0][0], out2[0][0])
