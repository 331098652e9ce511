"""`python -m pipeline verify` accepts an intact dataset and catches every kind of damage."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from test_manifest import build

from pipeline.dataset.manifest import write_manifest
from pipeline.dataset.verify import verify_dataset

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def dataset(tmp_path: Path) -> Path:
    ds = tmp_path / "ds"
    build(tmp_path / "w", ds, "mug", 6, {"views": 2})
    build(tmp_path / "w", ds, "car", 3, {"views": 2})
    write_manifest(ds)
    return ds


def run_verify(ds: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pipeline", "verify", str(ds)], cwd=ROOT, capture_output=True, text=True, timeout=120
    )


def first_shard(ds: Path) -> Path:
    return sorted((ds / "mug").glob("train-*.tar"))[0]


def test_intact_dataset_verifies(dataset: Path) -> None:
    assert verify_dataset(dataset) == []
    r = run_verify(dataset)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "OK" in r.stdout


def test_corrupted_shard_fails_cli(dataset: Path) -> None:
    shard = first_shard(dataset)
    data = bytearray(shard.read_bytes())
    data[700] ^= 0xFF  # flip bits inside the first member's data
    shard.write_bytes(bytes(data))
    r = run_verify(dataset)
    assert r.returncode != 0
    assert shard.name in r.stdout and "sha256" in r.stdout


def test_missing_extra_and_truncated_shards(dataset: Path) -> None:
    shard = first_shard(dataset)
    shutil.copy(shard, dataset / "mug" / "train-00099.tar")
    assert any("not listed" in p for p in verify_dataset(dataset))
    (dataset / "mug" / "train-00099.tar").unlink()
    shard.write_bytes(shard.read_bytes()[:1024])
    assert any("size" in p for p in verify_dataset(dataset))
    shard.unlink()
    assert any("missing" in p for p in verify_dataset(dataset))


def test_edited_manifest_fails_checksum(dataset: Path) -> None:
    path = dataset / "manifest.json"
    m = json.loads(path.read_text())
    m["categories"]["car"]["models_built"] += 1
    path.write_text(json.dumps(m))
    problems = verify_dataset(dataset)
    assert any("checksum" in p for p in problems) and any("car/category.json" in p for p in problems)


def test_preview_writes_one_sheet_per_category(dataset: Path, tmp_path: Path) -> None:
    import numpy as np
    from PIL import Image

    r = subprocess.run(
        [sys.executable, "-m", "pipeline", "preview", str(dataset), "--out", str(tmp_path / "pv")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "pv").iterdir()) == ["car.png", "mug.png"]
    mug = np.asarray(Image.open(tmp_path / "pv" / "mug.png"))
    car = np.asarray(Image.open(tmp_path / "pv" / "car.png"))
    assert mug.shape[0] > car.shape[0]  # 6 rows vs 3 rows of sketches
    assert mug.min() < 100  # sketch pixels are on the sheet, not just a white page
