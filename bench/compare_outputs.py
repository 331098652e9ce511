"""Do two work folders hold the same outputs? Pixels, parsed JSON and bytes, stage by stage.

    .venv/bin/python bench/compare_outputs.py WORK_A WORK_B [--stages prepare render augment]

``WORK_A`` and ``WORK_B`` are the ``--work`` folders of two ``bench/bench_pipeline.py`` runs (or any
two build work folders of the same sources and settings; stage folders are paired by what they
were made from, so two code versions and both backends compare). Per model file: PNGs must have equal
pixels, JSON files equal parsed content (formatting may differ), anything else (meshes, samples)
equal bytes. Records and batch files are skipped: they hold timings. Exits 1 when a file differs
or is missing, so a speed change can show it changed nothing else.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

SKIPPED = {"record.json"}


def same_file(a: Path, b: Path) -> bool:
    if a.suffix == ".png":
        with Image.open(a) as ia, Image.open(b) as ib:
            return ia.mode == ib.mode and np.array_equal(np.asarray(ia), np.asarray(ib))
    if a.suffix == ".json":
        return json.loads(a.read_text()) == json.loads(b.read_text())
    return a.read_bytes() == b.read_bytes()


def _a_record(folder: Path) -> dict:
    for rec in sorted(folder.glob("*/*/record.json")):
        doc = json.loads(rec.read_text())
        if doc.get("status") == "ok":
            return doc
    return {}


def _signature(folder: Path) -> str:
    """What a stage folder was made from, the same in both work folders whatever the stage keys
    (code versions change those): render its settings' hash, augment its render folder's."""
    rec = _a_record(folder)
    if "settings_hash" in rec:
        return rec["settings_hash"]
    if "render_dir" in rec:
        return _signature(Path(rec["render_dir"]).parents[1])
    return ""


def stage_folders(work_a: Path, work_b: Path, stage: str) -> list[tuple[Path, Path]]:
    """The stage's folders of the two work folders, paired by what they were made from (a build
    with both backends has two render and two augment folders)."""
    b_by = {_signature(f): f for f in sorted(work_b.glob(f"{stage}-*"))}
    pairs = [(f, b_by.get(_signature(f))) for f in sorted(work_a.glob(f"{stage}-*"))]
    if not pairs or any(b is None for _, b in pairs):
        raise SystemExit(f"{stage}: the folders of {work_a} and {work_b} do not pair up")
    return pairs


def compare(work_a: Path, work_b: Path, stages: list[str]) -> dict:
    """Per stage and file type: files compared and the relative paths that differ or are missing."""
    out: dict = {}
    for stage, (ra, rb) in ((st, pair) for st in stages for pair in stage_folders(work_a, work_b, st)):
        for fa in sorted(ra.glob("*/*/*")):
            rel = fa.relative_to(ra)
            if not fa.is_file() or rel.parts[1].startswith("_") or fa.name in SKIPPED:
                continue
            entry = out.setdefault(f"{stage} {fa.suffix or fa.name}", {"files": 0, "differ": []})
            entry["files"] += 1
            fb = rb / rel
            if not fb.is_file() or not same_file(fa, fb):
                entry["differ"].append(str(rel))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work_a", type=Path)
    ap.add_argument("work_b", type=Path)
    ap.add_argument("--stages", nargs="+", default=["prepare", "render", "augment"])
    args = ap.parse_args()
    result = compare(args.work_a, args.work_b, args.stages)
    bad = 0
    for kind, entry in result.items():
        bad += len(entry["differ"])
        shown = ", ".join(entry["differ"][:3])
        print(f"{kind:16s} {entry['files']:6d} files, {len(entry['differ'])} differ{': ' + shown if shown else ''}")
    if not result:
        print("no per-model files to compare")
        return 1
    print("same outputs" if bad == 0 else f"{bad} files differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
