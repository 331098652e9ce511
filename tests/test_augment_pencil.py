"""Pencil rasterizer: widths, antialiasing, no beads at joints, grain, determinism; variants."""

from __future__ import annotations

import dataclasses

import numpy as np

from augment.pencil import draw_pencil
from augment.settings import AugmentSettings
from augment.variants import view_variants

PLAIN = dataclasses.replace(AugmentSettings(), grain=0.0, pressure_noise=0.0, paper_mottle=0.0, tones=((0.8, 0.8),))


def shape_strokes() -> list[np.ndarray]:
    t = np.linspace(0, 2 * np.pi, 200)
    return [
        np.stack([64 + 40 * np.cos(t), 64 + 30 * np.sin(t)], 1),
        np.array([[20.0, 20.0], [108.0, 20.0], [108.0, 108.0]]),
        np.array([[20.0, 110.0], [100.0, 40.0]]),
    ]


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


def _ink_stats(img: np.ndarray) -> tuple[float, float]:
    """(mean darkness of ink pixels, share of the frame that is ink); ink: darkness > 0.1."""
    d = 1.0 - img.astype(np.float32) / 255.0
    m = d > 0.1
    return float(d[m].mean()), float(m.mean())


def test_variants_span_dark_thin_lines_and_light_broad_shaded_ones():
    from augment.variants import make_variant, reference_strokes

    s = AugmentSettings()
    assert s.tones_for(0)[1] > s.tones_for(1)[1] and s.shading_for(0) == 0.0 < s.shading_for(1)
    ref = reference_strokes(shape_strokes(), 128, s)
    stats = [[_ink_stats(make_variant(ref, s, k, (seed, "mug", "a", 0)).image) for seed in range(6)] for k in (0, 1)]
    dark0, cover0 = np.median(stats[0], axis=0)
    dark1, cover1 = np.median(stats[1], axis=0)
    assert dark1 < 0.8 * dark0  # lighter graphite ...
    assert cover1 > 1.3 * cover0  # ... broader, with tone beside the lines


def test_tone_strokes_are_seeded_and_off_at_share_zero():
    from augment.shading import tone_strokes

    lines = shape_strokes()
    a = tone_strokes(lines, np.random.default_rng(3), 1.0, (1.0, 2.0))
    b = tone_strokes(lines, np.random.default_rng(3), 1.0, (1.0, 2.0))
    assert len(a) >= len(lines) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert tone_strokes(lines, np.random.default_rng(3), 0.0, (1.0, 2.0)) == []
    # each tone stroke lies beside its line, within the offset range (x2 for a second copy)
    d = np.linalg.norm(a[0][:, None] - lines[0][None], axis=-1).min(axis=1)
    assert 0.5 < np.median(d) < 4.5


def test_a_variant_without_shading_draws_no_tone():
    rng = lambda: np.random.default_rng(5)  # noqa: E731
    plain = draw_pencil(shape_strokes(), 128, 1.5, rng())
    assert np.array_equal(plain, draw_pencil(shape_strokes(), 128, 1.5, rng(), tone=[]))
