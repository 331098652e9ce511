"""Atomic writes: a file either exists whole or not at all (temp file in the same folder + rename).

Storage errors (disk full, permission denied, read-only filesystem) are re-raised as
StorageError naming the file and the problem in words, so a build log says what to fix.
``SKETCH_FAULT_KILL_AT`` and ``SKETCH_FAULT_ERRNO_AT`` are test hooks for kill/restart and
storage-error tests; see ``_fault_point``.
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import io
import itertools
import json
import os
import signal
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from pipeline.core.canonical_json import canonical_dumps
from pipeline.core.points_text import compact_dumps

# errno → what the user should read (and do) when a write fails
_STORAGE_PROBLEMS = {
    errno.ENOSPC: "disk full (no space left on device); free space or point --work-dir/--dataset-dir elsewhere",
    errno.EDQUOT: "disk quota exceeded; free space or raise the quota",
    errno.EACCES: "permission denied; make the folder writable by this user",
    errno.EPERM: "permission denied (operation not permitted); make the folder writable by this user",
    errno.EROFS: "read-only filesystem; point --work-dir/--dataset-dir at writable storage",
}


class StorageError(OSError):
    """An output file could not be written; ``str()`` names the file and the problem."""

    def __str__(self) -> str:
        return str(self.strerror)


def storage_error(path: str | Path, exc: OSError) -> OSError:
    """``exc`` translated into a StorageError naming ``path`` if it is a storage problem, else ``exc``."""
    problem = _STORAGE_PROBLEMS.get(exc.errno) if exc.errno is not None else None
    if problem is None or isinstance(exc, StorageError):
        return exc
    err = StorageError(exc.errno, f"cannot write {path}: {problem}")
    err.filename = str(path)
    return err


_fault_counts: dict[str, int] = {}


def _fault_point(path: Path) -> None:
    """Test hooks, unset in normal runs (they cost one lookup each):

    - ``SKETCH_FAULT_KILL_AT="<glob>:<n>"`` SIGKILLs this process group just before the n-th
      atomic rename (in this process) of a path matching the glob, leaving the temp file behind
      exactly as a power cut or ``kill -9`` would.
    - ``SKETCH_FAULT_ERRNO_AT="<glob>:<ERRNO>"`` (e.g. ``*/view_00.png:ENOSPC``) makes every write
      of a matching path fail with that errno, as a full disk or read-only mount would, in any
      process (the Blender worker included).
    """
    failing = os.environ.get("SKETCH_FAULT_ERRNO_AT")
    if failing:
        pattern, _, name = failing.rpartition(":")
        if fnmatch.fnmatch(str(path), pattern):
            code = getattr(errno, name)
            raise OSError(code, os.strerror(code))
    spec = os.environ.get("SKETCH_FAULT_KILL_AT")
    if not spec:
        return
    pattern, _, nth = spec.rpartition(":")
    if not fnmatch.fnmatch(str(path), pattern):
        return
    _fault_counts[spec] = _fault_counts.get(spec, 0) + 1
    if _fault_counts[spec] == int(nth):
        os.killpg(os.getpgid(0), signal.SIGKILL)


_tmp_numbers = itertools.count()


@contextlib.contextmanager
def _replacing(path: Path, suffix: str) -> Iterator[tuple[int, Path]]:
    """A new temp file next to ``path`` (its descriptor, for the block to close, and its path),
    renamed onto ``path`` if the block succeeds, removed if not (storage errors named).

    The temp name is hidden, holds the process id and a counter (writers never share one; a
    leftover of a killed process is skipped, ``O_EXCL``) and keeps ``suffix``, so libraries that
    pick a format from the extension (trimesh, cv2) still work; the umask sets its mode, as for
    any new file, so other users and machines sharing the storage can read it. Open, write,
    close and rename: half the system calls of mkstemp, a chmod and a second open.
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    try:
        while True:
            tmp = path.parent / f".{path.name}.{os.getpid()}-{next(_tmp_numbers)}.tmp{suffix}"
            try:
                fd = os.open(tmp, flags, 0o666)
                break
            except FileExistsError:
                continue
            except FileNotFoundError:
                path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise storage_error(path, exc) from exc
    try:
        yield fd, tmp
        _fault_point(path)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise storage_error(path, exc) from exc
        raise


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` only if the block succeeds.

    The temp name keeps the target's suffix (or ``suffix``) for libraries that pick a format
    from the extension.
    """
    path = Path(path)
    with _replacing(path, suffix if suffix is not None else "".join(path.suffixes)) as (fd, tmp):
        os.close(fd)
        yield tmp


def write_bytes(path: str | Path, data: bytes) -> None:
    """``data`` at ``path`` whole or not at all, on disk before the rename (fsync)."""
    path = Path(path)
    with _replacing(path, "".join(path.suffixes)) as (fd, tmp):
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)


def dumps_json(obj: Any) -> str:
    """Canonical JSON (sorted keys, fixed separators) so equal content gives equal bytes: the text
    of ``json.dumps(obj, sort_keys=True, indent=1)``, written by pipeline.core.canonical_json."""
    return canonical_dumps(obj, _json_default) + "\n"


def dumps_json_compact(obj: Any) -> str:
    """Canonical JSON without white space (sorted keys, ``,`` and ``:``): for bulk data such as
    the stroke files (~100k coordinates a model), which the C encoder writes several times
    faster than the indented text and in about half the bytes; equal content, equal bytes.
    ``pipeline.core.points_text.RoundedPoints`` values are written by its compiled writer."""
    return compact_dumps(obj, _json_default) + "\n"


def write_json(path: str | Path, obj: Any, compact: bool = False) -> None:
    """``obj`` as canonical JSON: indented (records, manifests: read by people) or, with
    ``compact``, :func:`dumps_json_compact` (bulk data read by programs)."""
    write_bytes(path, (dumps_json_compact(obj) if compact else dumps_json(obj)).encode())


def read_json(path: str | Path) -> Any:
    with open(path) as f:
        return json.load(f)


def write_npy(path: str | Path, array: np.ndarray) -> None:
    # serialized in memory: np.save onto a full disk raises an OSError without errno
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    write_bytes(path, buf.getvalue())


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")
