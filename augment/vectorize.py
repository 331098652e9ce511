"""Raster line drawing → centerline strokes.

Works on any black-on-white line drawing (our renders or a scan): ink mask (fixed level or Otsu)
→ thinning (scikit-image) → skeleton paths (``augment.skeleton_graph``) → junction clustering →
spur pruning → joining branches through junctions by tangent continuity → corner re-snapping
(all strokes touching a junction end exactly at one least-squares junction point) → smoothing +
Douglas–Peucker.

Strokes come back as float (K, 2) arrays of (u, v) in the pixel convention of the contract:
origin at the image's top-left corner, u right, v down, pixel i covering [i, i+1).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numba
import numpy as np
from skimage.morphology import skeletonize

from augment.fitting import cumulative_length, polyline_length, simplify, smooth
from augment.settings import VectorizeSettings
from augment.skeleton_graph import skeleton_paths


class VectorizeError(ValueError):
    """The image is not a line drawing that can be vectorized (e.g. all ink)."""


def to_gray(image: np.ndarray) -> np.ndarray:
    """uint8 grayscale from gray/RGB/RGBA (alpha composited on white) uint8 or float in [0, 1]."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(np.round(img.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 4:
        a = img[..., 3:4].astype(np.float32) / 255.0
        rgb = img[..., :3].astype(np.float32) * a + 255.0 * (1.0 - a)
        img = np.round(rgb).astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise VectorizeError(f"expected a 2D image, got shape {np.asarray(image).shape}")
    return img


def ink_mask(gray: np.ndarray, settings: VectorizeSettings) -> np.ndarray:
    """Boolean ink mask. Blank (uniform light) images give an empty mask; mostly-ink raises."""
    lo, hi = int(gray.min()), int(gray.max())
    if hi - lo < 32:  # no contrast: blank paper, or a uniformly dark image
        if gray.mean() < 128:
            raise VectorizeError("image is uniformly dark: no lines on a light background")
        return np.zeros(gray.shape, bool)
    if settings.ink_threshold is None:
        # cv2's THRESH_BINARY keeps pixels > level as paper, so ink is <= level.
        level, _ = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        mask = gray <= level
    else:
        mask = gray < settings.ink_threshold
    frac = float(mask.mean())
    if frac > settings.max_ink_fraction:
        raise VectorizeError(
            f"{100 * frac:.0f}% of pixels are ink (> {100 * settings.max_ink_fraction:.0f}%): not a line drawing"
        )
    return mask


def fill_small_holes(mask: np.ndarray, max_size: int) -> np.ndarray:
    """``mask`` with every 4-connected region of paper of at most ``max_size`` px made ink:
    ``skimage.morphology.remove_small_holes(mask, max_size=max_size)``, from one cv2 labelling
    (half its time)."""
    _, labels = cv2.connectedComponents((~mask).view(np.uint8), connectivity=4)
    small = np.bincount(labels.ravel()) <= max_size
    small[0] = False  # label 0 is the ink itself
    return mask | small[labels]


@dataclasses.dataclass
class _Branch:
    points: np.ndarray  # (n, 2) uv, ordered from start to end
    ends: list  # [start vertex, end vertex]; vertex = ("J", cluster) | ("T", node)
    length: float
    alive: bool = True


def vectorize(image: np.ndarray, settings: VectorizeSettings = VectorizeSettings()) -> list[np.ndarray]:
    """Centerline strokes of a line drawing. Blank image → []; mostly ink → VectorizeError."""
    gray = to_gray(image)
    mask = ink_mask(gray, settings)
    if not mask.any():
        return []
    if settings.hole_area > 0:  # doubled lines leave pin holes that thin into tiny loops
        mask = fill_small_holes(mask, settings.hole_area)
    skel = skeletonize(mask)
    if skel.sum() < 2:
        return []
    branches, centers, radii = _skeleton_branches(skel, settings)
    _prune_spurs(branches, settings)
    chains = _link_gaps(_chain(branches, centers, radii, settings), settings)
    strokes = []
    for pts, closed in chains:
        if polyline_length(pts) < settings.min_stroke_length:
            continue
        strokes.append(simplify(_smooth_keeping_corners(pts, closed, settings), settings.simplify_epsilon))
    return strokes


def _line_fit(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centroid, unit direction) of the least-squares line through ``points``."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    return c, vt[0]


def _intersect(l1, l2) -> np.ndarray | None:
    (p1, d1), (p2, d2) = l1, l2
    det = d1[0] * (-d2[1]) - d1[1] * (-d2[0])
    if abs(det) < 0.2:  # nearly parallel: no well-defined corner
        return None
    t = ((p2 - p1)[0] * (-d2[1]) - (p2 - p1)[1] * (-d2[0])) / det
    return p1 + t * d1


def _corners(pts: np.ndarray, reach: float, min_angle_deg: float) -> list[int]:
    """Indices of sharp turns of an open chain: turning angle over ±reach px above the limit,
    strongest first, at least ``reach`` apart, not within ``reach`` of the ends."""
    s = cumulative_length(pts)
    if len(pts) < 5 or s[-1] < 3 * reach:
        return []
    interp = lambda q: np.stack([np.interp(q, s, pts[:, 0]), np.interp(q, s, pts[:, 1])], 1)
    a = pts - interp(s - reach)
    b = interp(s + reach) - pts
    cos = np.sum(a * b, axis=1) / np.maximum(np.hypot(*a.T) * np.hypot(*b.T), 1e-9)
    angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    ok = (angle > min_angle_deg) & (s > reach) & (s < s[-1] - reach)
    picked: list[int] = []
    for i in sorted(np.flatnonzero(ok), key=lambda i: (-angle[i], i)):
        if all(abs(s[i] - s[j]) > reach for j in picked):
            picked.append(int(i))
    return sorted(picked)


def _smooth_keeping_corners(pts: np.ndarray, closed: bool, settings: VectorizeSettings) -> np.ndarray:
    """Smooth a pixel chain piecewise between its sharp corners, each corner re-snapped to the
    crossing of the lines fitted on either side (thinning cuts corners of thick lines)."""
    reach = settings.tangent_length / 2
    if closed:
        # Open the loop at its sharpest turn so that corner becomes the two (fixed) ends.
        ring = np.concatenate([pts, pts, pts])
        inner = _corners(ring, reach, settings.corner_angle_deg)
        inner = [i - len(pts) for i in inner if len(pts) <= i < 2 * len(pts)]
        if not inner:
            out = smooth(pts, settings.smooth_sigma, closed=True)
            return np.concatenate([out, out[:1]])
        start = inner[0]
        pts = np.concatenate([pts[start:], pts[:start], pts[start : start + 1]])
    corners = _corners(pts, reach, settings.corner_angle_deg)
    pts = pts.copy()
    s = cumulative_length(pts)
    fit_len = 3 * reach

    def side(lo: float, hi: float) -> np.ndarray | None:
        sel = pts[(s >= lo) & (s <= hi)]
        return sel if len(sel) >= 3 else None

    snapped = {}
    for i in corners:
        before, after = side(s[i] - fit_len, s[i] - reach / 2), side(s[i] + reach / 2, s[i] + fit_len)
        if before is not None and after is not None:
            x = _intersect(_line_fit(before), _line_fit(after))
            if x is not None and np.linalg.norm(x - pts[i]) <= settings.snap_radius:
                snapped[i] = x
    if closed:  # the corner at the seam: lines from the tail and the head
        tail, head = side(s[-1] - fit_len, s[-1] - reach / 2), side(reach / 2, fit_len)
        if tail is not None and head is not None:
            x = _intersect(_line_fit(tail), _line_fit(head))
            if x is not None and np.linalg.norm(x - pts[0]) <= settings.snap_radius:
                pts[0] = pts[-1] = x
    for i, x in snapped.items():
        pts[i] = x
    cuts = [0] + corners + [len(pts) - 1]
    pieces = [smooth(pts[a : b + 1], settings.smooth_sigma) for a, b in zip(cuts[:-1], cuts[1:])]
    return np.concatenate([pieces[0]] + [p[1:] for p in pieces[1:]])


def _skeleton_branches(skel: np.ndarray, settings: VectorizeSettings):
    """Skeleton paths as branches between tips (degree 1) and merged junction clusters."""
    sk = skeleton_paths(skel)
    uv = sk.coordinates[:, ::-1].astype(np.float64) + 0.5  # (row, col) → pixel-centre (u, v)
    deg = sk.degrees
    paths = [np.asarray(sk.path(i)) for i in range(sk.n_paths)]

    # Union-find over junction pixels: adjacent junction pixels and very short junction-junction
    # links are one junction (thinning leaves small clusters where lines cross).
    parent: dict[int, int] = {int(n): int(n) for n in np.flatnonzero(deg >= 3)}

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    lengths = [polyline_length(uv[p]) for p in paths]
    for p, length in zip(paths, lengths):
        s, e = int(p[0]), int(p[-1])
        if s != e and s in parent and e in parent and length <= settings.junction_merge:
            ra, rb = find(s), find(e)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    members: dict[int, list[int]] = {}
    for n in parent:
        members.setdefault(find(n), []).append(n)
    cluster_of = {n: cid for cid, root in enumerate(sorted(members)) for n in members[root]}
    centers = np.array([uv[members[root]].mean(axis=0) for root in sorted(members)]).reshape(-1, 2)
    radii = np.array(
        [np.linalg.norm(uv[members[root]] - uv[members[root]].mean(axis=0), axis=1).max() for root in sorted(members)]
    )

    branches = []
    for p, length in zip(paths, lengths):
        s, e = int(p[0]), int(p[-1])
        vs = ("J", cluster_of[s]) if s in cluster_of else ("T", s)
        ve = ("J", cluster_of[e]) if e in cluster_of else ("T", e)
        if vs[0] == "J" and vs == ve and length <= settings.junction_merge:
            continue  # internal link of a junction cluster
        if s == e and vs[0] == "T":  # an isolated closed loop: no ends
            vs = ve = ("L", s)
        branches.append(_Branch(uv[p], [vs, ve], length))
    return branches, centers, radii


def _incidence(branches: list[_Branch]) -> dict:
    count: dict = {}
    for b in branches:
        if b.alive:
            for v in b.ends:
                if v[0] == "J":
                    count[v] = count.get(v, 0) + 1
    return count


def _prune_spurs(branches: list[_Branch], settings: VectorizeSettings) -> None:
    """Remove short tip-to-junction branches (thinning artefacts), keeping junctions ≥ 2-way."""
    changed = True
    while changed:
        changed = False
        count = _incidence(branches)
        spurs = sorted(
            (b.length, i)
            for i, b in enumerate(branches)
            if b.alive and b.length < settings.spur_length and {v[0] for v in b.ends} == {"T", "J"}
        )
        for _, i in spurs:
            j = next(v for v in branches[i].ends if v[0] == "J")
            if count.get(j, 0) > 2:
                branches[i].alive = False
                count[j] -= 1
                changed = True


def _end_points(b: _Branch, end: int) -> np.ndarray:
    """Branch points ordered outward from the given end (0 = start, 1 = end)."""
    return b.points if end == 0 else b.points[::-1]


def _end_tangent(pts: np.ndarray, center: np.ndarray, radius: float, length: float):
    """(near point, unit direction) of a branch leaving a junction, skipping distorted pixels."""
    near = pts[: int(2 * (radius + length)) + 6]  # only the part near the junction matters
    first, d = _end_offset(
        np.ascontiguousarray(near, np.float64), float(center[0]), float(center[1]), float(radius), float(length)
    )
    n = np.linalg.norm(d)  # numpy's own 2-vector norm: the compiled loop would round it differently
    return first, (d / n if n > 1e-9 else np.zeros(2))


@numba.njit(cache=True, nogil=True)
def _end_offset(pts, cx, cy, radius, length):
    """The first point of ``pts`` past ``radius`` + 1.5 of the centre (or the first point), and the
    offset from it to the point ``length`` further along (thousands of calls per model)."""
    m = pts.shape[0]
    start = 0
    for i in range(m):
        dx, dy = pts[i, 0] - cx, pts[i, 1] - cy
        if np.sqrt(dx * dx + dy * dy) > radius + 1.5:
            start = i
            break
    count = m - start
    if count <= 1:
        return pts[start].copy(), pts[m - 1] - pts[0]
    s = np.zeros(count)
    for i in range(1, count):
        s[i] = s[i - 1] + math.hypot(
            pts[start + i, 0] - pts[start + i - 1, 0], pts[start + i, 1] - pts[start + i - 1, 1]
        )
    k = np.searchsorted(s, min(length, s[-1]))
    k = min(max(k, 1), count - 1)
    return pts[start].copy(), pts[start + k] - pts[start]


def _chain(
    branches: list[_Branch], centers: np.ndarray, radii: np.ndarray, settings: VectorizeSettings
) -> list[tuple[np.ndarray, bool]]:
    """Pair branch ends at each junction by tangent continuity and walk the pairs into strokes."""
    alive = [i for i, b in enumerate(branches) if b.alive]
    at_junction: dict[int, list[tuple[int, int]]] = {}
    for i in alive:
        for end, v in enumerate(branches[i].ends):
            if v[0] == "J":
                at_junction.setdefault(v[1], []).append((i, end))

    partner: dict[tuple[int, int], tuple[int, int]] = {}
    snap: dict[int, np.ndarray] = {}
    cos_join = np.cos(np.radians(settings.join_angle_deg))
    for c, ends in sorted(at_junction.items()):
        center, radius = centers[c], radii[c]
        tang = [_end_tangent(_end_points(branches[i], e), center, radius, settings.tangent_length) for i, e in ends]
        snap[c] = _snap_point(center, tang, settings.snap_radius)
        if len(ends) == 2:
            partner[ends[0]], partner[ends[1]] = ends[1], ends[0]
            continue
        pairs = sorted(
            (float(np.dot(tang[a][1], tang[b][1])), a, b) for a in range(len(ends)) for b in range(a + 1, len(ends))
        )
        used: set[int] = set()
        for cos_ab, a, b in pairs:
            if cos_ab > -cos_join:
                break
            if a in used or b in used:
                continue
            used |= {a, b}
            partner[ends[a]], partner[ends[b]] = ends[b], ends[a]

    def oriented(i: int, from_end: int) -> np.ndarray:
        """Branch i walked from ``from_end``, junction-distorted pixels replaced by the snap point."""
        b = branches[i]
        pts = _end_points(b, from_end)
        first, last = b.ends[from_end], b.ends[1 - from_end]
        lo, hi = 0, len(pts)
        if first[0] == "J":
            c = first[1]
            d = np.linalg.norm(pts - centers[c], axis=1)
            while lo < hi - 1 and d[lo] <= radii[c] + 1.5:
                lo += 1
        if last[0] == "J":
            c = last[1]
            d = np.linalg.norm(pts - centers[c], axis=1)
            while hi > lo + 1 and d[hi - 1] <= radii[c] + 1.5:
                hi -= 1
        body = [pts[lo:hi]]
        if first[0] == "J":
            body.insert(0, snap[first[1]][None])
        if last[0] == "J":
            body.append(snap[last[1]][None])
        return np.concatenate(body)

    visited: set[int] = set()
    chains: list[tuple[np.ndarray, bool]] = []

    def walk(i: int, from_end: int) -> tuple[np.ndarray, bool]:
        parts, closed = [], False
        start = (i, from_end)
        while True:
            visited.add(i)
            seg = oriented(i, from_end)
            same = bool(parts) and float(np.abs(seg[0] - parts[-1][-1]).max()) < 1e-9
            parts.append(seg[1:] if same else seg)
            nxt = partner.get((i, 1 - from_end))
            if nxt is None:
                break
            if nxt == start:
                closed = True
                break
            if nxt[0] in visited:
                break
            i, from_end = nxt
        pts = np.concatenate(parts)
        if closed and len(pts) > 1 and np.allclose(pts[0], pts[-1]):
            pts = pts[:-1]
        return pts, closed

    # Open strokes start at free ends (tips or unpaired junction ends), in a fixed order.
    for i in alive:
        for end in (0, 1):
            if i not in visited and branches[i].ends[end][0] != "L" and (i, end) not in partner:
                chains.append(walk(i, end))
    # What is left are closed loops.
    for i in alive:
        if i not in visited:
            pts, closed = walk(i, 0)
            if branches[i].ends[0][0] == "L":
                pts, closed = pts[:-1], True
            chains.append((pts, closed))
    return chains


def _link_gaps(chains: list[tuple[np.ndarray, bool]], settings: VectorizeSettings) -> list[tuple[np.ndarray, bool]]:
    """Join open strokes whose ends face each other across a small gap (broken render lines).

    Greedy, shortest gap first; a stroke whose two ends meet is closed into a loop.
    """
    cos_link = np.cos(np.radians(settings.link_angle_deg))
    strokes: dict[int, list] = {}  # id → [points, closed, (end0 point, dir), (end1 point, dir)]

    def add(k: int, pts: np.ndarray, closed: bool) -> None:
        info = [pts, closed]
        for end in (0, 1):
            seq = pts if end == 0 else pts[::-1]
            _, d = _end_tangent(seq, seq[0], -1.5, settings.tangent_length)
            info.append((seq[0], -d))  # end point, outward direction
        strokes[k] = info

    for k, (pts, closed) in enumerate(chains):
        add(k, np.asarray(pts), closed)
    next_id = len(chains)
    while True:
        ends = [(k, e) for k in sorted(strokes) if not strokes[k][1] and len(strokes[k][0]) >= 2 for e in (0, 1)]
        if len(ends) < 2:
            break
        pos = np.array([strokes[k][2 + e][0] for k, e in ends])
        gap = pos[None, :, :] - pos[:, None, :]
        dist = np.hypot(gap[..., 0], gap[..., 1])
        cand = np.argwhere(np.triu(dist <= settings.link_gap, k=1))
        best = None
        for a, b in sorted(cand.tolist(), key=lambda ab: (dist[ab[0], ab[1]], ab[0], ab[1])):
            (ka, ea), (kb, eb) = ends[a], ends[b]
            if ka == kb and len(strokes[ka][0]) < 8:
                continue
            da, db, d = strokes[ka][2 + ea][1], strokes[kb][2 + eb][1], dist[a, b]
            if d > 1e-9:
                g = gap[a, b] / d
                ok = np.dot(da, g) > cos_link and np.dot(db, -g) > cos_link
            else:
                ok = np.dot(da, db) < 0
            if ok:
                best = (ka, ea, kb, eb)
                break
        if best is None:
            break
        ka, ea, kb, eb = best
        if ka == kb:
            strokes[ka][1] = True
            continue
        pa, pb = strokes.pop(ka)[0], strokes.pop(kb)[0]
        first = pa[::-1] if ea == 0 else pa  # ... ends at the linked end
        second = pb if eb == 0 else pb[::-1]  # starts at the linked end
        add(next_id, np.concatenate([first, second]), False)
        next_id += 1
    return [(strokes[k][0], strokes[k][1]) for k in sorted(strokes)]


def _snap_point(center: np.ndarray, tang: list, radius: float) -> np.ndarray:
    """Least-squares intersection of the branches' tangent lines, if it lies near the junction.

    Thinning pulls corners and T-junctions off their true position; the tangent lines of the
    branches, measured away from the junction, still cross where the lines really meet.
    """
    a = np.zeros((2, 2))
    b = np.zeros(2)
    for p, d in tang:
        proj = np.eye(2) - np.outer(d, d)
        a += proj
        b += proj @ p
    lam = 0.05 * max(len(tang), 1)  # weak pull to the centre keeps parallel lines well-posed
    j = np.linalg.solve(a + lam * np.eye(2), b + lam * center)
    return j if np.linalg.norm(j - center) <= radius else center.copy()
