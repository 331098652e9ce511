"""Preparation on hand-made meshes: watertight output, normalization, outward normals,
determinism, resume, and a clear recorded error for every kind of bad input."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import point_cloud_utils as pcu
import pytest
import trimesh

from pipeline.core.records import ModelRef, read_record
from pipeline.prepare.batch import PrepareSettings, prepare_batch, prepare_model
from pipeline.prepare.mesh_checks import surface_facts
from pipeline.prepare.watertight import validated_surface
from pipeline.sources.mesh_io import read_ply

FAST = PrepareSettings(resolution=3000, max_faces=4000, n_samples=16384)


def _leaky_assembly() -> trimesh.Trimesh:
    """Intersecting parts (fuselage, thin wing, box) with holes punched: a ShapeNet-like soup."""
    body = trimesh.creation.cylinder(0.12, 1.6, sections=48)
    wing = trimesh.creation.box((1.8, 0.015, 0.3))  # thin part that must survive
    box = trimesh.creation.box((0.5, 0.3, 0.4))
    soup = trimesh.util.concatenate([body, wing, box]).subdivide().subdivide()
    keep = np.arange(len(soup.faces)) % 53 != 0
    soup.update_faces(keep)
    soup.apply_translation([3.0, -2.0, 5.0])
    soup.apply_scale(7.0)
    return soup


def _write(tmp: Path, name: str, mesh: trimesh.Trimesh) -> Path:
    path = tmp / "src" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


def _ref(path: Path, model_id: str = "m0", category: str = "test") -> ModelRef:
    return ModelRef(category, model_id, path, "folder")


def assert_prepared(folder: Path, settings: PrepareSettings) -> None:
    """The contract of a prepared model: closed oriented solid in the unit sphere + samples."""
    rec = read_record(folder)
    assert rec["status"] == "ok"
    v, f = read_ply(folder / "mesh.ply")
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.body_count == 1
    assert mesh.volume > 0
    assert len(f) <= settings.max_faces
    assert abs(np.linalg.norm(v, axis=1).max() - 1.0) < 1e-4
    lo, hi = v.min(axis=0), v.max(axis=0)
    assert np.allclose((lo + hi) / 2, 0.0, atol=1e-5)

    samples = np.load(folder / "samples.npy")
    assert samples.dtype == np.float32 and samples.shape == (settings.n_samples, 6)
    assert settings.n_samples >= 16384
    pts, nrm = samples[:, :3].astype(np.float64), samples[:, 3:].astype(np.float64)
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    assert np.linalg.norm(pts, axis=1).max() <= 1.0 + 1e-5
    # Points lie on the surface; a small step along the normal leaves the solid, a step against
    # it enters (point-cloud-utils signed distance: positive outside, an independent check).
    sub = np.random.default_rng(0).choice(len(pts), 500, replace=False)
    eps = 2e-3
    query = np.vstack([pts[sub], pts[sub] + eps * nrm[sub], pts[sub] - eps * nrm[sub]])
    sd, _, _ = pcu.signed_distance_to_mesh(query, v, f.astype(np.int32))
    on, out, inn = np.split(sd, 3)
    assert np.abs(on).max() < 1e-4
    assert (out > 0).mean() > 0.95 and (inn < 0).mean() > 0.9
    # Flux of the position field through a closed outward surface is 3·volume > 0.
    assert (pts * nrm).sum(axis=1).mean() > 0


def test_leaky_assembly_becomes_unit_watertight_solid(tmp_path):
    src = _write(tmp_path, "plane.obj", _leaky_assembly())
    rec = prepare_model(_ref(src), tmp_path / "out", FAST)
    assert_prepared(tmp_path / "out", FAST)
    # The record says where the model came from and how to undo the normalization.
    assert rec["source"]["sha256"] and rec["source"]["path"] == str(src)
    assert rec["faces"]["input"] > 0 and rec["faces"]["output"] <= FAST.max_faces
    assert rec["normalization"]["scale"] > 1.0  # the soup was scaled by 7
    center = np.array(rec["normalization"]["center"])
    assert np.allclose(center, [21.0, -14.0, 35.0], atol=0.5)
    assert set(rec["timings"]) >= {"load", "watertight", "decimate", "sample", "total"}
    # The thin wing survives: the prepared model still spans the wing's length along x.
    v, _ = read_ply(tmp_path / "out" / "mesh.ply")
    assert np.ptp(v[:, 0]) > 1.8


def test_inside_out_input_gets_outward_normals(tmp_path):
    sphere = trimesh.creation.icosphere(3)
    flipped = trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1], process=False)
    src = _write(tmp_path, "inv.ply", flipped)
    prepare_model(_ref(src), tmp_path / "out", FAST)
    assert_prepared(tmp_path / "out", FAST)


def test_decimation_bounds_faces(tmp_path):
    src = _write(tmp_path, "a.obj", _leaky_assembly())
    s = PrepareSettings(resolution=3000, max_faces=1500)
    rec = prepare_model(_ref(src), tmp_path / "out", s)
    assert rec["faces"]["watertight"] > 1500 >= rec["faces"]["output"]
    assert_prepared(tmp_path / "out", PrepareSettings(resolution=3000, max_faces=1500))


def test_preparation_is_byte_deterministic(tmp_path):
    src = _write(tmp_path, "a.obj", _leaky_assembly())
    outs = []
    for run in range(2):
        prepare_model(_ref(src), tmp_path / f"run{run}", FAST)
        outs.append(
            (
                (tmp_path / f"run{run}" / "mesh.ply").read_bytes(),
                (tmp_path / f"run{run}" / "samples.npy").read_bytes(),
                (tmp_path / f"run{run}" / "lines.ply").read_bytes(),
            )
        )
    assert outs[0] == outs[1]
    # A different model id draws different samples (keyed generator, not a global one).
    prepare_model(_ref(src, model_id="other"), tmp_path / "run2", FAST)
    assert (tmp_path / "run2" / "samples.npy").read_bytes() != outs[0][1]


def _bad_inputs(tmp: Path) -> dict[str, tuple[Path, str]]:
    """model id -> (file, words the error reason must contain)."""
    d = tmp / "src"
    d.mkdir(parents=True, exist_ok=True)
    cases = {}
    (d / "garbled.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nend_header\n\x01")
    cases["unreadable"] = (d / "garbled.ply", "unreadable")
    cases["missing"] = (d / "missing.obj", "not found")
    (d / "empty.obj").write_text("# nothing here\n")
    cases["empty"] = (d / "empty.obj", "empty")
    (d / "zero.obj").write_bytes(b"")
    cases["zero_bytes"] = (d / "zero.obj", "empty")
    (d / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 2 3 4\nf 1 4 2\n")
    cases["nan"] = (d / "nan.obj", "NaN")
    (d / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    cases["degenerate"] = (d / "flat.obj", "degenerate")
    big = trimesh.creation.icosphere(4)  # 5120 faces > max_input_faces below
    cases["huge_faces"] = (_write(tmp, "big.ply", big), "huge")
    far = trimesh.creation.box()
    far.apply_translation([1e9, 0, 0])
    cases["huge_coords"] = (_write(tmp, "far.obj", far), "huge")
    # Shattered input: more equal-sized separate pieces than max_bodies (separate parts are kept).
    grains = [trimesh.creation.box((0.2, 0.2, 0.2)).apply_translation([i % 10, i // 10, 0]) for i in range(70)]
    cases["shattered"] = (_write(tmp, "shattered.obj", trimesh.util.concatenate(grains)), "repair failed verification")
    return cases


def test_bad_inputs_are_recorded_and_batch_completes(tmp_path):
    cases = _bad_inputs(tmp_path)
    good = _write(tmp_path, "good.obj", trimesh.creation.icosphere(3))
    refs = [_ref(path, model_id) for model_id, (path, _) in cases.items()]
    refs.insert(4, _ref(good, "good"))  # a good model in the middle must still be prepared
    settings = PrepareSettings(resolution=2000, max_faces=3000, max_input_faces=5000)
    seen = []
    records = prepare_batch(refs, tmp_path / "stage", settings, lambda d, t, m: seen.append((d, t)))
    assert seen[-1] == (len(refs), len(refs))
    by_id = {r["model_id"]: r for r in records}
    assert by_id["good"]["status"] == "ok"
    for model_id, (path, words) in cases.items():
        rec = by_id[model_id]
        assert rec["status"] == "failed", model_id
        assert rec["error"]["path"] == str(path)
        assert words.lower() in rec["error"]["reason"].lower(), (model_id, rec["error"]["reason"])
        # The failure is on disk, so a re-run skips it rather than crashing again.
        assert read_record(tmp_path / "stage" / "test" / model_id)["status"] == "failed"
        assert not (tmp_path / "stage" / "test" / model_id / "mesh.ply").exists()
    assert "70 separate volumes (max 32)" in by_id["shattered"]["error"]["reason"]


def test_batch_skips_finished_models(tmp_path):
    a = _write(tmp_path, "a.obj", trimesh.creation.icosphere(2))
    b = _write(tmp_path, "b.obj", trimesh.creation.box())
    refs = [_ref(a, "a"), _ref(b, "b")]
    stage = tmp_path / "stage"
    prepare_batch(refs[:1], stage, FAST)  # a run "killed" after the first model
    rec_a = stage / "test" / "a" / "record.json"
    mtime = rec_a.stat().st_mtime_ns
    a.unlink()  # if model a were redone it would now fail
    records = prepare_batch(refs, stage, FAST)
    assert [r["status"] for r in records] == ["ok", "ok"]
    assert rec_a.stat().st_mtime_ns == mtime


def test_unexpected_exception_is_recorded(tmp_path):
    src = _write(tmp_path, "a.obj", trimesh.creation.box())
    # An impossible setting makes the sampler raise a plain ValueError deep inside trimesh/numpy
    # (set past PrepareSettings' own check, which a build runs before anything else).
    settings = PrepareSettings(resolution=2000)
    object.__setattr__(settings, "n_samples", -1)
    records = prepare_batch([_ref(src)], tmp_path / "stage", settings)
    assert records[0]["status"] == "failed"
    assert "Error" in records[0]["error"]["reason"]


@pytest.mark.parametrize("ext", ["off", "stl", "glb", "ply"])
def test_other_formats_load(tmp_path, ext):
    src = _write(tmp_path, f"a.{ext}", trimesh.creation.annulus(0.3, 0.6, 0.4))
    prepare_model(_ref(src), tmp_path / "out", FAST)
    assert_prepared(tmp_path / "out", FAST)


def _facts_by_trimesh(mesh: trimesh.Trimesh) -> tuple:
    parts = len(trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces))))
    return mesh.is_watertight, mesh.is_winding_consistent, parts, mesh.body_count, mesh.volume


@functools.cache  # built once for all the parametrized cases (they only read them)
def _surfaces_to_check() -> dict[str, trimesh.Trimesh]:
    box = trimesh.creation.box()
    ball = trimesh.creation.icosphere(2)
    far = trimesh.Trimesh(box.vertices + 3.0, box.faces)
    corner = trimesh.Trimesh(box.vertices + 1.0, box.faces)  # touches `box` at one vertex only
    fin = np.array([[0.5, 0.5, 0.5], [0.5, -0.5, 0.5], [1.5, 0.0, 0.5]])
    i = np.flatnonzero((np.abs(box.vertices - fin[0]).sum(1) < 1e-9) | (np.abs(box.vertices - fin[1]).sum(1) < 1e-9))
    flipped = box.faces.copy()
    flipped[0] = flipped[0, ::-1]
    return {
        "box": box,
        "sphere": ball,
        "inside out": trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False),
        "open": trimesh.Trimesh(box.vertices, box.faces[1:], process=False),
        "one face flipped": trimesh.Trimesh(box.vertices, flipped, process=False),
        "two apart": trimesh.util.concatenate([box, far]),
        "two at a corner": trimesh.Trimesh(
            *trimesh.util.append_faces([box.vertices, corner.vertices], [box.faces, corner.faces]), process=True
        ),
        # a third face on an existing edge: non-manifold
        "fin": trimesh.Trimesh(
            np.vstack([box.vertices, fin[2:]]), np.vstack([box.faces, [[i[0], i[1], len(box.vertices)]]]), process=False
        ),
    }


@pytest.mark.parametrize("name", list(_surfaces_to_check()))
def test_surface_facts_answer_as_trimesh_does(name):
    mesh = _surfaces_to_check()[name]
    facts = surface_facts(mesh.vertices, mesh.faces)
    watertight, winding, parts, bodies, volume = _facts_by_trimesh(mesh)
    assert (facts.watertight, facts.winding_consistent, facts.face_parts, facts.bodies) == (
        watertight,
        winding,
        parts,
        bodies,
    )
    if watertight and winding:  # (otherwise the "volume" depends on the formula; the checks never ask it)
        assert facts.volume == pytest.approx(volume, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("name", list(_surfaces_to_check()))
def test_validated_mesh_is_what_trimesh_validation_gives(name):
    mesh = _surfaces_to_check()[name]
    v = np.vstack([mesh.vertices, mesh.vertices[:3]])  # duplicate vertices and a duplicate face too
    f = np.vstack([mesh.faces, [[len(mesh.vertices), len(mesh.vertices) + 1, len(mesh.vertices) + 2]]])
    ours, facts = validated_surface(v, f)
    theirs = trimesh.Trimesh(v, f, process=True, validate=True)
    assert np.array_equal(ours.vertices, theirs.vertices) and np.array_equal(ours.faces, theirs.faces)
    assert facts == surface_facts(theirs.vertices, theirs.faces)
