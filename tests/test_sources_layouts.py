"""Listing models from ShapeNet Core v2 and plain-folder trees, without opening any mesh."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from pipeline.core.records import ModelRef
from pipeline.sources.layouts import (
    SHAPENET_SYNSETS,
    ModelIdClash,
    detect_layout,
    iter_models,
    list_categories,
    list_models,
)


def _shapenet_tree(root: Path, per_synset: int) -> None:
    for synset in ("02691156", "03797390", "04379243", "03948459"):  # airplane, mug, table, pistol
        for i in range(per_synset):
            model = root / synset / f"{i:04x}deadbeef{synset}" / "models"
            model.mkdir(parents=True)
            # Not a mesh at all: listing must never open it.
            (model / "model_normalized.obj").write_text("not parsed")
    (root / "taxonomy.json").write_text("[]")


def test_shapenet_layout_maps_synsets_to_names(tmp_path):
    _shapenet_tree(tmp_path, 5)
    assert detect_layout(str(tmp_path)) == "shapenet"
    assert list_categories(str(tmp_path)) == ["airplane", "mug"]
    refs = list_models(str(tmp_path), "airplane", None, 0, tmp_path / "work")
    assert len(refs) == 5
    assert all(isinstance(r, ModelRef) and r.category == "airplane" and r.source == "shapenet" for r in refs)
    assert [r.model_id for r in refs] == sorted(r.model_id for r in refs)
    assert refs[0].path == tmp_path / "02691156" / refs[0].model_id / "models" / "model_normalized.obj"
    # Synset id works as the category too, limit takes the first ones in order.
    by_synset = list_models(str(tmp_path), "03797390", 2, 0, tmp_path / "work")
    assert [r.category for r in by_synset] == ["mug", "mug"] and len(by_synset) == 2
    assert by_synset == list_models(str(tmp_path), "mug", None, 0, tmp_path / "work")[:2]
    # A category of ours absent from this tree is simply empty; a foreign name is an error.
    assert list_models(str(tmp_path), "car", None, 0, tmp_path / "work") == []
    with pytest.raises(ValueError):
        list_models(str(tmp_path), "table", None, 0, tmp_path / "work")
    # Pistols are readable on request (by name or id) though "gun" means rifles.
    assert [r.category for r in list_models(str(tmp_path), "03948459", 1, 0, tmp_path)] == ["pistol"]


def test_all_eight_categories_have_synsets():
    assert sorted(SHAPENET_SYNSETS.values()) == sorted(
        ("airplane", "bathtub", "bottle", "car", "guitar", "gun", "knife", "mug")
    )


def test_folder_layout(tmp_path):
    for cat, names in {"chairs": ["b.obj", "a.PLY", "c.stl", "notes.txt", "d.glb"], "mugs": ["x.off", "x.obj"]}.items():
        (tmp_path / cat).mkdir()
        for n in names:
            (tmp_path / cat / n).write_text("")
    (tmp_path / "chairs" / "sub").mkdir()
    assert detect_layout(str(tmp_path)) == "folder"
    assert list_categories(str(tmp_path)) == ["chairs", "mugs"]
    refs = list_models(str(tmp_path), "chairs", None, 0, tmp_path / "w")
    assert [r.model_id for r in refs] == ["a", "b", "c", "d"]
    assert refs[0].path == tmp_path / "chairs" / "a.PLY" and refs[0].source == "folder"
    # Two files that would be the same model: a clear error naming both, nothing listed.
    with pytest.raises(ModelIdClash, match="'x.obj' and 'x.off' would both be model 'mugs_x'"):
        list_models(str(tmp_path), "mugs", None, 0, tmp_path / "w")
    assert len(list_models(str(tmp_path), "chairs", 2, 0, tmp_path / "w")) == 2


def test_listing_streams_a_large_tree_quickly(tmp_path):
    _shapenet_tree(tmp_path, 400)
    start = time.perf_counter()
    it = iter_models(str(tmp_path), "airplane")
    first = next(it)  # a generator: the first model comes before the rest are listed
    rest = list(it)
    elapsed = time.perf_counter() - start
    assert first.model_id == "0000deadbeef02691156" and len(rest) == 399
    assert elapsed < 2.0


def test_missing_source_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError):
        list_categories(str(tmp_path / "nope"))
