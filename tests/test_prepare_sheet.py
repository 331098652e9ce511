"""The documented contact-sheet command draws raw/prepared pairs, in the build's prepare folder, and
reuses prepared models."""

from __future__ import annotations

import numpy as np
from PIL import Image

from workflows.build_settings import BuildSettings
from workflows.sheets.prepare import main


def test_prepare_sheet_command(tmp_path):
    out = tmp_path / "sheets" / "prepared.png"
    args = [
        "--out",
        str(out),
        "--work",
        str(tmp_path / "work"),
        "--per-category",
        "1",
        "--categories",
        "mug",
        "knife",
        "--resolution",
        "2000",
        "--size",
        "64",
    ]
    main(args)
    img = np.asarray(Image.open(out).convert("L"))
    # Two rows (categories) of two thumbnails (raw, prepared), each with drawn (non-white) pixels.
    assert img.shape[1] >= 2 * 64 and img.shape[0] >= 2 * 64
    assert (img < 200).mean() > 0.02
    first = out.read_bytes()
    records = sorted((tmp_path / "work").glob("prepare-*/*/*/record.json"))
    assert len(records) == 2
    # the sheet prepares into the folder a build with these settings uses
    build = BuildSettings(work_dir=tmp_path / "work", models_per_category=1, prepare_overrides='{"resolution": 2000}')
    assert {r.parents[2] for r in records} == {build.stage_dir("prepare")}
    mtimes = [r.stat().st_mtime_ns for r in records]
    main(args)  # a second run reuses the prepared models and draws the same sheet
    assert out.read_bytes() == first
    assert [r.stat().st_mtime_ns for r in records] == mtimes
