"""The Template model and its JSON file: control points, curves, patches, junctions, optional parts, symmetry.

A template is a deformable set of Coons patches that share control points. It is stored as JSON
(UTF-8, canonical key order)::

    {
      "format": "coons-template", "version": 1, "name": "sphere24",
      "points": [                      # every control point, referenced by index
        {"xyz": [x, y, z]},            #   free point: 3 parameters
        {"curve": c, "t": 0.25}        #   junction point on curve c at t in (0, 1): 1 parameter,
      ],                               #   stored as logit(t), position = curve c at t
      "curves": [
        {"points": [p0, p1, p2, p3]},  # ordinary cubic curve: 4 point indices (p1, p2 usually free)
        {"parent": c, "start": pa, "end": pb}
                                       # junction sub-curve: the piece of curve c between points pa
                                       # and pb (each either an end point of c or a junction point
                                       # on c); all 4 control points come from exact subdivision of
                                       # c, so T-junctions stay watertight
      ],
      "patches": [
        {"curves": [c1, c2, c3, c4], "reverse": [false, true, false, false], "label": "body"}
      ],                               # paper orientation after applying "reverse": c1 bottom
                                       # P(0,0)→P(1,0), c2 right →P(1,1), c3 top →P(0,1),
                                       # c4 left →P(0,0); P_s × P_t points outward
      "optional_parts": {"engine": [patch ids]},
                                       # patches present only when the part is present
      "closing_patches": {"engine": [patch ids]},
                                       # patches present only when the part is ABSENT: they close
                                       # the surface where the part was attached (written only
                                       # when some template part has them)
      "part_groups": {"wheels": ["wheel_front", "wheel_rear"]},
                                       # optional: patch labels whose Chamfer and normal terms are
                                       # computed apart from the rest (the paper's car wheels);
                                       # labels in no group form one more group
      "regularizers": {"template_normal": 1e-4, "symmetry": 1.0},
                                       # optional: default weights of the regularizers this
                                       # template wants; a regularizer not named is off (weight 0)
      "match_normals": 0.1,            # optional: default λ of normal-aware matching in training
                                       # (thin walls whose two sides face opposite ways); 0 if absent
      "symmetry": {"plane_x": 0.0, "pairs": [[i, j], ...], "self": [k, ...]} or null,
                                       # mirror x = plane_x; pairs of point indices that mirror each
                                       # other, and points on the plane
      "metadata": {...}                # free-form (source, category, construction settings)
    }

With optional parts, ``Template.active_patches({"engine": False})`` is the patch set of one
on/off combination; every combination is a closed surface (templates built from cuboids).

Parameter vector (what the network outputs): points in order; a free point contributes its
x, y, z; a junction point one number, logit(t). ``Template.patches_from_params`` maps a batch
of parameter vectors to patches ``(B, P, 4, 4, 3)`` differentiably.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from pipeline.core.atomic import dumps_json, write_bytes
from train.geometry.bezier import bezier_eval, bezier_subdivide

FORMAT = "coons-template"
VERSION = 1


@dataclass(frozen=True)
class FreePoint:
    xyz: tuple[float, float, float]


@dataclass(frozen=True)
class JunctionPoint:
    curve: int
    t: float


@dataclass(frozen=True)
class Curve:
    """Either ``points`` (4 point indices) or ``parent`` + ``start`` + ``end`` (a sub-curve)."""

    points: tuple[int, int, int, int] | None = None
    parent: int | None = None
    start: int | None = None
    end: int | None = None

    @property
    def is_sub(self) -> bool:
        return self.parent is not None


@dataclass(frozen=True)
class Patch:
    curves: tuple[int, int, int, int]
    reverse: tuple[bool, bool, bool, bool] = (False, False, False, False)
    label: str = ""


@dataclass(frozen=True)
class Symmetry:
    plane_x: float = 0.0
    pairs: tuple[tuple[int, int], ...] = ()
    self_points: tuple[int, ...] = ()


class TemplateError(ValueError):
    """The template is inconsistent (bad reference, open patch loop, junction cycle)."""


@dataclass(frozen=True)
class Template:
    """A template, validated and compiled once when made; never changed afterwards: a changed
    template is a new one (``dataclasses.replace`` validates it again, ``with_symmetry``)."""

    points: list[FreePoint | JunctionPoint]
    curves: list[Curve]
    patches: list[Patch]
    name: str = ""
    optional_parts: dict[str, list[int]] = field(default_factory=dict)
    symmetry: Symmetry | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    closing_patches: dict[str, list[int]] = field(default_factory=dict)
    part_groups: dict[str, list[str]] = field(default_factory=dict)
    regularizers: dict[str, float] = field(default_factory=dict)
    match_normals: float = 0.0  # training's default λ of normal-aware matching (FitSettings.match_normals)

    def __post_init__(self) -> None:
        self._compile()

    # ---- sizes ---------------------------------------------------------------------------
    @property
    def num_params(self) -> int:
        return sum(3 if isinstance(p, FreePoint) else 1 for p in self.points)

    @property
    def num_points(self) -> int:
        return len(self.points)

    @property
    def num_patches(self) -> int:
        return len(self.patches)

    @property
    def patch_labels(self) -> list[str]:
        return [p.label for p in self.patches]

    @property
    def part_names(self) -> list[str]:
        """Names of the parts that can be switched on/off (optional or closing patches)."""
        return sorted(set(self.optional_parts) | set(self.closing_patches))

    def active_patches(self, parts: dict[str, bool] | None = None) -> list[int]:
        """Patch ids making the surface for the given parts (missing names: present).

        A patch listed under ``optional_parts[name]`` needs the part present; one listed under
        ``closing_patches[name]`` needs it absent; a patch in several lists needs all conditions.
        """
        parts = dict(parts or {})
        unknown = set(parts) - set(self.part_names)
        if unknown:
            raise ValueError(f"template has no optional part(s) {sorted(unknown)}; it has {self.part_names}")
        off = set()
        for name in self.part_names:
            present = bool(parts.get(name, True))
            off.update(self.closing_patches.get(name, []) if present else self.optional_parts.get(name, []))
        return [i for i in range(len(self.patches)) if i not in off]

    # ---- compile: validation and an evaluation schedule -----------------------------------
    def _compile(self) -> None:
        n_pts, n_cur = len(self.points), len(self.curves)
        offsets, off = [], 0
        for p in self.points:
            offsets.append(off)
            off += 3 if isinstance(p, FreePoint) else 1
        object.__setattr__(self, "_offsets", offsets)
        for i, p in enumerate(self.points):
            if isinstance(p, JunctionPoint):
                if not 0 <= p.curve < n_cur:
                    raise TemplateError(f"point {i}: junction on missing curve {p.curve}")
                if not 0.0 < p.t < 1.0:
                    raise TemplateError(f"point {i}: junction t={p.t} not in (0, 1)")
        for ci, c in enumerate(self.curves):
            refs = list(c.points) if not c.is_sub else [c.start, c.end]
            if (c.points is None) == (c.parent is None) or any(r is None or not 0 <= r < n_pts for r in refs):
                raise TemplateError(f"curve {ci}: needs 4 valid points or parent/start/end")
            if c.is_sub and not 0 <= c.parent < n_cur:
                raise TemplateError(f"curve {ci}: missing parent {c.parent}")
        object.__setattr__(self, "_ends", [self._curve_ends(ci) for ci in range(n_cur)])
        for ci, c in enumerate(self.curves):
            if c.is_sub:
                for r in (c.start, c.end):
                    self._param_on(ci, c.parent, r)  # validates
        for pi, patch in enumerate(self.patches):
            if len(patch.curves) != 4 or any(not 0 <= c < n_cur for c in patch.curves):
                raise TemplateError(f"patch {pi}: needs 4 valid curves")
            chain = [self._oriented_ends(c, r) for c, r in zip(patch.curves, patch.reverse)]
            for k in range(4):
                if chain[k][1] != chain[(k + 1) % 4][0]:
                    raise TemplateError(f"patch {pi}: curve {k + 1} does not end where curve {(k + 1) % 4 + 1} starts")
        for kind, table in (("optional part", self.optional_parts), ("closing patches of", self.closing_patches)):
            for name, ids in table.items():
                if any(not 0 <= i < len(self.patches) for i in ids):
                    raise TemplateError(f"{kind} {name!r}: bad patch index")
        # which names are regularizers is the loss table's to say (train.losses.weights.template_weights)
        for name, weight in self.regularizers.items():
            if not (isinstance(weight, (int, float)) and math.isfinite(weight) and weight >= 0):
                raise TemplateError(f"regularizer {name!r}: expected a weight >= 0, got {weight!r}")
        if not (math.isfinite(self.match_normals) and self.match_normals >= 0):
            raise TemplateError(f"match_normals: expected a number >= 0, got {self.match_normals!r}")
        grouped = [lab for labels in self.part_groups.values() for lab in labels]
        if len(grouped) != len(set(grouped)):
            raise TemplateError("part_groups: a label is in more than one group")
        object.__setattr__(self, "_schedule", self._make_schedule())
        object.__setattr__(self, "_boundary_cache", {})
        object.__setattr__(self, "_dev_cache", {})

    def _curve_ends(self, ci: int) -> tuple[int, int]:
        c = self.curves[ci]
        return (c.points[0], c.points[3]) if not c.is_sub else (c.start, c.end)

    def _oriented_ends(self, ci: int, rev: bool) -> tuple[int, int]:
        a, b = self._ends[ci]
        return (b, a) if rev else (a, b)

    def _param_on(self, sub: int, parent: int, point: int) -> float | int:
        """Fixed parameter 0/1 of ``point`` on ``parent``, or ``-1 - point`` for a junction."""
        a, b = self._ends[parent]
        if point == a:
            return 0.0
        if point == b:
            return 1.0
        p = self.points[point]
        if isinstance(p, JunctionPoint) and p.curve == parent:
            return -1 - point
        raise TemplateError(f"curve {sub}: point {point} is neither an end of nor a junction on curve {parent}")

    def _param_column(self, sub: int, point: int) -> float | int:
        """0.0 / 1.0 for a parent end point, else the parameter column (int) of the junction's logit."""
        v = self._param_on(sub, self.curves[sub].parent, point)
        return v if isinstance(v, float) else self._offsets[-1 - v]

    def _make_schedule(self) -> list[tuple[list[int], list[int]]]:
        """Rounds of (curves, junction points) whose inputs are ready, in index order."""
        ready_pt = [isinstance(p, FreePoint) for p in self.points]
        ready_cv = [False] * len(self.curves)
        rounds = []
        while not all(ready_cv) or not all(ready_pt):
            cur = [
                ci
                for ci, c in enumerate(self.curves)
                if not ready_cv[ci]
                and (
                    all(ready_pt[r] for r in c.points)
                    if not c.is_sub
                    else ready_cv[c.parent] and ready_pt[c.start] and ready_pt[c.end]
                )
            ]
            for ci in cur:
                ready_cv[ci] = True
            jun = [i for i, p in enumerate(self.points) if not ready_pt[i] and ready_cv[p.curve]]
            for i in jun:
                ready_pt[i] = True
            if not cur and not jun:
                raise TemplateError("junction points and curves depend on each other in a cycle")
            rounds.append((cur, jun))
        return rounds

    # ---- parameters ------------------------------------------------------------------------
    def initial_params(self, dtype: torch.dtype = torch.float32) -> Tensor:
        """The template's own geometry as a parameter vector ``(D,)``."""
        vals: list[float] = []
        for p in self.points:
            if isinstance(p, FreePoint):
                vals.extend(float(x) for x in p.xyz)
            else:
                vals.append(math.log(p.t / (1.0 - p.t)))
        return torch.tensor(vals, dtype=dtype)

    def params_from_points(self, xyz: np.ndarray, t: dict[int, float] | None = None) -> Tensor:
        """Parameter vector for new free-point positions ``(N, 3)`` (junction t kept or from ``t``)."""
        vals: list[float] = []
        for i, p in enumerate(self.points):
            if isinstance(p, FreePoint):
                vals.extend(float(x) for x in xyz[i])
            else:
                tt = (t or {}).get(i, p.t)
                vals.append(math.log(tt / (1.0 - tt)))
        return torch.tensor(vals, dtype=torch.float64)

    def _index_cache(self, device: torch.device) -> dict[str, Any]:
        key = str(device)
        cache = self._dev_cache
        if key not in cache:
            free = [i for i, p in enumerate(self.points) if isinstance(p, FreePoint)]
            cols = [self._offsets[i] + k for i in free for k in range(3)]
            rounds = []
            for cur, jun in self._schedule:
                reg = [c for c in cur if not self.curves[c].is_sub]
                sub = [c for c in cur if self.curves[c].is_sub]
                rounds.append(
                    dict(
                        reg=torch.tensor(reg, dtype=torch.long, device=device),
                        reg_pts=torch.tensor(
                            [self.curves[c].points for c in reg], dtype=torch.long, device=device
                        ).reshape(-1, 4),
                        sub=torch.tensor(sub, dtype=torch.long, device=device),
                        sub_parent=torch.tensor([self.curves[c].parent for c in sub], dtype=torch.long, device=device),
                        **self._sub_ends(sub, device),
                        jun=torch.tensor(jun, dtype=torch.long, device=device),
                        jun_curve=torch.tensor([self.points[i].curve for i in jun], dtype=torch.long, device=device),
                        jun_col=torch.tensor([self._offsets[i] for i in jun], dtype=torch.long, device=device),
                    )
                )
            pc = torch.tensor([p.curves for p in self.patches], dtype=torch.long, device=device).reshape(-1, 4)
            pr = torch.tensor([p.reverse for p in self.patches], dtype=torch.bool, device=device).reshape(-1, 4)
            cache[key] = dict(
                free=torch.tensor(free, dtype=torch.long, device=device),
                cols=torch.tensor(cols, dtype=torch.long, device=device),
                rounds=rounds,
                patch_curves=pc,
                patch_reverse=pr,
            )
        return cache[key]

    def _sub_ends(self, sub: list[int], device: torch.device) -> dict[str, Tensor]:
        """Where each sub-curve of a round starts and ends on its parent, as index tensors built
        once: ``sub_col`` (n, 2) the parameter column of a junction's logit, ``sub_fixed`` (n, 2)
        the fixed 0.0 / 1.0 of a parent end point, ``sub_is_col`` which of the two applies (one
        gather per round instead of a tensor per end and step)."""
        ends = [[self._param_column(c, r) for r in (self.curves[c].start, self.curves[c].end)] for c in sub]
        is_col = [[isinstance(v, int) for v in pair] for pair in ends]
        return dict(
            sub_col=torch.tensor(
                [[v if isinstance(v, int) else 0 for v in pair] for pair in ends], dtype=torch.long, device=device
            ).reshape(-1, 2),
            sub_fixed=torch.tensor(
                [[0.0 if isinstance(v, int) else v for v in pair] for pair in ends], dtype=torch.float64, device=device
            ).reshape(-1, 2),
            sub_is_col=torch.tensor(is_col, dtype=torch.bool, device=device).reshape(-1, 2),
        )

    def _evaluate(self, params: Tensor) -> tuple[Tensor, Tensor]:
        if params.dim() == 1:
            params = params[None]
        if params.shape[-1] != self.num_params:
            raise TemplateError(f"expected {self.num_params} parameters, got {params.shape[-1]}")
        idx = self._index_cache(params.device)
        bsz = params.shape[0]
        pts = params.new_zeros(bsz, self.num_points, 3)
        pts = pts.index_copy(1, idx["free"], params[:, idx["cols"]].reshape(bsz, -1, 3))
        ctrl = params.new_zeros(bsz, len(self.curves), 4, 3)
        sig = torch.sigmoid(params)
        for rnd in idx["rounds"]:
            if len(rnd["reg"]):
                ctrl = ctrl.index_copy(1, rnd["reg"], pts[:, rnd["reg_pts"]])
            if len(rnd["sub"]):
                fixed = rnd["sub_fixed"].to(params.dtype)
                ab = torch.where(rnd["sub_is_col"], sig[:, rnd["sub_col"]], fixed)  # (B, n_sub, 2)
                sub_ctrl = bezier_subdivide(ctrl[:, rnd["sub_parent"]], ab[..., 0], ab[..., 1])
                ctrl = ctrl.index_copy(1, rnd["sub"], sub_ctrl)
            if len(rnd["jun"]):
                t = sig[:, rnd["jun_col"]]  # (B, n_jun)
                pos = bezier_eval(ctrl[:, rnd["jun_curve"]], t[..., None])[..., 0, :]
                pts = pts.index_copy(1, rnd["jun"], pos)
        return pts, ctrl

    def points_from_params(self, params: Tensor) -> Tensor:
        """Positions of all template points ``(B, N, 3)`` (junction points evaluated on their curves)."""
        return self._evaluate(params)[0]

    def curves_from_params(self, params: Tensor) -> Tensor:
        """Control points of every curve ``(B, C, 4, 3)`` (sub-curves by exact subdivision)."""
        return self._evaluate(params)[1]

    def patches_from_params(self, params: Tensor) -> Tensor:
        """Patches ``(B, P, 4, 4, 3)`` in the paper's orientation, differentiable in ``params (B, D)``."""
        return self._patches_of(self._evaluate(params)[1], params.device)

    def patches_and_points(self, params: Tensor) -> tuple[Tensor, Tensor]:
        """``patches_from_params`` and ``points_from_params`` from one evaluation (the loss needs
        both: evaluating twice doubles the template's share of the forward and backward)."""
        pts, ctrl = self._evaluate(params)
        return self._patches_of(ctrl, params.device), pts

    def _patches_of(self, ctrl: Tensor, device: torch.device) -> Tensor:
        idx = self._index_cache(device)
        pc = ctrl[:, idx["patch_curves"]]  # (B, P, 4, 4, 3)
        return torch.where(idx["patch_reverse"][None, :, :, None, None], pc.flip(-2), pc)

    # ---- topology ----------------------------------------------------------------------------
    def curve_family(self, ci: int) -> int:
        """The root ancestor of a curve (a curve and its sub-curves share a family)."""
        while self.curves[ci].is_sub:
            ci = self.curves[ci].parent
        return ci

    def patch_boundary_points(self, pi: int) -> set[int]:
        """Corner point ids of a patch plus junction points lying on its curves."""
        cache = self.__dict__.setdefault("_boundary_cache", {})
        if pi not in cache:
            cache[pi] = self._boundary_points(pi)
        return cache[pi]

    def _boundary_points(self, pi: int) -> set[int]:
        curves = set(self.patches[pi].curves)
        out = {self._oriented_ends(c, r)[0] for c, r in zip(self.patches[pi].curves, self.patches[pi].reverse)}
        out |= {i for i, p in enumerate(self.points) if isinstance(p, JunctionPoint) and p.curve in curves}
        return out

    def shared_features(self, i: int, j: int) -> tuple[list[bool], list[bool]]:
        """Which sides (c1..c4) and corners (P00, P10, P11, P01) of patch i touch patch j.

        A side touches when it is the same curve as one of j's, its parent, or its sub-curve
        (T-junction). A corner touches when it is on j's boundary (a corner of j or a junction
        point on one of j's curves).
        """
        ci, cj = self.patches[i].curves, self.patches[j].curves
        related = set()
        for a in ci:
            for b in cj:
                if a == b or self._is_ancestor(a, b) or self._is_ancestor(b, a):
                    related.add(a)
        sides = [c in related for c in ci]
        bj = self.patch_boundary_points(j)
        corners = [self._oriented_ends(c, r)[0] in bj for c, r in zip(ci, self.patches[i].reverse)]
        return sides, corners

    def _is_ancestor(self, a: int, b: int) -> bool:
        while self.curves[b].is_sub:
            b = self.curves[b].parent
            if b == a:
                return True
        return False

    def adjacency(self) -> list[tuple[int, int]]:
        """Sorted patch pairs (i < j) that share a curve, part of a curve, a corner or a junction."""
        out = []
        for i in range(len(self.patches)):
            bi = self.patch_boundary_points(i)
            for j in range(i + 1, len(self.patches)):
                s_ij, c_ij = self.shared_features(i, j)
                if any(s_ij) or any(c_ij) or bi & self.patch_boundary_points(j):
                    out.append((i, j))
        return out

    def symmetry_pairs(self, include_self: bool = True) -> Tensor:
        """Index pairs ``(K, 2)`` of mirrored points; self-symmetric points appear as (k, k)."""
        if self.symmetry is None:
            return torch.zeros((0, 2), dtype=torch.long)
        pairs = [list(p) for p in self.symmetry.pairs]
        if include_self:
            pairs += [[k, k] for k in self.symmetry.self_points]
        return torch.tensor(pairs, dtype=torch.long).reshape(-1, 2)

    def with_symmetry(self, plane_x: float = 0.0, tol: float = 1e-4) -> "Template":
        """This template with its mirror symmetry across x = plane_x declared (``mirror_symmetry``)."""
        return replace(self, symmetry=self.mirror_symmetry(plane_x, tol))

    def mirror_symmetry(self, plane_x: float = 0.0, tol: float = 1e-4) -> Symmetry:
        """Points paired across x = plane_x (within ``tol``).

        Points of the same kind only (free with free, junction with junction); a point within
        ``tol`` of the plane is self-symmetric. Points with no mirror partner are left out.
        """
        with torch.no_grad():
            pos = self.points_from_params(self.initial_params(torch.float64))[0].numpy()
        from scipy.spatial import cKDTree

        mirrored = pos.copy()
        mirrored[:, 0] = 2.0 * plane_x - mirrored[:, 0]
        tree = cKDTree(pos)
        kinds = [isinstance(p, FreePoint) for p in self.points]
        pairs, selfs = [], []
        for i in range(len(pos)):
            if abs(pos[i, 0] - plane_x) <= tol:
                selfs.append(i)
                continue
            for j in sorted(tree.query_ball_point(mirrored[i], tol)):
                if j != i and kinds[j] == kinds[i] and i < j:
                    pairs.append((i, j))
                    break
        return Symmetry(float(plane_x), tuple(pairs), tuple(selfs))

    # ---- JSON --------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "name": self.name,
            "points": [
                {"xyz": [float(x) for x in p.xyz]} if isinstance(p, FreePoint) else {"curve": p.curve, "t": float(p.t)}
                for p in self.points
            ],
            "curves": [
                {"points": list(c.points)} if not c.is_sub else {"parent": c.parent, "start": c.start, "end": c.end}
                for c in self.curves
            ],
            "patches": [
                {"curves": list(p.curves), "reverse": [bool(r) for r in p.reverse], "label": p.label}
                for p in self.patches
            ],
            "optional_parts": {k: [int(i) for i in v] for k, v in sorted(self.optional_parts.items())},
            "symmetry": None
            if self.symmetry is None
            else {
                "plane_x": self.symmetry.plane_x,
                "pairs": [list(p) for p in self.symmetry.pairs],
                "self": list(self.symmetry.self_points),
            },
            "metadata": self.metadata,
            **(
                {"closing_patches": {k: [int(i) for i in v] for k, v in sorted(self.closing_patches.items())}}
                if self.closing_patches
                else {}
            ),
            # written only when set, so templates without them keep their bytes
            **({"part_groups": {k: list(v) for k, v in sorted(self.part_groups.items())}} if self.part_groups else {}),
            **({"regularizers": dict(sorted(self.regularizers.items()))} if self.regularizers else {}),
            **({"match_normals": float(self.match_normals)} if self.match_normals else {}),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "Template":
        if data.get("format") != FORMAT or data.get("version") != VERSION:
            raise TemplateError(
                f"not a {FORMAT} v{VERSION} file (format={data.get('format')!r}, version={data.get('version')!r})"
            )
        points: list[FreePoint | JunctionPoint] = []
        for p in data["points"]:
            points.append(
                FreePoint(tuple(float(x) for x in p["xyz"]))
                if "xyz" in p
                else JunctionPoint(int(p["curve"]), float(p["t"]))
            )
        curves = [
            Curve(points=tuple(int(x) for x in c["points"]))
            if "points" in c
            else Curve(parent=int(c["parent"]), start=int(c["start"]), end=int(c["end"]))
            for c in data["curves"]
        ]
        patches = [
            Patch(
                tuple(int(x) for x in p["curves"]),
                tuple(bool(x) for x in p.get("reverse", [False] * 4)),
                str(p.get("label", "")),
            )
            for p in data["patches"]
        ]
        sym = data.get("symmetry")
        symmetry = (
            None
            if sym is None
            else Symmetry(
                float(sym["plane_x"]),
                tuple(tuple(int(i) for i in p) for p in sym["pairs"]),
                tuple(int(i) for i in sym["self"]),
            )
        )
        return cls(
            points=points,
            curves=curves,
            patches=patches,
            name=str(data.get("name", "")),
            optional_parts={k: [int(i) for i in v] for k, v in data.get("optional_parts", {}).items()},
            symmetry=symmetry,
            metadata=dict(data.get("metadata", {})),
            closing_patches={k: [int(i) for i in v] for k, v in data.get("closing_patches", {}).items()},
            part_groups={k: [str(x) for x in v] for k, v in data.get("part_groups", {}).items()},
            regularizers={k: float(v) for k, v in data.get("regularizers", {}).items()},
            match_normals=float(data.get("match_normals", 0.0)),
        )


def save_template(template: Template, path: str | Path) -> None:
    """Write canonical JSON atomically (same template → same bytes)."""
    write_bytes(path, dumps_json(template.to_json()).encode())


def load_template_file(path: str | Path) -> Template:
    """Read and validate a template JSON file; raises TemplateError naming the file on bad input."""
    try:
        with open(path) as f:
            return Template.from_json(json.load(f))
    except (TemplateError, KeyError, TypeError, ValueError) as exc:
        raise TemplateError(f"{path}: {exc}") from exc
