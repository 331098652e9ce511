"""Vectorization quality: re-rasterize strokes thin and compare ink with a tolerance.

precision = share of predicted ink pixels within ``tol`` px of reference ink,
recall    = share of reference ink pixels within ``tol`` px of predicted ink,
F1 their harmonic mean (the usual edge/line-drawing benchmark measure, with distance transforms
instead of bipartite matching). Both sides are drawn 1 px thin so line width does not count.
"""

from __future__ import annotations

import cv2
import numpy as np

_SHIFT = 4  # cv2 sub-pixel bits


def rasterize_thin(strokes: list[np.ndarray], size: int | tuple[int, int]) -> np.ndarray:
    """Boolean (H, W) mask of the strokes drawn 1 px wide (pixel convention: centre at i + 0.5)."""
    h, w = (size, size) if isinstance(size, int) else size
    canvas = np.zeros((h, w), np.uint8)
    polys = [
        np.round((np.asarray(s, np.float64) - 0.5) * (1 << _SHIFT)).astype(np.int32) for s in strokes if len(s) >= 1
    ]
    polys = [p if len(p) > 1 else np.concatenate([p, p]) for p in polys]
    if polys:
        cv2.polylines(canvas, polys, False, 255, 1, cv2.LINE_8, _SHIFT)
    return canvas > 0


def ink_scores(pred: np.ndarray, ref: np.ndarray, tol: float = 2.0) -> dict:
    """precision / recall / F1 of two boolean ink masks with a pixel-distance tolerance."""
    return ink_scores_at(pred, ref, (tol,))[0]


def ink_scores_at(pred: np.ndarray, ref: np.ndarray, tols: tuple[float, ...]) -> list[dict]:
    """:func:`ink_scores` at each tolerance of ``tols``, from one pair of distance transforms."""
    if pred.shape != ref.shape:
        raise ValueError(f"mask shapes differ: {pred.shape} vs {ref.shape}")
    n_pred, n_ref = int(pred.sum()), int(ref.sum())
    if n_pred == 0 and n_ref == 0:
        return [{"precision": 1.0, "recall": 1.0, "f1": 1.0, "tol": tol} for tol in tols]
    if n_pred == 0 or n_ref == 0:
        return [{"precision": float(n_pred == 0), "recall": float(n_ref == 0), "f1": 0.0, "tol": tol} for tol in tols]
    to_ref = cv2.distanceTransform((~ref).astype(np.uint8), cv2.DIST_L2, 5)[pred]
    to_pred = cv2.distanceTransform((~pred).astype(np.uint8), cv2.DIST_L2, 5)[ref]
    out = []
    for tol in tols:
        precision = float((to_ref <= tol).mean())
        recall = float((to_pred <= tol).mean())
        f1 = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
        out.append({"precision": precision, "recall": recall, "f1": f1, "tol": tol})
    return out


def stroke_scores(pred: list[np.ndarray], ref: list[np.ndarray], size: int | tuple[int, int], tol: float = 2.0) -> dict:
    """Scores of vector strokes against reference vector strokes (e.g. Freestyle's), plus the
    stroke-count ratio pred / ref."""
    return stroke_scores_at(pred, ref, size, (tol,))[0]


def stroke_scores_at(
    pred: list[np.ndarray], ref: list[np.ndarray], size: int | tuple[int, int], tols: tuple[float, ...]
) -> list[dict]:
    """:func:`stroke_scores` at each tolerance of ``tols``, the strokes rasterized once."""
    count_ratio = len(pred) / len(ref) if ref else float("inf") if pred else 1.0
    scores = ink_scores_at(rasterize_thin(pred, size), rasterize_thin(ref, size), tols)
    return [{**sc, "n_pred": len(pred), "n_ref": len(ref), "count_ratio": count_ratio} for sc in scores]
