"""A category's model list, re-read from the source on every run, with each model's content key.

For a folder or ShapeNet source every model gets a *work id* ``<model_id>-<sha256[:12]>`` of its
file's bytes: stage outputs live in ``<stage-dir>/<category>/<work_id>/``, so a changed file gets
new outputs, an unchanged one finds its old ones, and a removed one is simply no longer listed.
Hashes are cached in ``<source-stage-dir>/<category>/_hashes.json`` by (size, mtime, inode), so a
re-run reads only files that changed. The list itself is stored content-addressed as
``_lists/<key>.json`` (the key hashes every entry), so any change of the folder gives a new key.

The procedural source keeps its ids as work ids: its content is fixed by the seed and the count.
"""

from __future__ import annotations

import functools
import hashlib
import os
import stat
from pathlib import Path

from pipeline.build.settings import BuildSettings
from pipeline.core.atomic import read_json, write_json
from pipeline.core.records import ModelRef
from pipeline.core.stage_keys import settings_hash
from pipeline.sources.mesh_io import sha256_file

LISTS = "_lists"
HASHES = "_hashes.json"


def procedural_tag(s: BuildSettings) -> str:
    """The procedural list's key: its models are fixed by seed (in the stage key) and count."""
    return f"n{s.limit}" if s.limit is not None else "all"


def list_path(s: BuildSettings, category: str, key: str) -> Path:
    return s.stage_dir("source") / category / LISTS / f"{key}.json"


def content_key(path: Path, cache: dict, cache_name: str) -> str:
    """sha256 of a regular readable file (from ``cache`` when size, mtime and inode match), else a
    hash of what stat says about the entry: a broken link, FIFO or unreadable file gets a key that
    changes when it is fixed, and is never opened here (reading a FIFO would block)."""
    try:
        st = os.stat(path)
    except OSError:
        try:
            lst = os.lstat(path)
            what = f"missing:{lst.st_mode}:{lst.st_mtime_ns}:{os.readlink(path) if stat.S_ISLNK(lst.st_mode) else ''}"
        except OSError:
            what = "missing"
        return hashlib.sha256(what.encode()).hexdigest()
    sig = [st.st_size, st.st_mtime_ns, st.st_ino]
    hit = cache.get(cache_name)
    if hit is not None and hit[:3] == sig:
        return hit[3]
    if stat.S_ISREG(st.st_mode):
        try:
            sha = sha256_file(path)
        except OSError:
            sha = hashlib.sha256(f"unreadable:{st.st_mode}:{st.st_mtime_ns}".encode()).hexdigest()
    else:
        sha = hashlib.sha256(f"special:{st.st_mode}".encode()).hexdigest()
    cache[cache_name] = sig + [sha]
    return sha


def work_id(model_id: str, sha: str) -> str:
    return f"{model_id}-{sha[:12]}"


def _procedural(s: BuildSettings, category: str) -> dict:
    from pipeline.sources.layouts import DEFAULT_PROCEDURAL_COUNT, procedural_source_dir

    folder = procedural_source_dir(Path(s.work_dir), s.seed) / category
    count = s.limit if s.limit is not None else DEFAULT_PROCEDURAL_COUNT
    models = [{"model_id": f"{i:05d}", "work_id": f"{i:05d}", "path": str(folder / f"{i:05d}.obj"),
               "source": "procedural"} for i in range(count)]
    return {"category": category, "key": procedural_tag(s), "models": models}


def current_listing(s: BuildSettings, category: str) -> dict:
    """``{"category", "key", "models": [{"model_id", "work_id", "path", "source"}]}`` as the
    source is now; for file sources the list is written to ``list_path`` (if new) before returning.
    Raises ModelIdClash (a ValueError) when two files would be the same model."""
    if s.is_procedural:
        return _procedural(s, category)
    from pipeline.sources.layouts import list_models

    refs = list_models(s.source, category, s.limit, s.seed, Path(s.work_dir))
    cache_path = s.stage_dir("source") / category / HASHES
    cache = read_json(cache_path) if cache_path.exists() else {}
    before = dict(cache)
    root = os.path.abspath(s.source)
    models = []
    for r in refs:
        sha = content_key(Path(r.path), cache, os.path.relpath(os.path.abspath(r.path), root))
        models.append({"model_id": r.model_id, "work_id": work_id(r.model_id, sha), "path": str(r.path),
                       "source": r.source})
    if cache != before:
        write_json(cache_path, cache)
    doc = {"category": category, "models": models}
    doc["key"] = f"{procedural_tag(s)}-{settings_hash(doc)}"
    path = list_path(s, category, doc["key"])
    if not path.exists():
        write_json(path, doc)
    return doc


@functools.lru_cache(maxsize=64)
def _read_cached(path: str) -> dict:
    return read_json(path)  # list files are content-addressed: a path's content never changes


def read_listing(s: BuildSettings, category: str, key: str) -> dict:
    """The list stored under ``key`` (the procedural one is computed, it needs no file)."""
    if s.is_procedural:
        return _procedural(s, category)
    return _read_cached(str(list_path(s, category, key)))


def model_ref(category: str, m: dict) -> ModelRef:
    """A list entry as the stages see it: named by its work id (its output folder and seed key)."""
    return ModelRef(category, m["work_id"], Path(m["path"]), m["source"])


def listed_models(s: BuildSettings, category: str) -> list[ModelRef]:
    """The category's models as a build hands them to the stages (procedural meshes are made
    first when missing): for sheets and previews that run stages outside a build."""
    if s.is_procedural:
        from pipeline.sources.layouts import list_models

        list_models(s.source, category, s.limit, s.seed, Path(s.work_dir))  # writes the meshes
    return [model_ref(category, m) for m in current_listing(s, category)["models"]]
