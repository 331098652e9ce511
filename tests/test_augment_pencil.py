"""Pencil rasterizer: widths, antialiasing, no beads at joints, grain, determinism; variants."""

from __future__ import annotations

import dataclasses

import numpy as np

from augment.pencil import draw_pencil
from augment.settings import AugmentSettings
from augment.variants import view_variants

PLAIN = dataclasses.replace(AugmentSettings(), grain=0.0, pressure_noise=0.0, paper_mottle=0.0,
                            darkness=(0.8, 0.8))


def shape_strokes() -> list[np.ndarray]:
    t = np.linspace(0, 2 * np.pi, 200)
    return [np.stack([64 + 40 * np.cos(t), 64 + 30 * np.sin(t)], 1),
            np.array([[20.0, 20.0], [108.0, 20.0], [108.0, 108.0]]),
            np.array([[20.0, 110.0], [100.0, 40.0]])]


def ink(img: np.ndarray) -> float:
    return float((255.0 - img.astype(float)).sum() / 255.0)


def test_widths_give_increasing_ink_coverage():
    cover = [ink(draw_pencil(shape_strokes(), 128, w, np.random.default_rng(0))) for w in (0.75, 1.25, 1.75)]
    assert cover[0] * 1.2 < cover[1] and cover[1] * 1.15 < cover[2]


def test_antialiased_grayscale_output():
    img = draw_pencil(shape_strokes(), 128, 1.25, np.random.default_rng(0))
    assert img.shape == (128, 128) and img.dtype == np.uint8
    values = np.unique(img)
    assert len(values) > 20  # soft edges and graphite tones, not a binary mask
    assert img.min() < 120 and np.median(img) > 240  # dark lines, light paper


def test_no_dark_beads_where_a_stroke_overlaps_itself():
    straight = [np.array([[10.0, 64.0], [118.0, 64.0]])]
    hairpin = [np.array([[10.0, 64.0], [118.0, 64.0], [10.0, 64.0]])]  # goes over itself
    a = draw_pencil(straight, 128, 2.0, np.random.default_rng(0), PLAIN)
    b = draw_pencil(hairpin, 128, 2.0, np.random.default_rng(0), PLAIN)
    mid = slice(30, 98)
    assert abs(int(a[64, mid].min()) - int(b[64, mid].min())) <= 2
    # Two separate strokes over each other do darken (graphite layers).
    c = draw_pencil(straight * 2, 128, 2.0, np.random.default_rng(0), PLAIN)
    assert int(c[64, mid].min()) < int(a[64, mid].min()) - 10


def test_pressure_tapers_the_ends():
    s = [np.array([[10.0, 64.0], [118.0, 64.0]])]
    img = draw_pencil(s, 128, 2.0, np.random.default_rng(0), PLAIN).astype(float)
    col_ink = (255 - img).sum(axis=0)
    assert col_ink[12] < 0.8 * col_ink[64]


def test_grain_breaks_up_graphite():
    s = [np.array([[10.0, 64.0], [118.0, 64.0]])]
    plain = draw_pencil(s, 128, 3.0, np.random.default_rng(0), PLAIN)
    grainy = draw_pencil(s, 128, 3.0, np.random.default_rng(0), dataclasses.replace(PLAIN, grain=0.8))
    assert grainy[64, 30:98].std() > 2 * plain[64, 30:98].std() + 1


def test_deterministic_and_seeded():
    s = shape_strokes()
    a = draw_pencil(s, 128, 1.25, np.random.default_rng(5))
    b = draw_pencil(s, 128, 1.25, np.random.default_rng(5))
    c = draw_pencil(s, 128, 1.25, np.random.default_rng(6))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_empty_strokes_give_blank_paper():
    img = draw_pencil([], 64, 1.0, np.random.default_rng(0))
    assert img.min() > 240


def test_view_variants_differ_and_repeat():
    strokes = [s * 2 for s in shape_strokes()]  # as if vectorized from a 256² render
    s = AugmentSettings(variants=4)
    v1 = view_variants(strokes, 256, s, (0, "mug", "00001", 0))
    v2 = view_variants(strokes, 256, s, (0, "mug", "00001", 0))
    assert len(v1) == 4 and [v.width for v in v1] == [0.75, 1.25, 1.75, 0.75]
    for a, b in zip(v1, v2):
        assert np.array_equal(a.image, b.image)
    assert not np.array_equal(v1[0].image, v1[3].image)  # same width, different seed key
    other = view_variants(strokes, 256, s, (0, "mug", "00002", 0))
    assert not np.array_equal(v1[0].image, other[0].image)
    for v in v1:  # strokes are in output pixels
        pts = np.concatenate(v.strokes)
        assert pts.min() > -5 and pts.max() < 128 + 5
