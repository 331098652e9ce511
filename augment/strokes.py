"""Stroke augmentations: each a small pure function (strokes, rng, its parameters) → new strokes.

Strokes are float (K, 2) arrays in reference-canvas pixels (see settings.REFERENCE_SIZE); the
input list and arrays are never modified. All randomness comes from the ``rng`` passed in, drawn
in a fixed order, so a keyed generator gives the same strokes every run.
"""

from __future__ import annotations

import numpy as np

from augment.fitting import catmull_rom, cumulative_length, normals, polyline_length
from augment.settings import AugmentSettings

Strokes = list[np.ndarray]


def cut(points: np.ndarray, s0: float, s1: float, s: np.ndarray | None = None) -> np.ndarray:
    """The part of a polyline between arc lengths s0 < s1, with interpolated end points; ``s``:
    its ``cumulative_length`` when the caller has it (a stroke cut several times)."""
    if s is None:
        s = cumulative_length(points)
    s0, s1 = max(0.0, s0), min(float(s[-1]), s1)
    inner = points[(s > s0) & (s < s1)]
    # both ends in one interp per axis (the same per-element interpolation as scalar calls)
    out = np.empty((len(inner) + 2, 2), np.result_type(points.dtype, np.float64))
    out[[0, -1], 0] = np.interp((s0, s1), s, points[:, 0])
    out[[0, -1], 1] = np.interp((s0, s1), s, points[:, 1])
    out[1:-1] = inner
    return out


def _length(arc: np.ndarray) -> float:
    """``polyline_length`` of a stroke from its ``cumulative_length``."""
    return float(arc[-1]) if len(arc) > 1 else 0.0


def resample_strokes(strokes: Strokes, spacing: float) -> Strokes:
    """Smooth (Catmull-Rom) curves through the simplified vertices, a point every ``spacing``."""
    return [catmull_rom(s, spacing) for s in strokes if len(s) >= 2]


def drop(
    strokes: Strokes,
    rng: np.random.Generator,
    short_length: float,
    short_prob: float,
    prob: float,
    keep_fraction: float = 0.5,
) -> Strokes:
    """Drop strokes shorter than ``short_length`` with ``short_prob``, any stroke with ``prob``.

    Dropped strokes come back, longest first, until at least ``keep_fraction`` of the drawing's
    length is kept: a view drawn with one or two strokes (a mug's outline, an end-on knife) must
    not become a blank or unrecognisable training sketch.
    """
    lengths = [polyline_length(s) for s in strokes]
    keep = []
    for s, length in zip(strokes, lengths):
        u_short, u_any = rng.random(2)
        keep.append(not ((length < short_length and u_short < short_prob) or u_any < prob))
    total = sum(lengths)
    for i in sorted(range(len(strokes)), key=lambda i: -lengths[i]):
        if sum(length for length, k in zip(lengths, keep) if k) >= keep_fraction * total:
            break
        keep[i] = True
    return [s for s, k in zip(strokes, keep) if k]


def split(
    strokes: Strokes, rng: np.random.Generator, prob: float, max_points: int, gap: tuple[float, float], min_piece: float
) -> Strokes:
    """With ``prob`` per stroke, cut it at 1..max_points random places, leaving gaps in ``gap``.

    Pieces are never shorter than ``min_piece``: cut points that would make one are skipped.
    """
    out = []
    for s in strokes:
        u = rng.random()
        k = int(rng.integers(1, max_points + 1))
        where = rng.random(k)
        gaps = rng.uniform(gap[0], gap[1], k)
        arc = cumulative_length(s)
        length = _length(arc)
        if u >= prob or length < 2 * min_piece + gap[1]:
            out.append(s)
            continue
        start = 0.0
        for t, g in sorted(zip(where, gaps)):
            c = min_piece + t * (length - 2 * min_piece - g)
            if c - start < min_piece or length - (c + g) < min_piece:
                continue
            out.append(cut(s, start, c, arc))
            start = c + g
        out.append(cut(s, start, length, arc))
    return out


def truncate(strokes: Strokes, rng: np.random.Generator, prob: float, max_fraction: float, max_px: float) -> Strokes:
    """Shorten each end, with ``prob``, by up to min(max_fraction · length, max_px)."""
    out = []
    for s in strokes:
        u = rng.random(2)
        f = rng.random(2)
        arc = cumulative_length(s)
        length = _length(arc)
        limit = min(max_fraction * length, max_px)
        a = f[0] * limit if u[0] < prob else 0.0
        b = f[1] * limit if u[1] < prob else 0.0
        out.append(cut(s, a, length - b, arc) if a > 0 or b > 0 else s)
    return out


def extend(strokes: Strokes, rng: np.random.Generator, prob: float, max_px: float) -> Strokes:
    """Overshoot each end, with ``prob``, by up to ``max_px`` along its end tangent."""
    out = []
    for s in strokes:
        u = rng.random(2)
        f = rng.random(2)
        pts = s
        arc = cumulative_length(s)
        length = _length(arc)
        for end in (0, 1):
            if u[end] >= prob or length < 2.0:
                continue
            inner = cut(s, 0.0, min(3.0, length), arc) if end == 0 else cut(s, max(0.0, length - 3.0), length, arc)
            tip, base = (inner[0], inner[-1]) if end == 0 else (inner[-1], inner[0])
            d = tip - base
            d = d / max(np.linalg.norm(d), 1e-9)
            new = tip + d * f[end] * max_px
            pts = np.concatenate([new[None], pts]) if end == 0 else np.concatenate([pts, new[None]])
        out.append(pts)
    return out


def jitter(strokes: Strokes, rng: np.random.Generator, rotation_deg: float, scale: float) -> Strokes:
    """Per-stroke rotation (±rotation_deg) and scale (1 ± scale) about the stroke's centroid."""
    out = []
    for s in strokes:
        a = np.radians(rng.uniform(-rotation_deg, rotation_deg))
        k = rng.uniform(1.0 - scale, 1.0 + scale)
        c = s.sum(axis=0) / len(s)  # what s.mean(axis=0) computes, without its overhead
        r = k * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        out.append((s - c) @ r.T + c)
    return out


def noise_knots(rng: np.random.Generator, length: float, wavelength: float) -> tuple[np.ndarray, float]:
    """The random draws of ``smooth_noise`` over ``length`` of arc: knots in [-1, 1], one per
    ``wavelength`` + 2, then the phase (the compiled pencil draws its width noise with this too)."""
    knots = rng.uniform(-1.0, 1.0, int(np.ceil(length / wavelength)) + 2)
    return knots, rng.random()


def smooth_noise(rng: np.random.Generator, s: np.ndarray, wavelength: float) -> np.ndarray:
    """Smooth noise in [-1, 1] along arc length s: cosine-interpolated random knots."""
    knots, phase = noise_knots(rng, s[-1] if len(s) else 0.0, wavelength)
    n = len(knots)
    x = s / wavelength + phase
    i = np.floor(x).astype(int)
    f = x - i
    w = (1 - np.cos(np.pi * f)) / 2
    return knots[np.minimum(i, n - 1)] * (1 - w) + knots[np.minimum(i + 1, n - 1)] * w


def wobble(strokes: Strokes, rng: np.random.Generator, amplitude: float, wavelength: float) -> Strokes:
    """Smooth lateral offset along each stroke's normal, |offset| ≤ amplitude."""
    out = []
    for s in strokes:
        if len(s) < 2 or amplitude <= 0:
            out.append(s)
            continue
        off = amplitude * smooth_noise(rng, cumulative_length(s), wavelength)
        out.append(s + normals(s) * off[:, None])
    return out


def overdraw(strokes: Strokes, rng: np.random.Generator, prob: float, max_copies: int, offset: float) -> Strokes:
    """With ``prob`` per stroke, add 1..max_copies re-drawn copies, shifted by ≤ ``offset`` px
    and each covering a random 60–100 % of the stroke (a hand going over a line again)."""
    out = []
    for s in strokes:
        out.append(s)
        u = rng.random()
        k = int(rng.integers(1, max_copies + 1))
        shifts = rng.uniform(-offset, offset, (k, 2))
        spans = rng.uniform(0.6, 1.0, k)
        starts = rng.random(k)
        if u >= prob or len(s) < 2:
            continue
        arc = cumulative_length(s)
        length = _length(arc)
        for d, span, st in zip(shifts, spans, starts):
            a = st * (1.0 - span) * length
            out.append(cut(s, a, a + span * length, arc) + d)
    return out


def augment_strokes(strokes: Strokes, rng: np.random.Generator, settings: AugmentSettings) -> Strokes:
    """The full augmentation chain of one variant, in a fixed order.

    ``strokes`` should be densely sampled (``resample_strokes``, done once per view) so that
    cuts, wobble and overdraws follow the smooth curve.
    """
    st = settings
    out = drop(strokes, rng, st.drop_short_length, st.drop_short_prob, st.drop_prob, st.drop_keep_fraction)
    out = split(out, rng, st.split_prob, st.split_max_points, st.split_gap, st.split_min_piece)
    out = truncate(out, rng, st.truncate_prob, st.truncate_max_fraction, st.truncate_max_px)
    out = extend(out, rng, st.extend_prob, st.extend_max_px)
    out = jitter(out, rng, st.jitter_rotation_deg, st.jitter_scale)
    out = wobble(out, rng, st.wobble_amplitude, st.wobble_wavelength)
    out = overdraw(out, rng, st.overdraw_prob, st.overdraw_max_copies, st.overdraw_offset)
    return out
