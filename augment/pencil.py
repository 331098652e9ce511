"""Procedural pencil rasterizer: vector strokes → grayscale sketch.

Each stroke is drawn as a filled outline (quads between the offset curves, round joins and
caps) into its own coverage mask, so overlapping pieces of one stroke never darken twice — no
dark beads at joints. The width follows a pressure curve (tapered ends + slow noise); each stroke
gets its own darkness; graphite only sticks to the paper's tooth (thresholded noise texture), and
the paper itself is mottled. Drawn ``supersample``× larger and area-downsampled (antialiasing).
Everything random comes from the ``rng`` passed in.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.special import ndtr

from augment.fitting import cumulative_length, dedupe, normals, resample
from augment.settings import REFERENCE_SIZE, AugmentSettings
from augment.strokes import smooth_noise

_SHIFT = 3          # cv2 sub-pixel bits
_GRAPHITE = 0.93    # darkest graphite tone (fraction of white removed)


@functools.lru_cache(maxsize=4)
def _tooth_texture(n: int, grain_sigma: float) -> np.ndarray:
    """Paper-tooth noise in [0, 1] (uniformly distributed), 2n × 2n so variants can crop it.

    Generated once per size from a fixed seed; each sketch takes a random crop, so the cache
    changes nothing about the output, only its speed.
    """
    rng = np.random.default_rng(0x9E11C)
    t = gaussian_filter(rng.standard_normal((2 * n, 2 * n)), grain_sigma, mode="wrap")
    t = (t - t.mean()) / t.std()
    return ndtr(t).astype(np.float32)


def _pressure(s: np.ndarray, taper: float, noise: np.ndarray, amount: float) -> np.ndarray:
    """Relative width along a stroke: smooth ramps at both ends times (1 + slow noise)."""
    length = s[-1] if len(s) else 0.0
    taper = max(min(taper, 0.5 * length), 1e-6)
    def ramp(x: np.ndarray) -> np.ndarray:
        c = np.clip(x / taper, 0, 1)
        return 0.45 + 0.55 * c ** 2 * (3 - 2 * c)

    return ramp(s) * ramp(length - s) * (1.0 + amount * noise)


def _stroke_mask(pts: np.ndarray, half_width: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """uint8 coverage of one stroke's filled outline in a canvas of ``shape`` (cv2 pixel coords)."""
    mask = np.zeros(shape, np.uint8)
    scale = 1 << _SHIFT
    if len(pts) == 1:
        c = np.round(pts[0] * scale).astype(int)
        cv2.circle(mask, (int(c[0]), int(c[1])), int(round(half_width[0] * scale)), 255, -1,
                   cv2.LINE_8, _SHIFT)
        return mask
    n = normals(pts) * half_width[:, None]
    left = np.round((pts + n) * scale).astype(np.int32)
    right = np.round((pts - n) * scale).astype(np.int32)
    quads = np.stack([left[:-1], left[1:], right[1:], right[:-1]], axis=1)
    for quad in quads:  # one call per quad: fillPoly's even-odd rule would punch holes at overlaps
        cv2.fillConvexPoly(mask, quad, 255, cv2.LINE_8, _SHIFT)
    # Round caps, and round joins where the stroke turns sharply (the quads leave a notch there).
    d = np.diff(pts, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    turn = np.ones(len(pts), bool)
    turn[1:-1] = np.sum(d[:-1] * d[1:], axis=1) < 0.95
    at = np.flatnonzero(turn)
    centers = np.round(pts[at] * scale).astype(int).tolist()
    radii = np.round(half_width[at] * scale).astype(int).tolist()  # half to even, as round() is
    for (cx, cy), r in zip(centers, radii):
        cv2.circle(mask, (cx, cy), r, 255, -1, cv2.LINE_8, _SHIFT)
    return mask


def draw_pencil(strokes: list[np.ndarray], size: int, width: float, rng: np.random.Generator,
                settings: AugmentSettings = AugmentSettings()) -> np.ndarray:
    """Pencil sketch (size, size) uint8, black-ish graphite on white paper.

    ``strokes`` are (K, 2) (u, v) arrays in output pixels (contract convention) and ``width`` the
    nominal line width in output pixels; lengths in ``settings`` are reference-canvas pixels.
    """
    st = settings
    ss = st.supersample
    big = size * ss
    scale = size / REFERENCE_SIZE          # reference px → output px
    tooth_all = _tooth_texture(big, 0.45 * ss)
    oy, ox = rng.integers(0, big, 2)
    tooth = tooth_all[oy:oy + big, ox:ox + big]
    dark = np.zeros((big, big), np.float32)
    for s in strokes:
        a = rng.uniform(*st.darkness)
        pts = dedupe(np.asarray(s, np.float64))
        if len(pts) == 0:
            continue
        pts = resample(pts, 1.0) if len(pts) > 1 else pts  # one vertex per output px
        arc = cumulative_length(pts)
        noise = smooth_noise(rng, arc, 12.0 * scale)
        hw = 0.5 * width * ss * _pressure(arc, st.taper_length * scale, noise, st.pressure_noise)
        p = pts * ss - 0.5  # contract pixel (u, v) → cv2 pixel-centre coordinates at ss
        pad = float(hw.max()) + 2
        x0, y0 = np.floor(p.min(axis=0) - pad).astype(int)
        x1, y1 = np.ceil(p.max(axis=0) + pad).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, big), min(y1, big)
        if x1 <= x0 or y1 <= y0:
            continue
        m = _stroke_mask(p - [x0, y0], hw, (y1 - y0, x1 - x0))
        ys, xs = np.nonzero(m)  # work on covered pixels only: far fewer than the bounding box
        if len(ys) == 0:
            continue
        ys += y0
        xs += x0
        # Graphite catches the paper's tooth first: harder (darker) strokes fill more of it.
        catch = np.clip((tooth[ys, xs] - (0.75 - 0.5 * a)) * 4.0 + 0.5, 0.0, 1.0)
        deposit = a * ((1.0 - st.grain) + st.grain * catch)
        old = dark[ys, xs]
        dark[ys, xs] = old + deposit * (1.0 - old)  # multiplicative layering: overdraws darken
    small = cv2.resize(dark, (size, size), interpolation=cv2.INTER_AREA)
    mottle_knots = rng.uniform(-1.0, 1.0, (6, 6)).astype(np.float32)
    mottle = cv2.resize(mottle_knots, (size, size), interpolation=cv2.INTER_CUBIC)
    paper = 1.0 - st.paper_mottle * (0.5 + 0.5 * np.clip(mottle, -1, 1))
    img = paper * (1.0 - _GRAPHITE * small)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
