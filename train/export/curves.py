"""The curve structure of a patch collection, recovered from geometry alone.

Patch sides that coincide (up to direction) are one curve; a curve that runs along part of
another (a template junction curve: an exact sub-curve of its parent) is that parent's child.
Working from positions means exports need nothing but the patch array (template file or not).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from train.export.bicubic import bernstein3


@dataclasses.dataclass
class CurveGraph:
    curves: np.ndarray  # (C, 4, 3) distinct curves
    sides: np.ndarray  # (P, 4) curve index of each patch side
    flipped: np.ndarray  # (P, 4) side runs opposite to its curve
    children: dict[int, list[tuple[int, float, float]]]  # parent -> [(child, a, b)], child(0)=parent(a)
    lengths: np.ndarray  # (C,) arc lengths


def bezier_points(ctrl: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.einsum("...i,cik->c...k", bernstein3(u), ctrl) if ctrl.ndim == 3 else bernstein3(u) @ ctrl


def bezier_tangent(ctrl: np.ndarray, u: np.ndarray) -> np.ndarray:
    d = 3.0 * (ctrl[1:] - ctrl[:-1])
    u = np.asarray(u, dtype=np.float64)[..., None]
    return (1 - u) ** 2 * d[0] + 2 * u * (1 - u) * d[1] + u**2 * d[2]


def arc_lengths(curves: np.ndarray, samples: int = 64) -> np.ndarray:
    pts = bezier_points(curves, np.linspace(0, 1, samples + 1))
    return np.linalg.norm(np.diff(pts, axis=1), axis=-1).sum(-1)


def _project(ctrl: np.ndarray, p: np.ndarray, coarse: np.ndarray, coarse_pts: np.ndarray) -> tuple[float, float]:
    """Curve parameter of the point of ``ctrl`` nearest ``p`` and the distance (coarse + Newton)."""
    u = float(coarse[np.argmin(np.linalg.norm(coarse_pts - p, axis=-1))])
    for _ in range(8):
        d = bezier_tangent(ctrl, u)
        r = bezier_points(ctrl, np.array(u)) - p
        # Gauss-Newton on |c(u) - p|^2; the tangent-only step is enough this close to the answer
        step = float(r @ d) / max(float(d @ d), 1e-30)
        u = min(1.0, max(0.0, u - step))
    return u, float(np.linalg.norm(bezier_points(ctrl, np.array(u)) - p))


def curve_graph(patches: np.ndarray, rel_tol: float = 1e-5) -> CurveGraph:
    """Distinct curves, per-side curve ids and junction (parent/child) relations of ``(P,4,4,3)``."""
    patches = np.asarray(patches, dtype=np.float64)
    n = len(patches)
    sides = patches.reshape(n * 4, 4, 3)
    tol = rel_tol * max(1.0, float(np.abs(patches).max()))
    curves: list[np.ndarray] = []
    ids = np.zeros(n * 4, int)
    flipped = np.zeros(n * 4, bool)
    for k, c in enumerate(sides):
        for cid, d in enumerate(curves):
            if np.abs(c - d).max() < tol:
                ids[k] = cid
                break
            if np.abs(c[::-1] - d).max() < tol:
                ids[k], flipped[k] = cid, True
                break
        else:
            ids[k] = len(curves)
            curves.append(c)
    arr = np.stack(curves)
    return CurveGraph(arr, ids.reshape(n, 4), flipped.reshape(n, 4), _junctions(arr, tol), arc_lengths(arr))


def _junctions(curves: np.ndarray, tol: float) -> dict[int, list[tuple[int, float, float]]]:
    coarse = np.linspace(0, 1, 129)
    checks = np.array([0.25, 0.5, 0.75])
    contained: dict[int, list[tuple[int, float, float]]] = {}
    ends = curves[:, [0, 3]]  # (C, 2, 3)
    for a, parent in enumerate(curves):
        pts = bezier_points(parent, coarse)
        # the Newton projection is the slow part: run it only for curves whose two ends both come
        # within a sample spacing of this one (a point on the curve is that close to a sample)
        reach = tol + np.linalg.norm(np.diff(pts, axis=0), axis=-1).max()
        near = np.linalg.norm(ends[:, :, None] - pts[None, None], axis=-1).min(-1).max(-1) <= reach
        for b in np.nonzero(near)[0]:
            child = curves[b]
            if a == b:
                continue
            u0, d0 = _project(parent, child[0], coarse, pts)
            if d0 > tol:
                continue
            u1, d1 = _project(parent, child[3], coarse, pts)
            if d1 > tol or abs(u1 - u0) < 1e-9 or abs(u1 - u0) > 1 - 1e-9:
                continue
            # an exact sub-curve: child(u) = parent(u0 + (u1 - u0) u) at interior checks too
            inner = bezier_points(parent, u0 + (u1 - u0) * checks)
            if np.abs(bezier_points(child, checks) - inner).max() < tol:
                contained.setdefault(a, []).append((b, u0, u1))
    children: dict[int, list[tuple[int, float, float]]] = {}
    for a, items in contained.items():
        inside = {b for b, _, _ in items}
        # direct children only: drop curves that lie inside another curve contained in a
        direct = [it for it in items if not any(it[0] in {c for c, _, _ in contained.get(o, [])} for o in inside)]
        direct.sort(key=lambda it: min(it[1], it[2]))
        ends = [(min(u0, u1), max(u0, u1)) for _, u0, u1 in direct]
        covers = abs(ends[0][0]) < 1e-6 and abs(ends[-1][1] - 1) < 1e-6
        covers = covers and all(abs(ends[k][1] - ends[k + 1][0]) < 1e-6 for k in range(len(ends) - 1))
        if covers:
            children[a] = direct
        else:
            warnings.warn(f"curve {a}: sub-curves do not cover it; treated as a plain curve")
    return children
