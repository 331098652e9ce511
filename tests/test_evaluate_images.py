"""`evaluate --images DIR`: a checkpoint on a folder of drawings, each normalized as `predict`
normalizes it, with the CAD kernel's verdict on each and, where a mesh with the drawing's stem
lies beside it, evaluate's metrics against that ground truth."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import box_sketch, camera  # noqa: E402

from train.cli import main
from train.errors import UsageError
from train.evaluate_images import evaluate_images
from train.export.quadmesh import quad_mesh
from train.fit import FitSettings, save_checkpoint
from train.model import SketchToPatches
from train.templates import load_template


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict:
    """A knife checkpoint that predicts its template (zero output layer) and a folder of three
    drawings: one with the template's own surface beside it (moved and scaled, as a mesh in mm
    would be), one with a sphere, one without ground truth (inverted), plus a file that is no image."""
    d = tmp_path_factory.mktemp("evimg")
    t = load_template("knife")
    model = SketchToPatches(t.initial_params(), encoder_width=8).eval()
    s = FitSettings(
        dataset="-", category="knife", template="knife", out=str(d), image_size=32, encoder_width=8, n_points=1500
    )
    save_checkpoint(d / "checkpoint.pt", model, torch.optim.Adam(model.parameters()), 0, s, t)
    images = d / "drawings"
    images.mkdir()
    sketch = box_sketch(np.array([1, 0.3, 0.2]) / 1.06, camera(30, 20, 96), 96, 1)
    cv2.imwrite(str(images / "a_own.png"), sketch)
    cv2.imwrite(str(images / "b_sphere.jpg"), sketch)
    cv2.imwrite(str(images / "c_alone.png"), 255 - sketch)
    patches = t.patches_from_params(t.initial_params(torch.float64)[None])[0].numpy()[t.active_patches(None)]
    qm = quad_mesh(patches, alpha=40.0)
    own = trimesh.Trimesh(qm.vertices * 50.0 + [300.0, -20.0, 5.0], qm.triangles(), process=False)
    own.export(images / "a_own.obj")
    trimesh.creation.icosphere(3).export(images / "b_sphere.stl")
    (images / "notes.txt").write_text("not a drawing")
    return {"ckpt": d / "checkpoint.pt", "images": images}


def test_each_drawing_is_normalized_checked_and_measured(world, tmp_path) -> None:
    res = evaluate_images(world["ckpt"], world["images"], out=tmp_path / "e.json")
    assert json.loads((tmp_path / "e.json").read_text()) == json.loads(json.dumps(res))
    assert res["samples"] == 3 and res["with_ground_truth"] == 2 and res["cad_checked"] == 3
    rows = {r["image"]: r for r in res["per_image"]}
    assert sorted(rows) == ["a_own.png", "b_sphere.jpg", "c_alone.png"]
    # normalized as predict does: the white-on-black drawing was found inverted, the others not
    assert rows["c_alone.png"]["input"]["inverted"] and not rows["a_own.png"]["input"]["inverted"]
    assert all(len(r["input"]["crop_box"]) == 4 for r in rows.values())
    # the template's own surface, moved and scaled, is measured in the unit-sphere frame: close
    own, sphere = rows["a_own.png"], rows["b_sphere.jpg"]
    assert own["ground_truth"] == "a_own.obj" and sphere["ground_truth"] == "b_sphere.stl"
    assert own["model"]["chamfer"] < 0.1 < 1.0 < sphere["model"]["chamfer"]  # 0.05: two samplings of one surface
    assert own["model"]["fscore@0.05"] > 0.99
    assert own["model"]["chamfer"] == pytest.approx(own["template"]["chamfer"], rel=1e-6)  # it predicts the template
    assert "model" not in rows["c_alone.png"]
    # the kernel's verdict on every prediction (the knife template is a clean solid)
    assert all(r["cad_kernel"]["clean"] and r["cad_kernel"]["solid"] for r in rows.values())
    assert res["model"]["cad_clean"] == 1.0
    assert res["model"]["chamfer"] == pytest.approx((own["model"]["chamfer"] + sphere["model"]["chamfer"]) / 2)


def test_denser_samples_lower_the_floor_of_two_samplings_of_one_surface(world) -> None:
    plain = evaluate_images(world["ckpt"], world["images"], cad_check=False)
    denser = evaluate_images(world["ckpt"], world["images"], cad_check=False, points=4 * plain["points"])
    assert denser["points"] == 4 * plain["points"]
    own = {r["image"]: r for r in plain["per_image"]}["a_own.png"]["model"]["chamfer"]
    own_denser = {r["image"]: r for r in denser["per_image"]}["a_own.png"]["model"]["chamfer"]
    assert own_denser < 0.75 * own  # about half the spacing: 1/sqrt(4)


def test_command_line_prints_a_table_and_saves_json(world, capsys) -> None:
    assert main(["evaluate", "--checkpoint", str(world["ckpt"]), "--images", str(world["images"])]) == 0
    out = capsys.readouterr().out
    assert "a_own.png" in out and "c_alone.png" in out and "cad_clean" in out
    saved = world["ckpt"].with_name("eval_checkpoint_images-drawings.json")
    assert json.loads(saved.read_text())["samples"] == 3


def _error(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    return capsys.readouterr().err.strip()


def test_bad_folders_and_meshes_are_one_line_errors(world, tmp_path, capsys) -> None:
    ck = str(world["ckpt"])
    assert "--dataset" in _error(capsys, ["evaluate", "--checkpoint", ck]) and "--images" in _error(
        capsys, ["evaluate", "--checkpoint", ck, "--dataset", "x", "--images", "y"]
    )
    empty = tmp_path / "empty"
    empty.mkdir()
    line = _error(capsys, ["evaluate", "--checkpoint", ck, "--images", str(empty), "--out", str(tmp_path / "e.json")])
    assert line.endswith(f"{empty}: no images in it (.png, .jpg, .jpeg, .webp, .tif, .tiff) (--images)")
    broken = tmp_path / "broken"
    broken.mkdir()
    cv2.imwrite(str(broken / "k.png"), cv2.imread(str(world["images"] / "a_own.png")))
    (broken / "k.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nthis is not a mesh\n")
    line = _error(capsys, ["evaluate", "--checkpoint", ck, "--images", str(broken), "--out", str(tmp_path / "e.json")])
    assert f"{broken / 'k.ply'}: not a readable mesh" in line and "\n" not in line
    assert not (tmp_path / "e.json").exists()


def test_mirror_average_is_refused_by_name_for_a_template_without_a_mirror(world, tmp_path) -> None:
    """The knife template's curves do not pair up across a plane: --mirror-average says so before
    any drawing is read or any file written."""
    with pytest.raises(UsageError, match="'knife'.*--mirror-average"):
        evaluate_images(world["ckpt"], world["images"], out=tmp_path / "m.json", mirror_average=True)
    assert not (tmp_path / "m.json").exists()
