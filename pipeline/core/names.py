"""Names that become paths: one rule for every model id, category and file name taken from outside.

A source folder, a glTF or a manifest can hold any name: ``../x``, ``manifest.json``, ``CON``,
250 characters, a newline, ``{1}`` (a Blender path template), a backslash. ``safe_component``
keeps a name that is already a plain, short file name unchanged (procedural and ShapeNet ids
never move) and turns any other into a readable slug plus a short hash of the original, so two
different names stay two names. ``inside`` is the last check before a path is written or read.
"""

from __future__ import annotations

import hashlib
import os
import re
import unicodedata
from pathlib import Path

from pipeline.core.schema import FRAGMENT, MANIFEST, RECORD

MAX_LEN = 64  # with the work id's "-<sha12>" well under every file system's 255-byte limit
SLUG_LEN = 40
HASH_LEN = 8
_SAFE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]*")
_SLUG_DROP = re.compile(r"[^A-Za-z0-9_-]+")
# Names the dataset and work folders use themselves, and names Windows will not create.
RESERVED = frozenset(n.casefold() for n in (MANIFEST, FRAGMENT, RECORD))
_WINDOWS = re.compile(r"(con|prn|aux|nul|com[0-9]|lpt[0-9])(\..*)?", re.IGNORECASE)


class UnsafePath(ValueError):
    """A path built from an outside name would lie outside the folder it must stay in."""


def is_safe_component(name: str, leading: str = "") -> bool:
    """Whether ``name`` is used as it is: ASCII letters, digits, '.', '_', '-', at most MAX_LEN
    characters, starting with a letter, digit or '_' (none of ``leading``), not reserved, no
    trailing dot (Windows drops it)."""
    return (
        bool(_SAFE.fullmatch(name))
        and len(name) <= MAX_LEN
        and not name.endswith(".")
        and name.casefold() not in RESERVED
        and not _WINDOWS.fullmatch(name)
        and not (leading and name.startswith(tuple(leading)))
    )


def name_hash(name: str) -> str:
    """Short hash of a name's exact bytes (undecodable file-name bytes included)."""
    return hashlib.sha256(name.encode("utf-8", "surrogateescape")).hexdigest()[:HASH_LEN]


def safe_component(name: str, leading: str = "") -> str:
    """``name`` itself when ``is_safe_component``, else ``<slug>-<hash of name>``: the slug is
    the name folded to ASCII with every other run of characters read as '_' (at most SLUG_LEN),
    never empty, never starting with '_' or '.'. Deterministic: equal names, equal results."""
    if is_safe_component(name, leading):
        return name
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    slug = _SLUG_DROP.sub("_", ascii_name).strip("_-")[:SLUG_LEN].rstrip("_-") or "x"
    return f"{slug}-{name_hash(name)}"


def inside(root: Path, path: Path) -> Path:
    """``path`` resolved, after checking it lies inside ``root`` (also resolved, links followed);
    raises UnsafePath otherwise. Call it on every path joined from an outside name."""
    base = Path(os.path.realpath(root))
    full = Path(os.path.realpath(path))
    if full != base and not full.is_relative_to(base):
        raise UnsafePath(f"{str(path)!r} lies outside {str(root)!r}")
    return full
