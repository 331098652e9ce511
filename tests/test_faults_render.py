"""A Blender batch that hangs is killed at its timeout, retried per [RenderBatch] crash_retries,
then its models are recorded failed with the cause; the dataset is written, and the build fails
because nothing was built."""

from __future__ import annotations

import json
from pathlib import Path

import luigi

from pipeline.dataset.manifest import read_manifest
from workflows import BuildCategory
from workflows.build_settings import BuildSettings
from workflows.listing import current_listing
from workflows.steps import batch_path

# a timeout no Blender start can meet: the worker "hangs" from the supervisor's point of view
HANG = '{"timeout_s": 0.01, "startup_timeout_s": 0.3}'
PARAMS = dict(
    category="mug",
    models_per_category=2,
    batch_size=2,
    views=1,
    variants=1,
    image_size=64,
    out_size=64,
    render_settings=HANG,
)


def test_hung_render_batch_is_retried_then_recorded(tmp_path: Path) -> None:
    task = BuildCategory(work_dir=str(tmp_path / "work"), dataset_dir=str(tmp_path / "ds"), **PARAMS)
    assert not luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING")  # nothing built
    s = BuildSettings(
        models_per_category=2,
        batch_size=2,
        views=1,
        variants=1,
        image_size=64,
        out_size=64,
        render_overrides=HANG,
        work_dir=tmp_path / "work",
        dataset_dir=tmp_path / "ds",
    )
    doc = json.loads(batch_path(s, "render", current_listing(s, "mug"), 0).read_text())
    assert doc["attempts"] == 2 and len(doc["crashes"]) == 1  # crash_retries = 1 (luigi.cfg)
    assert "timed out" in doc["crashes"][0]
    cat = read_manifest(tmp_path / "ds")["categories"]["mug"]
    assert cat["models_built"] == 0 and cat["models_failed"] == 2
    for f in cat["failed"]:
        assert f["stage"] == "render"
        assert "render worker timed out after 0.3 s and was killed" in f["reason"], f
        assert f["path"].endswith("lines.ply")  # the render stage draws the line mesh
