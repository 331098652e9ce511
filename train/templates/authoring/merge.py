"""Greedy agglomerative merging of lattice quads into large rectangular patches.

Quads are visited in order of descending area; each is merged with a coplanar neighbour of the
same part label when the union is a rectangle and the result keeps every junction well defined:

* along any lattice line, the distinct patch sides must nest — each side is either equal to the
  sides across, or contains all other sides overlapping it (it is their parent curve), or lies
  inside a single other side (it is a junction curve on that parent); with optional parts more
  than two patches can share a line (a part's side, the body's, a closing patch's), and the rule
  over distinct sides keeps every on/off combination nested;
* a patch corner may lie strictly inside at most one patch side (its single parent curve),
  otherwise it would be a junction point on two curves at once;
* the curves' dependencies (a curve whose end is a junction point depends on that point's
  parent curve) have no cycle, so every junction position can be evaluated.

With ``mirror`` the merges are done in mirror pairs across x = 0, so a symmetric quad mesh gives a
symmetric patch layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lattice import QuadMesh

LineKey = tuple[int, int, int, int]  # (axis, x, y, z) with the axis entry set to -1
Side = tuple[LineKey, int, int]  # a patch side: its line and its extent along the line


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle on lattice plane ``axis = k``, outward normal ``sign * e_axis``.

    ``b`` / ``c`` are the extents along axes (axis+1)%3 and (axis+2)%3, in lattice indices.
    """

    axis: int
    sign: int
    k: int
    b0: int
    b1: int
    c0: int
    c1: int
    label: int
    neg: int = -1  # optional label whose absence this patch needs (closing patch), -1 if none

    def corners(self) -> list[tuple[int, int, int]]:
        """Corners P00, P10, P11, P01 counter-clockwise seen from outside (Coons (s, t) order)."""
        a, b, c = self.axis, (self.axis + 1) % 3, (self.axis + 2) % 3
        uv = [(self.b0, self.c0), (self.b1, self.c0), (self.b1, self.c1), (self.b0, self.c1)]
        if self.sign < 0:  # reversed winding: s runs along c, t along b
            uv = [(self.b0, self.c0), (self.b0, self.c1), (self.b1, self.c1), (self.b1, self.c0)]
        out = []
        for ub, uc in uv:
            p = [0, 0, 0]
            p[a], p[b], p[c] = self.k, ub, uc
            out.append(tuple(p))
        return out

    def sides(self) -> list[tuple[LineKey, int, int]]:
        """The four sides as (line key, lo, hi) along the line's axis."""
        a, b, c = self.axis, (self.axis + 1) % 3, (self.axis + 2) % 3
        out = []
        for cc in (self.c0, self.c1):  # sides along b
            p = [0, 0, 0]
            p[a], p[b], p[c] = self.k, -1, cc
            out.append(((b, *p), self.b0, self.b1))
        for bb in (self.b0, self.b1):  # sides along c
            p = [0, 0, 0]
            p[a], p[b], p[c] = self.k, bb, -1
            out.append(((c, *p), self.c0, self.c1))
        return out


def _line_point(line: LineKey, t: int) -> tuple[int, int, int]:
    p = list(line[1:])
    p[line[0]] = t
    return tuple(p)  # type: ignore[return-value]


class PatchSet:
    """Rectangles with the indexes needed to test merges locally."""

    def __init__(self, rects: list[Rect], lines: tuple[np.ndarray, np.ndarray, np.ndarray]):
        self.lines = lines
        self.rects: dict[int, Rect] = {}
        self.by_rect: dict[Rect, int] = {}
        self.line_sides: dict[LineKey, dict[int, tuple[int, int]]] = {}
        self.side_index: dict[tuple[LineKey, int, int], set[int]] = {}
        self.corner_count: dict[tuple[int, int, int], int] = {}
        self._next = 0
        for r in rects:
            self.add(r)

    # -- bookkeeping --
    def add(self, r: Rect) -> int:
        pid = self._next
        self._next += 1
        self.rects[pid] = r
        self.by_rect[r] = pid
        for line, lo, hi in r.sides():
            self.line_sides.setdefault(line, {})[pid] = (lo, hi)
            self.side_index.setdefault((line, lo, hi), set()).add(pid)
        for p in r.corners():
            self.corner_count[p] = self.corner_count.get(p, 0) + 1
        return pid

    def remove(self, pid: int) -> Rect:
        r = self.rects.pop(pid)
        del self.by_rect[r]
        for line, lo, hi in r.sides():
            del self.line_sides[line][pid]
            self.side_index[(line, lo, hi)].discard(pid)
        for p in r.corners():
            self.corner_count[p] -= 1
        return r

    def area(self, r: Rect) -> float:
        b, c = (r.axis + 1) % 3, (r.axis + 2) % 3
        return float((self.lines[b][r.b1] - self.lines[b][r.b0]) * (self.lines[c][r.c1] - self.lines[c][r.c0]))

    # -- validity --
    def line_ok(self, line: LineKey) -> bool:
        spans = sorted(set(self.line_sides.get(line, {}).values()))
        for lo, hi in spans:
            across = [(l2, h2) for l2, h2 in spans if (l2, h2) != (lo, hi) and min(hi, h2) > max(lo, l2)]
            if all(lo <= l2 and h2 <= hi for l2, h2 in across):
                continue  # equal to, or parent of, everything across it
            if len(across) == 1 and across[0][0] <= lo and hi <= across[0][1]:
                continue  # a junction curve inside one parent
            return False
        return True

    def parent_lines(self, v: tuple[int, int, int]) -> int:
        """Number of lattice lines through ``v`` with a patch side strictly containing ``v``."""
        n = 0
        for d in range(3):
            key = list(v)
            key[d] = -1
            sides = self.line_sides.get((d, *key))
            if sides and any(lo < v[d] < hi for lo, hi in sides.values()):
                n += 1
        return n

    def host(self, v: tuple[int, int, int]) -> Side | None:
        """The longest side strictly containing corner ``v`` (its parent curve), if any."""
        best = None
        for d in range(3):
            key = list(v)
            key[d] = -1
            line = (d, *key)
            for lo, hi in self.line_sides.get(line, {}).values():
                if lo < v[d] < hi and (best is None or hi - lo > best[2] - best[1]):
                    best = (line, lo, hi)
        return best

    def deps(self, side: Side) -> list[Side]:
        """Curves that must be evaluated before ``side``: its parent if it is a sub-curve, else
        the parents of its end points that are junction points."""
        line, lo, hi = side
        for l2, h2 in self.line_sides.get(line, {}).values():
            if l2 <= lo and hi <= h2 and (l2, h2) != (lo, hi):
                return [(line, l2, h2)]
        out = []
        for t in (lo, hi):
            h = self.host(_line_point(line, t))
            if h is not None and h != side:
                out.append(h)
        return out

    def acyclic_from(self, starts: list[Side]) -> bool:
        """No dependency cycle (junction on a curve that depends on it) reachable from ``starts``."""
        state: dict[Side, int] = {}  # 1 = on the DFS stack, 2 = done
        for s0 in starts:
            if s0 in state:
                continue
            stack = [(s0, iter(self.deps(s0)))]
            state[s0] = 1
            while stack:
                node, it = stack[-1]
                nxt = next(it, None)
                if nxt is None:
                    state[node] = 2
                    stack.pop()
                elif state.get(nxt) == 1:
                    return False
                elif nxt not in state:
                    state[nxt] = 1
                    stack.append((nxt, iter(self.deps(nxt))))
        return True

    def local_ok(self, r: Rect) -> bool:
        starts: list[Side] = []
        for line, _, _ in r.sides():
            if not self.line_ok(line):
                return False
            for lo, hi in self.line_sides[line].values():
                starts.append((line, lo, hi))
                for t in (lo, hi):
                    v = _line_point(line, t)
                    if self.corner_count.get(v, 0) > 0 and self.parent_lines(v) > 1:
                        return False
        return self.acyclic_from(sorted(set(starts)))

    def valid(self) -> bool:
        """Global check (tests): lines nest, corners have ≤ 1 parent, no dependency cycles."""
        if not all(self.line_ok(line) for line in self.line_sides):
            return False
        if not all(self.parent_lines(v) <= 1 for v, n in self.corner_count.items() if n > 0):
            return False
        sides = sorted({(line, lo, hi) for line, d in self.line_sides.items() for lo, hi in d.values()})
        return self.acyclic_from(sides)


def union_rect(a: Rect, b: Rect) -> Rect | None:
    """The rectangle a ∪ b when a and b are coplanar, same label, and share a whole side."""
    if (a.axis, a.sign, a.k, a.label, a.neg) != (b.axis, b.sign, b.k, b.label, b.neg):
        return None
    if (a.b0, a.b1) == (b.b0, b.b1) and (a.c1 == b.c0 or b.c1 == a.c0):
        return Rect(a.axis, a.sign, a.k, a.b0, a.b1, min(a.c0, b.c0), max(a.c1, b.c1), a.label, a.neg)
    if (a.c0, a.c1) == (b.c0, b.c1) and (a.b1 == b.b0 or b.b1 == a.b0):
        return Rect(a.axis, a.sign, a.k, min(a.b0, b.b0), max(a.b1, b.b1), a.c0, a.c1, a.label, a.neg)
    return None


def mirror_rect(r: Rect, nx: int) -> Rect:
    """Mirror image across the lattice's symmetric x grid (x line i ↔ nx-1-i)."""
    if r.axis == 0:
        return Rect(0, -r.sign, nx - 1 - r.k, r.b0, r.b1, r.c0, r.c1, r.label, r.neg)
    if r.axis == 1:  # b = z, c = x
        return Rect(1, r.sign, r.k, r.b0, r.b1, nx - 1 - r.c1, nx - 1 - r.c0, r.label, r.neg)
    return Rect(2, r.sign, r.k, nx - 1 - r.b1, nx - 1 - r.b0, r.c0, r.c1, r.label, r.neg)  # b = x


def rects_from_quads(mesh: QuadMesh) -> list[Rect]:
    out = []
    neg = mesh.neg if mesh.neg is not None else np.full(len(mesh.quads), -1)
    for q, a, s, lab, n in zip(mesh.quads, mesh.axis, mesh.sign, mesh.label, neg):
        pts = mesh.vertices[q]
        b, c = (int(a) + 1) % 3, (int(a) + 2) % 3
        out.append(
            Rect(
                int(a),
                int(s),
                int(pts[0, a]),
                int(pts[:, b].min()),
                int(pts[:, b].max()),
                int(pts[:, c].min()),
                int(pts[:, c].max()),
                int(lab),
                int(n),
            )
        )
    return out


def merge_quads(mesh: QuadMesh, mirror: bool = False, max_passes: int = 1000) -> PatchSet:
    """Greedy merging by descending area; returns the merged, valid patch set."""
    ps = PatchSet(rects_from_quads(mesh), mesh.lattice.lines)
    nx = len(mesh.lattice.lines[0])
    for _ in range(max_passes):
        merged_any = False
        order = sorted(ps.rects.values(), key=lambda r: (-ps.area(r), _rect_key(r)))
        for rect in order:
            if rect not in ps.by_rect:  # already merged into another patch in this pass
                continue
            if _try_merge_patch(ps, rect, nx, mirror):
                merged_any = True
        if not merged_any:
            break
    return ps


def _rect_key(r: Rect) -> tuple:
    return (r.axis, r.sign, r.k, r.b0, r.b1, r.c0, r.c1, r.label, r.neg)


def _neighbours(ps: PatchSet, r: Rect) -> list[Rect]:
    """Coplanar same-label patches sharing a whole side with ``r``, largest first."""
    out = set()
    for side in r.sides():
        for q in ps.side_index.get(side, ()):
            other = ps.rects[q]
            if other != r and union_rect(r, other) is not None:
                out.add(other)
    return sorted(out, key=lambda o: (-ps.area(o), _rect_key(o)))


def _try_merge_patch(ps: PatchSet, a: Rect, nx: int, mirror: bool) -> bool:
    for b in _neighbours(ps, a):
        steps: list[Rect] = [a, b]  # merged left to right: ((a ∪ b) ∪ c) ...
        pairs: list[list[Rect]] = [steps]
        if mirror:
            ma, mb = mirror_rect(a, nx), mirror_rect(b, nx)
            if ma not in ps.by_rect or mb not in ps.by_rect:
                continue  # the layout is not symmetric here: leave it alone
            if {ma, mb} == {a, b}:
                pass  # the merged patch is its own mirror image
            elif ma == a:
                steps.append(mb)  # a straddles x = 0: grow it on both sides at once
            elif mb == b:
                steps.append(ma)
            elif {ma, mb} & {a, b}:
                continue
            else:
                pairs.append([ma, mb])
        if _apply(ps, pairs):
            return True
    return False


def _apply(ps: PatchSet, groups: list[list[Rect]]) -> bool:
    """Merge each group into one rectangle; keep it only if every new patch passes the checks."""
    done: list[tuple[list[Rect], Rect]] = []
    for group in groups:
        u: Rect | None = group[0]
        for r in group[1:]:
            u = union_rect(u, r) if u is not None else None
        if u is None:
            break
        for r in group:
            ps.remove(ps.by_rect[r])
        ps.add(u)
        done.append((group, u))
    ok = len(done) == len(groups) and all(ps.local_ok(u) for _, u in done)
    if not ok:
        for group, u in reversed(done):
            ps.remove(ps.by_rect[u])
            for r in group:
                ps.add(r)
    return ok
