"""Watertight repair (Huang et al. 2018, "Robust Watertight Manifold Surface Generation") and
decimation to a bounded face count.

The Manifold method voxelizes the input in an octree, flood-fills from outside and extracts the
outer envelope, so it closes holes and fuses intersecting parts at the cost of an inflation of
about one octree cell. ``pull_to_source`` then moves the envelope most of the way back onto the
source surface, which lets a coarse (cheap) octree give a closer envelope than a fine one alone.
A dense envelope is decimated after.
"""

from __future__ import annotations

import numpy as np
import point_cloud_utils as pcu
import pymeshlab
import trimesh

from pipeline.prepare.mesh_checks import SurfaceFacts, surface_facts


def make_watertight(
    vertices: np.ndarray, faces: np.ndarray, resolution: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Manifold envelope of a triangle soup; ``resolution`` is the target octree leaf count.

    A fixed seed makes the result deterministic (the library's default, -1, is random).
    """
    v, f = pcu.make_mesh_watertight(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int32),
        float(resolution),
        seed=int(seed),
    )
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


# Vertices within PULL_FULL x the envelope's median offset are pulled fully; beyond PULL_NONE x
# they stay: those are the caps Manifold puts over holes, and pulling a cap onto its hole's rim
# would collapse it.
PULL_FULL = 2.0
PULL_NONE = 3.0
# A face whose normal turns by more than ~78 degrees while pulling is folding over; its vertices
# are pulled less (halved per round, then not at all).
FOLD_COS = 0.2
FOLD_ROUNDS = 8


def pull_to_source(
    env_vertices: np.ndarray,
    env_faces: np.ndarray,
    src_vertices: np.ndarray,
    src_faces: np.ndarray,
    fraction: float,
) -> np.ndarray:
    """Envelope vertices moved ``fraction`` of the way to their closest point on the source.

    Connectivity is unchanged, so the envelope stays closed. For a vertex outside the solid the
    closest source point is always on the outer surface (any interior face lies behind it), so
    the faces buried inside fused parts never attract it. ``fraction`` < 1 keeps the two sides of
    a thin wall apart: at 1 they would meet on the wall (measured: no longer watertight).
    """
    if fraction <= 0.0:
        return env_vertices
    sv = np.ascontiguousarray(src_vertices, dtype=np.float64)
    sf = _faces_with_area(sv, np.ascontiguousarray(src_faces, dtype=np.int32))
    if len(sf) == 0:
        return env_vertices
    dist, fid, bary = pcu.closest_points_on_mesh(np.ascontiguousarray(env_vertices, dtype=np.float64), sv, sf)
    target = pcu.interpolate_barycentric_coords(sf, fid, bary, sv)
    # a point without a finite answer stays where it is (NaN would be cut out with its faces)
    found = np.isfinite(target).all(axis=1) & np.isfinite(dist)
    if not found.any():
        return env_vertices
    offset = float(np.median(dist[found]))
    if offset <= 0.0:
        return env_vertices
    weight = fraction * np.clip((PULL_NONE * offset - dist) / ((PULL_NONE - PULL_FULL) * offset), 0.0, 1.0)
    step = target - env_vertices
    if not found.all():
        weight[~found], step[~found] = 0.0, 0.0

    def face_normals(v: np.ndarray) -> np.ndarray:
        n = np.cross(v[env_faces[:, 1]] - v[env_faces[:, 0]], v[env_faces[:, 2]] - v[env_faces[:, 0]])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    before = face_normals(env_vertices)
    # a zero-area envelope face has no normal to keep (and would never stop "folding")
    has_normal = np.abs(before).sum(axis=1) > 0
    # Ends: a folding face has a vertex still moving (an unmoved face keeps its normal), and
    # after FOLD_ROUNDS halvings every such vertex is stopped.
    rounds = 0
    while True:
        pulled = env_vertices + weight[:, None] * step
        folding = has_normal & ((before * face_normals(pulled)).sum(axis=1) <= FOLD_COS)
        if not folding.any():
            return pulled
        touched = np.unique(env_faces[folding])
        weight[touched] = weight[touched] * 0.5 if rounds < FOLD_ROUNDS else 0.0
        rounds += 1


def _faces_with_area(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` without the zero-area ones: their barycentric closest points are NaN (triangle
    strips' repeated-vertex joins in game meshes). The array itself when every face has area."""
    tri = vertices[faces]
    has_area = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).any(axis=1)
    return faces if has_area.all() else np.ascontiguousarray(faces[has_area])


def decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge-collapse down to at most ``max_faces`` (no-op when already below)."""
    if len(faces) <= max_faces:
        return vertices, faces
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(vertices), np.ascontiguousarray(faces, dtype=np.int32)))
    # preservetopology keeps the genus and manifoldness; preservenormal forbids face flips, which
    # is what keeps the decimated surface consistently oriented.
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(max_faces), preservetopology=True, preservenormal=True
    )
    ms.meshing_remove_unreferenced_vertices()
    out = ms.current_mesh()
    return np.asarray(out.vertex_matrix(), dtype=np.float64), np.asarray(out.face_matrix(), dtype=np.int64)


def clean_solid(
    vertices: np.ndarray, faces: np.ndarray, min_component_fraction: float
) -> tuple[trimesh.Trimesh, SurfaceFacts]:
    """Merged-vertex mesh with specks dropped and faces oriented outward (positive volume), and
    its :func:`surface_facts` (what the verification asks).

    Components whose area is below ``min_component_fraction`` of the largest one are debris the
    voxelization left behind (a stray triangle becomes a tiny closed blob); they are removed.
    """
    mesh, facts = validated_surface(vertices, faces)
    if facts.faces == 0:
        return mesh, facts
    if facts.face_parts > 1:  # the usual envelope is one part: no split (it copies every part)
        parts = mesh.split(only_watertight=False)
        areas = np.array([p.area for p in parts])
        keep = [p for p, a in zip(parts, areas) if a >= min_component_fraction * areas.max()]
        if len(keep) < len(parts):
            mesh = trimesh.util.concatenate(keep)
            facts = surface_facts(mesh.vertices, mesh.faces)
    # The envelope is one orientation per component; flip components that enclose negative volume.
    if facts.watertight and facts.winding_consistent:
        if facts.bodies > 1:
            comps = mesh.split(only_watertight=False)
            volumes = [surface_facts(c.vertices, c.faces).volume for c in comps]
        else:
            comps, volumes = [mesh], [facts.volume]
        if any(v < 0 for v in volumes):
            fixed = []
            for c, v in zip(comps, volumes):
                if v < 0:
                    c = trimesh.Trimesh(c.vertices, c.faces[:, ::-1], process=False)
                fixed.append(c)
            mesh = trimesh.util.concatenate(fixed) if len(fixed) > 1 else fixed[0]
            facts = surface_facts(mesh.vertices, mesh.faces)
    return mesh, facts


def validated_surface(vertices: np.ndarray, faces: np.ndarray) -> tuple[trimesh.Trimesh, SurfaceFacts]:
    """``trimesh.Trimesh(vertices, faces, process=True, validate=True)`` (the same arrays) and its
    facts, without trimesh's normal fixing where there is nothing to fix: a one-body envelope
    already wound consistently and enclosing positive volume (Manifold's usual output), where
    trimesh would still compute the winding and full mass properties (BENCHMARKS.md)."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if mesh.is_empty:
        return mesh, surface_facts(mesh.vertices, mesh.faces)
    mesh.update_faces(mesh.unique_faces() & mesh.nondegenerate_faces())
    facts = surface_facts(mesh.vertices, mesh.faces)
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    clearly_outward = facts.volume > 1e-6 * extent**3  # no sign doubt against trimesh's own volume
    to_fix = not (facts.winding_consistent and facts.bodies == 1 and (not facts.watertight or clearly_outward))
    if to_fix:
        mesh.fix_normals()
    n_vertices = len(mesh.vertices)
    mesh.remove_infinite_values()
    mesh.merge_vertices()
    if to_fix or len(mesh.vertices) != n_vertices:  # else the same surface, the same facts
        facts = surface_facts(mesh.vertices, mesh.faces)
    return mesh, facts
