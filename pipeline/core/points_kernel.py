"""The compiled writer behind ``pipeline.core.points_text.points_json`` (its own module so that
writing other JSON, e.g. in the render worker, never imports numba: ~0.6 CPU s a process)."""

from __future__ import annotations

import numba


@numba.njit(cache=True)
def _digits(out, pos, value):
    """Write the decimal digits of ``value`` >= 0 at ``out[pos:]``; returns the new position."""
    if value == 0:
        out[pos] = 48
        return pos + 1
    n = 0
    v = value
    while v > 0:
        n += 1
        v //= 10
    for i in range(n - 1, -1, -1):
        out[pos + i] = 48 + value % 10
        value //= 10
    return pos + n


@numba.njit(cache=True)
def write_points(units, negative, ends, scale, decimals, out):
    """``[[[u,v],...],...]`` of ``units / scale`` into ``out`` (ASCII); returns its length, or -1
    if ``out`` is too short."""
    pos = 0
    out[pos] = 91  # [
    pos += 1
    start = 0
    for s in range(len(ends)):
        if s > 0:
            out[pos] = 44  # ,
            pos += 1
        out[pos] = 91
        pos += 1
        for p in range(start, ends[s]):
            if pos + 64 > len(out):  # never reached with the caller's bound; no write past the end
                return -1
            if p > start:
                out[pos] = 44
                pos += 1
            out[pos] = 91
            pos += 1
            for c in range(2):
                if c == 1:
                    out[pos] = 44
                    pos += 1
                if negative[p, c]:
                    out[pos] = 45  # -
                    pos += 1
                k = units[p, c]
                pos = _digits(out, pos, k // scale)
                out[pos] = 46  # .
                pos += 1
                frac = k % scale
                if frac == 0:
                    out[pos] = 48
                    pos += 1
                else:
                    width = decimals
                    while frac % 10 == 0:
                        frac //= 10
                        width -= 1
                    for i in range(width - 1, -1, -1):
                        out[pos + i] = 48 + frac % 10
                        frac //= 10
                    pos += width
            out[pos] = 93  # ]
            pos += 1
        out[pos] = 93
        pos += 1
        start = ends[s]
    out[pos] = 93
    return pos + 1
