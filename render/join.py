"""Join captured stroke fragments end to end (pure numpy, no Blender).

Freestyle breaks a chain wherever a tiny piece of it is hidden, which on thin parts (wing edges,
blades) and on the slightly bumpy surfaces of remeshed models cuts one visible outline into
dozens of 1–3 px fragments whose ends are a fraction of a pixel apart. The drawing is continuous
there (lines are wider than the gaps), so the vector ground truth should be too: fragments whose
ends lie within ``gap_px`` and whose directions continue smoothly are concatenated. Points are
never moved, only chained; the result is deterministic (fixed visiting order, ties by index).
"""

from __future__ import annotations

import math

import numpy as np

Fragment = tuple[np.ndarray, list[str]]  # (n,2) points, natures under its vertices


def _direction(points: np.ndarray, at_end: bool, reach_px: float = 3.0) -> np.ndarray | None:
    """Unit direction pointing out of the stroke at one end, over up to ``reach_px`` of arc."""
    p = points[::-1] if at_end else points
    d = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if d.sum() < 1.0:  # a speck has no usable direction: any continuation fits it
        return None
    k = int(np.searchsorted(np.cumsum(d), reach_px)) + 1
    v = p[0] - p[min(k, len(p) - 1)]
    n = np.linalg.norm(v)
    return v / n if n > 0 else None


def join_fragments(fragments: list[Fragment], gap_px: float, max_turn_deg: float = 60.0) -> list[Fragment]:
    """Greedily extend each stroke, in order, by the nearest fitting fragment at either end."""
    if gap_px <= 0 or len(fragments) < 2:
        return list(fragments)
    cos_max = math.cos(math.radians(max_turn_deg))
    pts = [np.asarray(p, float) for p, _ in fragments]
    types = [list(t) for _, t in fragments]
    alive = np.ones(len(pts), bool)
    heads = np.array([p[0] for p in pts])
    tails = np.array([p[-1] for p in pts])
    out: list[Fragment] = []
    for i in range(len(pts)):
        if not alive[i]:
            continue
        alive[i] = False
        cur, cur_t = pts[i], types[i]
        for side in ("tail", "head"):
            if side == "head":  # extend the head by reversing, extending the tail, reversing back
                cur, cur_t = cur[::-1], cur_t[::-1]
            while True:
                j, flip = _best_continuation(cur, pts, heads, tails, alive, gap_px, cos_max)
                if j is None:
                    break
                alive[j] = False
                nxt, nxt_t = (pts[j][::-1], types[j][::-1]) if flip else (pts[j], types[j])
                if np.linalg.norm(nxt[0] - cur[-1]) < 1e-6:
                    nxt, nxt_t = nxt[1:], nxt_t[1:]
                cur = np.vstack([cur, nxt])
                cur_t = cur_t + nxt_t
            if side == "head":
                cur, cur_t = cur[::-1], cur_t[::-1]
        out.append((cur, cur_t))
    return out


def _best_continuation(
    cur: np.ndarray,
    pts: list[np.ndarray],
    heads: np.ndarray,
    tails: np.ndarray,
    alive: np.ndarray,
    gap_px: float,
    cos_max: float,
) -> tuple[int | None, bool]:
    """The live fragment whose head (flip False) or tail (flip True) continues ``cur``'s tail."""
    end = cur[-1]
    d = np.concatenate([np.linalg.norm(heads - end, axis=1), np.linalg.norm(tails - end, axis=1)])
    d[np.concatenate([~alive, ~alive])] = np.inf
    near = np.flatnonzero(d <= gap_px)
    if near.size == 0:
        return None, False
    out_dir = _direction(cur, at_end=True)
    n = len(pts)
    # nearest first; equal distances: heads before tails, then lower index (stable sort)
    for k in near[np.argsort(d[near], kind="stable")]:
        j, flip = int(k % n), bool(k >= n)
        in_dir = _direction(pts[j][::-1] if flip else pts[j], at_end=False)
        # out_dir points away from cur's tail; a smooth continuation's "out of its head"
        # direction points back toward cur
        if out_dir is None or in_dir is None or float(-in_dir @ out_dir) >= cos_max:
            return j, flip
    return None, False
