"""The optional steps after the watertight envelope, each kept only when its output is still a
closed solid: a refinement never costs a model.

Manifold's envelope is the last step that must succeed. What follows it (``pull_to_source``,
then decimation) improves it, and each step's output is checked (:func:`check_solid`, the same
check the repaired mesh gets at the end); a step whose output fails is undone, so the next step
takes that step's input. The path taken is returned per step, for the model's record:
``"applied"``, ``"off"`` (pull_to_source 0), ``"not needed"`` (decimation of an envelope already
within max_faces) or ``"fell back: <problems>"``.

On inputs where every step passes (every procedural model), the result is exactly the old
envelope -> pull -> decimate -> clean-up -> verify chain: a passing step's cleaned output is the
one that chain cleaned, and the envelope is only checked on its own when a pull is undone.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import trimesh

from pipeline.prepare.mesh_checks import closed_surface_problems
from pipeline.prepare.settings import PrepareSettings
from pipeline.prepare.watertight import clean_solid, decimate, pull_to_source

APPLIED, OFF, NOT_NEEDED, FELL_BACK = "applied", "off", "not needed", "fell back: "


@dataclasses.dataclass(frozen=True)
class Stage:
    """A step's raw output (what the next step takes) and, once checked, its cleaned mesh and
    the reasons it is not a closed solid ([] if it is)."""

    vertices: np.ndarray
    faces: np.ndarray
    mesh: trimesh.Trimesh | None = None
    problems: tuple[str, ...] = ()

    @property
    def checked(self) -> bool:
        return self.mesh is not None


@dataclasses.dataclass(frozen=True)
class Refined:
    """The repaired solid (None when even the unrefined envelope fails), why it failed, and
    the path each optional step took."""

    mesh: trimesh.Trimesh | None
    problems: list[str]
    paths: dict[str, str]


def check_solid(vertices: np.ndarray, faces: np.ndarray, settings: PrepareSettings) -> Stage:
    """Clean-up (pipeline.prepare.watertight.clean_solid) and the closed-solid verification."""
    mesh, facts = clean_solid(vertices, faces, settings.min_component_fraction)
    return Stage(vertices, faces, mesh, tuple(closed_surface_problems(facts, settings.max_bodies)))


def _timed(timings: dict, key: str, fn, *args):
    t = time.perf_counter()
    out = fn(*args)
    timings[key] = timings.get(key, 0.0) + time.perf_counter() - t
    return out


def refine_envelope(
    env_vertices: np.ndarray,
    env_faces: np.ndarray,
    src_vertices: np.ndarray,
    src_faces: np.ndarray,
    settings: PrepareSettings,
    timings: dict | None = None,
) -> Refined:
    """Pull, decimate and verify an envelope, undoing a step whose output fails the check."""
    timings = {} if timings is None else timings
    for step in ("pull", "decimate", "verify"):  # the record's timings keep every key, as before
        timings.setdefault(step, 0.0)
    paths: dict[str, str] = {}
    stage = _pull(Stage(env_vertices, env_faces), src_vertices, src_faces, settings, timings, paths)
    if stage.problems:  # the pull was undone onto an envelope that is no solid either
        return Refined(None, list(stage.problems), paths)
    stage = _decimate(stage, settings, timings, paths)
    if not stage.checked:
        stage = _timed(timings, "verify", check_solid, stage.vertices, stage.faces, settings)
    problems = list(stage.problems) + _size_problems(stage.mesh, settings)
    if problems and paths["decimate"].startswith(FELL_BACK):
        problems.append(f"decimation {paths['decimate']}")
    return Refined(None if problems else stage.mesh, problems, paths)


def _pull(
    envelope: Stage,
    src_vertices: np.ndarray,
    src_faces: np.ndarray,
    settings: PrepareSettings,
    timings: dict,
    paths: dict,
) -> Stage:
    if settings.pull_to_source <= 0.0:
        paths["pull_to_source"] = OFF
        return envelope
    pulled = _timed(
        timings,
        "pull",
        pull_to_source,
        envelope.vertices,
        envelope.faces,
        src_vertices,
        src_faces,
        settings.pull_to_source,
    )
    out = _timed(timings, "verify", check_solid, pulled, envelope.faces, settings)
    if not out.problems:
        paths["pull_to_source"] = APPLIED
        return out
    paths["pull_to_source"] = FELL_BACK + ", ".join(out.problems)
    return _timed(timings, "verify", check_solid, envelope.vertices, envelope.faces, settings)


def _decimate(stage: Stage, settings: PrepareSettings, timings: dict, paths: dict) -> Stage:
    if len(stage.faces) <= settings.max_faces:
        paths["decimate"] = NOT_NEEDED
        return stage
    dv, df = _timed(timings, "decimate", decimate, stage.vertices, stage.faces, settings.max_faces)
    out = _timed(timings, "verify", check_solid, dv, df, settings)
    problems = list(out.problems) + _size_problems(out.mesh, settings)
    if not problems:
        paths["decimate"] = APPLIED
        return out
    paths["decimate"] = FELL_BACK + ", ".join(problems)
    return stage  # over max_faces: the attempt fails, a coarser envelope follows


def _size_problems(mesh: trimesh.Trimesh, settings: PrepareSettings) -> list[str]:
    n = len(mesh.faces)
    return [f"{n} faces after decimation > max_faces {settings.max_faces}"] if n > settings.max_faces else []
