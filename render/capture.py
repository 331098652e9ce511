"""Capture Freestyle's own stroke polylines while it draws them (vector ground truth).

A shader factory appended to ``parameter_editor.callbacks_modifiers_post`` adds, at the end of
every lineset's shader list, a shader that only reads each stroke: its vertices (pixels, origin
bottom-left, y up) and the nature of the feature edge under each vertex. Points are converted to
the contract's (u right, v down, origin top-left) convention; stroke geometry is not changed, so
the polylines overlay the rendered PNG exactly. Fragments that Freestyle split at tiny hidden
pieces are chained back together afterwards (render.join; points are never moved).
"""

from __future__ import annotations

from typing import Any

# Name order decides a stroke vertex's type when its edge has several natures at once.
_TYPE_ORDER = (
    "silhouette",
    "border",
    "crease",
    "ridge",
    "valley",
    "suggestive_contour",
    "material_boundary",
    "edge_mark",
)


class StrokeRecorder:
    """Collects the strokes Freestyle draws during one render; ``reset()`` between views."""

    def __init__(self) -> None:
        self.image_height = 0
        self.join_gap_px = 0.0
        self._fragments: list[tuple[list[list[float]], list[str]]] = []
        self._installed = False

    def install(self) -> None:
        """Register with Freestyle's parameter editor (importable only inside bpy)."""
        if self._installed:
            return
        import parameter_editor  # Blender's freestyle/modules, on sys.path once bpy is imported

        parameter_editor.callbacks_modifiers_post.append(self._shaders)
        self._installed = True

    def reset(self, image_height: int, join_gap_px: float = 0.0) -> None:
        self.image_height = image_height
        self.join_gap_px = join_gap_px
        self._fragments = []

    @property
    def strokes(self) -> list[dict]:
        """The strokes drawn since ``reset``, fragments joined (render.join), typed."""
        import numpy as np

        from render.join import join_fragments

        frags = [(np.asarray(p, float), t) for p, t in self._fragments]
        return [
            _stroke_entry([[round(float(x), 4), round(float(y), 4)] for x, y in p], t)
            for p, t in join_fragments(frags, self.join_gap_px)
        ]

    def _shaders(self, scene: Any, layer: Any, lineset: Any) -> list:
        from freestyle.types import StrokeShader

        recorder = self

        class _Record(StrokeShader):
            def shade(self, stroke: Any) -> None:
                recorder._record(stroke)

        return [_Record()]

    def _record(self, stroke: Any) -> None:
        from freestyle.types import Nature

        natures = [
            (Nature.SILHOUETTE, "silhouette"),
            (Nature.BORDER, "border"),
            (Nature.CREASE, "crease"),
            (Nature.RIDGE, "ridge"),
            (Nature.VALLEY, "valley"),
            (Nature.SUGGESTIVE_CONTOUR, "suggestive_contour"),
            (Nature.MATERIAL_BOUNDARY, "material_boundary"),
            (Nature.EDGE_MARK, "edge_mark"),
        ]
        H = self.image_height
        points: list[list[float]] = []
        seg_types: list[str] = []
        for sv in stroke:
            p = sv.point
            points.append([round(float(p[0]), 4), round(float(H - p[1]), 4)])
            fedge = sv.fedge
            # one type per vertex (kept aligned with the points so joined fragments stay typed)
            nat = fedge.nature if fedge is not None else None
            seg_types.append("" if nat is None else next((name for bit, name in natures if nat & bit), "other"))
        if len(points) < 2:
            return
        self._fragments.append((points, seg_types))


def _stroke_entry(points: list[list[float]], seg_types: list[str]) -> dict:
    counts: dict[str, int] = {}
    for t in seg_types:
        if t:  # "" marks a vertex without a feature edge under it
            counts[t] = counts.get(t, 0) + 1
    return typed_stroke(points, counts)


def typed_stroke(points: list[list[float]], counts: dict[str, int]) -> dict:
    """A strokes.json entry: typed by the nature under most of its vertices (``counts``: vertices
    per nature; ties: the _TYPE_ORDER order)."""
    if counts:
        rank = {t: i for i, t in enumerate(_TYPE_ORDER)}
        main = max(counts, key=lambda t: (counts[t], -rank.get(t, len(rank))))
    else:
        main = "other"
    return {"type": main, "types": sorted(counts), "points": points}
