"""Dataset manifest: per-category fragments merged into ``<dataset-dir>/manifest.json``.

Each category folder holds ``category.json`` (its settings and their hash, models built, failed
models with reasons, and per split the shards with sample counts and sha256). The top-level
manifest merges every fragment present in the dataset folder, so rebuilding one category updates
the manifest without touching other categories' shards. Nothing in either file depends on where
the build ran (no absolute paths, no times), so equal builds give equal manifests and checksums.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from pipeline import __version__
from pipeline.core.atomic import dumps_json, read_json, write_json
from pipeline.core.schema import FRAGMENT, FRAGMENT_FIT, MANIFEST, SPLITS
from pipeline.dataset.shards import ShardSet

FORMAT = 1


def content_checksum(obj: dict) -> str:
    """sha256 of the canonical JSON of ``obj`` without its "checksum" field."""
    body = {k: v for k, v in obj.items() if k != "checksum"}
    return hashlib.sha256(dumps_json(body).encode()).hexdigest()


def category_fragment(
    category: str,
    result: ShardSet,
    settings: dict[str, Any],
    settings_hash: str,
    models_requested: int,
    upstream_failed: list[dict],
    listing: str | None = None,
    fit: dict | None = None,
) -> dict:
    """The manifest entry of one category after its shards were written. ``listing`` is the key
    of the source list it was built from (file sources only: a changed folder changes it);
    ``fit`` the fit stage's figures over the models built (only when the stage ran)."""
    failed = sorted(upstream_failed + result.failed, key=lambda f: (f["model_id"], f.get("stage", "")))
    splits = {
        s: {
            "samples": sum(i.samples for i in result.shards.get(s, [])),
            "shards": [i.to_json() for i in result.shards.get(s, [])],
        }
        for s in SPLITS
    }
    frag = {
        "category": category,
        "settings": settings,
        "settings_hash": settings_hash,
        "models_requested": models_requested,
        "models_built": sum(v["samples"] for v in splits.values()),
        "models_failed": len(failed),
        "failed": failed,
        "splits": splits,
    }
    if listing is not None:
        frag["listing"] = listing
    if fit is not None:
        frag[FRAGMENT_FIT] = fit
    frag["checksum"] = content_checksum(frag)
    return frag


def write_fragment(category_dir: Path, fragment: dict) -> None:
    write_json(Path(category_dir) / FRAGMENT, fragment)


def read_fragment(category_dir: Path) -> dict | None:
    path = Path(category_dir) / FRAGMENT
    return read_json(path) if path.exists() else None


def build_manifest(dataset_dir: Path) -> dict:
    """Merge every category fragment under ``dataset_dir`` into one manifest dict."""
    dataset_dir = Path(dataset_dir)
    categories: dict[str, dict] = {}
    for frag_path in sorted(dataset_dir.glob(f"*/{FRAGMENT}")):
        frag = read_json(frag_path)
        categories[frag["category"]] = frag
    # Categories may have been built with different settings (one regenerated): list each set once.
    settings = {f["settings_hash"]: f["settings"] for f in categories.values()}
    per_cat = {c: f["settings_hash"] for c, f in categories.items()}
    totals = {
        "categories": len(categories),
        "models_built": sum(f["models_built"] for f in categories.values()),
        "models_failed": sum(f["models_failed"] for f in categories.values()),
        "shards": sum(len(f["splits"][s]["shards"]) for f in categories.values() for s in SPLITS),
        **{s: sum(f["splits"][s]["samples"] for f in categories.values()) for s in SPLITS},
    }
    manifest = {
        "format": FORMAT,
        "project_version": __version__,
        "settings": settings,
        "settings_hash": hashlib.sha256(dumps_json(per_cat).encode()).hexdigest()[:10],
        "categories": categories,
        "totals": totals,
    }
    manifest["checksum"] = content_checksum(manifest)
    return manifest


def write_manifest(dataset_dir: Path) -> dict:
    """Rewrite ``<dataset_dir>/manifest.json`` from the fragments; returns it."""
    manifest = build_manifest(dataset_dir)
    write_json(Path(dataset_dir) / MANIFEST, manifest)
    return manifest


def read_manifest(dataset_dir: Path) -> dict:
    return read_json(Path(dataset_dir) / MANIFEST)
