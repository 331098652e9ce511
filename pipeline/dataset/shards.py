"""WebDataset tar shards: one sample per model, written byte-deterministically.

A sample's key is ``<category>_<model_id>``; its members are ``points.npy``, one
``sketch_<view>_<variant>.png`` per view and variant, ``strokes.json``, ``cameras.json``,
``meta.json`` and, where the source has part labels, ``point_parts.npy``. Every name and
``meta.json`` field is defined in :mod:`pipeline.core.schema`. Tars are written with :mod:`tarfile` rather than ``webdataset.TarWriter`` so
every header field is fixed (sorted member order, mtime 0, uid/gid 0, empty user/group names,
mode 0o644, GNU format): the same inputs give the same bytes.

Shards of one category go to ``<dataset-dir>/<category>/<split>-NNNNN.tar``. They are first
written into a staging folder of this process, then moved into place one by one; a shard whose
bytes did not change is not rewritten, so its mtime stays. One writer at a time per category
folder (``.shards.lock``), whatever scheduler started it. Only files this build's records list
(``.shards.json``, ``category.json``, ``manifest.json``) are ever replaced or deleted: any other
``<split>-NNNNN.tar`` in the folder stops the build with its name.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import io
import os
import re
import shutil
import socket
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from pipeline.core.atomic import dumps_json, read_json, write_json
from pipeline.core.errors import ModelError
from pipeline.core.hashing import file_sha256
from pipeline.core.schema import (
    CAMERAS_FILE,
    CAMERAS_MEMBER,
    FIT_MEMBER,
    FIT_PARAMS_MEMBER,
    FRAGMENT,
    MANIFEST,
    META_MEMBER,
    POINT_PARTS_MEMBER,
    POINTS_MEMBER,
    RECORD,
    SAMPLES_FILE,
    SHARD_RE,
    SKETCH_GLOB,
    SPLITS,
    STROKES_FILE,
    STROKES_MEMBER,
    SampleMeta,
    present_parts,
    sample_key,
    shard_name,
)
from pipeline.core.seeding import rng_for
from pipeline.core.settings_io import setting
from pipeline.core.splits import DEFAULT_FRACTIONS, split_of
from pipeline.dataset.point_parts import prepared_point_parts, procedural_point_parts, source_obj

TAR_FORMAT = tarfile.GNU_FORMAT
MIN_POINTS = 7000
_BLOCK = tarfile.BLOCKSIZE


@dataclasses.dataclass(frozen=True)
class ShardSettings:
    """How samples are packed. Part of the shard stage key."""

    max_samples_per_shard: int = setting(256, "a shard holds at most this many samples")
    max_bytes_per_shard: int = setting(512 * 2**20, "... and at most about this many bytes")
    points: int = setting(16384, "points per sample; the prepared samples are subsampled when larger")
    split_fractions: tuple[float, float, float] = setting(
        DEFAULT_FRACTIONS, "train, val and test shares of each category"
    )


@dataclasses.dataclass(frozen=True)
class ModelDirs:
    """Where one model's finished stage outputs are."""

    model_id: str
    prepare_dir: Path
    render_dir: Path
    augment_dir: Path
    # the fit stage's result, when it ran: (float32 parameters (D,), the FIT_MEMBER fields)
    fit: tuple[np.ndarray, dict] | None = None


@dataclasses.dataclass
class Sample:
    key: str
    split: str
    members: dict[str, bytes]  # member suffix ("points.npy", ...) -> bytes

    @property
    def tar_size(self) -> int:
        """Bytes this sample takes in a tar (one header block per member + padded data)."""
        return sum(_BLOCK + -(-len(b) // _BLOCK) * _BLOCK for b in self.members.values())


@dataclasses.dataclass(frozen=True)
class ShardInfo:
    name: str
    split: str
    samples: int
    bytes: int
    sha256: str
    keys: tuple[str, ...]

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "samples": self.samples,
            "bytes": self.bytes,
            "sha256": self.sha256,
            "keys": list(self.keys),
        }


# ---------------------------------------------------------------- sample assembly


def _read_bytes(path: Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise ModelError(path, f"cannot read: {e.strerror or e}") from e


def _load_points(path: Path, n: int, key: tuple) -> tuple[np.ndarray, np.ndarray | None]:
    """The sample's points and which prepared samples they are (None: all of them)."""
    try:
        pts = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise ModelError(path, f"cannot load surface samples: {e}") from e
    if pts.ndim != 2 or pts.shape[1] != 6 or not np.isfinite(pts).all():
        raise ModelError(path, f"surface samples must be finite (N, 6), got shape {pts.shape}")
    idx = None
    if len(pts) > n:
        # a seeded subset, sorted so the member keeps the prepared order
        idx = np.sort(rng_for(*key).choice(len(pts), size=n, replace=False))
        pts = pts[idx]
    if len(pts) < MIN_POINTS:
        raise ModelError(path, f"only {len(pts)} surface samples, need at least {MIN_POINTS}")
    return np.ascontiguousarray(pts, dtype=np.float32), idx


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _record(folder: Path) -> dict:
    path = Path(folder) / RECORD
    try:
        rec = read_json(path)
    except (OSError, ValueError) as e:
        raise ModelError(path, f"cannot read stage record: {e}") from e
    if rec.get("status") != "ok":
        reason = (rec.get("error") or {}).get("reason", "stage did not finish")
        raise ModelError(path, f"stage record is not ok: {reason}")
    return rec


def _part_labels(rec: dict) -> tuple[list[str] | None, list[str] | None]:
    """(part labels, present families) of a prepare record, (None, None) without parts.

    A file source's parts carry their family, named at prepare as the template builder names
    them (``seg3`` stays ``seg3``; a part the map drops has none); the generator's labels are
    reduced to families here (``part_family``)."""
    parts = rec.get("parts") or []
    if any("family" in p for p in parts):
        kept = [p for p in parts if p.get("family")]
        return [p["label"] for p in kept] or None, sorted({p["family"] for p in kept}) or None
    labels = [p["label"] for p in parts] or None
    return labels, present_parts(labels)


def assemble_sample(
    category: str,
    dirs: ModelDirs,
    settings: ShardSettings,
    seed: int,
    settings_hash: str,
    portable=lambda p: p,
) -> Sample:
    """Gather one model's members from the prepare, render and augment folders.

    ``portable`` maps absolute paths to ones that do not depend on where the build ran, so two
    builds in different folders write the same ``meta.json``. Raises ModelError on bad input.
    """
    prep = _record(dirs.prepare_dir)
    _record(dirs.render_dir)
    _record(dirs.augment_dir)
    key = sample_key(category, dirs.model_id)
    points, idx = _load_points(
        dirs.prepare_dir / SAMPLES_FILE, settings.points, (seed, "shards", category, dirs.model_id)
    )
    members: dict[str, bytes] = {POINTS_MEMBER: _npy_bytes(points)}
    sketches = sorted(p for p in Path(dirs.augment_dir).glob(SKETCH_GLOB))
    if not sketches:
        raise ModelError(dirs.augment_dir, "no sketch_<view>_<variant>.png images")
    for p in sketches:
        members[p.name] = _read_bytes(p)
    members[STROKES_MEMBER] = _read_bytes(dirs.augment_dir / STROKES_FILE)
    members[CAMERAS_MEMBER] = _read_bytes(dirs.render_dir / CAMERAS_FILE)
    if dirs.fit is not None:
        members[FIT_PARAMS_MEMBER] = _npy_bytes(np.ascontiguousarray(dirs.fit[0], dtype=np.float32))
        members[FIT_MEMBER] = dumps_json(dirs.fit[1]).encode()
    labels, present = _part_labels(prep)
    point_names = None
    prepared = prepared_point_parts(dirs.prepare_dir, prep, idx) if labels else None
    obj = source_obj(dirs.prepare_dir, prep) if labels and prepared is None else None
    if prepared is not None:
        ids, point_names = prepared
        members[POINT_PARTS_MEMBER] = _npy_bytes(ids)
    elif obj is not None:
        norm = prep.get("normalization") or {}
        try:
            ids, point_names = procedural_point_parts(
                obj, points, norm["center"], norm["scale"], rng_for(seed, "point-parts", category, dirs.model_id)
            )
        except (KeyError, ValueError) as e:
            raise ModelError(obj, f"cannot label surface points by part: {e}") from e
        members[POINT_PARTS_MEMBER] = _npy_bytes(ids)
    src = prep.get("source") or {}  # {"kind", "path", "sha256"}, as prepare writes it
    meta = SampleMeta(
        key=key,
        category=category,
        model_id=dirs.model_id,
        source=portable(src["path"]) if src.get("path") else None,
        source_sha256=src.get("sha256"),
        normalization=prep.get("normalization"),
        part_labels=labels,
        present_parts=present,
        point_part_names=point_names,
        bodies=prep.get("bodies"),
        seed=seed,
        settings_hash=settings_hash,
        split=split_of(category, dirs.model_id, settings.split_fractions),
        sketches=[p.name for p in sketches],
        points=int(len(points)),
    )
    members[META_MEMBER] = dumps_json(meta.to_json()).encode()
    return Sample(key=key, split=meta.split, members=members)


def fit_target(
    category: str, prepare_dir: Path, model_id: str, n: int, seed: int
) -> tuple[np.ndarray, np.ndarray | None, list[str] | None, list[str] | None]:
    """What the fit stage fits a model to, from its prepare folder, labelled as its shard sample
    is: (points (n, 6): a seeded subset of the samples, drawn with replacement when there are
    fewer; per-point family ids or None; their names; the families present). ModelError on bad input."""
    prep = _record(prepare_dir)
    path = Path(prepare_dir) / SAMPLES_FILE
    try:
        pts = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise ModelError(path, f"cannot load surface samples: {e}") from e
    if pts.ndim != 2 or pts.shape[1] != 6 or not len(pts) or not np.isfinite(pts).all():
        raise ModelError(path, f"surface samples must be finite (N, 6), got shape {pts.shape}")
    idx = np.sort(rng_for(seed, "fit", category, model_id).choice(len(pts), size=n, replace=len(pts) < n))
    points = np.ascontiguousarray(pts[idx], dtype=np.float32)
    labels, present = _part_labels(prep)
    if not labels:
        return points, None, None, present
    prepared = prepared_point_parts(prepare_dir, prep, idx)
    if prepared is not None:
        return points, prepared[0].astype(np.int64), prepared[1], present
    obj = source_obj(prepare_dir, prep)
    if obj is None:
        return points, None, None, present
    norm = prep.get("normalization") or {}
    try:
        ids, names = procedural_point_parts(
            obj, points, norm["center"], norm["scale"], rng_for(seed, "fit-point-parts", category, model_id)
        )
    except (KeyError, ValueError) as e:
        raise ModelError(obj, f"cannot label surface points by part: {e}") from e
    return points, ids.astype(np.int64), names, present


# ---------------------------------------------------------------- tar writing / reading


def _tarinfo(name: str, size: int) -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.size = size
    info.mtime = 0
    info.mode = 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.type = tarfile.REGTYPE
    return info


class TarShard:
    """Append samples to one tar with fixed headers; the file is complete only after close()."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self._file = open(self.path, "wb")
        self._tar = tarfile.open(fileobj=self._file, mode="w", format=TAR_FORMAT)
        self.keys: list[str] = []
        # end-of-archive blocks + padding to a full record: an upper bound of the tar's overhead
        self.size = tarfile.RECORDSIZE

    def add(self, sample: Sample) -> None:
        for suffix in sorted(sample.members):
            data = sample.members[suffix]
            self._tar.addfile(_tarinfo(f"{sample.key}.{suffix}", len(data)), io.BytesIO(data))
        self.keys.append(sample.key)
        self.size += sample.tar_size

    def close(self) -> None:
        self._tar.close()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()


def write_split_shards(
    samples: Iterable[Sample], split: str, out_dir: Path, settings: ShardSettings
) -> list[ShardInfo]:
    """Write ``<split>-NNNNN.tar`` files into ``out_dir`` from samples in key order.

    A shard closes when it holds max_samples_per_shard samples or the next sample would push it
    past max_bytes_per_shard (a single oversized sample still gets a shard of its own).
    """
    infos: list[ShardInfo] = []
    writer: TarShard | None = None

    def close() -> None:
        assert writer is not None
        writer.close()
        infos.append(
            ShardInfo(
                writer.path.name,
                split,
                len(writer.keys),
                writer.path.stat().st_size,
                file_sha256(writer.path),
                tuple(writer.keys),
            )
        )

    for sample in samples:
        if writer is not None and (
            len(writer.keys) >= settings.max_samples_per_shard
            or writer.size + sample.tar_size > settings.max_bytes_per_shard
        ):
            close()
            writer = None
        if writer is None:
            writer = TarShard(Path(out_dir) / shard_name(split, len(infos)))
        writer.add(sample)
    if writer is not None:
        close()
    return infos


def iter_shard(path: Path) -> Iterator[tuple[str, dict[str, bytes]]]:
    """Samples of a shard as (key, {suffix: bytes}), read with plain tarfile, in tar order."""
    current: str | None = None
    members: dict[str, bytes] = {}
    with tarfile.open(path, mode="r:") as tar:
        for info in tar:
            if not info.isfile():
                continue
            base = info.name.rsplit("/", 1)[-1]
            key, _, suffix = base.partition(".")
            f = tar.extractfile(info)
            data = f.read() if f is not None else b""
            if key != current:
                if current is not None:
                    yield current, members
                current, members = key, {}
            members[suffix] = data
    if current is not None:
        yield current, members


def list_shards(category_dir: Path) -> list[Path]:
    """Shard files of a category folder, sorted by name."""
    d = Path(category_dir)
    if not d.is_dir():
        return []
    return sorted(p for p in d.iterdir() if SHARD_RE.match(p.name))


# ---------------------------------------------------------------- what in a category folder is ours

# Names of the shards this build placed in a category folder, rewritten before shards are moved
# in (old and new names) and after stale ones are removed (the current names): with category.json
# and manifest.json it tells our files from a user's that merely look like shards.
OWNED_FILE = ".shards.json"
LOCK_FILE = ".shards.lock"
LOCK_WAIT_S = 900.0
# <host>-<pid>-<mkdtemp's random part>; the host part is optional for folders of older builds
_STAGING_RE = re.compile(r"^\.staging-(?:.+-\d+-)?[a-z0-9_]{8}$")


class NotOurFiles(RuntimeError):
    """Shard-named files in a category folder that this build did not write; it touches none."""

    def __init__(self, category_dir: Path, problems: list[str]):
        self.problems = problems
        where = Path(category_dir)
        shown = "; ".join(problems[:5]) + (f"; and {len(problems) - 5} more" if len(problems) > 5 else "")
        super().__init__(
            f"{where} holds {shown}; not written by this build (not in its "
            f"{FRAGMENT} or {MANIFEST}), so it is left alone: move it away or choose another --dataset-dir"
        )


class CategoryBusy(RuntimeError):
    """Another process holds the category's lock for longer than we wait."""


def _json_or_none(path: Path) -> dict | None:
    try:
        doc = read_json(path)
    except (OSError, ValueError):
        return None  # missing or damaged: it vouches for nothing
    return doc if isinstance(doc, dict) else None


def _listed_names(entry: dict | None) -> set[str]:
    """Shard names a category.json (or its manifest.json entry) lists."""
    names: set[str] = set()
    for split in ((entry or {}).get("splits") or {}).values():
        for sh in (split or {}).get("shards") or []:
            if isinstance(sh, dict) and isinstance(sh.get("name"), str):
                names.add(sh["name"])
    return names


def owned_shards(category_dir: Path) -> set[str]:
    """Names in ``category_dir`` this build may replace or delete: those its own marker file,
    category.json or the dataset's manifest.json lists (any one is enough: each may be the one
    a killed run or a user's edit left behind)."""
    d = Path(category_dir)
    marker = _json_or_none(d / OWNED_FILE) or {}
    names = {n for n in marker.get("shards") or [] if isinstance(n, str)}
    names |= _listed_names(_json_or_none(d / FRAGMENT))
    manifest = _json_or_none(d.parent / MANIFEST) or {}
    names |= _listed_names((manifest.get("categories") or {}).get(d.name))
    return {n for n in names if SHARD_RE.match(n)}


def _is_empty_dir(p: Path) -> bool:
    return p.is_dir() and not p.is_symlink() and not any(p.iterdir())


def shard_conflicts(category_dir: Path) -> list[str]:
    """Shard-named entries of ``category_dir`` a build must not touch, each as "<name>: why"
    ([] = none). Empty folders are not listed: removing one loses nothing."""
    owned = owned_shards(category_dir)
    out = []
    for p in list_shards(category_dir):
        if _is_empty_dir(p):
            continue
        if p.is_dir() and not p.is_symlink():
            out.append(f"{p.name}: a folder with files in it")
        elif p.name not in owned:
            out.append(f"{p.name}: a {'link' if p.is_symlink() else 'file'}")
    return out


def _write_owned(category_dir: Path, names: Iterable[str]) -> None:
    write_json(Path(category_dir) / OWNED_FILE, {"shards": sorted(set(names))})


def _remove_shard_path(p: Path) -> None:
    """Delete a shard file (or the empty folder that took its name)."""
    if _is_empty_dir(p):
        p.rmdir()
    else:
        p.unlink()


def _holder(lock_path: Path) -> str:
    try:
        host, pid = lock_path.read_text().split()[:2]
        return f"pid {pid} on {host}"
    except (OSError, ValueError):
        return "a process that did not say who it is"


@contextlib.contextmanager
def category_lock(category_dir: Path, wait_s: float = LOCK_WAIT_S) -> Iterator[None]:
    """Hold the category folder's exclusive lock (flock on ``.shards.lock``): one writer at a
    time whatever scheduler started it. Waits up to ``wait_s`` for another holder, then raises
    CategoryBusy naming it. The kernel drops the lock of a killed holder, so none goes stale."""
    path = Path(category_dir) / LOCK_FILE
    deadline = time.monotonic() + wait_s
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            if time.monotonic() >= deadline:
                raise CategoryBusy(
                    f"another build is writing {category_dir} ({_holder(path)}) and did not finish "
                    f"within {wait_s:g} s; let it finish, or use another --dataset-dir"
                ) from None
            time.sleep(0.2)
            continue
        # A holder unlinks the file before it lets go: a lock won on the unlinked file guards nothing.
        try:
            st = os.stat(path)
            mine = os.fstat(fd)
            if (st.st_ino, st.st_dev) == (mine.st_ino, mine.st_dev):
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{socket.gethostname()} {os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)


def _remove_stale_staging(category_dir: Path) -> None:
    """Staging folders of killed runs (called under the category lock, so none is in use)."""
    for p in Path(category_dir).iterdir():
        if _STAGING_RE.match(p.name) and p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)


# ---------------------------------------------------------------- a category's shard set


@dataclasses.dataclass
class ShardSet:
    """What writing one category's shards did (the Luigi task ``CategoryShards`` runs it)."""

    shards: dict[str, list[ShardInfo]]  # split -> shards
    failed: list[dict]  # {"model_id", "stage", "path", "reason"}
    written: list[str]  # shard names whose bytes changed (or are new)
    removed: list[str]  # stale shard names deleted


def write_category_shards(
    category: str,
    models: list[ModelDirs],
    category_dir: Path,
    settings: ShardSettings,
    seed: int,
    settings_hash: str,
    portable=lambda p: p,
    before_cleanup=None,
    lock_wait_s: float = LOCK_WAIT_S,
) -> ShardSet:
    """Build the shard set of one category in a staging folder, then move it into place.

    Unchanged shards (same sha256) are left untouched. ``before_cleanup(result)`` runs after the
    new shards are in place and before stale ones are deleted: the caller writes the category's
    manifest fragment there, so the fragment never lists a shard that is missing. Raises
    NotOurFiles, before writing anything, when a shard-named file the build did not write is in
    the folder; CategoryBusy when another process keeps the folder locked past ``lock_wait_s``.
    """
    category_dir = Path(category_dir)
    category_dir.mkdir(parents=True, exist_ok=True)
    with category_lock(category_dir, lock_wait_s):
        _remove_stale_staging(category_dir)
        problems = shard_conflicts(category_dir)
        if problems:
            raise NotOurFiles(category_dir, problems)
        return _write_locked(category, models, category_dir, settings, seed, settings_hash, portable, before_cleanup)


def _write_locked(
    category: str,
    models: list[ModelDirs],
    category_dir: Path,
    settings: ShardSettings,
    seed: int,
    settings_hash: str,
    portable,
    before_cleanup,
) -> ShardSet:
    failed: list[dict] = []
    by_split: dict[str, list[ModelDirs]] = {s: [] for s in SPLITS}
    for m in sorted(models, key=lambda m: sample_key(category, m.model_id)):
        by_split[split_of(category, m.model_id, settings.split_fractions)].append(m)

    def samples(ms: list[ModelDirs]) -> Iterator[Sample]:
        for m in ms:
            try:
                yield assemble_sample(category, m, settings, seed, settings_hash, portable)
            except ModelError as e:
                failed.append({"model_id": m.model_id, "stage": "shards", "path": portable(e.path), "reason": e.reason})

    owned = owned_shards(category_dir)
    staging = Path(tempfile.mkdtemp(prefix=f".staging-{socket.gethostname()}-{os.getpid()}-", dir=category_dir))
    try:
        shards = {s: write_split_shards(samples(by_split[s]), s, staging, settings) for s in SPLITS}
        keep = {i.name for infos in shards.values() for i in infos}
        # before any move: a run killed from here on still knows every shard name it may own
        _write_owned(category_dir, owned | keep)
        written: list[str] = []
        for infos in shards.values():
            for info in infos:
                dst = category_dir / info.name
                if (
                    dst.is_file()
                    and not dst.is_symlink()
                    and dst.stat().st_size == info.bytes
                    and file_sha256(dst) == info.sha256
                ):
                    continue  # same bytes: keep the old file and its mtime
                if _is_empty_dir(dst):
                    dst.rmdir()  # a folder took the shard's name; it holds nothing
                os.replace(staging / info.name, dst)
                written.append(info.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    result = ShardSet(shards, sorted(failed, key=lambda f: f["model_id"]), written, [])
    if before_cleanup is not None:
        before_cleanup(result)
    for p in list_shards(category_dir):
        if p.name not in keep and (p.name in owned or _is_empty_dir(p)):
            _remove_shard_path(p)
            result.removed.append(p.name)
    _write_owned(category_dir, keep)
    return result


def retire_category(category_dir: Path, lock_wait_s: float = LOCK_WAIT_S) -> list[str]:
    """Delete a category the source no longer has: the shards its records list, category.json
    and the marker, then the folder if nothing else is in it. Returns what was left (a user's
    files), relative to the folder."""
    category_dir = Path(category_dir)
    with category_lock(category_dir, lock_wait_s):
        _remove_stale_staging(category_dir)
        owned = owned_shards(category_dir)
        for p in list_shards(category_dir):
            if p.name in owned and not (p.is_dir() and not _is_empty_dir(p)):
                _remove_shard_path(p)
        for name in (FRAGMENT, OWNED_FILE):
            with contextlib.suppress(FileNotFoundError):
                (category_dir / name).unlink()
    left = sorted(p.name for p in category_dir.iterdir())
    if not left:
        category_dir.rmdir()
    return left
