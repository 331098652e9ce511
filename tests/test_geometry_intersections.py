import io
import json
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import cv2
import numpy as np
import pymeshlab
import torch

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera  # noqa: E402
from test_export_quadmesh import box_with_junctions, line  # noqa: E402

from train.cli import main
from train.export.quadmesh import patch_intersections, quad_mesh
from train.fit import FitSettings, save_checkpoint
from train.geometry.intersections import candidate_pairs, mesh_intersections
from train.model import SketchToPatches
from train.templates import load_template


def flat_patch(p00, p10, p11, p01) -> np.ndarray:
    p00, p10, p11, p01 = map(np.asarray, (p00, p10, p11, p01))
    return np.stack([line(p00, p10), line(p10, p11), line(p11, p01), line(p01, p00)])


def pushed_sphere() -> np.ndarray:
    """sphere24 with its first corner pushed through the far side (params of point 0 × −1.3)."""
    t = load_template("sphere24")
    params = t.initial_params(torch.float64).clone()
    params[:3] *= -1.3
    return t.patches_from_params(params[None])[0].numpy()


def test_crossing_patches_are_found_and_touching_ones_are_not():
    a = flat_patch([-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0])
    crossing = flat_patch([0.13, -0.5, -1], [0.13, 0.5, -1], [0.13, 0.5, 1], [0.13, -0.5, 1])  # off the grid lines
    apart = crossing + [0, 0, 2.5]
    res = patch_intersections(np.stack([a, crossing, apart]), alpha=6.0)
    assert res.patch_pairs == [(0, 1)] and res.folded_patches == [] and not res.clean
    assert len(res.faces) > 0 and res.summary()["intersecting_patch_pairs"] == 1


def test_closed_template_with_junctions_is_clean():
    # T-junction sides share their (conforming) vertices: touching there is not a crossing
    assert patch_intersections(box_with_junctions(), alpha=6.0).clean
    t = load_template("mug")
    assert patch_intersections(t.patches_from_params(t.initial_params(torch.float64)[None])[0].numpy()).clean


def test_self_intersecting_faces_agree_with_meshlab():
    qm = quad_mesh(pushed_sphere(), alpha=12.0)
    tris = qm.triangles()
    res = mesh_intersections(qm.vertices, tris, np.repeat(qm.patch_of_face, 2))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(qm.vertices, tris))
    ms.compute_selection_by_self_intersections_per_face()
    meshlab = np.nonzero(ms.current_mesh().face_selection_array())[0]
    assert len(res.faces) > 0 and res.faces.tolist() == meshlab.tolist()
    assert len(res.patch_pairs) > 0


def test_predict_flags_an_intersecting_prediction(tmp_path):
    t = load_template("sphere24")
    model = SketchToPatches(t.initial_params()).eval()
    with torch.no_grad():  # an untrained network outputs its bias: make that the pushed sphere
        model.out.bias[:3] *= -1.3
    s = FitSettings(dataset="-", category="x", template="sphere24", out=str(tmp_path), image_size=32)
    save_checkpoint(tmp_path / "ck.pt", model, torch.optim.Adam(model.parameters()), 0, s, t)
    cv2.imwrite(str(tmp_path / "s.png"), box_sketch(np.array([0.6, 0.6, 0.5]), camera(30, 20, 32), 32, 1))
    printed, said = io.StringIO(), io.StringIO()
    with redirect_stdout(printed), redirect_stderr(said):
        main(
            [
                "predict",
                "--checkpoint",
                str(tmp_path / "ck.pt"),
                "--sketch",
                str(tmp_path / "s.png"),
                "--out",
                str(tmp_path / "out"),
                "--units",
                "in",
                "--json",
            ]
        )
    last = said.getvalue().strip().splitlines()[-1]
    assert last.startswith("NOT CLEAN:") and "the CAD kernel finds" in last and "patch pairs" in last
    res = json.loads(printed.getvalue())  # with --json, stdout is JSON only
    assert res == json.loads((tmp_path / "out" / "prediction.json").read_text())
    assert res["cad_kernel"]["self_interferences"] > 0 and not res["clean"]
    header = [ln for ln in (tmp_path / "out" / "mesh.obj").read_text().splitlines() if ln.startswith("#")]
    assert "# watertight: True" in header and "# clean: False" in header
    assert any(ln.startswith("# intersecting_patch_pairs: ") and not ln.endswith(": 0") for ln in header)
    assert any("in inch" in ln or "in in," in ln for ln in header)


def test_candidates_include_every_overlapping_pair_with_a_large_face():
    rng = np.random.default_rng(0)
    tris = rng.uniform(-1, 1, size=(300, 1, 3)) + rng.normal(0, 0.03, size=(300, 3, 3))
    tris[7] = [[-1.2, -1, -1], [1.2, 1, 1], [1.2, 1.1, 1]]  # one long sliver across everything
    lo, hi = tris.min(1), tris.max(1)
    i, j = np.triu_indices(len(tris), 1)
    want = {(a, b) for a, b in zip(i, j) if np.all(lo[a] <= hi[b]) and np.all(lo[b] <= hi[a])}
    assert {tuple(p) for p in candidate_pairs(tris).tolist()} == want
    assert any(7 in p for p in want)
