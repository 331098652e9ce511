import os
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.atomic import atomic_path, read_json, write_json
from pipeline.core.seeding import derive_seed, rng_for
from pipeline.core.stage_keys import settings_hash, stage_key


def test_seed_depends_on_every_key_part():
    base = derive_seed(0, "render", "car", "00001", 0, 0)
    assert base == derive_seed(0, "render", "car", "00001", 0, 0)
    for other in [
        (1, "render", "car", "00001", 0, 0),
        (0, "augment", "car", "00001", 0, 0),
        (0, "render", "mug", "00001", 0, 0),
        (0, "render", "car", "00002", 0, 0),
        (0, "render", "car", "00001", 1, 0),
        (0, "render", "car", "00001", 0, 1),
    ]:
        assert derive_seed(*other) != base
    assert np.array_equal(rng_for(3, "x").random(4), rng_for(3, "x").random(4))


def test_settings_hash_changes_with_settings_and_upstream():
    a = settings_hash({"views": 4})
    assert a == settings_hash({"views": 4})
    assert a != settings_hash({"views": 5})
    assert a != settings_hash({"views": 4}, upstream="abc")
    assert stage_key("render", {"views": 4}).startswith("render-")


def test_code_version_bump_rekeys_the_stage_and_downstream(monkeypatch):
    from pipeline.core import stage_keys as config
    from workflows.build_settings import BuildSettings

    s = BuildSettings()
    before = {st: s.stage_dir(st).name for st in ("prepare", "render", "augment", "shards")}
    monkeypatch.setitem(config.STAGE_VERSIONS, "render", config.STAGE_VERSIONS["render"] + 1)
    after = {st: s.stage_dir(st).name for st in before}
    assert after["prepare"] == before["prepare"]
    assert all(after[st] != before[st] for st in ("render", "augment", "shards"))


def test_atomic_write_leaves_nothing_on_failure(tmp_path: Path):
    target = tmp_path / "out.json"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert not target.exists()
    assert os.listdir(tmp_path) == []
    write_json(target, {"b": 1, "a": [1, 2]})
    assert read_json(target) == {"a": [1, 2], "b": 1}


def test_write_bytes_replaces_whole_files_with_the_usual_mode(tmp_path: Path, monkeypatch):
    from pipeline.core import atomic

    target = tmp_path / "new" / "deeper" / "view_00.png"  # folders made on the way
    atomic.write_bytes(target, b"first")
    atomic.write_bytes(target, b"second, longer")
    assert target.read_bytes() == b"second, longer"
    umask = os.umask(0o022)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    # a leftover temp file of an earlier process with this pid and number is skipped, not reused
    number = next(atomic._tmp_numbers) + 1
    stale = target.parent / f".{target.name}.{os.getpid()}-{number}.tmp.png"
    stale.write_bytes(b"stale")
    atomic.write_bytes(target, b"third")
    assert target.read_bytes() == b"third" and stale.read_bytes() == b"stale"
    assert sorted(p.name for p in target.parent.iterdir()) == sorted([stale.name, target.name])
    # a failed write leaves the old file and no temp file
    monkeypatch.setattr(atomic.os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(28, "No space left")))
    with pytest.raises(OSError, match="disk full"):
        atomic.write_bytes(target, b"fourth")
    assert target.read_bytes() == b"third"
    assert sorted(p.name for p in target.parent.iterdir()) == sorted([stale.name, target.name])
