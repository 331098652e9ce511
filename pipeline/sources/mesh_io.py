"""Reading source meshes and writing prepared ones.

Loading turns any supported file (OBJ, OFF, PLY, STL, GLB/GLTF) into one triangle soup (float64
vertices, int64 faces), flattening scene graphs with their transforms. Every failure becomes a
ModelError naming the file, so a batch can record it and move on.

Each format is one ``MeshFormat`` entry in ``FORMATS`` (its extensions, how its first bytes
look, its integrity checks, its loader); listing, sniffing, checking and loading only look the
entry up. A new format is one ``register_format(MeshFormat(...))`` call at the end of this file.
"""

from __future__ import annotations

import io
import json
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from pipeline.core.atomic import write_bytes
from pipeline.core.errors import ModelError
from pipeline.core.plain_ply import read_plain_ply

HEAD_BYTES = 4096
_DENIED = "permission denied (check the owner and mode of the file and its folders)"

# Signatures of common files that are not meshes, so the error can say what the file is.
_NOT_MESH_MAGIC = {
    b"\x89PNG": "a PNG image",
    b"\xff\xd8\xff": "a JPEG image",
    b"%PDF": "a PDF document",
    b"PK\x03\x04": "a ZIP archive",
    b"\x1f\x8b": "a gzip archive",
    b"\x7fELF": "an executable",
    b"GIF8": "a GIF image",
}
_PLY_SIZES = {
    "char": 1,
    "int8": 1,
    "uchar": 1,
    "uint8": 1,
    "short": 2,
    "int16": 2,
    "ushort": 2,
    "uint16": 2,
    "int": 4,
    "int32": 4,
    "uint": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}
_OBJ_LINE = re.compile(rb"^[ \t]*(v|vn|vt|f|o|g|mtllib|usemtl)[ \t]", re.M)
_OBJ_ZERO = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])0(?=[/ \t\r\n]|$)", re.M)  # a face corner "0", "0/..", "0//.."
_BOM = b"\xef\xbb\xbf"


def _file_kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
    ):
        if test(mode):
            return name
    return "not a regular file"


@dataclass(frozen=True)
class MeshFormat:
    """One mesh file format.

    ``name`` is how messages call it (upper-cased) and what ``sniff_format`` returns;
    ``extensions`` (lower case, with the dot) are the file names it claims. ``sniff(head, size)``
    says whether the first ``HEAD_BYTES`` bytes of a file of ``size`` bytes are this format.
    ``accepts``: sniffed formats a file with this extension may hold (default: this one);
    ``unsniffed_ok(head)``: whether content no format recognises is still worth parsing (OBJ has
    no magic). ``check(path, head, size, found)`` raises ModelError for a truncated or corrupt
    file before it is parsed (``found``: what ``sniff_format`` said). ``load(path, head)`` returns
    (vertices, faces) or raises; any exception becomes a ModelError naming the file.
    ``sniff_last``: tried after every other format's sniff (a loose test such as OBJ's)."""

    name: str
    extensions: tuple[str, ...]
    sniff: Callable[[bytes, int], bool]
    load: Callable[[Path, bytes], tuple[np.ndarray, np.ndarray]]
    check: Callable[[Path, bytes, int, str | None], None] | None = None
    accepts: tuple[str, ...] = ()
    unsniffed_ok: Callable[[bytes], bool] = lambda head: False
    sniff_last: bool = False


FORMATS: dict[str, MeshFormat] = {}


def register_format(fmt: MeshFormat) -> MeshFormat:
    """Add a format (name and extensions must be new); listing and loading then know it."""
    taken = {e for f in FORMATS.values() for e in f.extensions}
    if fmt.name in FORMATS or taken & set(fmt.extensions):
        raise ValueError(f"mesh format {fmt.name!r} or one of its extensions {fmt.extensions} is already registered")
    FORMATS[fmt.name] = fmt
    return fmt


def mesh_extensions() -> tuple[str, ...]:
    """Every extension (lower case, with the dot) of a registered format."""
    return tuple(e for f in FORMATS.values() for e in f.extensions)


def format_for(path: Path) -> MeshFormat | None:
    """The registered format a file name's extension (any case) claims, or None."""
    ext = path.suffix.lower()
    return next((f for f in FORMATS.values() if ext in f.extensions), None)


def sniff_format(head: bytes, size: int) -> str | None:
    """The name of the mesh format the file's first bytes show, or None if none."""
    for fmt in sorted(FORMATS.values(), key=lambda f: f.sniff_last):  # stable: registration order
        if fmt.sniff(head, size):
            return fmt.name
    return None


def _ply_min_bytes(header: str) -> int:
    """Fewest body bytes a binary PLY with this header can have (faces: 3 indices each)."""
    total, element, count = 0, None, 0
    for line in header.splitlines():
        words = line.split()
        if words[:1] == ["element"] and len(words) >= 3:
            element, count = words[1], int(words[2])
        elif words[:1] == ["property"] and element is not None:
            if len(words) >= 5 and words[1] == "list":
                per = _PLY_SIZES.get(words[2], 1) + (3 * _PLY_SIZES.get(words[3], 4) if element == "face" else 0)
            else:
                per = _PLY_SIZES.get(words[1], 4)
            total += count * per
    return total


def check_container(path: Path, head: bytes, size: int) -> MeshFormat:
    """The file's format, after raising ModelError if the bytes are not a mesh, are a mesh of
    another format than the extension says, or fail the format's own checks (truncated files)."""
    ext = path.suffix.lower()
    fmt = format_for(path)
    if fmt is None:
        raise ModelError(path, f"unreadable: unsupported extension {path.suffix!r}")
    for magic, what in _NOT_MESH_MAGIC.items():
        if head.startswith(magic):
            raise ModelError(path, f"not a mesh: the file is {what}")
    found = sniff_format(head, size)
    if found is not None and found not in (fmt.accepts or (fmt.name,)):
        raise ModelError(path, f"wrong extension: named {ext} but the content is {found.upper()} data")
    if found is None and not fmt.unsniffed_ok(head):
        kind = "text" if b"\0" not in head else "binary data"
        raise ModelError(path, f"not a mesh: {kind} in no {ext[1:].upper()} layout")
    if fmt.check is not None:
        fmt.check(path, head, size, found)
    return fmt


def _is_ascii_stl(head: bytes) -> bool:
    return head.lstrip().lower().startswith(b"solid")


def _check_stl(path: Path, head: bytes, size: int, found: str | None) -> None:
    if _is_ascii_stl(head):
        return
    n = int.from_bytes(head[80:84], "little") if size >= 84 else 0
    if size < 84 or size < 84 + 50 * n:
        raise ModelError(
            path, f"truncated: binary STL declares {n} triangles ({84 + 50 * n} bytes) but the file has {size} bytes"
        )


def _check_ply(path: Path, head: bytes, size: int, found: str | None) -> None:
    end = head.find(b"end_header")
    if end < 0:
        raise ModelError(path, "truncated: PLY header has no end_header")
    header = head[:end].decode("ascii", "replace")
    body_start = head.index(b"\n", end) + 1 if b"\n" in head[end:] else len(head)
    need = _ply_min_bytes(header) if "binary" in header else 0
    if size - body_start < need:
        raise ModelError(
            path, f"truncated: PLY header declares at least {need} bytes of data but the file has {size - body_start}"
        )
    if b"format ascii" in head:
        _check_ascii_ply_body(path)


def _check_glb(path: Path, head: bytes, size: int, found: str | None) -> None:
    if found == "glb" and size >= 12 and size < (declared := int.from_bytes(head[8:12], "little")):
        raise ModelError(path, f"truncated: GLB header declares {declared} bytes but the file has {size}")
    _check_gltf_files(path)


# ---------------------------------------------------------------- glTF external files


def _gltf_json(path: Path) -> dict | None:
    """The JSON of a .gltf, or of a .glb's first (JSON) chunk; None when it is not readable as such."""
    try:
        with open(path, "rb") as f:
            head = f.read(20)
            if head[:4] == b"glTF" and len(head) == 20 and head[16:20] == b"JSON":
                data = f.read(int.from_bytes(head[12:16], "little"))
            elif path.suffix.lower() == ".gltf":
                data = head + f.read()
            else:
                return None
        doc = json.loads(data.decode("utf-8-sig"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def _resolve_like_trimesh(folder: Path, uri: str) -> Path | None:
    """The file trimesh's FilePathResolver reads for ``uri`` (same candidates, in its order,
    none outside the glTF's folder), or None when it would find none."""
    base = folder.resolve()
    for candidate in (uri.strip(), uri.strip().lstrip("/"), os.path.split(uri)[-1]):
        if not candidate:
            continue
        full = (base / candidate).resolve()
        if full.is_relative_to(base) and full.exists():
            return full
    return None


def gltf_external_files(path: str | Path) -> list[tuple[str, str, Path | None]]:
    """(kind, uri, file or None when missing) of every buffer and image a glTF/GLB reads from
    outside itself, in file order; [] for embedded data, other formats and unparsable files.
    These bytes are part of the model: the listing hashes them into its content key."""
    path = Path(path)
    if path.suffix.lower() not in (".gltf", ".glb"):
        return []
    doc = _gltf_json(path)
    if doc is None:
        return []
    out = []
    for kind in ("buffers", "images"):
        entries = doc.get(kind)
        for entry in entries if isinstance(entries, list) else []:
            uri = entry.get("uri") if isinstance(entry, dict) else None
            if isinstance(uri, str) and "base64," not in uri:  # trimesh decodes those inline
                out.append((kind, uri, _resolve_like_trimesh(path.parent, uri)))
    return out


def _check_gltf_files(path: Path) -> None:
    """A missing buffer is this model's failure, named, before trimesh's bare FileNotFoundError.
    (A missing image is not: trimesh loads the geometry without its texture.)"""
    for kind, uri, found in gltf_external_files(path):
        if kind == "buffers" and found is None:
            raise ModelError(
                path,
                f"missing glTF buffer {uri!r}: no such file in {path.parent.name!r} "
                "(external files must lie in the glTF's own folder)",
            )


def _read_all(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ModelError(path, f"unreadable: {exc.strerror or exc}") from None


def _data_lines(text: str) -> list[list[str]]:
    """Non-empty lines of a text mesh as words, comments dropped."""
    return [w for w in (line.split("#", 1)[0].split() for line in text.splitlines()) if w]


# Whole-file checks of text meshes the parsers get wrong (each format's ``check`` calls its own).


def _check_obj(path: Path, head: bytes, size: int, found: str | None) -> None:
    """OBJ face indices of 0: OBJ counts from 1, and a 0 silently becomes the last vertex."""
    data = _read_all(path)  # searched as bytes: an OBJ can be large, no decoded copy
    m = _OBJ_ZERO.search(data)
    if m is not None:
        line = data.count(b"\n", 0, m.start()) + 1
        raise ModelError(path, f"corrupt OBJ: face index 0 on line {line} (OBJ indices start at 1)")


def _check_off(path: Path, head: bytes, size: int, found: str | None) -> None:
    """OFF counts that disagree with the data."""
    lines = _data_lines(_read_all(path).decode("utf-8", "replace").lstrip("\ufeff"))
    words = lines[0][1:] if lines else []
    body = lines[1:]
    if not words and body:  # counts on their own line after "OFF"
        words, body = body[0], body[1:]
    try:
        nv, nf = int(words[0]), int(words[1])
    except (IndexError, ValueError):
        raise ModelError(path, "corrupt OFF: no vertex and face counts after the OFF line") from None
    if len(body) != nv + nf:
        what = "truncated or wrong OFF header counts" if len(body) < nv + nf else "wrong OFF header counts"
        raise ModelError(
            path,
            f"{what}: the header declares {nv} vertices and {nf} faces "
            f"({nv + nf} lines) but the file has {len(body)} data lines",
        )


def _check_ascii_ply_body(path: Path) -> None:
    """ASCII PLY bodies shorter than their header declares."""
    header, _, body = _read_all(path).decode("utf-8", "replace").partition("end_header")
    counts = [int(w[2]) for w in _data_lines(header) if w[:1] == ["element"] and len(w) >= 3 and w[2].isdigit()]
    rows = len(_data_lines(body))
    if rows < sum(counts):
        raise ModelError(path, f"truncated: ASCII PLY header declares {sum(counts)} data lines but the file has {rows}")


def load_mesh(path: str | Path, max_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n,3) float64 and triangle faces (m,3) int64 of a mesh file.

    Raises ModelError for a missing, unreadable, oversized, truncated or unparsable file, one
    whose content is not a mesh or not the format its extension says, or one without triangles.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            raise ModelError(
                path, f"unreadable: broken link (points to {os.readlink(path)}, which does not exist)"
            ) from None
        raise ModelError(path, "unreadable: file not found") from None
    except PermissionError:
        raise ModelError(path, f"unreadable: {_DENIED} on a folder above it") from None
    except OSError as exc:
        raise ModelError(path, f"unreadable: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ModelError(path, f"unreadable: not a regular file but {_file_kind(st.st_mode)}")
    if format_for(path) is None:
        raise ModelError(path, f"unreadable: unsupported extension {path.suffix!r}")
    size = st.st_size
    if size == 0:
        raise ModelError(path, "empty mesh: file has 0 bytes")
    if max_bytes is not None and size > max_bytes:
        raise ModelError(path, f"huge mesh: file is {size} bytes > max_input_bytes {max_bytes}")
    try:
        with open(path, "rb") as f:
            head = f.read(HEAD_BYTES)
    except PermissionError:
        raise ModelError(path, f"unreadable: {_DENIED}") from None
    except OSError as exc:
        raise ModelError(path, f"unreadable: {exc.strerror or exc}") from None
    fmt = check_container(path, head, size)
    try:
        vertices, faces = fmt.load(path, head)
    except ModelError:
        raise
    except IndexError as exc:  # OBJ faces naming vertices the file doesn't have
        raise ModelError(path, f"unreadable: face indices out of range (truncated or corrupt file?): {exc}") from exc
    except Exception as exc:  # parsers raise anything from ValueError to struct.error
        raise ModelError(path, f"unreadable: {type(exc).__name__}: {exc}") from exc
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or len(faces) == 0 or len(vertices) == 0:
        raise ModelError(path, "empty mesh: no faces")
    if faces.shape[1] != 3:
        raise ModelError(path, f"unreadable: faces have {faces.shape[1]} corners, expected 3")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ModelError(path, "unreadable: face indices out of range (truncated or corrupt file?)")
    return vertices, faces


def _utf8(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:  # undecodable bytes of a file name, read as surrogates
        return False
    return True


def _trimesh_load(path: Path, head: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Any format trimesh reads: force="mesh" flattens scenes (GLB, multi-object OBJ) applying
    node transforms; process=False keeps the file's vertices untouched (watertighting repairs
    them anyway)."""
    import trimesh  # imported on use: see read_ply

    # From bytes when a UTF-8 byte order mark (Windows editors) would hide the first line from
    # the parser, or when the file name is not UTF-8 (trimesh names the geometry after it).
    if head.startswith(_BOM) or not _utf8(str(path)):
        data = _read_all(path)
        loaded = trimesh.load(
            io.BytesIO(data[len(_BOM) :] if data.startswith(_BOM) else data),
            file_type=path.suffix.lower()[1:],
            force="mesh",
            process=False,
            resolver=trimesh.resolvers.FilePathResolver(str(path.parent)),
        )
    else:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    if not isinstance(loaded, trimesh.Trimesh):
        # An empty scene (nothing parsable in the file) comes back as a Scene or a point cloud.
        raise ModelError(path, f"empty mesh: no triangles found (got {type(loaded).__name__})")
    return loaded.vertices, loaded.faces


def ply_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary little-endian PLY (float32 xyz, int32 indices); equal arrays give equal bytes."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64), process=False)
    return trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False, include_attributes=False)


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a mesh as binary PLY atomically."""
    write_bytes(path, ply_bytes(vertices, faces))


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a PLY written by write_ply, exactly as stored (no merging); any other
    mesh file through trimesh, which is imported only then (the embree render worker reads
    prepared PLYs without it)."""
    plain = read_plain_ply(path)
    if plain is not None:
        return plain
    import trimesh

    mesh = trimesh.load(str(path), force="mesh", process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


# Sniff order matters where tests overlap: registration order, OBJ's loose line test last.
register_format(MeshFormat("ply", (".ply",), lambda head, size: head.startswith(b"ply"), _trimesh_load, _check_ply))
register_format(MeshFormat("glb", (".glb",), lambda head, size: head.startswith(b"glTF"), _trimesh_load, _check_glb))
register_format(
    MeshFormat(
        "off",
        (".off",),
        lambda head, size: head.split(None, 1)[:1] in ([b"OFF"], [b"COFF"], [b"NOFF"]),
        _trimesh_load,
        _check_off,
    )
)
register_format(
    MeshFormat(
        "stl",
        (".stl",),
        # ASCII: "solid" ... "facet"; binary: the size matches the triangle count exactly
        lambda head, size: (
            (_is_ascii_stl(head) and b"facet" in head.lower())
            or (size >= 84 and 84 + 50 * int.from_bytes(head[80:84], "little") == size)
        ),
        _trimesh_load,
        _check_stl,
        unsniffed_ok=lambda head: not _is_ascii_stl(head),
    )
)
register_format(
    MeshFormat(
        "gltf",
        (".gltf",),
        lambda head, size: head.lstrip().startswith(b"{") and b'"asset"' in head,  # every glTF has an "asset"
        _trimesh_load,
        _check_glb,
        accepts=("glb", "gltf"),
    )
)
register_format(
    MeshFormat(
        "obj",
        (".obj",),
        lambda head, size: b"\0" not in head and _OBJ_LINE.search(head) is not None,
        _trimesh_load,
        _check_obj,
        unsniffed_ok=lambda head: True,
        sniff_last=True,
    )
)
