import numpy as np
import trimesh

from train.export.obj import edge_report, obj_text
from train.export.quadmesh import quad_mesh

# (a, b) axes per outward normal so that e_a x e_b = normal
AXES = {(0, 1): (1, 2), (0, -1): (2, 1), (1, 1): (2, 0), (1, -1): (0, 2), (2, 1): (0, 1), (2, -1): (1, 0)}


def line(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.stack([p + (q - p) * k / 3.0 for k in range(4)])


def face_patch(axis: int, sign: int, half: np.ndarray, a_rng=(-1, 1), b_rng=(-1, 1)) -> np.ndarray:
    a, b = AXES[(axis, sign)]

    def corner(ua, ub):
        p = np.zeros(3)
        p[axis], p[a], p[b] = sign, ua, ub
        return p * half

    p00, p10 = corner(a_rng[0], b_rng[0]), corner(a_rng[1], b_rng[0])
    p11, p01 = corner(a_rng[1], b_rng[1]), corner(a_rng[0], b_rng[1])
    return np.stack([line(p00, p10), line(p10, p11), line(p11, p01), line(p01, p00)])


def box_with_junctions(half=np.array([1.0, 0.5, 0.25])) -> np.ndarray:
    """A box whose top (+y) face is two patches split at x = 0: the front/back faces' top edges
    are parent curves with two junction children each."""
    patches = [face_patch(ax, sg, half) for (ax, sg) in AXES if (ax, sg) != (1, 1)]
    patches.append(face_patch(1, 1, half, b_rng=(-1, 0)))  # +y face: a = z, b = x
    patches.append(face_patch(1, 1, half, b_rng=(0, 1)))
    return np.stack(patches)


def test_quad_mesh_is_watertight_with_compatible_counts():
    patches = box_with_junctions()
    qm = quad_mesh(patches, alpha=6.0)
    g = qm.graph
    assert len(g.children) == 2 and all(len(k) == 2 for k in g.children.values())
    for parent, kids in g.children.items():
        assert qm.counts[parent] == sum(qm.counts[c] for c, _, _ in kids)
    for sides in g.sides:
        assert qm.counts[sides[0]] == qm.counts[sides[2]] and qm.counts[sides[1]] == qm.counts[sides[3]]
    assert (qm.counts >= 1).all()
    assert edge_report(qm.faces)["watertight"]
    mesh = trimesh.Trimesh(qm.vertices, qm.triangles(), process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert np.isclose(mesh.volume, 2.0 * 1.0 * 0.5)
    # counts follow arc length: the 2-long x edges get about 2 * alpha... (junction sums allowed)
    assert np.abs(np.abs(qm.vertices) - [1.0, 0.5, 0.25]).min(axis=1).max() < 1e-9


def test_triangle_obj_text_has_groups_and_one_based_indices():
    qm = quad_mesh(box_with_junctions(), alpha=3.0)
    text = obj_text(qm.vertices, qm.faces, qm.patch_of_face)
    assert text.count("\nf ") + text.startswith("f ") == len(qm.faces)
    assert "g patch_0" in text and "g patch_6" in text
    idx = [int(t) for line in text.splitlines() if line.startswith("f ") for t in line.split()[1:]]
    assert min(idx) == 1 and max(idx) == len(qm.vertices)
