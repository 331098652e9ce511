"""Exact conversion of a Coons patch with cubic boundaries to a bicubic Bézier control net.

The Coons patch is (ruled surface in t) + (ruled surface in s) − (bilinear corner surface).
Each term is polynomial of degree ≤ 3 in s and t; degree-elevating a linear direction to cubic
just places control points at 0, 1/3, 2/3, 1 along the line, so the sum of the three elevated nets
is the patch's bicubic net exactly (no fitting).
"""

from __future__ import annotations

import numpy as np

_W = np.arange(4) / 3.0  # the elevated linear direction's control-point parameters


def coons_to_bezier(patches: np.ndarray) -> np.ndarray:
    """(..., 4, 4, 3) Coons boundaries -> (..., 4, 4, 3) net ``N[i, j]`` (i along s, j along t)."""
    p = np.asarray(patches, dtype=np.float64)
    c1, c2, c3, c4 = p[..., 0, :, :], p[..., 1, :, :], p[..., 2, :, :], p[..., 3, :, :]
    i = _W[:, None, None]  # s weight, broadcasts over j
    j = _W[None, :, None]  # t weight
    # (1−t) c1(s) + t c3(1−s): c3 reversed so its k-th control point sits at s = k/3
    ruled_t = (1 - j) * c1[..., :, None, :] + j * c3[..., ::-1, :][..., :, None, :]
    # s c2(t) + (1−s) c4(1−t): c4 reversed along t
    ruled_s = i * c2[..., None, :, :] + (1 - i) * c4[..., ::-1, :][..., None, :, :]
    p00, p10, p01, p11 = c1[..., 0, :], c1[..., 3, :], c3[..., 3, :], c3[..., 0, :]
    e = lambda a: a[..., None, None, :]  # noqa: E731 - broadcast a corner over the net
    bilinear = (1 - i) * (1 - j) * e(p00) + i * (1 - j) * e(p10) + (1 - i) * j * e(p01) + i * j * e(p11)
    return ruled_t + ruled_s - bilinear


def bernstein3(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64)
    u = 1.0 - t
    return np.stack([u**3, 3 * t * u * u, 3 * t * t * u, t**3], axis=-1)


def eval_bezier_surface(net: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points of a bicubic net (4, 4, 3) at parameter arrays s, t (same shape) -> (..., 3)."""
    return np.einsum("...i,...j,ijk->...k", bernstein3(s), bernstein3(t), net)
