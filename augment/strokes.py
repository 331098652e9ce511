"""Stroke augmentations: each a small pure function (strokes, rng, its parameters) → new strokes.

Strokes are float (K, 2) arrays in reference-canvas pixels (see settings.REFERENCE_SIZE); the
input list and arrays are never modified. All randomness comes from the ``rng`` passed in, drawn
in a fixed order (per stroke, in stroke order), so a keyed generator gives the same strokes every
run.

Every augmentation is compiled (numba) over all strokes of a drawing at once, held flat: points
(N, 2) and ``starts`` (S + 1,), stroke k being ``points[starts[k]:starts[k + 1]]``. The chain
(``augment_strokes``) stays flat from its first step to its last, in one compiled call; the list
functions convert at their edges. Numba's generator methods share the numpy ``Generator``'s state and draw the same
numbers, and the arithmetic follows numpy's (``np.interp``'s formula, sequential sums, the fused
multiply-add OpenBLAS uses in a 2 × 2 product and a 2-vector's norm), so the strokes are the ones
the per-stroke numpy code drew.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

from augment.fitting import catmull_rom_flat, interp_one
from augment.settings import AugmentSettings

Strokes = list[np.ndarray]


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c rounded once (llvm.fma), as OpenBLAS's kernels compute a product's last term."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


# ---------------------------------------------------------------- flat strokes


def flat_strokes(strokes: Strokes) -> tuple[np.ndarray, np.ndarray]:
    """(points (N, 2) float64, starts (S + 1,) int64) of a list of strokes."""
    counts = np.array([len(s) for s in strokes], np.int64)
    starts = np.zeros(len(strokes) + 1, np.int64)
    np.cumsum(counts, out=starts[1:])
    if not len(strokes):
        return np.zeros((0, 2)), starts
    return np.concatenate([np.asarray(s, np.float64).reshape(-1, 2) for s in strokes]), starts


def split_strokes(points: np.ndarray, starts: np.ndarray) -> Strokes:
    """The strokes of flat ``points`` (views into it)."""
    return [points[a:b] for a, b in zip(starts[:-1].tolist(), starts[1:].tolist())]


@numba.njit(cache=True)
def _arc(points, i0, i1):
    """``augment.fitting.cumulative_length`` of points[i0:i1]."""
    out = np.zeros(i1 - i0)
    for i in range(i0 + 1, i1):
        out[i - i0] = out[i - i0 - 1] + np.hypot(points[i, 0] - points[i - 1, 0], points[i, 1] - points[i - 1, 1])
    return out


@numba.njit(cache=True)
def _cut_into(points, i0, i1, arc, s0, s1, out, o, dx, dy):
    """Write ``cut(points[i0:i1], s0, s1)`` shifted by (dx, dy) at out[o:]; returns the new o."""
    s0 = max(0.0, s0)
    s1 = min(arc[len(arc) - 1], s1)
    xs = points[i0:i1, 0]
    ys = points[i0:i1, 1]
    out[o, 0] = interp_one(s0, arc, xs) + dx
    out[o, 1] = interp_one(s0, arc, ys) + dy
    o += 1
    for i in range(len(arc)):
        if arc[i] > s0 and arc[i] < s1:
            out[o, 0] = points[i0 + i, 0] + dx
            out[o, 1] = points[i0 + i, 1] + dy
            o += 1
    out[o, 0] = interp_one(s1, arc, xs) + dx
    out[o, 1] = interp_one(s1, arc, ys) + dy
    return o + 1


@numba.njit(cache=True)
def _copy_into(points, i0, i1, out, o):
    for i in range(i0, i1):
        out[o, 0] = points[i, 0]
        out[o, 1] = points[i, 1]
        o += 1
    return o


@numba.njit(cache=True)
def _length(points, i0, i1):
    """``polyline_length`` of points[i0:i1]."""
    if i1 - i0 < 2:
        return 0.0
    return _arc(points, i0, i1)[i1 - i0 - 1]


# ---------------------------------------------------------------- the augmentations, flat


@numba.njit(cache=True)
def _drop(points, starts, rng, short_length, short_prob, prob, keep_fraction):
    n = len(starts) - 1
    lengths = np.empty(n)
    keep = np.empty(n, np.bool_)
    for k in range(n):
        lengths[k] = _length(points, starts[k], starts[k + 1])
        u_short = rng.random()
        u_any = rng.random()
        keep[k] = not ((lengths[k] < short_length and u_short < short_prob) or u_any < prob)
    total = 0.0
    for k in range(n):
        total += lengths[k]
    for i in np.argsort(-lengths, kind="mergesort"):  # longest first, ties in stroke order
        kept = 0.0
        for k in range(n):
            if keep[k]:
                kept += lengths[k]
        if kept >= keep_fraction * total:
            break
        keep[i] = True
    out = np.empty_like(points)
    out_starts = np.zeros(n + 1, np.int64)
    o, m = 0, 0
    for k in range(n):
        if keep[k]:
            o = _copy_into(points, starts[k], starts[k + 1], out, o)
            m += 1
            out_starts[m] = o
    return out[:o], out_starts[: m + 1]


@numba.njit(cache=True)
def _split(points, starts, rng, prob, max_points, gap0, gap1, min_piece):
    n = len(starts) - 1
    out = np.empty((len(points) + 2 * (max_points + 1) * n, 2))
    out_starts = np.zeros((max_points + 1) * n + 1, np.int64)
    o, m = 0, 0
    for k in range(n):
        i0, i1 = starts[k], starts[k + 1]
        u = rng.random()
        cuts = rng.integers(1, max_points + 1)
        where = rng.random(cuts)
        gaps = rng.uniform(gap0, gap1, cuts)
        arc = _arc(points, i0, i1)
        length = arc[len(arc) - 1] if len(arc) > 1 else 0.0
        if u >= prob or length < 2 * min_piece + gap1:
            o = _copy_into(points, i0, i1, out, o)
            m += 1
            out_starts[m] = o
            continue
        start = 0.0
        for j in np.argsort(where, kind="mergesort"):
            t, g = where[j], gaps[j]
            c = min_piece + t * (length - 2 * min_piece - g)
            if c - start < min_piece or length - (c + g) < min_piece:
                continue
            o = _cut_into(points, i0, i1, arc, start, c, out, o, 0.0, 0.0)
            m += 1
            out_starts[m] = o
            start = c + g
        o = _cut_into(points, i0, i1, arc, start, length, out, o, 0.0, 0.0)
        m += 1
        out_starts[m] = o
    return out[:o], out_starts[: m + 1]


@numba.njit(cache=True)
def _truncate(points, starts, rng, prob, max_fraction, max_px):
    n = len(starts) - 1
    out = np.empty((len(points) + 2 * n, 2))
    out_starts = np.zeros(n + 1, np.int64)
    o = 0
    for k in range(n):
        i0, i1 = starts[k], starts[k + 1]
        u0 = rng.random()
        u1 = rng.random()
        f0 = rng.random()
        f1 = rng.random()
        arc = _arc(points, i0, i1)
        length = arc[len(arc) - 1] if len(arc) > 1 else 0.0
        limit = min(max_fraction * length, max_px)
        a = f0 * limit if u0 < prob else 0.0
        b = f1 * limit if u1 < prob else 0.0
        if a > 0 or b > 0:
            o = _cut_into(points, i0, i1, arc, a, length - b, out, o, 0.0, 0.0)
        else:
            o = _copy_into(points, i0, i1, out, o)
        out_starts[k + 1] = o
    return out[:o], out_starts


@numba.njit(cache=True)
def _extend(points, starts, rng, prob, max_px):
    n = len(starts) - 1
    out = np.empty((len(points) + 2 * n, 2))
    out_starts = np.zeros(n + 1, np.int64)
    inner = np.empty((len(points) + 2, 2))
    o = 0
    for k in range(n):
        i0, i1 = starts[k], starts[k + 1]
        u = rng.random(2)
        f = rng.random(2)
        arc = _arc(points, i0, i1)
        length = arc[len(arc) - 1] if len(arc) > 1 else 0.0
        grow = np.zeros((2, 2))
        has = np.zeros(2, np.bool_)
        for end in range(2):
            if u[end] >= prob or length < 2.0:
                continue
            if end == 0:
                last = _cut_into(points, i0, i1, arc, 0.0, min(3.0, length), inner, 0, 0.0, 0.0) - 1
                tx, ty, bx, by = inner[0, 0], inner[0, 1], inner[last, 0], inner[last, 1]
            else:
                last = _cut_into(points, i0, i1, arc, max(0.0, length - 3.0), length, inner, 0, 0.0, 0.0) - 1
                tx, ty, bx, by = inner[last, 0], inner[last, 1], inner[0, 0], inner[0, 1]
            dx, dy = tx - bx, ty - by
            norm = max(np.sqrt(_fma(dy, dy, dx * dx)), 1e-9)
            dx, dy = dx / norm, dy / norm
            grow[end, 0] = tx + dx * f[end] * max_px
            grow[end, 1] = ty + dy * f[end] * max_px
            has[end] = True
        if has[0]:
            out[o] = grow[0]
            o += 1
        o = _copy_into(points, i0, i1, out, o)
        if has[1]:
            out[o] = grow[1]
            o += 1
        out_starts[k + 1] = o
    return out[:o], out_starts


@numba.njit(cache=True)
def _jitter(points, starts, rng, rotation_deg, scale):
    out = np.empty_like(points)
    for k in range(len(starts) - 1):
        i0, i1 = starts[k], starts[k + 1]
        a = rng.uniform(-rotation_deg, rotation_deg) * (np.pi / 180.0)  # np.radians
        g = rng.uniform(1.0 - scale, 1.0 + scale)
        cx, cy = 0.0, 0.0
        for i in range(i0, i1):
            cx += points[i, 0]
            cy += points[i, 1]
        cx, cy = cx / (i1 - i0), cy / (i1 - i0)
        r00, r01, r10, r11 = g * np.cos(a), g * -np.sin(a), g * np.sin(a), g * np.cos(a)
        for i in range(i0, i1):
            dx, dy = points[i, 0] - cx, points[i, 1] - cy
            out[i, 0] = _fma(dy, r01, dx * r00) + cx  # (s - c) @ r.T + c
            out[i, 1] = _fma(dy, r11, dx * r10) + cy
    return out, starts


@numba.njit(cache=True)
def _noise(arc, knots, phase, wavelength):
    """``smooth_noise`` at arc lengths ``arc`` from its draws."""
    n = len(knots)
    out = np.empty(len(arc))
    for i in range(len(arc)):
        x = arc[i] / wavelength + phase
        c = np.floor(x)
        f = x - c
        w = (1 - np.cos(np.pi * f)) / 2
        j = int(c)
        out[i] = knots[min(j, n - 1)] * (1 - w) + knots[min(j + 1, n - 1)] * w
    return out


@numba.njit(cache=True)
def _wobble(points, starts, rng, amplitude, wavelength):
    out = points.copy()
    for k in range(len(starts) - 1):
        i0, i1 = starts[k], starts[k + 1]
        if i1 - i0 < 2 or amplitude <= 0:
            continue
        arc = _arc(points, i0, i1)
        knots = rng.uniform(-1.0, 1.0, int(np.ceil(arc[len(arc) - 1] / wavelength)) + 2)
        off = _noise(arc, knots, rng.random(), wavelength)
        for i in range(i0, i1):
            # augment.fitting.normals: central differences, one-sided at the ends
            a, b = max(i - 1, i0), min(i + 1, i1 - 1)
            gx, gy = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1]
            norm = max(np.hypot(gx, gy), 1e-12)
            tx, ty = gx / norm, gy / norm
            out[i, 0] = points[i, 0] + -ty * (amplitude * off[i - i0])
            out[i, 1] = points[i, 1] + tx * (amplitude * off[i - i0])
    return out, starts


@numba.njit(cache=True)
def _overdraw(points, starts, rng, prob, max_copies, offset):
    n = len(starts) - 1
    out = np.empty((len(points) * (max_copies + 1) + 2 * max_copies * n, 2))
    out_starts = np.zeros((max_copies + 1) * n + 1, np.int64)
    o, m = 0, 0
    for k in range(n):
        i0, i1 = starts[k], starts[k + 1]
        o = _copy_into(points, i0, i1, out, o)
        m += 1
        out_starts[m] = o
        u = rng.random()
        copies = rng.integers(1, max_copies + 1)
        shifts = rng.uniform(-offset, offset, (copies, 2))
        spans = rng.uniform(0.6, 1.0, copies)
        begins = rng.random(copies)
        if u >= prob or i1 - i0 < 2:
            continue
        arc = _arc(points, i0, i1)
        length = arc[len(arc) - 1]
        for c in range(copies):
            a = begins[c] * (1.0 - spans[c]) * length
            o = _cut_into(points, i0, i1, arc, a, a + spans[c] * length, out, o, shifts[c, 0], shifts[c, 1])
            m += 1
            out_starts[m] = o
    return out[:o], out_starts[: m + 1]


# ---------------------------------------------------------------- the list functions


def cut(points: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of a polyline between arc lengths s0 < s1, with interpolated end points."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
    out = np.empty((len(p) + 2, 2))
    n = _cut_into(p, 0, len(p), _arc(p, 0, len(p)), float(s0), float(s1), out, 0, 0.0, 0.0)
    return out[:n]


def resample_strokes(strokes: Strokes, spacing: float) -> Strokes:
    """Smooth (Catmull-Rom) curves through the simplified vertices, a point every ``spacing``."""
    return split_strokes(*catmull_rom_flat(*flat_strokes([s for s in strokes if len(s) >= 2]), spacing))


def _listed(kernel, strokes: Strokes, rng: np.random.Generator, *args) -> Strokes:
    return split_strokes(*kernel(*flat_strokes(strokes), rng, *args))


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
    return _listed(_drop, strokes, rng, float(short_length), float(short_prob), float(prob), float(keep_fraction))


def split(
    strokes: Strokes, rng: np.random.Generator, prob: float, max_points: int, gap: tuple[float, float], min_piece: float
) -> Strokes:
    """With ``prob`` per stroke, cut it at 1..max_points random places, leaving gaps in ``gap``.

    Pieces are never shorter than ``min_piece``: cut points that would make one are skipped.
    """
    return _listed(_split, strokes, rng, float(prob), int(max_points), float(gap[0]), float(gap[1]), float(min_piece))


def truncate(strokes: Strokes, rng: np.random.Generator, prob: float, max_fraction: float, max_px: float) -> Strokes:
    """Shorten each end, with ``prob``, by up to min(max_fraction · length, max_px)."""
    return _listed(_truncate, strokes, rng, float(prob), float(max_fraction), float(max_px))


def extend(strokes: Strokes, rng: np.random.Generator, prob: float, max_px: float) -> Strokes:
    """Overshoot each end, with ``prob``, by up to ``max_px`` along its end tangent."""
    return _listed(_extend, strokes, rng, float(prob), float(max_px))


def jitter(strokes: Strokes, rng: np.random.Generator, rotation_deg: float, scale: float) -> Strokes:
    """Per-stroke rotation (±rotation_deg) and scale (1 ± scale) about the stroke's centroid."""
    return _listed(_jitter, strokes, rng, float(rotation_deg), float(scale))


def noise_knots(rng: np.random.Generator, length: float, wavelength: float) -> tuple[np.ndarray, float]:
    """The random draws of ``smooth_noise`` over ``length`` of arc: knots in [-1, 1], one per
    ``wavelength`` + 2, then the phase (the compiled pencil draws its width noise with this too)."""
    knots = rng.uniform(-1.0, 1.0, int(np.ceil(length / wavelength)) + 2)
    return knots, rng.random()


def smooth_noise(rng: np.random.Generator, s: np.ndarray, wavelength: float) -> np.ndarray:
    """Smooth noise in [-1, 1] along arc length s: cosine-interpolated random knots."""
    knots, phase = noise_knots(rng, s[-1] if len(s) else 0.0, wavelength)
    return _noise(np.asarray(s, np.float64), knots, float(phase), float(wavelength))


def wobble(strokes: Strokes, rng: np.random.Generator, amplitude: float, wavelength: float) -> Strokes:
    """Smooth lateral offset along each stroke's normal (``augment.fitting.normals``),
    |offset| ≤ amplitude."""
    return _listed(_wobble, strokes, rng, float(amplitude), float(wavelength))


def overdraw(strokes: Strokes, rng: np.random.Generator, prob: float, max_copies: int, offset: float) -> Strokes:
    """With ``prob`` per stroke, add 1..max_copies re-drawn copies, shifted by ≤ ``offset`` px
    and each covering a random 60–100 % of the stroke (a hand going over a line again)."""
    return _listed(_overdraw, strokes, rng, float(prob), int(max_copies), float(offset))


@numba.njit(cache=True)
def _chain(p, s, rng, drop_args, split_args, truncate_args, extend_args, jitter_args, wobble_args, overdraw_args):
    p, s = _drop(p, s, rng, *drop_args)
    p, s = _split(p, s, rng, *split_args)
    p, s = _truncate(p, s, rng, *truncate_args)
    p, s = _extend(p, s, rng, *extend_args)
    p, s = _jitter(p, s, rng, *jitter_args)
    p, s = _wobble(p, s, rng, *wobble_args)
    return _overdraw(p, s, rng, *overdraw_args)


def augment_strokes(strokes: Strokes, rng: np.random.Generator, settings: AugmentSettings) -> Strokes:
    """The full augmentation chain of one variant, in a fixed order: drop, split, truncate,
    extend, jitter, wobble, overdraw (one compiled call: handing numba the generator costs more
    than a step).

    ``strokes`` should be densely sampled (``resample_strokes``, done once per view) so that
    cuts, wobble and overdraws follow the smooth curve.
    """
    st = settings
    f = float
    return split_strokes(
        *_chain(
            *flat_strokes(strokes),
            rng,
            (f(st.drop_short_length), f(st.drop_short_prob), f(st.drop_prob), f(st.drop_keep_fraction)),
            (f(st.split_prob), int(st.split_max_points), f(st.split_gap[0]), f(st.split_gap[1]), f(st.split_min_piece)),
            (f(st.truncate_prob), f(st.truncate_max_fraction), f(st.truncate_max_px)),
            (f(st.extend_prob), f(st.extend_max_px)),
            (f(st.jitter_rotation_deg), f(st.jitter_scale)),
            (f(st.wobble_amplitude), f(st.wobble_wavelength)),
            (f(st.overdraw_prob), int(st.overdraw_max_copies), f(st.overdraw_offset)),
        )
    )
