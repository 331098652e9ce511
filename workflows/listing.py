"""A category's model list, re-read from the source on every run, with each model's content key.

For a folder or ShapeNet source every model gets a *work id* ``<model_id>-<sha256[:12]>`` of
every byte it is built from (its file, and a glTF's external buffers and images): stage outputs
live in ``<stage-dir>/<category>/<work_id>/``, so a changed file gets new outputs, an unchanged
one finds its old ones, and a removed one is simply no longer listed. Model ids are safe file
names already (pipeline.core.names), so a work id is too. Hashes are cached in
``<source-stage-dir>/<category>/_hashes.json`` by (size, mtime, inode, mode), so a re-run reads
only files that changed. Two files of one category with equal content are one model: the first
by name is built, the others are recorded failed as its duplicates. The list itself is stored
content-addressed as ``_lists/<key>.json`` (the key hashes every entry), so any change of the
folder gives a new key.

The procedural source keeps its ids as work ids: its content is fixed by the seed and the count.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import logging
import os
import stat
from pathlib import Path

from pipeline.core.atomic import read_json, write_json
from pipeline.core.hashing import file_sha256
from pipeline.core.records import ModelRef
from pipeline.core.stage_keys import settings_hash
from pipeline.sources.mesh_io import gltf_external_files
from workflows.build_settings import BuildSettings

log = logging.getLogger(__name__)

LISTS = "_lists"
HASHES = "_hashes.json"


def procedural_tag(s: BuildSettings) -> str:
    """The procedural list's key: its models are fixed by seed (in the stage key) and count."""
    return f"n{s.limit}" if s.limit is not None else "all"


def list_path(s: BuildSettings, category: str, key: str) -> Path:
    return s.stage_dir("source") / category / LISTS / f"{key}.json"


@dataclasses.dataclass(frozen=True)
class FileKey:
    """A file's key: ``sha`` of its bytes when ``content`` is set, else of what stat says about
    it (missing, unreadable, not a regular file), which changes when it is fixed."""

    sha: str
    content: bool


def _stat_key(what: str) -> FileKey:
    return FileKey(hashlib.sha256(what.encode()).hexdigest(), False)


def file_key(path: Path, cache: dict, cache_name: str) -> FileKey:
    """The key of one file, hashed only when it changed since ``cache`` saw it.

    The cache signature holds the mode besides size, mtime and inode: ``chmod`` changes none of
    the others, and a file that was unreadable must be re-read once it is readable. Keys of
    failed reads are never cached; they hold the mode, owner and ctime, so fixing any of them
    gives a new key and the model is tried again. A FIFO is never opened (reading it would block).
    """
    try:
        st = os.stat(path)
    except OSError:
        try:
            lst = os.lstat(path)
            return _stat_key(
                f"missing:{lst.st_mode}:{lst.st_mtime_ns}:{os.readlink(path) if stat.S_ISLNK(lst.st_mode) else ''}"
            )
        except OSError:
            return _stat_key("missing")
    if not stat.S_ISREG(st.st_mode):
        return _stat_key(f"special:{st.st_mode}")
    sig = [st.st_size, st.st_mtime_ns, st.st_ino, st.st_mode]
    hit = cache.get(cache_name)
    if hit is not None and hit[:-1] == sig:
        return FileKey(hit[-1], True)
    try:
        sha = file_sha256(path)
    except OSError:
        return _stat_key(f"unreadable:{st.st_mode}:{st.st_uid}:{st.st_gid}:{st.st_ctime_ns}")
    cache[cache_name] = sig + [sha]
    return FileKey(sha, True)


def model_key(path: Path, cache: dict, root: str) -> FileKey:
    """The key of a model: its file's, combined with every external file its loader reads (a
    glTF's buffers and images), so editing a ``.bin`` re-runs the model. A model without
    external files keeps its file's own sha256 as key. An OBJ's ``.mtl`` and textures are not
    part of it: they do not change the loaded geometry (tests/test_trust_keys.py checks this)."""
    own = file_key(path, cache, _cache_name(path, root))
    if not own.content:
        return own
    externals = gltf_external_files(path)
    if not externals:
        return own
    parts, content = [own.sha], True
    for kind, uri, found in externals:
        key = file_key(found, cache, _cache_name(found, root)) if found is not None else _stat_key("missing")
        parts.append(f"{kind}:{uri}:{key.sha}")
        content = content and key.content
    return FileKey(hashlib.sha256("|".join(parts).encode("utf-8", "surrogateescape")).hexdigest(), content)


def _cache_name(path: Path, root: str) -> str:
    return os.path.relpath(os.path.abspath(path), root)


def content_key(path: Path, cache: dict, cache_name: str) -> str:
    """sha256 of a regular readable file, else a hash of what stat says (see ``file_key``)."""
    return file_key(path, cache, cache_name).sha


def work_id(model_id: str, sha: str) -> str:
    return f"{model_id}-{sha[:12]}"


def _procedural(s: BuildSettings, category: str) -> dict:
    return _procedural_list(str(s.work_dir), s.seed, s.limit, category, procedural_tag(s))


@functools.lru_cache(maxsize=64)
def _procedural_list(work_dir: str, seed: int, limit: int | None, category: str, key: str) -> dict:
    # cached: every batch task of a category asks for it (the scheduler's graph walk: 2,448 tasks
    # at ShapeNet's size); callers only read it
    from pipeline.sources.layouts import DEFAULT_PROCEDURAL_COUNT, procedural_source_dir

    folder = procedural_source_dir(Path(work_dir), seed) / category
    count = limit if limit is not None else DEFAULT_PROCEDURAL_COUNT
    models = [
        {"model_id": f"{i:05d}", "work_id": f"{i:05d}", "path": str(folder / f"{i:05d}.obj"), "source": "procedural"}
        for i in range(count)
    ]
    return {"category": category, "key": key, "models": models}


def mark_duplicates(models: list[dict], keys: list[FileKey], root: str) -> None:
    """Give every model whose content equals an earlier one's ``"duplicate_of"``: the first's
    path relative to the source. Models come sorted by file name, so the first name is kept
    and its copies are recorded as failed (never one in train and its copy in test). Keys from
    stat (unreadable, missing files) say nothing about content and never match."""
    first: dict[str, dict] = {}
    for m, k in zip(models, keys):
        if not k.content:
            continue
        kept = first.setdefault(k.sha, m)
        if kept is not m:
            m["duplicate_of"] = Path(os.path.relpath(kept["path"], root)).as_posix()
            log.warning(
                "%s is a copy of %s (same content): only %s is built",
                os.path.relpath(m["path"], root),
                m["duplicate_of"],
                m["duplicate_of"],
            )


def duplicate_outcome(m: dict) -> dict | None:
    """The batch outcome of a list entry that is a copy of another model (None if it is not):
    failed at the "source" stage, with the reason naming the file it copies."""
    if "duplicate_of" not in m:
        return None
    return {
        "model_id": m["model_id"],
        "work_id": m["work_id"],
        "stage": "source",
        "status": "failed",
        "error": {"path": m["path"], "reason": f"duplicate of {m['duplicate_of']} (same content)"},
    }


def current_listing(s: BuildSettings, category: str) -> dict:
    """``{"category", "key", "models": [{"model_id", "work_id", "path", "source"}]}`` as the
    source is now (a copy of an earlier model also has "duplicate_of", see ``mark_duplicates``);
    for file sources the list is written to ``list_path`` (if new) before returning. Raises
    ModelIdClash (a ValueError) when two files would be the same model."""
    if s.is_procedural:
        return _procedural(s, category)
    from pipeline.sources.layouts import list_models

    refs = list_models(s.source, category, s.limit, s.seed, Path(s.work_dir))
    cache_path = s.stage_dir("source") / category / HASHES
    cache = read_json(cache_path) if cache_path.exists() else {}
    before = dict(cache)
    root = os.path.abspath(s.source)
    keys = [model_key(Path(r.path), cache, root) for r in refs]
    models = [
        {"model_id": r.model_id, "work_id": work_id(r.model_id, k.sha), "path": str(r.path), "source": r.source}
        for r, k in zip(refs, keys)
    ]
    mark_duplicates(models, keys, root)
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
