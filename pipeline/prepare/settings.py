"""Settings of the prepare stage (watertight + decimate + verify + normalize + sample)."""

from __future__ import annotations

import dataclasses

from pipeline.core.settings_io import setting


@dataclasses.dataclass(frozen=True)
class PrepareSettings:
    # Manifold octree leaf count. Thin parts survive: the envelope inflates by about one cell
    # (0.026 of the unit-sphere radius at 2500, 0.016 at 5000), never drops. 2500 costs about a
    # third of 5000's CPU (0.07 vs 0.18 s per model) and, pulled back (below), lies three times
    # closer to the source than 5000 does unpulled. 2000 would be cheaper
    # still but fuses the procedural airplanes' detached engines with their pylons.
    resolution: int = setting(2500, "Manifold envelope octree leaf count (finer keeps thinner parts apart)")
    # Move the envelope's vertices this fraction of the way back to the source surface
    # (pipeline.prepare.watertight.pull_to_source; 0: off). Below 1 so thin walls keep two sides.
    pull_to_source: float = setting(0.9, "fraction of the way the envelope moves back to the source surface (0: off)")
    # Decimate the envelope down to this many faces. Above the usual envelope's size, so decimation
    # is the exception (a dense input): at 20000 it cost ~0.16 CPU s per model for a few thousand
    # faces less; the samples lie on the mesh either way.
    max_faces: int = setting(50000, "decimate the envelope above this many faces")
    n_samples: int = setting(16384, "surface points (+ normals) in samples.npy")
    seed: int = setting(0, "keys the sampling generator and the Manifold octree seed")
    # Bad-input bounds: beyond these a model fails with a clear reason instead of eating the box.
    max_input_faces: int = setting(2_000_000, "a source mesh with more faces fails as bad input")
    max_input_bytes: int = setting(1 << 30, "a source file larger than this fails as bad input")
    max_abs_coordinate: float = setting(1e5, "a vertex coordinate beyond this fails the model as bad input")
    # Repair acceptance: components smaller than this fraction of the largest (by area) are
    # debris and dropped; every other body is kept (wheels, engines, caps are separate bodies in
    # real models). More than max_bodies remaining volumes is shattered input and fails.
    min_component_fraction: float = setting(0.01, "components below this fraction of the largest's area are dropped")
    max_bodies: int = setting(32, "more separate volumes than this after repair fails the model")
    # The line mesh (the cleaned source surface the renderer draws) is decimated, edges kept,
    # above this many faces so a view stays within the render time target.
    max_line_faces: int = setting(20000, "decimate the line mesh (edges kept) above this many faces")
    # When the repaired mesh fails verification, retry at resolution / 2 this many times (a
    # coarser envelope fuses nearly-touching parts and decimates less).
    fallback_attempts: int = setting(2, "retries at half the resolution when the repaired mesh fails its checks")

    def __post_init__(self) -> None:
        # out-of-range values would record every model as bad input instead of stopping the build
        for name in ("resolution", "max_faces", "n_samples", "max_input_faces", "max_input_bytes", "max_bodies"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not 0.0 <= self.pull_to_source < 1.0:
            raise ValueError(f"pull_to_source must be in [0, 1), got {self.pull_to_source!r}")
        if (
            not self.max_abs_coordinate > 0
            or not 0.0 <= self.min_component_fraction < 1.0
            or self.fallback_attempts < 0
        ):
            raise ValueError("max_abs_coordinate must be > 0, min_component_fraction in [0, 1), fallback_attempts >= 0")
