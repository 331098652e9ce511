import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera  # noqa: E402

from train.export.iges import read_iges
from train.fit import FitSettings, save_checkpoint
from train.interpolate import interpolate
from train.model import SketchToPatches
from train.predict import predict
from train.templates import load_template, load_template_file


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """An untrained-but-perturbed network checkpoint (predictions differ per sketch)."""
    d = tmp_path_factory.mktemp("ck")
    torch.manual_seed(0)
    t = load_template("sphere24")
    model = SketchToPatches(t.initial_params())
    with torch.no_grad():
        model.out.weight.normal_(0, 0.02)
    model.eval()
    s = FitSettings(dataset="-", category="knife", template="sphere24", out=str(d), image_size=32)
    save_checkpoint(d / "checkpoint.pt", model, torch.optim.Adam(model.parameters()), 0, s, t)
    sketches = []
    for i, half in enumerate(([1, 0.3, 0.2], [0.3, 1, 0.3])):
        h = np.array(half) / np.linalg.norm(half)
        cv2.imwrite(str(d / f"s{i}.png"), box_sketch(h, camera(30, 20, 32), 32, 1))
        sketches.append(str(d / f"s{i}.png"))
    return d / "checkpoint.pt", sketches


def test_predict_writes_all_exports(checkpoint, tmp_path):
    ck, sketches = checkpoint
    res = predict(ck, sketches[:1], tmp_path)
    assert res["mesh"]["watertight"]
    mesh = trimesh.load(tmp_path / "mesh.obj", process=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    patches = np.load(tmp_path / "patches.npy")
    t = load_template_file(tmp_path / "patches.json")
    again = t.patches_from_params(t.initial_params(torch.float64)[None])[0].numpy()
    assert np.abs(again - patches).max() < 1e-5
    surf = read_iges(tmp_path / "patches.igs")
    assert len(surf) == 24
    for p in (tmp_path / "quads.obj", tmp_path / "render.png"):
        assert p.stat().st_size > 0


def test_interpolation_endpoints_equal_the_inputs(checkpoint, tmp_path):
    ck, (a, b) = checkpoint
    res = interpolate(ck, [a], [b], tmp_path, steps=3, alpha=4.0)
    for space in ("patch", "latent"):
        params = res["params"][space]
        assert params.shape == (3, 366)
        assert not np.allclose(params[0], params[-1])
    from train.fit import load_run
    from train.predict import load_sketches

    model = load_run(ck).model
    with torch.no_grad():
        pa, pb = (model(load_sketches([s], 32).tensor)[0].numpy() for s in (a, b))
    for space in ("patch", "latent"):
        assert np.allclose(res["params"][space][0], pa, atol=1e-6) and np.allclose(
            res["params"][space][-1], pb, atol=1e-6
        )
    assert sorted(p.name for p in tmp_path.glob("latent_*.obj")) == ["latent_00.obj", "latent_01.obj", "latent_02.obj"]


@pytest.mark.parametrize("guard", [True, False])
def test_predict_with_a_part_switched_off_exports_a_closed_mesh(tmp_path, guard):
    """`predict --part guard=off` swaps the guard's patches for its closing patches: no holes
    (the knife template: small, so the full export stays fast)."""
    t = load_template("knife")
    model = SketchToPatches(t.initial_params())  # zero last layer: predicts the template itself
    model.eval()
    s = FitSettings(dataset="-", category="knife", template="knife", out=str(tmp_path), image_size=32)
    save_checkpoint(tmp_path / "checkpoint.pt", model, torch.optim.Adam(model.parameters()), 0, s, t)
    sketch = tmp_path / "s.png"
    cv2.imwrite(str(sketch), box_sketch(np.array([1, 0.3, 0.2]) / 1.06, camera(30, 20, 32), 32, 1))
    res = predict(tmp_path / "checkpoint.pt", [sketch], tmp_path / "out", {"guard": guard})
    assert res["mesh"]["boundary_edges"] == 0 and res["mesh"]["watertight"]
    assert res["patches"] == len(t.active_patches({"guard": guard}))
    assert (res["patches"] < t.num_patches - len(t.closing_patches["guard"]) - len(t.closing_patches["pommel"])) == (
        not guard
    )


def test_interpolation_frames_share_one_mesh_and_strip_shows_verdicts(checkpoint, tmp_path):
    """Every frame of a series has the same faces array (a morph, not a remesh: per-frame counts
    gave 874 then 1098 vertices), and strip.png has one tile per frame, two rows (patch, latent)."""
    from pipeline.core.images import contact_sheet
    from train.interpolate import STRIP_TILE

    ck, (a, b) = checkpoint
    steps = 3
    res = interpolate(ck, [a], [b], tmp_path, steps=steps, alpha=6.0)
    for space in ("patch", "latent"):
        meshes = [trimesh.load(tmp_path / f"{space}_{k:02d}.obj", process=False) for k in range(steps)]
        for m in meshes[1:]:
            assert np.array_equal(m.faces, meshes[0].faces)
            assert len(m.vertices) == len(meshes[0].vertices) == res["mesh"][space]["vertices"]
        assert not np.allclose(meshes[0].vertices, meshes[-1].vertices)  # the shape does move
        assert meshes[0].is_watertight and meshes[-1].is_watertight
        assert len(res["clean"][space]) == steps and all(isinstance(c, bool) for c in res["clean"][space])
    strip = cv2.imread(str(tmp_path / "strip.png"))
    want = contact_sheet([np.zeros((STRIP_TILE, STRIP_TILE, 3), np.uint8)] * 2 * steps, [""] * 2 * steps, cols=steps)
    assert strip.shape[:2] == want.shape[:2]  # `steps` tiles wide, two rows with their labels
    assert (strip < 200).any(axis=-1).mean() > 0.02  # shaded meshes drawn, not a blank sheet


def test_sequence_meshing_keeps_counts_where_per_frame_meshing_changes_them():
    """Frames whose arc lengths grow: per-frame integer programs choose different counts, the
    sequence uses one set, at least each frame's own density (from the longest arc lengths)."""
    from train.export.quadmesh import quad_mesh, quad_mesh_sequence

    t = load_template("sphere24")
    base = t.patches_from_params(t.initial_params(torch.float64)[None])[0].numpy()
    frames = [base * s for s in (1.0, 1.3, 1.6)]
    alone = [quad_mesh(f, alpha=6.0) for f in frames]
    assert len({len(m.vertices) for m in alone}) > 1  # what interpolate did before
    seq = quad_mesh_sequence(frames, alpha=6.0)
    assert all(np.array_equal(m.faces, seq[0].faces) and len(m.vertices) == len(seq[0].vertices) for m in seq)
    assert np.array_equal(seq[0].counts, alone[-1].counts)  # the longest frame's lengths decide
    for m, f in zip(seq, frames):  # each frame's mesh is that frame's patches meshed at the shared counts
        given = quad_mesh(f, counts=seq[0].counts)
        assert np.allclose(m.vertices, given.vertices, atol=1e-12) and np.array_equal(m.faces, given.faces)
        assert trimesh.Trimesh(m.vertices, m.triangles(), process=False).is_watertight
