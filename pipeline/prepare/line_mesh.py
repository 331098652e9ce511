"""The mesh the renderer draws: the source's own surface, so its sharp edges stay sharp.

The watertight envelope (pipeline.prepare.watertight) is what the training targets are sampled on, but
its voxel-based repair rounds creases off. Freestyle needs no closed solid, only a surface it can
read edge natures from, so the drawing is made from the source mesh under the prepared mesh's
normalization, cleaned of what makes Freestyle draw lines the object does not have:

- duplicate vertices (split UV seams, separately exported triangles) → merged, else every seam
  is a border line;
- degenerate (zero-area) faces and duplicate faces (either winding) → removed, else they make
  spurious creases and z-fighting;
- inconsistent winding → made consistent and outward per connected part, else flipped faces
  read as 180° creases and break smooth shading.

Meshes above ``max_faces`` are decimated with a quadric that keeps borders and sharp edges
(pymeshlab, planar-aware), so render time stays bounded; smaller ones have their long sliver
faces split (see ``_split_long_edges``). Holes are left open: their rims are
real borders of the source and are drawn as such.
"""

from __future__ import annotations

import numpy as np
import pymeshlab
import trimesh

from pipeline.core.normalize import apply_transform


def line_mesh(
    vertices: np.ndarray, faces: np.ndarray, center: np.ndarray, scale: float, max_faces: int
) -> trimesh.Trimesh:
    """The cleaned source surface in the normalized frame (``(v - center) / scale``)."""
    v = apply_transform(vertices, center, scale)
    # process=True merges vertices that coincide (to trimesh's 1e-8 grid) and drops NaN faces.
    mesh = trimesh.Trimesh(v, np.asarray(faces, np.int64), process=True, validate=False)
    keep = mesh.nondegenerate_faces(height=1e-9)
    mesh.update_faces(keep)
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) > max_faces:
        mesh = _decimate_keeping_edges(mesh, max_faces)
    else:
        mesh = _split_long_edges(mesh, max_faces)
    # Consistent winding through shared edges, then each body turned outward (by signed volume,
    # meaningful also for nearly-closed parts); Freestyle's creases use the face normals.
    if not mesh.is_winding_consistent:
        mesh = _wound_coherently(mesh)
    _turn_bodies_outward(mesh)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def _turn_bodies_outward(mesh: trimesh.Trimesh) -> None:
    """``trimesh.repair.fix_inversion(mesh, multibody=True)``: the faces of every closed,
    consistently wound body with negative volume flipped, in place. The same bodies, tests and
    volume (the first term of trimesh's mass properties, summed the same way), without the nine
    inertia terms trimesh computes and drops (~2/3 of its time)."""
    groups = trimesh.graph.connected_components(mesh.face_adjacency)
    tri, cross = mesh.triangles, mesh.triangles_cross
    face_edges = mesh.edges.reshape((-1, 6))
    flip = np.zeros(len(mesh.faces), bool)
    for face_index in groups:
        if len(face_index) < 4:  # no closed body has fewer faces than a tetrahedron
            continue
        tight, wound = trimesh.graph.is_watertight(face_edges[face_index].reshape((-1, 2)))
        if not (tight and wound):
            continue
        t = tri[face_index]
        if (cross[face_index, 0] * (t[:, 0, 0] + t[:, 1, 0] + t[:, 2, 0])).sum() / 6.0 < 0.0:
            flip[face_index] = True
    if flip.any():
        mesh.faces[flip] = np.fliplr(mesh.faces[flip])


def _wound_coherently(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Faces re-oriented to agree with their neighbours (pymeshlab: ~100× trimesh's fix_winding,
    which walks the faces in Python); trimesh's walk when meshlab refuses the mesh."""
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(mesh.vertices), np.ascontiguousarray(mesh.faces, np.int32)))
    try:
        ms.meshing_re_orient_faces_coherently()
    except pymeshlab.PyMeshLabException:
        trimesh.repair.fix_winding(mesh)
        return mesh
    out = ms.current_mesh()
    return trimesh.Trimesh(out.vertex_matrix(), out.face_matrix(), process=False)


# Longest edge allowed (model radius 1), tried in order while the face budget allows.
MAX_EDGE_STEPS = (0.1, 0.2, 0.4)


def _split_long_edges(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """Midpoint-subdivide faces with long edges (the shape is unchanged, no new creases).

    Freestyle's smooth silhouettes (zero crossings of the interpolated n·v) lose their visibility
    on long sliver triangles, as CAD tessellations of revolved and lofted surfaces have: whole
    stretches of a mug's outline vanished. Shorter edges fix it; the finest step that stays
    within ``max_faces`` is used.
    """
    for max_edge in MAX_EDGE_STEPS:
        if mesh.edges_unique_length.max(initial=0.0) <= max_edge:
            return mesh
        v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge, max_iter=8)
        if len(f) <= max_faces:
            return trimesh.Trimesh(v, f, process=True)
    return mesh


def _decimate_keeping_edges(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(mesh.vertices), np.ascontiguousarray(mesh.faces, np.int32)))
    # boundaries kept and planar regions simplified first: the quadric then spends its error on
    # flat areas, and sharp edges (high quadric cost) survive.
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(max_faces),
        preserveboundary=True,
        boundaryweight=2.0,
        preservenormal=True,
        planarquadric=True,
        qualitythr=0.3,
    )
    ms.meshing_remove_unreferenced_vertices()
    out = ms.current_mesh()
    return trimesh.Trimesh(out.vertex_matrix(), out.face_matrix(), process=True)


def sharp_edges(mesh: trimesh.Trimesh, turn_deg: float) -> np.ndarray:
    """(k, 2) vertex pairs of edges whose two faces' normals turn by more than ``turn_deg``."""
    angles = mesh.face_adjacency_angles
    return mesh.face_adjacency_edges[np.degrees(angles) > turn_deg]


def border_edges(mesh: trimesh.Trimesh) -> np.ndarray:
    """(k, 2) vertex pairs of edges used by exactly one face."""
    edges = mesh.edges_sorted
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    return uniq[counts == 1]
