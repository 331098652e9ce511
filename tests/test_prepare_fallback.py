"""A refinement never costs a model: a step after the envelope whose output fails the check is
undone and the path recorded; game-mesh strip joins do not poison the pull; a model far from the
origin builds like the same model at it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import point_cloud_utils as pcu
import pytest
import trimesh

import pipeline.prepare.refine as refine
from pipeline.core.records import ModelRef, read_record
from pipeline.prepare.batch import PrepareSettings, pre_scale, prepare_model
from pipeline.prepare.watertight import make_watertight, pull_to_source
from pipeline.shapes import generate
from pipeline.sources.mesh_io import load_mesh, read_ply

BOX = (1.0, 0.6, 0.4)


def _write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    # repr keeps every digit: a far-off box must reach the loader exactly
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, float).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces, int).tolist()]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def _box_obj(folder: Path, offset=(0.0, 0.0, 0.0), extents=BOX) -> Path:
    box = trimesh.creation.box(extents)
    return _write_obj(folder / "src" / "box.obj", box.vertices + np.asarray(offset, float), box.faces)


def _prepare(src: Path, out: Path, settings: PrepareSettings = PrepareSettings()) -> dict:
    # one model id for every build, so they share the Manifold seed and compare
    return prepare_model(ModelRef("test", "box", src, "folder"), out, settings)


def _pull_leaving_a_nan(*args):
    # what the pull did on strip joins before it skipped zero-area source faces
    pulled = pull_to_source(*args).copy()
    pulled[0] = np.nan
    return pulled


def test_pull_output_failing_the_check_falls_back_to_the_envelope(tmp_path, monkeypatch):
    src = _box_obj(tmp_path)
    unpulled = _prepare(src, tmp_path / "off", PrepareSettings(pull_to_source=0.0))
    monkeypatch.setattr(refine, "pull_to_source", _pull_leaving_a_nan)
    rec = _prepare(src, tmp_path / "broken")
    assert rec["status"] == "ok"
    assert rec["refinements"] == {
        "pull_to_source": "fell back: not watertight (open or non-manifold edges)",
        "decimate": "not needed",
    }
    assert unpulled["refinements"] == {"pull_to_source": "off", "decimate": "not needed"}
    assert rec["method"]["attempts"] == 1  # the fallback is not a coarser retry
    # falling back is exactly the build without the pull
    assert (tmp_path / "broken" / "mesh.ply").read_bytes() == (tmp_path / "off" / "mesh.ply").read_bytes()


def test_decimation_failing_the_check_costs_the_attempt_not_the_model(tmp_path, monkeypatch):
    def decimate_opening_a_hole(vertices, faces, max_faces):
        return vertices, faces[: max_faces - 1]

    monkeypatch.setattr(refine, "decimate", decimate_opening_a_hole)
    # a 2000 envelope of the box has 11072 faces, a 1000 one 2864: only the first needs decimating
    rec = _prepare(_box_obj(tmp_path), tmp_path / "out", PrepareSettings(resolution=2000, max_faces=5000))
    assert rec["status"] == "ok" and rec["method"]["resolution"] == 1000
    rejected = rec["method"]["rejected_attempts"]
    assert [r["resolution"] for r in rejected] == [2000]
    assert rejected[0]["refinements"]["decimate"].startswith("fell back: not watertight")
    assert "11072 faces after decimation > max_faces 5000" in rejected[0]["problems"]
    assert rec["refinements"] == {"pull_to_source": "applied", "decimate": "not needed"}


def test_an_invalid_envelope_is_no_fallback():
    box = trimesh.creation.box(BOX)
    v, f = make_watertight(box.vertices, box.faces, 1000, 0)
    out = refine.refine_envelope(v, f[1:], box.vertices, box.faces, PrepareSettings())  # one face missing
    assert out.mesh is None
    assert out.problems == ["not watertight (open or non-manifold edges)"]
    assert out.paths == {"pull_to_source": "fell back: not watertight (open or non-manifold edges)"}


def test_strip_joins_in_the_source_do_not_poison_the_pull(tmp_path):
    # Triangle strips (TORCS's AC3D bodies) join with zero-area faces that repeat a vertex; their
    # closest points are NaN, and NaN vertices were cut out of every pulled envelope.
    box = trimesh.creation.box(BOX)
    faces = np.vstack([box.faces, box.faces[:, [0, 0, 1]], box.faces[:, [1, 2, 2]]])
    v, f = make_watertight(box.vertices, faces, 1000, 0)
    pulled = pull_to_source(v, f, box.vertices, faces, 0.9)
    assert np.isfinite(pulled).all()
    dist = [pcu.closest_points_on_mesh(p, box.vertices, box.faces.astype(np.int32))[0] for p in (v, pulled)]
    assert np.median(dist[1]) < 0.2 * np.median(dist[0])
    rec = _prepare(_write_obj(tmp_path / "src" / "box.obj", box.vertices, faces), tmp_path / "out")
    assert rec["refinements"]["pull_to_source"] == "applied"


@pytest.mark.parametrize(
    "offset,extents",
    [((9.9e4, 0.0, 0.0), (1.0, 1.0, 1.0)), ((9.9e4, 9.9e4, 9.9e4), BOX), ((-9.9e4, -9.9e4, -9.9e4), (0.1, 0.1, 0.1))],
    ids=["unit-box-x", "box-xyz", "small-box-negative"],
)
def test_a_box_far_from_the_origin_builds_as_it_does_at_the_origin(tmp_path, offset, extents):
    # At 1e5 units out the signed volume cancelled to noise: "non-positive enclosed volume"
    far = _prepare(_box_obj(tmp_path / "far", offset, extents), tmp_path / "far" / "out")
    near = _prepare(_box_obj(tmp_path / "near", extents=extents), tmp_path / "near" / "out")
    assert far["status"] == "ok" and far["refinements"]["pull_to_source"] == "applied"
    # the same solid (not the same bits: the far box's corners are not exact after centring)
    moved = np.asarray(near["normalization"]["center"]) + offset
    assert np.allclose(far["normalization"]["center"], moved, rtol=0, atol=1e-3 * max(extents))
    assert far["normalization"]["scale"] == pytest.approx(near["normalization"]["scale"], rel=1e-3)
    solids = [trimesh.Trimesh(*read_ply(tmp_path / w / "out" / "mesh.ply"), process=False) for w in ("far", "near")]
    assert solids[0].is_watertight and solids[0].volume == pytest.approx(solids[1].volume, rel=1e-3)
    assert read_record(tmp_path / "far" / "out")["method"]["attempts"] == 1


def test_procedural_models_are_repaired_where_they_are_and_refined_as_before(tmp_path):
    model = generate("car", 0)
    src = tmp_path / "src" / "00000.obj"
    src.parent.mkdir(parents=True)
    model.write(src)
    vertices, faces = load_mesh(src)
    assert pre_scale(vertices, faces) == (None, 1.0)  # no pre-transform: the same arrays as before
    rec = prepare_model(ModelRef("car", "00000", src, "procedural"), tmp_path / "out", PrepareSettings())
    assert rec["refinements"] == {"pull_to_source": "applied", "decimate": "not needed"}
