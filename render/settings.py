"""Settings of the render stage (hashed into the stage's folder name)."""

from __future__ import annotations

import dataclasses
import math

from pipeline.core.settings_io import setting
from render.rigs import RIGS

BACKENDS = ("freestyle", "embree")
# Freestyle edge types a lineset can select (names of its ``select_<type>`` flags).
EDGE_TYPES = (
    "silhouette",
    "border",
    "crease",
    "contour",
    "external_contour",
    "suggestive_contour",
    "ridge_valley",
    "material_boundary",
    "edge_mark",
)
# What the embree backend draws of them: Freestyle's contours are silhouettes to it (one test, an
# edge between a front and a back face; render.edge_lines), and borders and creases.
EMBREE_SILHOUETTE_TYPES = ("silhouette", "contour", "external_contour")
EMBREE_EDGE_TYPES = EMBREE_SILHOUETTE_TYPES + ("border", "crease")


@dataclasses.dataclass(frozen=True)
class RenderSettings:
    """How each prepared (unit-radius, origin-centred) mesh is drawn.

    ``rig`` names a camera rig of ``render.rigs``: "representative" (the default) draws views as
    "random" does but keeps only those whose silhouette spans ``min_view_extent`` of the frame
    and ``view_extent_fraction`` of the widest of ``view_candidates`` draws; "random" places
    ``views`` cameras at seeded azimuths over 360° and elevations drawn uniformly from
    ``elevation_range``; "front_side_top" three fixed cameras (``views`` is ignored).
    """

    backend: str = setting(
        "freestyle", '"embree": visible feature edges by ray casting, no Blender (render.edge_lines)'
    )
    views: int = setting(4, "views drawn per model")
    image_size: int = setting(256, "drawing size in pixels (square)")
    elevation_range: tuple[float, float] = setting((-10.0, 40.0), "camera elevations in degrees, drawn uniformly")
    rig: str = setting("representative", "camera rig: " + ", ".join(RIGS))
    min_view_extent: float = setting(0.35, "representative rig: a view's silhouette spans at least this of the frame")
    view_extent_fraction: float = setting(0.6, "... and at least this share of the widest candidate's")
    view_candidates: int = setting(32, "... out of this many seeded draws per model")
    view_area_fraction: float = setting(
        0.0,
        "representative rig: a kept view's silhouette hull also covers this share of the largest "
        "candidate's (0: off; an airplane seen with its wings edge-on covers little)",
    )
    orthographic: bool = setting(False, "orthographic cameras instead of perspective")
    lens_mm: float = setting(50.0, "on a 36 mm sensor: 39.6° field of view")
    sensor_mm: float = setting(36.0, "sensor width; with lens_mm, the field of view")
    margin: float = setting(1.08, "the unit sphere fills 1/margin of the half-frame")
    crease_angle_deg: float = setting(134.43, "Blender's default; dihedral angles below it are creases")
    # what is drawn: the paper's occluding contours (silhouette, contours) and sharp edges
    # (crease), plus borders of open surfaces; visible lines only
    edge_types: tuple[str, ...] = setting(
        ("silhouette", "border", "crease", "contour", "external_contour"),
        "Freestyle edge types drawn: " + ", ".join(EDGE_TYPES),
    )
    smooth_shading: bool = setting(True, "smooth silhouettes on curved parts; edges at creases stay sharp")
    line_thickness: float = setting(1.5, "pixels")
    min_stroke_px: float = setting(0.0, "drop strokes shorter than this; >0 also opens gaps in noisy outlines")
    join_gap_px: float = setting(1.0, "join captured stroke fragments whose ends are this close (0: raw)")
    samples: int = setting(1, "Cycles samples; lines are anti-aliased by Freestyle itself")
    threads: int = setting(1, "Cycles render threads and the size of Blender's TBB pool (0: all CPUs)")
    timeout_s: float = setting(60.0, "per model; a batch gets startup_timeout_s + n * timeout_s")
    startup_timeout_s: float = setting(60.0, "a render batch's allowance for starting Blender")

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.rig not in RIGS:
            raise ValueError(f"rig must be one of {tuple(RIGS)}, got {self.rig!r}")
        if self.image_size < 8 or self.views < 1:
            raise ValueError("image_size must be >= 8 and views >= 1")
        unknown = set(self.edge_types) - set(EDGE_TYPES)
        if unknown or not self.edge_types:
            raise ValueError(f"edge_types must be a non-empty subset of {EDGE_TYPES}, got {self.edge_types!r}")
        if self.backend == "embree" and not set(self.edge_types) & set(EMBREE_EDGE_TYPES):
            raise ValueError(
                f"the embree backend draws only {', '.join(EMBREE_EDGE_TYPES)}; edge_types {self.edge_types!r} "
                "names none of them (backend freestyle draws every Freestyle type)"
            )
        if not all(0.0 <= x <= 1.0 for x in (self.min_view_extent, self.view_extent_fraction, self.view_area_fraction)):
            raise ValueError("min_view_extent, view_extent_fraction and view_area_fraction must lie in [0, 1]")
        if self.view_candidates < 1:
            raise ValueError("view_candidates must be >= 1")
        lo, hi = self.elevation_range
        if not -90.0 < lo <= hi < 90.0:
            raise ValueError(f"elevation_range must lie in (-90, 90): {self.elevation_range}")

    @property
    def half_fov_rad(self) -> float:
        return math.atan(0.5 * self.sensor_mm / self.lens_mm)

    @property
    def distance(self) -> float:
        """Camera distance at which the unit sphere's outline fits the frame with ``margin``."""
        if self.orthographic:
            return 3.0  # any distance outside the unit sphere; only the clip range cares
        return self.margin / math.sin(self.half_fov_rad)

    @property
    def ortho_scale(self) -> float:
        """Width of the orthographic frame in world units."""
        return 2.0 * self.margin

    def batch_timeout_s(self, n_models: int) -> float:
        return self.startup_timeout_s + self.timeout_s * max(1, n_models)
