"""Mesh preparation: source mesh → watertight, decimated, verified, unit-sphere mesh + samples.

Per model it writes ``<stage_dir>/<category>/<model_id>/{mesh.ply, lines.ply, samples.npy,
record.json}``, record last, so a killed batch resumes where it stopped. ``mesh.ply`` is the
watertight solid the samples lie on; ``lines.ply`` is the cleaned source surface in the same
frame, which the renderer draws (pipeline.prepare.line_mesh: it keeps the source's sharp edges).
A file source whose mesh carries a segmentation also gets ``sample_parts.npy``, the part of each
sample (pipeline.prepare.part_labels), and its parts in the record.
``prepare_batch`` is what the Luigi task calls; ``prepare_model`` does one model and raises
ModelError for bad input.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import trimesh

from pipeline.core.atomic import write_npy
from pipeline.core.errors import ModelError
from pipeline.core.hashing import file_sha256
from pipeline.core.model_loop import ModelJob, run_models
from pipeline.core.normalize import apply_transform, transform_box, unit_sphere_transform
from pipeline.core.records import ModelRef, Progress, write_ok
from pipeline.core.schema import LINE_MESH_FILE, MESH_FILE, SAMPLE_PARTS_FILE, SAMPLES_FILE, sidecar_path
from pipeline.core.seeding import derive_seed, rng_for
from pipeline.prepare.line_mesh import line_mesh
from pipeline.prepare.mesh_checks import check_input
from pipeline.prepare.part_labels import segmentation_labels
from pipeline.prepare.refine import refine_envelope
from pipeline.prepare.sampling import sample_surface
from pipeline.prepare.settings import PrepareSettings
from pipeline.prepare.watertight import make_watertight
from pipeline.sources.mesh_io import load_mesh, write_ply
from pipeline.sources.segmentation import PartLabelSettings

__all__ = ["PrepareSettings", "prepare_model", "prepare_batch", "repair_mesh"]

METHOD = {
    "watertight": "Manifold (Huang et al. 2018) via point_cloud_utils.make_mesh_watertight",
    "pull": "envelope vertices moved pull_to_source of the way to their closest source point, folds"
    " and hole caps left in place (pipeline.prepare.watertight.pull_to_source)",
    "refinement_fallback": "a refinement after the envelope (pull, decimation) whose output fails the"
    " closed-solid check is undone, its input kept; the path each took is in"
    " refinements (pipeline.prepare.refine)",
    "decimation": "pymeshlab meshing_decimation_quadric_edge_collapse (preservetopology, preservenormal)",
    "normalization": "bbox centre to origin, farthest vertex at radius 1",
    "sampling": "trimesh.sample.sample_surface (area-uniform) + face normals",
    "line_mesh": "source mesh under the same normalization, vertices merged, degenerate and duplicate"
    " faces removed, winding made consistent and outward per body, long slivers split, decimated"
    " keeping sharp edges above max_line_faces (pipeline.prepare.line_mesh)",
}


def repair_mesh(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    settings: PrepareSettings,
    seed: int,
    timings: dict | None = None,
) -> tuple[trimesh.Trimesh, dict]:
    """Watertight + refined + verified solid in the source frame, and how it was obtained.

    Tries the configured resolution, then coarser ones; raises ModelError listing what failed.
    The refinements after the envelope fall back to their input when their output fails the
    check (pipeline.prepare.refine), so only an envelope that fails costs an attempt.
    """
    timings = {} if timings is None else timings
    failures = []
    resolution = settings.resolution
    for attempt in range(settings.fallback_attempts + 1):
        t = time.perf_counter()
        wv, wf = make_watertight(vertices, faces, resolution, seed)
        timings["watertight"] = timings.get("watertight", 0.0) + time.perf_counter() - t
        refined = refine_envelope(wv, wf, vertices, faces, settings, timings)
        if refined.mesh is not None:
            info = {
                "resolution": resolution,
                "attempts": attempt + 1,
                "watertight_faces": int(len(wf)),
                "output_faces": int(len(refined.mesh.faces)),
                "rejected": failures,
                "refinements": refined.paths,
            }
            return refined.mesh, info
        failures.append({"resolution": resolution, "problems": refined.problems, "refinements": refined.paths})
        resolution = max(resolution // 2, 100)
    detail = "; ".join(f"resolution {f['resolution']}: {', '.join(f['problems'])}" for f in failures)
    raise ModelError(path, f"repair failed verification: {detail}")


TINY_DIAGONAL = 1e-2
# A model whose bbox centre lies farther from the origin than this many times its own size is
# repaired centred: at 1e5 units out, a metre-sized part keeps ~11 of float64's digits, and the
# signed volume (products of coordinates) cancels to noise ("non-positive enclosed volume").
FAR_OFFSET = 100.0


def pre_scale(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray | None, float]:
    """(centre, factor) mapping a model for repair to the origin, at unit size when it is under
    TINY_DIAGONAL across; (None, 1) for a model near the origin at ordinary size (every
    procedural or ShapeNet model), which is repaired exactly as it is."""
    used = vertices[np.unique(faces)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    centre = (lo + hi) / 2.0
    diag = float(np.linalg.norm(hi - lo))
    tiny = diag < TINY_DIAGONAL
    if not tiny and float(np.linalg.norm(centre)) <= FAR_OFFSET * diag:
        return None, 1.0
    return centre, diag if tiny else 1.0


def _read_sidecar(path: Path) -> dict | None:
    """The procedural generator's sidecar (part labels, cuboids, defects) if the source has one."""
    side = sidecar_path(path)
    if not side.is_file():
        return None
    try:
        data = json.loads(side.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and "parts" in data else None


def _sidecar_fields(side: dict, center: np.ndarray, scale: float) -> dict:
    cuboids = []
    for c in side.get("cuboids", []):
        lo, hi = transform_box(np.asarray(c["lo"], float), np.asarray(c["hi"], float), center, scale)
        cuboids.append({"label": c["label"], "lo": lo, "hi": hi})
    return {
        "parts": [{"label": p["label"], "n_faces": p.get("n_faces")} for p in side.get("parts", [])],
        "cuboids": cuboids,
        "defects": list(side.get("defects", [])),
    }


def prepare_model(
    ref: ModelRef, out_dir: Path, settings: PrepareSettings, parts: PartLabelSettings | None = None
) -> dict:
    """Prepare one model into ``out_dir`` (its files and record.json); returns the record.

    Raises ModelError for bad input or a repair that fails verification (no record written).
    """
    return write_ok(out_dir, **prepare_files(ref, out_dir, settings, parts))


def prepare_files(
    ref: ModelRef, out_dir: Path, settings: PrepareSettings, parts: PartLabelSettings | None = None
) -> dict:
    """Write one model's mesh.ply, lines.ply and samples.npy into ``out_dir``; returns its record
    fields (the caller writes record.json). Raises ModelError for bad input.

    ``parts``: how a file source's segmentation names its parts (None: no segmentation read,
    what a procedural build passes; its parts come from the generator's sidecar)."""
    out_dir = Path(out_dir)
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    path = Path(ref.path)

    t = time.perf_counter()
    vertices, faces = load_mesh(path, settings.max_input_bytes)
    sha = file_sha256(path)
    check_input(path, vertices, faces, settings.max_input_faces, settings.max_abs_coordinate)
    timings["load"] = time.perf_counter() - t

    # The Manifold octree seed is keyed like every other random choice (int32 range for the C++).
    wt_seed = derive_seed(settings.seed, "prepare-watertight", ref.category, ref.model_id) % (2**31 - 1)
    # Manifold's tolerances are absolute: a model under ~1e-3 units across (a part in km, a CAD
    # export in mm read as m) is repaired at unit size, one far from the origin centred, and the
    # pre-transform folded into the record.
    c0, k0 = pre_scale(vertices, faces)
    mesh, repair = repair_mesh(
        path, vertices if c0 is None else (vertices - c0) / k0, faces, settings, wt_seed, timings
    )

    t = time.perf_counter()
    c1, s1 = unit_sphere_transform(mesh.vertices)
    center, scale = (c1, s1) if c0 is None else (c0 + c1 * k0, s1 * k0)
    # Quantize to float32 (what the PLY stores) before sampling so samples lie on the stored mesh.
    norm_v = apply_transform(mesh.vertices, c1, s1).astype(np.float32).astype(np.float64)
    final = trimesh.Trimesh(norm_v, mesh.faces, process=False)
    timings["normalize"] = time.perf_counter() - t

    t = time.perf_counter()
    lines = line_mesh(vertices, faces, center, scale, settings.max_line_faces)
    timings["line_mesh"] = time.perf_counter() - t

    t = time.perf_counter()
    samples = sample_surface(final, settings.n_samples, rng_for(settings.seed, "prepare", ref.category, ref.model_id))
    timings["sample"] = time.perf_counter() - t

    side = _read_sidecar(path)
    labelled = None
    if side is None and parts is not None:
        t = time.perf_counter()
        labelled = segmentation_labels(
            path,
            vertices,
            faces,
            ref.model_id,
            parts,
            samples,
            center,
            scale,
            rng_for(settings.seed, "prepare-parts", ref.category, ref.model_id),
        )
        timings["part_labels"] = time.perf_counter() - t

    t = time.perf_counter()
    write_ply(out_dir / MESH_FILE, final.vertices, final.faces)
    write_ply(out_dir / LINE_MESH_FILE, lines.vertices, lines.faces)
    write_npy(out_dir / SAMPLES_FILE, samples)
    if labelled is not None:
        write_npy(out_dir / SAMPLE_PARTS_FILE, labelled[1])
    timings["write"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start

    fields = {
        "category": ref.category,
        "model_id": ref.model_id,
        "source": {"kind": ref.source, "path": str(path), "sha256": sha},
        "normalization": {"center": center.tolist(), "scale": scale},
        "faces": {"input": int(len(faces)), "watertight": repair["watertight_faces"], "output": int(len(final.faces))},
        "vertices": {"input": int(len(vertices)), "output": int(len(final.vertices))},
        "bodies": int(final.body_count),
        "line_mesh": {"faces": int(len(lines.faces)), "vertices": int(len(lines.vertices))},
        "method": {
            **METHOD,
            "resolution": repair["resolution"],
            "attempts": repair["attempts"],
            "rejected_attempts": repair["rejected"],
            "max_faces": settings.max_faces,
        },
        "refinements": repair["refinements"],
        "n_samples": int(len(samples)),
        "files": {"mesh": MESH_FILE, "line_mesh": LINE_MESH_FILE, "samples": SAMPLES_FILE},
        "settings": dataclasses.asdict(settings),
        "timings": {k: round(v, 4) for k, v in timings.items()},
    }
    if side is not None:
        fields.update(_sidecar_fields(side, center, scale))
    elif labelled is not None:
        fields.update(labelled[0])
        fields["files"]["sample_parts"] = SAMPLE_PARTS_FILE
    return fields


def prepare_batch(
    refs: list[ModelRef],
    stage_dir: Path,
    settings: PrepareSettings,
    progress: Progress = None,
    parts: PartLabelSettings | None = None,
) -> list[dict]:
    """Prepare every model not yet done (pipeline.core.model_loop: a bad model is recorded as
    failed, a storage or environment error fails the batch); ``parts`` as in ``prepare_files``."""
    jobs = [
        ModelJob(r.category, r.model_id, r.path, r, failed_fields={"source": {"kind": r.source, "path": str(r.path)}})
        for r in refs
    ]
    return run_models(
        "prepare", stage_dir, jobs, lambda job, folder: prepare_files(job.item, folder, settings, parts), progress
    )
