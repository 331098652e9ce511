"""Vectorization of synthetic line drawings (known ground-truth polylines) and metrics."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from augment.fitting import catmull_rom, polyline_length, resample, simplify
from augment.metrics import ink_scores, rasterize_thin, stroke_scores
from augment.settings import VectorizeSettings
from augment.vectorize import VectorizeError, vectorize


def draw(polylines: list[np.ndarray], size: int = 256, thickness: int = 2) -> np.ndarray:
    img = np.full((size, size), 255, np.uint8)
    for p in polylines:
        pts = np.round((np.asarray(p, float) - 0.5) * 16).astype(np.int32)
        cv2.polylines(img, [pts], False, 0, thickness, cv2.LINE_AA, 4)
    return img


def scene(seed: int) -> list[np.ndarray]:
    """Boxes, ellipses and lines crossing each other: junctions of every kind."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(2):
        x0, y0 = rng.uniform(20, 110, 2)
        w, h = rng.uniform(50, 120, 2)
        out.append(np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h], [x0, y0]]))
    c = rng.uniform(90, 160, 2)
    t = np.linspace(0, 2 * np.pi, 200)
    out.append(np.stack([c[0] + 50 * np.cos(t), c[1] + 30 * np.sin(t)], 1))
    out.append(rng.uniform(15, 240, (2, 2)))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_f1_against_known_strokes(seed):
    ref = scene(seed)
    strokes = vectorize(draw(ref))
    s = stroke_scores(strokes, ref, 256, tol=2.0)
    assert s["f1"] >= 0.97, s
    assert stroke_scores(strokes, ref, 256, tol=1.0)["f1"] >= 0.9
    assert 0.5 <= s["count_ratio"] <= 3.0


def test_crossing_lines_are_joined_through_the_junction():
    ref = [np.array([[20.0, 128.0], [236.0, 128.0]]), np.array([[128.0, 20.0], [128.0, 236.0]])]
    strokes = vectorize(draw(ref, thickness=3))
    assert len(strokes) == 2  # not four half-lines
    for s in strokes:
        d = s[-1] - s[0]
        assert abs(d[0]) > 200 or abs(d[1]) > 200  # each goes straight through


def test_t_junction_corner_is_resnapped():
    # Thinning pulls the stem's end off the bar; re-snapping puts it back on the bar's line.
    bar = np.array([[30.0, 100.0], [220.0, 100.0]])
    stem = np.array([[125.0, 100.0], [125.0, 230.0]])
    strokes = vectorize(draw([bar, stem], thickness=4))
    assert len(strokes) == 2
    stem_v = min(strokes, key=lambda s: abs(s[-1][0] - s[0][0]) < 5 and -1 or 1)
    top = stem_v[np.argmin(stem_v[:, 1])]
    assert abs(top[1] - 100.0) <= 1.0 and abs(top[0] - 125.0) <= 1.5


def test_small_gaps_are_bridged():
    pts = [np.array([[20.0 + 30 * i, 60.0], [20.0 + 30 * i + 27, 60.0]]) for i in range(7)]
    strokes = vectorize(draw(pts))
    assert len(strokes) == 1 and polyline_length(strokes[0]) > 200


def test_closed_curve_is_one_closed_stroke():
    t = np.linspace(0, 2 * np.pi, 300)
    circle = np.stack([128 + 80 * np.cos(t), 128 + 60 * np.sin(t)], 1)
    strokes = vectorize(draw([circle]))
    assert len(strokes) == 1
    assert np.allclose(strokes[0][0], strokes[0][-1])


def test_pixel_convention_top_left_origin():
    img = np.full((64, 64), 255, np.uint8)
    img[40, 10:50] = 0  # row 40 covers v in [40, 41)
    (s,) = vectorize(img)
    assert np.allclose(s[:, 1], 40.5, atol=0.01)
    assert s[:, 0].min() == pytest.approx(10.5, abs=0.6) and s[:, 0].max() == pytest.approx(49.5, abs=0.6)


def test_blank_gives_no_strokes_and_black_raises():
    assert vectorize(np.full((64, 64), 255, np.uint8)) == []
    assert vectorize(np.full((64, 64), 250, np.uint8)) == []
    with pytest.raises(VectorizeError, match="dark"):
        vectorize(np.zeros((64, 64), np.uint8))
    noisy_black = np.zeros((64, 64), np.uint8)
    noisy_black[::8, ::8] = 255
    with pytest.raises(VectorizeError, match="ink"):
        vectorize(noisy_black)


def test_rgb_float_and_scan_like_input():
    ref = scene(3)
    gray = draw(ref, thickness=3)
    rgb = np.repeat(gray[..., None], 3, axis=2)
    a = vectorize(gray)
    b = vectorize(rgb)
    c = vectorize(gray.astype(np.float32) / 255.0)
    assert len(a) == len(b) == len(c)
    # A "scan": gray paper, noise, soft dark-gray lines; Otsu picks the ink level.
    rng = np.random.default_rng(0)
    scan = 200 - (255 - gray.astype(float)) * 0.5 + rng.normal(0, 6, gray.shape)
    scan = cv2.GaussianBlur(np.clip(scan, 0, 255).astype(np.uint8), (3, 3), 0)
    s = stroke_scores(vectorize(scan), ref, 256, tol=2.0)
    assert s["f1"] >= 0.9, s


def test_deterministic():
    img = draw(scene(4))
    a, b = vectorize(img), vectorize(img)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_settings_change_the_result():
    img = draw(scene(5))
    coarse = vectorize(img, VectorizeSettings(simplify_epsilon=3.0))
    fine = vectorize(img)
    assert sum(map(len, coarse)) < sum(map(len, fine))


def test_metrics():
    a = rasterize_thin([np.array([[10.5, 10.5], [50.5, 10.5]])], 64)
    assert a.sum() == 41 and a[10, 10] and a[10, 50]
    b = np.roll(a, 1, axis=0)
    assert ink_scores(a, b, tol=1.0)["f1"] == 1.0
    assert ink_scores(a, np.roll(a, 3, axis=0), tol=2.0)["f1"] == 0.0
    half = a.copy()
    half[:, 31:] = False
    s = ink_scores(half, a, tol=1.0)
    assert s["precision"] == 1.0 and 0.4 < s["recall"] < 0.6


def test_fitting_helpers():
    p = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    c = catmull_rom(p, 0.5)
    for v in p:  # passes through every vertex
        assert np.min(np.linalg.norm(c - v, axis=1)) < 1e-9
    assert np.max(np.linalg.norm(np.diff(c, axis=0), axis=1)) < 0.8
    r = resample(p, 1.0)
    assert len(r) == 31 and np.allclose(np.linalg.norm(np.diff(r, axis=0), axis=1), 1.0)
    line = np.stack([np.linspace(0, 10, 50), np.zeros(50)], 1)
    assert len(simplify(line, 0.1)) == 2


def test_simplify_keeps_every_corner_of_a_loop_stored_open():
    # A closed outline stored with last point = first: all four corners must survive (cv2's
    # approxPolyDP drops the repeated end point, which once cost a box one of its sides).
    sq = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.0, 0.0]])
    dense = np.concatenate([np.linspace(sq[i], sq[i + 1], 11)[:-1] for i in range(4)] + [sq[:1]])
    assert np.array_equal(simplify(dense, 0.4), sq)
    box = vectorize(draw([sq * 10 + 60]))
    assert len(box) == 1 and len(box[0]) == 5
