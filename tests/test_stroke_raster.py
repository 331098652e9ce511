"""The compiled stroke steps of the pencil: densify, pressure half-widths, capsule deposit."""

from __future__ import annotations

import numpy as np

from augment.stroke_raster import EDGE, densify, deposit, half_widths


def test_densify_spacing_ends_and_duplicates():
    strokes = [
        np.array([[0.0, 0.0], [0.0, 0.0], [10.0, 0.0], [10.0, 5.0]]),  # duplicate dropped
        np.array([[3.0, 4.0]]),  # one point stays one
        np.zeros((0, 2)),
    ]  # empty stays empty
    pts, starts, arc = densify(strokes, 1.0)
    assert starts.tolist() == [0, 16, 17, 17]
    first = pts[:16]
    assert np.allclose(first[0], [0, 0]) and np.array_equal(first[-1], [10.0, 5.0])
    steps = np.hypot(*np.diff(first, axis=0).T)
    assert np.allclose(steps, 1.0, atol=1e-9)  # 15 px of polyline, one point per px, no corner cut
    assert np.allclose(arc[:16], np.arange(16.0)) and arc[16] == 0.0
    assert np.array_equal(pts[16], [3.0, 4.0])


def test_half_widths_taper_and_draw_from_the_generator():
    pts, starts, arc = densify([np.array([[0.0, 0.0], [100.0, 0.0]])], 1.0)
    w1, d1 = half_widths(arc, starts, np.random.default_rng(3), 12.0, 10.0, 0.0, 2.0, (0.5, 0.9))
    assert 0.5 <= d1[0] <= 0.9
    assert np.isclose(w1[0], 2.0 * 0.45 * 1.0) and np.isclose(w1[50], 2.0)  # tapered ends, full middle
    w2, d2 = half_widths(arc, starts, np.random.default_rng(3), 12.0, 10.0, 0.3, 2.0, (0.5, 0.9))
    assert d2[0] == d1[0] and not np.allclose(w1, w2)  # noise moves the width, same draws order
    w3, _ = half_widths(arc, starts, np.random.default_rng(3), 12.0, 10.0, 0.3, 2.0, (0.5, 0.9))
    assert np.array_equal(w2, w3)


def test_deposit_covers_a_capsule_once_per_stroke():
    canvas = lambda: np.zeros((40, 40), np.float32)
    tooth = np.full((40, 40), 0.5, np.float32)
    line = np.array([[5.0, 20.0], [35.0, 20.0]])
    dark = canvas()
    deposit(dark, tooth, line, np.array([0, 2]), np.array([3.0, 3.0]), np.array([0.6]), 0.0)
    covered = dark > 0
    assert np.allclose(dark[covered], 0.6)
    # a capsule: the half-width (+ EDGE) around the segment, round past its ends
    assert covered[20, 20] and covered[20 + 3, 20] and not covered[20 + 4, 20]
    assert covered[20, 5 - 3] and not covered[20, 5 - 4]
    assert not covered[20 + 3, 5 - 3]  # the corner of the bounding box is outside the round cap
    # the same segment twice in one stroke (a hairpin) darkens once; as two strokes it layers
    hairpin = np.array([[5.0, 20.0], [35.0, 20.0], [5.0, 20.0]])
    once = canvas()
    deposit(once, tooth, hairpin, np.array([0, 3]), np.full(3, 3.0), np.array([0.6]), 0.0)
    assert np.array_equal(once, dark)
    twice = canvas()
    deposit(twice, tooth, np.concatenate([line, line]), np.array([0, 2, 4]), np.full(4, 3.0), np.array([0.6, 0.6]), 0.0)
    assert np.allclose(twice[covered], 0.6 + 0.6 * 0.4)
    assert 3.0 + EDGE < 4.0
