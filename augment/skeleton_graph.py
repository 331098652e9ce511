"""The paths of a one-pixel-wide skeleton: pixel runs between tips and junctions, and closed loops.

The vectorizer used ``skan.Skeleton`` for this; building its sparse-matrix graph cost a quarter
of a view's vectorization. This module computes the same answer directly on the pixel grid
(compiled), and gives the same nodes, degrees and paths in the same order as skan 0.13, so the
strokes drawn from them do not change (``tests/test_skeleton_graph.py`` compares the two):

- nodes are the skeleton pixels in raster order, neighbours are the 8-connected ones;
- where junction pixels (3 or more neighbours) touch, only a minimum spanning tree of the
  links between them is kept (scipy's, on the same matrix skan builds, so ties break alike);
- paths are walked from every tip and junction along every unvisited link, then what is left
  (closed loops) from its lowest pixel, with skan's own path buffer arithmetic.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

_SQRT2 = float(np.sqrt(2.0))


@dataclasses.dataclass(frozen=True)
class SkeletonPaths:
    coordinates: np.ndarray  # (N, 2) int (row, col) of every skeleton pixel, raster order
    degrees: np.ndarray  # (N,) neighbours kept per pixel
    indptr: np.ndarray  # path i is indices[indptr[i]:indptr[i + 1]]
    indices: np.ndarray

    @property
    def n_paths(self) -> int:
        return len(self.indptr) - 1

    def path(self, i: int) -> np.ndarray:
        return self.indices[self.indptr[i] : self.indptr[i + 1]]


@numba.njit(cache=True, nogil=True)
def _pixel_links(labels: np.ndarray, rows: np.ndarray, cols: np.ndarray):
    """8-neighbour links of every pixel, each row in ascending node order (= raster order)."""
    n = rows.size
    indptr = np.zeros(n + 1, np.int64)
    indices = np.empty(8 * n, np.int64)
    diagonal = np.empty(8 * n, np.bool_)
    k = 0
    for i in range(n):
        r, c = rows[i] + 1, cols[i] + 1  # labels is padded by one
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                if dr == 0 and dc == 0:
                    continue
                j = labels[r + dr, c + dc]
                if j >= 0:
                    indices[k] = j
                    diagonal[k] = dr != 0 and dc != 0
                    k += 1
        indptr[i + 1] = k
    return indptr, indices[:k], diagonal[:k]


@numba.njit(cache=True, nogil=True)
def _link_position(indptr: np.ndarray, indices: np.ndarray, a: int, b: int) -> int:
    """Where the link a→b sits in ``indices`` (links are symmetric, so it is always found)."""
    k = indptr[a]
    while indices[k] != b:
        k += 1
    return k


@numba.njit(cache=True, nogil=True)
def _walk(indptr, indices, visited, degrees, node, neighbor, buf, start_j):
    buf[start_j] = node
    start_node = node
    j = start_j + 1
    k = _link_position(indptr, indices, node, neighbor)
    while not visited[k]:
        visited[k] = True
        visited[_link_position(indptr, indices, neighbor, node)] = True
        buf[j] = neighbor
        if degrees[neighbor] != 2 or neighbor == start_node:
            break
        n1, n2 = indices[indptr[neighbor]], indices[indptr[neighbor] + 1]
        nxt = n1 if n1 != node else n2
        node, neighbor = neighbor, nxt
        k = _link_position(indptr, indices, node, neighbor)
        j += 1
    return j - start_j + 1  # skan's count, kept so that the paths are the same


@numba.njit(cache=True, nogil=True)
def _walk_all(indptr: np.ndarray, indices: np.ndarray, degrees: np.ndarray, buf_size: int, max_paths: int):
    n = indptr.size - 1
    visited = np.zeros(indices.size, np.bool_)
    buf = np.zeros(buf_size, np.int64)
    path_ptr = np.zeros(max_paths + 1, np.int64)
    p = 0
    j = 0
    for node in range(n):  # from tips and junctions
        if degrees[node] > 2 or degrees[node] == 1:
            for k in range(indptr[node], indptr[node + 1]):
                if not visited[k]:
                    steps = _walk(indptr, indices, visited, degrees, node, indices[k], buf, j)
                    path_ptr[p + 1] = path_ptr[p] + steps
                    p += 1
                    j += steps
    for node in range(n):  # the rest are isolated loops
        if degrees[node] > 0:
            k = indptr[node]
            if not visited[k]:
                steps = _walk(indptr, indices, visited, degrees, node, indices[k], buf, j)
                path_ptr[p + 1] = path_ptr[p] + steps
                p += 1
                j += steps
    return path_ptr[: p + 1], buf[:j]


def _drop_junction_cycles(
    n: int, indptr: np.ndarray, indices: np.ndarray, diagonal: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Keep a minimum spanning tree of the links between junction pixels (skan's rule)."""
    degrees = np.diff(indptr)
    src = np.repeat(np.arange(n), degrees)
    junction = degrees >= 3
    between = junction[src] & junction[indices]
    if not between.any():
        return indptr, indices
    weights = np.where(diagonal[between], _SQRT2, 1.0)
    jgraph = sparse.csr_matrix((weights, (src[between], indices[between])), shape=(n, n))
    tree = csgraph.minimum_spanning_tree(jgraph)
    tree = (tree + tree.T).tocsr()
    in_tree = np.asarray(tree[src[between], indices[between]]).ravel() != 0
    keep = np.ones(indices.size, bool)
    keep[np.flatnonzero(between)[~in_tree]] = False
    kept_degrees = np.bincount(src[keep], minlength=n)
    return np.concatenate([[0], np.cumsum(kept_degrees)]).astype(np.int64), indices[keep]


def skeleton_paths(skel: np.ndarray) -> SkeletonPaths:
    """Nodes, degrees and paths of a 2-D boolean skeleton image."""
    skel = np.asarray(skel, bool)
    rows, cols = np.nonzero(skel)
    n = rows.size
    labels = np.full((skel.shape[0] + 2, skel.shape[1] + 2), -1, np.int64)
    labels[rows + 1, cols + 1] = np.arange(n)
    indptr, indices, diagonal = _pixel_links(labels, rows.astype(np.int64), cols.astype(np.int64))
    indptr, indices = _drop_junction_cycles(n, indptr, indices, diagonal)
    degrees = np.diff(indptr)
    # skan's buffer sizes: every link once per direction plus the junctions' extra starts, plus
    # room for the loops (at most a quarter of the links).
    extra = indices.size // 4
    ends = degrees[degrees != 2]
    buf_size = indices.size + int(np.maximum(0, ends - 1).sum()) + extra
    path_ptr, buf = _walk_all(indptr, indices, degrees, buf_size, int(ends.sum()) + extra)
    return SkeletonPaths(np.stack([rows, cols], axis=1), degrees, path_ptr, buf)
