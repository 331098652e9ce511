"""Multi-part meshes are kept: every body above the debris threshold stays in the prepared mesh,
its count is recorded, and a corpus of detached-part models builds without failures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from pipeline.core.records import ModelRef, read_record
from pipeline.core.schema import LINE_MESH_FILE, MESH_FILE
from pipeline.prepare.batch import PrepareSettings, prepare_batch
from pipeline.shapes import DETACHABLE, generate
from pipeline.sources.mesh_io import read_ply

FAST = PrepareSettings(resolution=3000, max_faces=6000)


def _car_with_loose_wheels() -> tuple[trimesh.Trimesh, list[np.ndarray]]:
    body = trimesh.creation.box((1.0, 0.3, 2.0)).apply_translation([0, 0.35, 0])
    wheels = []
    for x in (-0.7, 0.7):
        for z in (-0.6, 0.6):
            w = trimesh.creation.cylinder(0.2, 0.15, sections=32)
            w.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
            wheels.append(w.apply_translation([x, 0.2, z]))  # 0.125 clear of the body's side (over a cell)
    return trimesh.util.concatenate([body, *wheels]), [w.bounds for w in [body, *wheels]]


def _bottle_with_floating_cap() -> tuple[trimesh.Trimesh, list[np.ndarray]]:
    body = trimesh.creation.cylinder(0.3, 1.2, sections=40)
    body.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    cap = trimesh.creation.cylinder(0.15, 0.15, sections=32)
    cap.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    cap.apply_translation([0, 0.6 + 0.06 + 0.075, 0])
    return trimesh.util.concatenate([body, cap]), [body.bounds, cap.bounds]


def _write(tmp: Path, name: str, mesh: trimesh.Trimesh) -> Path:
    path = tmp / "src" / f"{name}.obj"
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


def test_detached_parts_stay_separate_bodies_with_samples_on_each(tmp_path):
    cases = {"car": _car_with_loose_wheels(), "bottle": _bottle_with_floating_cap()}
    refs = [ModelRef("test", name, _write(tmp_path, name, mesh), "folder") for name, (mesh, _) in cases.items()]
    records = prepare_batch(refs, tmp_path / "stage", FAST)
    for rec, (name, (_, boxes)) in zip(records, cases.items()):
        assert rec["status"] == "ok", rec.get("error")
        assert rec["bodies"] == len(boxes)
        folder = tmp_path / "stage" / "test" / name
        v, f = read_ply(folder / MESH_FILE)
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.body_count == len(boxes) and mesh.is_watertight and mesh.is_winding_consistent
        assert all(body.volume > 0 for body in mesh.split(only_watertight=False))  # each outward
        lv, lf = read_ply(folder / LINE_MESH_FILE)
        assert trimesh.Trimesh(lv, lf).body_count == len(boxes)
        # every part carries training samples (the envelope inflates by about a cell)
        pts = np.load(folder / "samples.npy")[:, :3].astype(np.float64)
        center, scale = np.array(rec["normalization"]["center"]), rec["normalization"]["scale"]
        for lo, hi in boxes:
            lo, hi = (lo - center) / scale - 0.05, (hi - center) / scale + 0.05
            assert ((pts >= lo) & (pts <= hi)).all(axis=1).sum() > 100


def test_generator_detaches_parts_in_some_models_by_default():
    flags = {cat: [generate(cat, i).detached for i in range(20)] for cat in DETACHABLE}
    for cat, f in flags.items():
        assert 0 < sum(f) < 20, cat  # some models of each detachable category, not all
    assert not any(generate("mug", i).detached for i in range(10))
    box = {}
    for cat in DETACHABLE:
        m = generate(cat, 0, detached_fraction=1.0)
        assert m.sidecar()["detached"] is True
        box[cat] = {c.label: c for c in m.cuboids}
        attached = generate(cat, 0, detached_fraction=0.0)
        assert not attached.detached
        assert attached.parts[0].vertices.tobytes() == m.parts[0].vertices.tobytes()  # same shape
    car, plane, bottle = box["car"], box["airplane"], box["bottle"]
    assert car["wheel_front_r"].lo[0] > car["body"].hi[0] and car["wheel_rear_l"].hi[0] < car["body"].lo[0]
    assert plane["engine0_r"].hi[1] < plane["pylon0_r"].lo[1]
    assert bottle["cap"].lo[1] > bottle["neck"].hi[1]


@pytest.mark.parametrize("category", DETACHABLE)
def test_detached_corpus_builds_without_body_count_failures(tmp_path, category):
    refs = []
    for i in range(2):
        m = generate(category, i, seed=4, detached_fraction=1.0)
        path = tmp_path / "src" / category / f"{m.model_id}.obj"
        m.write(path)
        refs.append(ModelRef(category, m.model_id, path, "procedural"))
    records = prepare_batch(refs, tmp_path / "stage", PrepareSettings())
    for ref, rec in zip(refs, records):
        assert rec["status"] == "ok", rec.get("error")
        assert rec["bodies"] > 1, (ref.model_id, rec["bodies"])
        assert read_record(tmp_path / "stage" / category / ref.model_id)["bodies"] == rec["bodies"]
