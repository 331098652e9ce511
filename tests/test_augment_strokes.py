"""Each stroke augmentation does what it says and stays within its bounds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from augment import strokes as A
from augment.fitting import cumulative_length, normals, polyline_length
from augment.settings import AugmentSettings, VectorizeSettings
from pipeline.core.settings_io import from_dict
from pipeline.core.stage_keys import settings_hash


def lines(n: int = 20, length: float = 100.0) -> list[np.ndarray]:
    """n horizontal strokes sampled every pixel."""
    x = np.linspace(0.0, length, int(length) + 1)
    return [np.stack([x + 10, np.full_like(x, 10.0 + 5 * i)], 1) for i in range(n)]


def rng(k: int = 0) -> np.random.Generator:
    return np.random.default_rng(k)


def total(strokes) -> float:
    return sum(polyline_length(s) for s in strokes)


def test_split_raises_count_and_respects_gaps_and_min_piece():
    src = lines()
    out = A.split(src, rng(), prob=1.0, max_points=3, gap=(1.0, 4.0), min_piece=6.0)
    assert len(out) > len(src)
    assert all(polyline_length(s) >= 6.0 - 1e-6 for s in out)
    removed = total(src) - total(out)
    n_cuts = len(out) - len(src)
    assert n_cuts * 1.0 - 1e-6 <= removed <= n_cuts * 4.0 + 1e-6
    # Every piece lies on its original line (cut, not moved).
    assert all(np.ptp(s[:, 1]) < 1e-9 for s in out)
    same = A.split(src, rng(), prob=0.0, max_points=3, gap=(1, 4), min_piece=6)
    assert len(same) == len(src) and all(np.array_equal(a, b) for a, b in zip(same, src))


def test_truncate_shortens_within_bounds():
    src = lines()
    out = A.truncate(src, rng(), prob=1.0, max_fraction=0.1, max_px=6.0)
    assert len(out) == len(src)
    for a, b in zip(src, out):
        cut = polyline_length(a) - polyline_length(b)
        assert 0.0 < cut <= 2 * 6.0 + 1e-9
        assert b[0, 0] >= a[0, 0] and b[-1, 0] <= a[-1, 0]


def test_extend_lengthens_along_tangent_within_bounds():
    src = lines()
    out = A.extend(src, rng(), prob=1.0, max_px=4.0)
    for a, b in zip(src, out):
        grow = polyline_length(b) - polyline_length(a)
        assert 0.0 < grow <= 8.0 + 1e-9
        assert np.allclose(b[:, 1], a[0, 1])  # straight line stays straight
        assert b[0, 0] <= a[0, 0] and b[-1, 0] >= a[-1, 0]


def test_wobble_is_smooth_and_bounded():
    src = lines(5, 200.0)
    out = A.wobble(src, rng(), amplitude=1.5, wavelength=40.0)
    for a, b in zip(src, out):
        off = b[:, 1] - a[:, 1]
        assert np.abs(off).max() <= 1.5 + 1e-9 and np.abs(off).max() > 0.2
        assert np.abs(np.diff(off)).max() < 0.2  # smooth: no per-point jitter


def test_jitter_bounds():
    src = lines(10)
    out = A.jitter(src, rng(), rotation_deg=2.5, scale=0.1)
    for a, b in zip(src, out):
        assert np.allclose(a.mean(0), b.mean(0))
        ratio = polyline_length(b) / polyline_length(a)
        assert 0.9 - 1e-9 <= ratio <= 1.1 + 1e-9
        d = b[-1] - b[0]
        assert abs(np.degrees(np.arctan2(d[1], d[0]))) <= 2.5 + 1e-6


def test_overdraw_adds_bounded_copies_near_the_original():
    src = lines()
    out = A.overdraw(src, rng(), prob=1.0, max_copies=2, offset=1.0)
    assert len(src) + len(src) <= len(out) <= 3 * len(src)
    orig = np.concatenate(src)
    for s in out:
        d = np.min(np.linalg.norm(orig[None] - s[:, None], axis=2), axis=1)
        assert d.max() <= np.sqrt(2) + 0.51


def test_drop_short_and_random():
    src = lines(10, 100.0) + lines(10, 5.0)
    out = A.drop(src, rng(), short_length=8.0, short_prob=1.0, prob=0.0)
    assert len(out) == 10 and all(polyline_length(s) > 8 for s in out)
    assert len(A.drop(src, rng(), 8.0, 0.0, 0.0)) == 20
    assert A.drop([], rng(), 8.0, 0.0, 1.0) == []


def test_drop_keeps_most_of_the_drawing():
    # dropping everything would leave a blank sketch: the longest strokes come back until half
    # the length is kept, in their original order
    src = lines(1, 30.0) + lines(1, 100.0) + lines(3, 20.0)
    kept = A.drop(src, rng(), 8.0, 0.0, 1.0)
    assert [polyline_length(s) for s in kept] == [pytest.approx(100.0)]
    src = lines(4, 25.0) + lines(1, 10.0)
    kept = A.drop(src, rng(), 8.0, 0.0, 1.0, keep_fraction=0.6)
    assert len(kept) == 3 and sum(polyline_length(s) for s in kept) == pytest.approx(75.0)
    assert A.drop(src, rng(), 8.0, 0.0, 1.0, keep_fraction=0.0) == []


def test_jitter_and_wobble_are_the_numpy_formulas():
    # the compiled steps against the per-stroke numpy they replace (to rounding: the 2 x 2 product
    # is a fused multiply-add in OpenBLAS, as in the kernel, but that is the machine's choice)
    src = [s + np.sin(s[:, :1] / 7.0) for s in lines(6, 60.0)] + [np.array([[3.0, 4.0]])]
    r = rng(5)
    want = []
    for s in src:
        a, k = np.radians(r.uniform(-2.0, 2.0)), r.uniform(0.9, 1.1)
        c = s.mean(axis=0)
        want.append((s - c) @ (k * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])).T + c)
    got = A.jitter(src, rng(5), 2.0, 0.1)
    assert all(np.allclose(g, w, rtol=0, atol=1e-9) for g, w in zip(got, want))
    r = rng(6)
    want = [
        s if len(s) < 2 else s + normals(s) * (0.8 * A.smooth_noise(r, cumulative_length(s), 30.0))[:, None]
        for s in src
    ]
    got = A.wobble(src, rng(6), 0.8, 30.0)
    assert all(np.allclose(g, w, rtol=0, atol=1e-9) for g, w in zip(got, want))
    assert not np.allclose(got[0], src[0])


def test_chain_is_deterministic_and_seed_dependent():
    s = AugmentSettings()
    src = A.resample_strokes(lines(), 1.0)
    a = A.augment_strokes(src, rng(1), s)
    b = A.augment_strokes(src, rng(1), s)
    c = A.augment_strokes(src, rng(2), s)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert len(a) != len(c) or any(not np.array_equal(x, y) for x, y in zip(a, c))
    assert all(np.array_equal(x, y) for x, y in zip(src, A.resample_strokes(lines(), 1.0)))


def test_settings_validate_and_json_overrides_normalize():
    with pytest.raises(ValueError):
        AugmentSettings(split_prob=1.5)
    a = from_dict(AugmentSettings, {"widths": [1, 2.0, 3.0], "vectorize": {"spur_length": 5}})
    b = AugmentSettings(widths=(1.0, 2.0, 3.0), vectorize=VectorizeSettings(spur_length=5.0))
    assert a == b and settings_hash(a) == settings_hash(b)
    assert settings_hash(dataclasses.replace(b, split_prob=0.1)) != settings_hash(b)
    assert [b.width_for(k) for k in range(4)] == [1.0, 2.0, 3.0, 1.0]
