"""Procedural pencil rasterizer: vector strokes → grayscale sketch.

Each stroke is drawn as a union of tapered capsules (round joins and caps), and covers a pixel
at most once, so overlapping pieces of one stroke never darken twice — no dark beads at joints
(augment.stroke_raster, compiled). The width follows a pressure curve (tapered ends + slow noise); each stroke
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

from augment.settings import REFERENCE_SIZE, AugmentSettings
from augment.stroke_raster import densify, deposit, half_widths

_GRAPHITE = 0.93  # darkest graphite tone (fraction of white removed)


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


def draw_pencil(
    strokes: list[np.ndarray],
    size: int,
    width: float,
    rng: np.random.Generator,
    settings: AugmentSettings = AugmentSettings(),
    tones: tuple[float, float] | None = None,
    tone: list[np.ndarray] = (),
) -> np.ndarray:
    """Pencil sketch (size, size) uint8, black-ish graphite on white paper.

    ``strokes`` are (K, 2) (u, v) arrays in output pixels (contract convention) and ``width`` the
    nominal line width in output pixels; lengths in ``settings`` are reference-canvas pixels.
    ``tones`` is the strokes' opacity range (default: the first of ``settings.tones``); ``tone``
    strokes (``augment.shading``) are drawn after them, lighter and broader.
    """
    st = settings
    ss = st.supersample
    big = size * ss
    scale = size / REFERENCE_SIZE  # reference px → output px
    tooth_all = _tooth_texture(big, 0.45 * ss)
    oy, ox = rng.integers(0, big, 2)
    tooth = tooth_all[oy : oy + big, ox : ox + big]
    dark = np.zeros((big, big), np.float32)
    lo, hi = tones or st.tones_for(0)
    passes = [(strokes, 1.0, (lo, hi))]
    if len(tone):
        passes.append((tone, st.shade_width, (lo * st.shade_tone, hi * st.shade_tone)))
    for lines, widen, opacity in passes:
        points, starts, arc = densify(lines, 1.0)  # one vertex per output px
        half_width, darkness = half_widths(
            arc,
            starts,
            rng,
            12.0 * scale,
            st.taper_length * scale,
            st.pressure_noise,
            0.5 * width * widen * ss,
            opacity,
        )
        # contract pixel (u, v) → pixel-centre coordinates of the supersampled canvas
        deposit(dark, tooth, points * ss - 0.5, starts, half_width, darkness, st.grain)
    small = cv2.resize(dark, (size, size), interpolation=cv2.INTER_AREA)
    mottle_knots = rng.uniform(-1.0, 1.0, (6, 6)).astype(np.float32)
    mottle = cv2.resize(mottle_knots, (size, size), interpolation=cv2.INTER_CUBIC)
    paper = 1.0 - st.paper_mottle * (0.5 + 0.5 * np.clip(mottle, -1, 1))
    img = paper * (1.0 - _GRAPHITE * small)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
