"""Pencil strokes → graphite in a darkness canvas, compiled with numba.

Three steps, all strokes of a sketch per call (the per-stroke numpy and ``cv2`` calls they
replace cost ~30 calls per stroke and were most of the augment stage's CPU time):

- ``densify``: consecutive duplicates dropped, one vertex per ``spacing`` of arc length.
- ``half_widths``: the pressure curve — smooth ramps at both ends times (1 + slow noise, the
  compiled form of ``augment.strokes.smooth_noise``, its knots drawn by ``noise_knots``).
- ``deposit``: a stroke is the union of tapered capsules, one per segment: a pixel is covered
  when its centre lies within the segment's half-width (interpolated along it) of the segment,
  which gives round caps and round joins. Each stroke covers a pixel at most once (a stamp
  canvas holds the last stroke that darkened it), so a stroke going over itself never darkens
  twice — no beads at joints — while separate strokes layer.
"""

from __future__ import annotations

import numba
import numpy as np

# Coverage reaches this far (canvas px) past the nominal half-width: pixels whose centre is just
# outside the outline are partly covered. Chosen so a sketch holds the same ink as the earlier
# polygon fill, which counted such pixels in (BENCHMARKS.md, augment).
EDGE = 0.5


@numba.njit(cache=True)
def _dedupe_count(points, i0, i1, keep):
    n = 0
    for i in range(i0, i1):
        if i == i0 or max(abs(points[i, 0] - points[i - 1, 0]), abs(points[i, 1] - points[i - 1, 1])) > 1e-6:
            keep[i] = True
            n += 1
        else:
            keep[i] = False
    return n


@numba.njit(cache=True)
def _densify(points, starts, spacing):
    n_strokes = len(starts) - 1
    keep = np.zeros(len(points), np.bool_)
    lengths = np.zeros(n_strokes)
    counts = np.zeros(n_strokes, np.int64)
    for k in range(n_strokes):
        m = _dedupe_count(points, starts[k], starts[k + 1], keep)
        length = 0.0
        px, py = 0.0, 0.0
        first = True
        for i in range(starts[k], starts[k + 1]):
            if keep[i]:
                if not first:
                    length += np.hypot(points[i, 0] - px, points[i, 1] - py)
                px, py = points[i, 0], points[i, 1]
                first = False
        lengths[k] = length
        counts[k] = m if m < 2 else max(2, int(np.ceil(length / spacing)) + 1)
    out_starts = np.zeros(n_strokes + 1, np.int64)
    for k in range(n_strokes):
        out_starts[k + 1] = out_starts[k] + counts[k]
    out = np.empty((out_starts[-1], 2))
    arc = np.empty(out_starts[-1])
    for k in range(n_strokes):
        o = out_starts[k]
        if counts[k] == 0:
            continue
        idx = np.array([i for i in range(starts[k], starts[k + 1]) if keep[i]])
        if counts[k] == 1:
            out[o] = points[idx[0]]
            arc[o] = 0.0
            continue
        n = counts[k]
        seg = 0
        s0 = 0.0  # arc length at the start of segment seg
        a, b = idx[0], idx[1]
        seg_len = np.hypot(points[b, 0] - points[a, 0], points[b, 1] - points[a, 1])
        for j in range(n):
            t = lengths[k] * j / (n - 1)
            while t > s0 + seg_len and seg < len(idx) - 2:
                s0 += seg_len
                seg += 1
                a, b = idx[seg], idx[seg + 1]
                seg_len = np.hypot(points[b, 0] - points[a, 0], points[b, 1] - points[a, 1])
            f = min(max((t - s0) / seg_len, 0.0), 1.0) if seg_len > 0 else 0.0
            out[o + j, 0] = points[a, 0] + f * (points[b, 0] - points[a, 0])
            out[o + j, 1] = points[a, 1] + f * (points[b, 1] - points[a, 1])
            arc[o + j] = t
        out[o + n - 1] = points[idx[-1]]  # ends kept exactly
    return out, out_starts, arc


def densify(strokes: list[np.ndarray], spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Strokes → (points (N, 2), starts (S + 1,), arc length at each point (N,)): duplicates
    dropped, ends kept, one point every ~``spacing``; an empty stroke stays empty, a one-point
    stroke stays one point."""
    counts = np.array([len(s) for s in strokes], np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    flat = (
        np.concatenate([np.asarray(s, np.float64).reshape(-1, 2) for s in strokes])
        if len(strokes)
        else np.zeros((0, 2))
    )
    points, out_starts, arc = _densify(np.ascontiguousarray(flat), starts, max(float(spacing), 1e-6))
    return points, out_starts, arc


@numba.njit(cache=True)
def _half_widths(arc, starts, knots, knot_starts, phases, wavelength, taper_length, amount, base):
    out = np.empty(len(arc))
    for k in range(len(starts) - 1):
        i0, i1 = starts[k], starts[k + 1]
        if i1 == i0:
            continue
        length = arc[i1 - 1]
        taper = max(min(taper_length, 0.5 * length), 1e-6)
        k0, nk = knot_starts[k], knot_starts[k + 1] - knot_starts[k]
        for i in range(i0, i1):
            x = arc[i] / wavelength + phases[k]
            cell = int(np.floor(x))
            w = (1.0 - np.cos(np.pi * (x - cell))) / 2.0
            noise = knots[k0 + min(cell, nk - 1)] * (1.0 - w) + knots[k0 + min(cell + 1, nk - 1)] * w
            c0 = min(max(arc[i] / taper, 0.0), 1.0)
            c1 = min(max((length - arc[i]) / taper, 0.0), 1.0)
            ramp = (0.45 + 0.55 * c0 * c0 * (3.0 - 2.0 * c0)) * (0.45 + 0.55 * c1 * c1 * (3.0 - 2.0 * c1))
            out[i] = base * ramp * (1.0 + amount * noise)
    return out


@numba.njit(cache=True)
def _pressure_draws(arc, starts, rng, lo, hi, wavelength):
    """Per stroke, in stroke order: its darkness (uniform in [lo, hi]), then, for a stroke with
    points, ``augment.strokes.noise_knots``' draws (knots in [-1, 1], one per wavelength + 2, and
    the phase)."""
    n_strokes = len(starts) - 1
    knot_starts = np.zeros(n_strokes + 1, np.int64)
    for k in range(n_strokes):
        count = 0
        if starts[k + 1] > starts[k]:
            count = int(np.ceil(arc[starts[k + 1] - 1] / wavelength)) + 2
        knot_starts[k + 1] = knot_starts[k] + count
    darkness = np.empty(n_strokes)
    knots = np.empty(knot_starts[-1])
    phases = np.zeros(n_strokes)
    for k in range(n_strokes):
        darkness[k] = rng.uniform(lo, hi)
        if starts[k + 1] == starts[k]:
            continue
        for i in range(knot_starts[k], knot_starts[k + 1]):
            knots[i] = rng.uniform(-1.0, 1.0)
        phases[k] = rng.random()
    return darkness, knots, knot_starts, phases


def half_widths(
    arc: np.ndarray,
    starts: np.ndarray,
    rng: np.random.Generator,
    wavelength: float,
    taper_length: float,
    noise_amount: float,
    base: float,
    tones: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Half-width at every point (``base`` × pressure) and one darkness per stroke.

    Per stroke, in stroke order, it draws from ``rng``: the darkness (uniform in ``tones``), the
    noise knots (uniform in [-1, 1], one per ``wavelength`` of arc length + 2) and the noise phase.
    """
    darkness, knots, knot_starts, phases = _pressure_draws(
        arc, starts, rng, float(tones[0]), float(tones[1]), float(wavelength)
    )
    widths = _half_widths(
        arc,
        starts,
        knots,
        knot_starts,
        phases,
        float(wavelength),
        float(taper_length),
        float(noise_amount),
        float(base),
    )
    return widths, darkness


@numba.njit(cache=True)
def _deposit(dark, tooth, stamp, points, starts, half_width, darkness, grain, edge):
    height, width = dark.shape
    for k in range(len(starts) - 1):
        a = darkness[k]
        # Graphite catches the paper's tooth first: harder (darker) strokes fill more of it.
        threshold = 0.75 - 0.5 * a
        i0, i1 = starts[k], starts[k + 1]
        n_segments = 0 if i1 == i0 else max(i1 - i0 - 1, 1)  # a one-point stroke: one of length 0, a disk
        for i in range(i0, i0 + n_segments):
            j = min(i + 1, i1 - 1)
            x0, y0, r0 = points[i, 0], points[i, 1], half_width[i] + edge
            x1, y1, r1 = points[j, 0], points[j, 1], half_width[j] + edge
            dx, dy = x1 - x0, y1 - y0
            dd = dx * dx + dy * dy
            r = max(r0, r1)
            xa = max(int(np.floor(min(x0, x1) - r)), 0)
            xb = min(int(np.ceil(max(x0, x1) + r)), width - 1)
            ya = max(int(np.floor(min(y0, y1) - r)), 0)
            yb = min(int(np.ceil(max(y0, y1) + r)), height - 1)
            for y in range(ya, yb + 1):
                for x in range(xa, xb + 1):
                    if stamp[y, x] == k:
                        continue
                    px, py = x - x0, y - y0
                    t = 0.0
                    if dd > 0.0:
                        t = min(max((px * dx + py * dy) / dd, 0.0), 1.0)
                    ex, ey = px - t * dx, py - t * dy
                    rad = r0 + t * (r1 - r0)
                    if ex * ex + ey * ey > rad * rad:
                        continue
                    stamp[y, x] = k
                    catch = min(max((tooth[y, x] - threshold) * 4.0 + 0.5, 0.0), 1.0)
                    deposit = a * ((1.0 - grain) + grain * catch)
                    old = dark[y, x]
                    dark[y, x] = old + deposit * (1.0 - old)  # multiplicative layering


def deposit(
    dark: np.ndarray,
    tooth: np.ndarray,
    points: np.ndarray,
    starts: np.ndarray,
    half_width: np.ndarray,
    darkness: np.ndarray,
    grain: float,
) -> None:
    """Darken ``dark`` (H, W) float32 in place by each stroke in order.

    ``points`` (N, 2) are canvas pixel-centre coordinates (pixel (x, y) has its centre at (x, y)),
    stroke k being ``points[starts[k]:starts[k + 1]]``; ``half_width`` (N,) in canvas pixels,
    ``darkness`` one tone per stroke in [0, 1], ``tooth`` the (H, W) paper texture in [0, 1] and
    ``grain`` how much of the tone depends on it.
    """
    if dark.shape != tooth.shape or dark.dtype != np.float32:
        raise ValueError("dark must be float32 and the same shape as tooth")
    if len(points) != len(half_width) or len(darkness) != len(starts) - 1:
        raise ValueError("one half-width per point and one darkness per stroke")
    stamp = np.full(dark.shape, -1, np.int32)
    _deposit(
        dark,
        tooth,
        stamp,
        np.ascontiguousarray(points, np.float64),
        np.asarray(starts, np.int64),
        np.ascontiguousarray(half_width, np.float64),
        np.asarray(darkness, np.float64),
        float(grain),
        EDGE,
    )
