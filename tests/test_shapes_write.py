"""ProceduralModel.write(): OBJ with one group per part and a complete sidecar JSON."""

from __future__ import annotations

import json

import numpy as np
import trimesh

from pipeline.shapes import generate
from pipeline.sheets.shapes import build_sheet


def test_write_round_trips(tmp_path):
    m = generate("airplane", 3, seed=0, defect_fraction=0.0)
    obj = tmp_path / "airplane" / "00003.obj"
    m.write(obj)
    loaded = trimesh.load(obj, force="mesh", process=False)
    assert len(loaded.faces) == m.n_faces
    v, _ = m.merged()
    assert np.allclose(np.sort(loaded.vertices, axis=0), np.sort(v, axis=0), atol=1e-5)
    text = obj.read_text()
    assert [ln[2:] for ln in text.splitlines() if ln.startswith("o ")] == [p.label for p in m.parts]
    side = json.loads(obj.with_suffix(".json").read_text())
    assert side["category"] == "airplane" and side["index"] == 3 and side["model_id"] == "00003"
    assert side["seed"] == 0 and side["defects"] == []
    assert [p["label"] for p in side["parts"]] == [p.label for p in m.parts]
    assert sum(p["n_faces"] for p in side["parts"]) == m.n_faces
    assert len(side["cuboids"]) == len(m.parts)
    assert np.allclose(side["cuboids"][0]["lo"], m.cuboids[0].lo, atol=1e-6)
    assert not [p for p in obj.parent.iterdir() if p.name.startswith(".")]  # no temp files left


def test_write_is_byte_deterministic(tmp_path):
    for d in ("a", "b"):
        generate("gun", 1, seed=5, defect_fraction=1.0).write(tmp_path / d / "x.obj")
    assert (tmp_path / "a" / "x.obj").read_bytes() == (tmp_path / "b" / "x.obj").read_bytes()
    assert (tmp_path / "a" / "x.json").read_bytes() == (tmp_path / "b" / "x.json").read_bytes()
    assert json.loads((tmp_path / "a" / "x.json").read_text())["defects"]


def test_shape_sheet_has_one_row_per_category():
    sheet = build_sheet(per_category=2, seed=0, size=48, categories=("mug", "knife"))
    assert sheet.dtype == np.uint8 and sheet.shape[2] == 3
    assert sheet.shape[1] < sheet.shape[0] * 1.5  # 2 columns, 2 rows
    assert (sheet < 200).any()
