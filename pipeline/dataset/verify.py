"""Re-check every shard of a dataset against its manifest.

Checks: the manifest's own checksum; per category the fragment on disk equals the manifest
entry; every listed shard exists with the recorded size and sha256 and reads back with tarfile
holding exactly the recorded sample keys, each with every required member and a matching
meta.json; no unlisted shard files lie in a category folder; no category is empty.
"""

from __future__ import annotations

import json
import tarfile
from pathlib import Path

from pipeline.core.hashing import file_sha256
from pipeline.core.names import UnsafePath, inside, is_safe_component
from pipeline.core.schema import (
    FRAGMENT,
    MANIFEST,
    META_MEMBER,
    REQUIRED_MEMBERS,
    SHARD_RE,
    SPLITS,
    sketch_view_variant,
)
from pipeline.dataset.manifest import content_checksum, read_fragment
from pipeline.dataset.shards import iter_shard, list_shards


def _check_sample(shard: str, key: str, members: dict[str, bytes], split: str) -> list[str]:
    problems = [f"{shard}: sample {key} lacks {m}" for m in REQUIRED_MEMBERS if m not in members]
    if not any(sketch_view_variant(m) for m in members):
        problems.append(f"{shard}: sample {key} has no sketch_<view>_<variant>.png")
    if META_MEMBER in members:
        try:
            meta = json.loads(members[META_MEMBER])
        except ValueError:
            return problems + [f"{shard}: sample {key} has unreadable {META_MEMBER}"]
        if meta.get("key") != key or meta.get("split") != split:
            problems.append(
                f"{shard}: sample {key} {META_MEMBER} names key {meta.get('key')!r} split {meta.get('split')!r}"
            )
    return problems


def _check_shard(path: Path, info: dict, split: str) -> list[str]:
    name = f"{path.parent.name}/{path.name}"
    if not path.exists():
        return [f"{name}: missing"]
    if path.is_dir():
        return [f"{name}: a folder, not a shard file"]
    if path.stat().st_size != info["bytes"]:
        return [f"{name}: size {path.stat().st_size} != manifest {info['bytes']}"]
    if file_sha256(path) != info["sha256"]:
        return [f"{name}: sha256 differs from manifest"]
    problems: list[str] = []
    keys: list[str] = []
    try:
        for key, members in iter_shard(path):
            keys.append(key)
            problems += _check_sample(name, key, members, split)
    except (tarfile.TarError, OSError) as e:
        return [f"{name}: unreadable tar: {e}"]
    if len(keys) != info["samples"]:
        problems.append(f"{name}: {len(keys)} samples != manifest {info['samples']}")
    if "keys" in info and keys != info["keys"]:
        problems.append(f"{name}: sample keys differ from manifest")
    return problems


def verify_dataset(dataset_dir: Path) -> list[str]:
    """All mismatches between the dataset folder and its manifest (empty list = valid)."""
    dataset_dir = Path(dataset_dir)
    try:
        manifest = json.loads((dataset_dir / MANIFEST).read_text())
    except (OSError, ValueError) as e:
        return [f"{MANIFEST}: cannot read: {e}"]
    problems: list[str] = []
    if manifest.get("checksum") != content_checksum(manifest):
        problems.append(f"{MANIFEST}: checksum does not match its content")
    for category, entry in sorted(manifest.get("categories", {}).items()):
        # a manifest from elsewhere must not make us read outside the dataset folder
        if not is_safe_component(category):
            problems.append(f"{MANIFEST}: category {category!r} is not a plain folder name; not read")
            continue
        cat_dir = dataset_dir / category
        frag = read_fragment(cat_dir)
        if frag != entry:
            problems.append(f"{category}/{FRAGMENT}: differs from the manifest entry")
        if not sum(entry["splits"][split]["samples"] for split in SPLITS):
            # consistent, yet useless: a build that built nothing fails, and so does its check
            problems.append(
                f"{category}: no samples ({entry.get('models_failed', 0)} of "
                f"{entry.get('models_requested', 0)} models failed)"
            )
        listed: set[str] = set()
        for split in SPLITS:
            for info in entry["splits"][split]["shards"]:
                name = info.get("name")
                if not (isinstance(name, str) and SHARD_RE.fullmatch(name)):
                    problems.append(f"{category}: shard name {name!r} is not a shard file name; not read")
                    continue
                listed.add(name)
                try:
                    problems += _check_shard(inside(dataset_dir, cat_dir / name), info, split)
                except UnsafePath as exc:  # a link out of the dataset folder
                    problems.append(f"{category}/{name}: {exc}; not read")
        for p in list_shards(cat_dir):
            if p.name not in listed:
                problems.append(f"{category}/{p.name}: shard not listed in the manifest")
    return problems
