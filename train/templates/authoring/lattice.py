"""Cuboids → manifold quad mesh on a non-uniform integer lattice (Smirnov et al. 2021, §3).

The cuboids' bounds are snapped to a lattice whose grid lines per axis are the distinct
(clustered) cuboid coordinates, so every cuboid, however thin, keeps at least one cell. The
union is voxelized on that grid (a cell is occupied when its centre lies in some cuboid), and
the faces between occupied and empty cells form a quad mesh with no overlapping and no interior
faces. Cells touching only along an edge or at a corner would make that mesh non-manifold; such
configurations are removed by filling the smallest empty cell of the offending block (a local
one-cell dilation) until none is left.

Optional parts (airplane engines, a knife's guard): a cell covered by a required cuboid belongs
to it; a cell covered only by optional cuboids belongs to one optional part and exists only when
that part is on. ``boundary_quads`` then returns every face that is on the surface for *some*
on/off combination, each with its condition: the owning cell's part must be on (when optional),
and the part across the face (``neg``) must be off. Faces with ``neg >= 0`` are the closing
faces: they seal the body where the part was attached. Every combination is a closed manifold
(the repair runs on each combination's occupancy).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, Sequence

import numpy as np


class CuboidLike(Protocol):
    label: str
    lo: np.ndarray
    hi: np.ndarray


@dataclass(frozen=True)
class Box:
    """An axis-aligned box with a semantic label (a plain stand-in for pipeline.shapes.Cuboid)."""

    label: str
    lo: np.ndarray
    hi: np.ndarray


@dataclass
class Lattice:
    """Occupancy of a union of cuboids on a non-uniform grid.

    ``lines[a]`` are the grid-line coordinates along axis ``a`` (cell i spans lines[a][i..i+1]);
    ``owner`` holds, per cell, the index into ``labels`` of the cuboid that claims it, -1 if empty.
    """

    lines: tuple[np.ndarray, np.ndarray, np.ndarray]
    owner: np.ndarray
    labels: list[str]
    filled: int = 0  # cells added to remove non-manifold configurations
    meta: dict = field(default_factory=dict)
    optional: tuple[str, ...] = ()  # labels whose cells exist only when that part is on

    @property
    def occupied(self) -> np.ndarray:
        return self.owner >= 0

    @property
    def optional_ids(self) -> list[int]:
        return [i for i, lab in enumerate(self.labels) if lab in self.optional]

    def combinations(self) -> list[frozenset[int]]:
        """Every on-set of optional label ids (all 2^k on/off combinations, all-on first)."""
        ids = self.optional_ids
        return [frozenset(i for b, i in enumerate(ids) if not (m >> b) & 1) for m in range(2 ** len(ids))]

    def occupied_with(self, on: frozenset[int]) -> np.ndarray:
        """Cells present when exactly the optional labels in ``on`` are switched on."""
        opt = np.zeros(len(self.labels) + 1, bool)  # last entry: empty cells (owner -1)
        opt[self.optional_ids] = True
        present = ~opt
        present[-1] = False
        present[list(on)] = True
        return present[self.owner]


@dataclass
class QuadMesh:
    """Boundary quads of a lattice, in lattice (integer) coordinates.

    ``quads`` (F, 4) index ``vertices`` (V, 3) int64 lattice points, counter-clockwise seen from
    outside; ``axis``/``sign`` give each quad's outward normal (sign * e_axis); ``label`` is the
    index of the owning cuboid label; ``neg`` the optional label across the face (the face exists
    only while that part is off), -1 for a face against empty space.
    """

    vertices: np.ndarray
    quads: np.ndarray
    axis: np.ndarray
    sign: np.ndarray
    label: np.ndarray
    lattice: Lattice
    neg: np.ndarray | None = None

    def active(self, on: frozenset[int]) -> np.ndarray:
        """Mask of the quads on the surface when exactly the optional labels ``on`` are on."""
        opt = set(self.lattice.optional_ids)
        neg = self.neg if self.neg is not None else np.full(len(self.quads), -1)
        return np.array(
            [(lab not in opt or lab in on) and (n < 0 or n not in on) for lab, n in zip(self.label, neg)], bool
        )

    def positions(self) -> np.ndarray:
        """World coordinates of the lattice vertices."""
        return lattice_to_world(self.lattice, self.vertices)


def lattice_to_world(lattice: Lattice, points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points)
    return np.stack([lattice.lines[a][pts[..., a]] for a in range(3)], axis=-1).astype(np.float64)


def snap_lines(values: np.ndarray, tol: float) -> np.ndarray:
    """Cluster sorted coordinates into groups spanning at most ``tol``; one line (the mean) each."""
    v = np.sort(np.asarray(values, np.float64))
    if len(v) == 0:
        return v
    groups: list[list[float]] = [[v[0]]]
    for x in v[1:]:
        if x - groups[-1][0] <= tol:
            groups[-1].append(x)
        else:
            groups.append([x])
    return np.array([float(np.mean(g)) for g in groups])


def mirrored_boxes(boxes: Sequence[CuboidLike]) -> list[Box]:
    """The boxes plus their mirror images across x = 0 (exact bilateral symmetry of the union)."""
    out = [Box(b.label, np.asarray(b.lo, float), np.asarray(b.hi, float)) for b in boxes]
    for b in list(out):
        lo, hi = b.lo.copy(), b.hi.copy()
        lo[0], hi[0] = -b.hi[0], -b.lo[0]
        out.append(Box(b.label, lo, hi))
    return out


def build_lattice(
    boxes: Sequence[CuboidLike], tol: float, symmetric_x: bool = False, optional: Sequence[str] = ()
) -> Lattice:
    """Snap ``boxes`` to a lattice (grid-line clustering with tolerance ``tol``) and voxelize.

    With ``symmetric_x`` the x grid lines are made exactly mirror-symmetric about x = 0, so a
    mirror-symmetric union gives a mirror-symmetric occupancy. Boxes labelled with one of
    ``optional`` never claim a cell that a required box covers.
    """
    if not boxes:
        raise ValueError("no cuboids")
    lo = np.array([np.asarray(b.lo, float) for b in boxes])
    hi = np.array([np.asarray(b.hi, float) for b in boxes])
    if np.any(hi - lo <= 0):
        raise ValueError("a cuboid has non-positive extent")
    lines = []
    for a in range(3):
        vals = np.concatenate([lo[:, a], hi[:, a]])
        if a == 0 and symmetric_x:
            vals = np.concatenate([vals, -vals])
        ln = snap_lines(vals, tol)
        if a == 0 and symmetric_x:
            ln = 0.5 * (ln - ln[::-1])  # exact symmetry despite float noise
        if len(ln) < 2:
            raise ValueError(f"snap tolerance {tol} merges every grid line along axis {a}")
        lines.append(ln)
    # Each cuboid bound → index of its nearest line; thin cuboids still span ≥ 1 cell.
    idx_lo = np.stack([np.abs(lines[a][None, :] - lo[:, a, None]).argmin(1) for a in range(3)], 1)
    idx_hi = np.stack([np.abs(lines[a][None, :] - hi[:, a, None]).argmin(1) for a in range(3)], 1)
    # a box snapped onto the last line keeps the cell below it instead of vanishing
    last = np.array([len(ln) - 1 for ln in lines])
    idx_hi = np.minimum(np.maximum(idx_hi, idx_lo + 1), last)
    idx_lo = np.minimum(idx_lo, idx_hi - 1)
    shape = tuple(len(ln) - 1 for ln in lines)
    owner = np.full(shape, -1, np.int64)
    # Smaller cuboids claim shared cells, so thin parts (turbines, handles) keep their own label;
    # required cuboids are painted last, so removing an optional part never cuts into the body.
    vol = np.prod(hi - lo, axis=1)
    labels: list[str] = []
    label_index: dict[str, int] = {}
    optional = tuple(optional)
    for i in sorted(range(len(boxes)), key=lambda j: (boxes[j].label not in optional, -vol[j], j)):
        lab = boxes[i].label
        if lab not in label_index:
            label_index[lab] = len(labels)
            labels.append(lab)
        sl = tuple(slice(idx_lo[i, a], idx_hi[i, a]) for a in range(3))
        owner[sl] = label_index[lab]
    lat = Lattice(tuple(lines), owner, labels, optional=tuple(lab for lab in optional if lab in label_index))  # type: ignore[arg-type]
    _repair_nonmanifold(lat)
    return lat


# --- non-manifold repair --------------------------------------------------------------------


def _block_is_manifold(bits: int) -> bool:
    """Is the boundary of a 2x2x2 occupancy block (bit i = cell (i&1, i>>1&1, i>>2&1)) a disk?

    On the sphere of directions around the shared vertex the octants form a cell complex; the
    boundary between occupied and empty octants is one simple loop iff both sets are non-empty
    and face-connected, or the vertex is not on the surface at all (all or none occupied).
    """
    occ = [(bits >> i) & 1 for i in range(8)]
    if all(occ) or not any(occ):
        return True

    def connected(value: int) -> bool:
        cells = [i for i in range(8) if occ[i] == value]
        seen, stack = {cells[0]}, [cells[0]]
        while stack:
            c = stack.pop()
            for a in range(3):
                n = c ^ (1 << a)
                if occ[n] == value and n not in seen:
                    seen.add(n)
                    stack.append(n)
        return len(seen) == len(cells)

    return connected(1) and connected(0)


_MANIFOLD_TABLE = np.array([_block_is_manifold(b) for b in range(256)])


def _bad_vertices(occ: np.ndarray) -> np.ndarray:
    """(K, 3) lattice vertices whose 2x2x2 cell block is non-manifold (covers bad edges too)."""
    p = np.pad(occ, 1).astype(np.int64)
    code = np.zeros(tuple(s - 1 for s in p.shape), np.int64)
    for i in range(8):
        dx, dy, dz = i & 1, (i >> 1) & 1, (i >> 2) & 1
        code |= p[dx : dx + code.shape[0], dy : dy + code.shape[1], dz : dz + code.shape[2]] << i
    return np.argwhere(~_MANIFOLD_TABLE[code])


def _repair_nonmanifold(lat: Lattice) -> None:
    """Fill the smallest empty cell of each non-manifold vertex block until none remains, for
    every on/off combination of optional parts (a filled cell takes a neighbour's label, a
    required one when there is one, so it stays filled in the other combinations)."""
    widths = [np.diff(ln) for ln in lat.lines]
    shape = lat.owner.shape
    combos = lat.combinations()
    for _ in range(10_000):
        for on in combos:
            occ = lat.occupied_with(on)
            bad = _bad_vertices(occ)
            if len(bad):
                break
        else:
            return
        v = bad[0]
        best = None
        for i in range(8):
            c = np.array([v[0] - 1 + (i & 1), v[1] - 1 + ((i >> 1) & 1), v[2] - 1 + ((i >> 2) & 1)])
            if np.any(c < 0) or np.any(c >= np.array(shape)) or occ[tuple(c)]:
                continue
            vol = widths[0][c[0]] * widths[1][c[1]] * widths[2][c[2]]
            key = (vol, tuple(c))
            if best is None or key < best[0]:
                best = (key, c)
        if best is None:  # only out-of-grid cells are empty: cannot happen with a padded border
            raise RuntimeError(f"cannot repair non-manifold vertex {v.tolist()}")
        c = best[1]
        lat.owner[tuple(c)] = _neighbour_label(lat.owner, c, occ, set(lat.optional_ids))
        lat.filled += 1
    raise RuntimeError("non-manifold repair did not converge")


def _neighbour_label(owner: np.ndarray, c: np.ndarray, occ: np.ndarray, optional: set[int] = frozenset()) -> int:
    """Label for a filled cell: the most common among its occupied face neighbours (lowest wins),
    required labels before optional ones."""
    labs = []
    for a in range(3):
        for d in (-1, 1):
            n = c.copy()
            n[a] += d
            if 0 <= n[a] < owner.shape[a] and occ[tuple(n)]:
                labs.append(int(owner[tuple(n)]))
    if not labs:
        return 0
    required = [lab for lab in labs if lab not in optional]
    vals, counts = np.unique(required or labs, return_counts=True)
    return int(vals[np.argmax(counts)])


# --- boundary quads -------------------------------------------------------------------------


def boundary_quads(lat: Lattice) -> QuadMesh:
    """Faces between occupied and empty cells, oriented outward, with shared lattice vertices.

    With optional labels: every face that is on the surface in some on/off combination, i.e.
    also faces between a cell and an optional part's cell of another label (closing faces).
    """
    own = np.pad(lat.owner, 1, constant_values=-1)
    p = own >= 0
    opt_ids = lat.optional_ids
    is_opt = np.isin(own, opt_ids) if opt_ids else np.zeros_like(p)
    # a cell "can vanish" when it is empty or optional; a face exists when its cell is there and
    # the cell across can vanish (not the same optional part)
    can_vanish = ~p | is_opt
    quads_pts: list[np.ndarray] = []
    axes, signs, labs, negs = [], [], [], []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        lo_sl = [slice(1, -1)] * 3
        hi_sl = [slice(1, -1)] * 3
        lo_sl[a] = slice(0, -1)
        hi_sl[a] = slice(1, None)
        below, above = p[tuple(lo_sl)], p[tuple(hi_sl)]
        own_below, own_above = own[tuple(lo_sl)], own[tuple(hi_sl)]
        gone_below, gone_above = can_vanish[tuple(lo_sl)], can_vanish[tuple(hi_sl)]
        differ = own_below != own_above
        for sign, mask, owner, across in (
            (1, below & gone_above & differ, own_below, np.where(above, own_above, -1)),
            (-1, above & gone_below & differ, own_above, np.where(below, own_below, -1)),
        ):
            idx = np.argwhere(mask)  # idx[:, a] is the plane index (0..n_lines[a]-1)
            if len(idx) == 0:
                continue
            base = idx.copy()
            corners = np.zeros((len(idx), 4, 3), np.int64)
            offs = [(0, 0), (1, 0), (1, 1), (0, 1)]  # CCW around +e_a in the (b, c) plane
            if sign < 0:
                offs = offs[::-1]
            for k, (db, dc) in enumerate(offs):
                q = base.copy()
                q[:, b] += db
                q[:, c] += dc
                corners[:, k] = q
            quads_pts.append(corners)
            axes.append(np.full(len(idx), a))
            signs.append(np.full(len(idx), sign))
            labs.append(owner[tuple(idx.T)])
            negs.append(across[tuple(idx.T)])
    allq = np.concatenate(quads_pts)
    verts, inv = np.unique(allq.reshape(-1, 3), axis=0, return_inverse=True)
    return QuadMesh(
        vertices=verts.astype(np.int64),
        quads=inv.reshape(-1, 4).astype(np.int64),
        axis=np.concatenate(axes).astype(np.int64),
        sign=np.concatenate(signs).astype(np.int64),
        label=np.concatenate(labs).astype(np.int64),
        lattice=lat,
        neg=np.concatenate(negs).astype(np.int64),
    )


def edge_use_counts(quads: np.ndarray) -> dict[tuple[int, int], int]:
    """How many quads use each undirected edge (2 everywhere on a closed manifold)."""
    counts: dict[tuple[int, int], int] = {}
    for q in quads:
        for k in range(4):
            a, b = int(q[k]), int(q[(k + 1) % 4])
            key = (a, b) if a < b else (b, a)
            counts[key] = counts.get(key, 0) + 1
    return counts


def euler_characteristic(quads: np.ndarray) -> int:
    v = len(np.unique(quads))
    e = len(edge_use_counts(quads))
    return v - e + len(quads)
