"""Procedural shapes: every category builds closed, symmetric, deterministic, bounded parts."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import point_cloud_utils as pcu
import pytest
import trimesh
from scipy.spatial import cKDTree

from pipeline.shapes import CATEGORIES, SHAPES_VERSION, generate
from pipeline.sources.layouts import DEFECT_FRACTION

N_PER = 3


def clean(category: str, index: int):
    return generate(category, index, seed=0, defect_fraction=0.0)


@pytest.mark.parametrize("category", CATEGORIES)
def test_category_generates_plausible_model(category):
    m = clean(category, 0)
    assert m.category == category and m.model_id == "00000" and m.defects == []
    assert len(m.parts) >= 2
    v, f = m.merged()
    assert 1500 <= len(f) <= 20000
    extent = v.max(axis=0) - v.min(axis=0)
    assert 0.8 <= extent.max() <= 2.2
    assert [c.label for c in m.cuboids] == [p.label for p in m.parts]
    assert len({p.label for p in m.parts}) == len(m.parts)


@pytest.mark.parametrize("category", CATEGORIES)
def test_parts_closed_and_outward(category):
    for i in range(N_PER):
        for p in clean(category, i).parts:
            mesh = trimesh.Trimesh(p.vertices, p.faces, process=True)
            assert mesh.is_watertight, (category, i, p.label)
            assert mesh.is_winding_consistent, (category, i, p.label)
            assert mesh.volume > 0, (category, i, p.label)


@pytest.mark.parametrize("category", CATEGORIES)
def test_symmetric_across_x0(category):
    for i in range(N_PER):
        v, _ = clean(category, i).merged()
        mirrored = v * np.array([-1.0, 1.0, 1.0])
        dist, _ = cKDTree(v).query(mirrored)
        assert dist.max() < 1e-6, (category, i, dist.max())


@pytest.mark.parametrize("category", CATEGORIES)
def test_cuboids_bound_parts(category):
    m = generate(category, 1, seed=3, defect_fraction=1.0)
    for part, box in zip(m.parts, m.cuboids):
        used = part.vertices[np.unique(part.faces)]
        assert np.all(used >= box.lo - 1e-12) and np.all(used <= box.hi + 1e-12)
        assert np.allclose(used.min(0), box.lo) and np.allclose(used.max(0), box.hi)


def test_deterministic_and_varied():
    for category in CATEGORIES:
        a, b = generate(category, 4, seed=7), generate(category, 4, seed=7)
        assert a.defects == b.defects
        assert len(a.parts) == len(b.parts)
        for pa, pb in zip(a.parts, b.parts):
            assert pa.label == pb.label
            assert np.array_equal(pa.vertices, pb.vertices) and np.array_equal(pa.faces, pb.faces)
        va, _ = clean(category, 4).merged()
        vc, _ = clean(category, 5).merged()
        assert va.shape != vc.shape or not np.allclose(va, vc)
        vs, _ = generate(category, 4, seed=8, defect_fraction=0.0).merged()
        assert va.shape != vs.shape or not np.allclose(va, vs)


def test_optional_parts_vary():
    labels = {c: set() for c in ("airplane", "car", "bottle", "gun", "knife")}
    for c in labels:
        for i in range(12):
            labels[c].add(frozenset(p.label for p in clean(c, i).parts))
        assert len(labels[c]) >= 2, c  # optional parts come and go


def _race_body(model) -> bool:
    """Wider than half its length, and widest over a wheel (flared arches), not mid-car."""
    body = next(p.vertices for p in model.parts if p.label == "body")
    length = np.ptp(body[:, 2])
    wheel_z = np.mean([p.vertices[:, 2].mean() for p in model.parts if p.label.startswith("wheel_front")])
    half_width = lambda z: np.abs(body[np.abs(body[:, 2] - z) < 0.03 * length, 0]).max()  # noqa: E731
    return np.ptp(body[:, 0]) > 0.5 * length and half_width(wheel_z) > 1.04 * half_width(body[:, 2].mean())


def _fighter(model) -> bool:
    """No engines under the wings, and a long wing root (a delta's) swept well back."""
    labels = {p.label for p in model.parts}
    wing = next(p.vertices for p in model.parts if p.label == "wing_r")
    fuselage = next(p.vertices for p in model.parts if p.label == "fuselage")
    root = wing[wing[:, 0] < wing[:, 0].min() + 0.01]
    return not any(lab.startswith("engine") for lab in labels) and np.ptp(root[:, 2]) > 0.3 * np.ptp(fuselage[:, 2])


def test_race_bodies_and_fighters_are_a_fifth_of_their_categories():
    # the real-mesh corpora are race bodies (TORCS) and fighters (GL-117): the procedural sets hold both
    races = sum(_race_body(clean("car", i)) for i in range(60))
    fighters = sum(_fighter(clean("airplane", i)) for i in range(60))
    assert 5 <= races <= 20 and 5 <= fighters <= 20, (races, fighters)


def test_defect_fraction_respected_and_listed():
    n = 80
    damaged = [generate(CATEGORIES[i % 8], i, seed=1, defect_fraction=0.25) for i in range(n)]
    share = sum(bool(m.defects) for m in damaged) / n
    assert 0.1 <= share <= 0.45
    kinds = {d.split(":")[0] for m in damaged for d in m.defects}
    assert kinds == {"holes", "flipped_faces", "duplicate_faces", "internal_faces"}
    assert all(not generate(CATEGORIES[i % 8], i, seed=1, defect_fraction=0.0).defects for i in range(16))


def test_defects_really_damage_the_mesh():
    found = set()
    for i in range(60):
        m = generate("mug", i, seed=2, defect_fraction=1.0)
        clean_m = generate("mug", i, seed=2, defect_fraction=0.0)
        for d in m.defects:
            kind, label = d.split(":")
            part = next(p for p in m.parts if p.label == label)
            ref = next(p for p in clean_m.parts if p.label == label)
            mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
            if sum(x.endswith(":" + label) for x in m.defects) > 1:
                continue  # two defects on one part: effects mix
            if kind == "holes":
                assert len(part.faces) < len(ref.faces)
            elif kind == "duplicate_faces":
                assert len(np.unique(np.sort(part.faces, axis=1), axis=0)) < len(part.faces)
            elif kind == "internal_faces":
                assert len(part.vertices) == len(ref.vertices) + 4
                # in the material (the cup's wall), not floating in the hollow: negative signed
                # distance to the undamaged part for every corner of the quad
                sd = pcu.signed_distance_to_mesh(part.vertices[-4:], ref.vertices, ref.faces)[0]
                assert (sd < 0).all(), (i, label, sd)
            elif kind == "flipped_faces" and len(m.defects) == 1:
                assert not mesh.is_winding_consistent
            found.add(kind)
    assert found == {"holes", "flipped_faces", "duplicate_faces", "internal_faces"}


def test_clean_shape_unchanged_by_defect_fraction():
    a = generate("car", 2, seed=0, defect_fraction=0.0)
    b = generate("car", 2, seed=0, defect_fraction=0.5)
    if not b.defects:
        b = generate("car", 2, seed=0, defect_fraction=1.0)
    damaged = {d.split(":")[1] for d in b.defects}
    for pa, pb in zip(a.parts, b.parts):
        if pa.label not in damaged:
            assert np.array_equal(pa.vertices, pb.vertices)


def test_a_new_generator_writes_to_a_new_source_folder(monkeypatch):
    """Models of an older generator in a work folder are never read as this one's."""
    import pipeline.shapes
    from pipeline.sources.layouts import procedural_source_dir

    now = procedural_source_dir(Path("w"), 0)
    monkeypatch.setattr(pipeline.shapes, "SHAPES_VERSION", pipeline.shapes.SHAPES_VERSION + 1)
    assert procedural_source_dir(Path("w"), 0) != now


# What each SHAPES_VERSION generates, fingerprinted: the version keys the procedural source folder,
# so a generator change that moves any vertex without a new version would let a work folder's
# cached models of the old generator pass for the new one's. Vertices are rounded to 1e-5, yet
# the same generator still fingerprints apart on some CPU kinds (numpy's sin/cos differ in the
# last bits between instruction sets, and a few of those differences grow past the rounding), so
# each version lists the fingerprint of every CPU kind it was seen on; a generator change moves
# every kind's.
SHAPES_FINGERPRINTS = {
    3: {
        "121d5a80394e641e",  # the reference machine
        "21323b80178421aa",  # an AMD EPYC with AVX2 and no AVX-512 (2026-12-07)
    }
}


def _generator_fingerprint(count: int = 40) -> str:
    h = hashlib.sha256()
    for category in CATEGORIES:
        for index in range(count):
            for part in generate(category, index, seed=0, defect_fraction=DEFECT_FRACTION).parts:
                h.update(part.label.encode())
                h.update((np.round(part.vertices.astype(np.float64), 5) + 0.0).tobytes())  # + 0.0: no -0.0
                h.update(np.asarray(part.faces, np.int64).tobytes())
    return h.hexdigest()[:16]


def test_generator_output_belongs_to_its_version():
    found = _generator_fingerprint()
    assert found in SHAPES_FINGERPRINTS.get(SHAPES_VERSION, set()), (
        f"the procedural models changed (fingerprint {found}): raise SHAPES_VERSION in "
        f"pipeline/shapes/__init__.py and add {{new version: {{{found!r}}}}} to SHAPES_FINGERPRINTS "
        "(or, if the generator did not change, this CPU kind's fingerprint to its version's set)"
    )


def test_unknown_category():
    with pytest.raises(ValueError):
        generate("teapot", 0)
