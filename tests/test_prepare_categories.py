"""Every procedural category through the procedural source and prepare_batch at default settings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.core.records import read_record
from pipeline.prepare.batch import PrepareSettings, prepare_batch
from pipeline.shapes import CATEGORIES
from pipeline.sources.layouts import list_categories, list_models, procedural_source_dir
from tests.test_prepare_core import assert_prepared

DEFAULTS = PrepareSettings()


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    """One model per category (index 1), sourced and prepared once for all tests here."""
    work = tmp_path_factory.mktemp("work")
    refs = [r for cat in CATEGORIES for r in list_models("procedural", cat, 2, 0, work)[1:]]
    stage = work / "prepare-test"
    records = prepare_batch(refs, stage, DEFAULTS)
    return work, stage, refs, records


def test_procedural_source_lists_and_materializes(prepared):
    work, _, refs, _ = prepared
    assert list_categories("procedural") == sorted(CATEGORIES)
    assert [r.category for r in refs] == list(CATEGORIES)
    for r in refs:
        assert r.source == "procedural" and r.model_id == "00001"
        assert r.path == procedural_source_dir(work, 0) / r.category / "00001.obj"
        assert r.path.is_file() and r.path.with_suffix(".json").is_file()
    # No stray temp files are left next to the models.
    assert not list(procedural_source_dir(work, 0).rglob(".*"))


def test_procedural_generation_is_deterministic_and_skips_existing(prepared, tmp_path):
    work, _, refs, _ = prepared
    again = list_models("procedural", "mug", 2, 0, tmp_path)
    for a, b in zip(list_models("procedural", "mug", 2, 0, work), again):
        assert a.path.read_bytes() == b.path.read_bytes()
        assert a.path.with_suffix(".json").read_bytes() == b.path.with_suffix(".json").read_bytes()
    # Existing models are not rewritten (a resumed run keeps what it has).
    mtime = again[0].path.stat().st_mtime_ns
    list_models("procedural", "mug", 2, 0, tmp_path)
    assert again[0].path.stat().st_mtime_ns == mtime
    # Another seed lands in another source folder.
    assert procedural_source_dir(tmp_path, 1) != procedural_source_dir(tmp_path, 0)


@pytest.mark.parametrize("category", CATEGORIES)
def test_category_prepares_to_unit_watertight_solid(prepared, category):
    _, stage, _, records = prepared
    rec = next(r for r in records if r["category"] == category)
    assert rec["status"] == "ok", rec.get("error")
    assert_prepared(stage / category / "00001", DEFAULTS)


def test_sidecar_parts_and_cuboids_carried_into_record(prepared):
    _, stage, refs, _ = prepared
    for ref in refs:
        rec = read_record(stage / ref.category / ref.model_id)
        side = json.loads(ref.path.with_suffix(".json").read_text())
        assert [p["label"] for p in rec["parts"]] == [p["label"] for p in side["parts"]]
        assert rec["defects"] == side["defects"]
        center, scale = np.array(rec["normalization"]["center"]), rec["normalization"]["scale"]
        for c_src, c_rec in zip(side["cuboids"], rec["cuboids"]):
            assert np.allclose(c_rec["lo"], (np.array(c_src["lo"]) - center) / scale)
            assert np.allclose(c_rec["hi"], (np.array(c_src["hi"]) - center) / scale)
            # Normalized boxes sit inside the (slightly inflated) unit-sphere model.
            assert np.abs(c_rec["lo"]).max() <= 1.0 and np.abs(c_rec["hi"]).max() <= 1.0


def test_category_preparation_is_byte_deterministic(prepared, tmp_path):
    _, stage, refs, _ = prepared
    ref = next(r for r in refs if r.category == "airplane")
    prepare_batch([ref], tmp_path, DEFAULTS)
    for name in ("mesh.ply", "samples.npy"):
        assert (tmp_path / "airplane" / "00001" / name).read_bytes() == (
            stage / "airplane" / "00001" / name
        ).read_bytes()
