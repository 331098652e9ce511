"""Fetch real furniture meshes (chairs, tables, sofas, lamps ...) from Debian's Sweet Home 3D
furniture libraries and write them as a folder source: ``<out>/<category>/<model>.obj``.

    python tools/realworld/fetch_sweethome3d.py --category chair --out sources/furniture
    .venv/bin/luigi --module workflows BuildDataset --local-scheduler --source sources/furniture --categories chair ...

The Debian package ``sweethome3d-furniture`` (CC0 / CC-BY 3.0 model libraries: Scopia, Kator
Legaz, BlendSwap, Reallusion) is downloaded with ``apt-get download`` (nothing installed) and
unpacked with ``dpkg -x``, unless ``--deb`` names a downloaded one. Each library (``.sh3f``) is a
zip with a catalog (``PluginFurnitureCatalog.properties``: name, category, model path, size in cm,
optional model rotation) and OBJ models. A model whose catalog name matches the category's
pattern is read, rotated by its ``modelRotation``, scaled to its catalog width (x) x height (y)
x depth (z) as Sweet Home 3D shows it (y up, the front towards +z), and written as a plain OBJ
(vertices, triangles, its ``g`` groups; no materials). ``<out>/<category>/SOURCES.tsv`` lists
each model's library, catalog id, name, creator and licence: CC-BY models need that attribution
wherever they are shown.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

PACKAGE = "sweethome3d-furniture"
LIBRARY_DIR = Path("usr/share/sweethome3d/furniture")
LICENCES = {
    "Scopia": "CC-BY-3.0",
    "KatorLegaz": "CC-BY-3.0-US",
    "Reallusion": "CC-BY-3.0-US",
    "BlendSwap-CC-BY": "CC-BY-3.0",
    "BlendSwap-CC-0": "CC0",
}
# catalog names per category: (include, exclude) regular expressions, case-insensitive
PRESETS = {
    "chair": (
        r"\bchair\b",
        r"arm|deck|wheel|beach|high|relax|ryokan|ottoman|\bbar\b|baby|rocking|lounge|office|desk|massage|swivel|garden",
    ),
    "table": (r"\btable\b", r"tennis|pool|billiard|night|bedside|dressing|changing|ping|foosball|football"),
    "sofa": (r"\bsofa\b|\bcouch\b", r"bed"),
    "lamp": (r"\blamp\b", r"street|ceiling|wall|spot"),
    "bed": (r"\bbed\b", r"bunk|sofa|baby|table|side"),
}


@dataclass
class Entry:
    library: str
    number: str
    fields: dict[str, str]


def read_properties(text: str) -> dict[str, str]:
    """Java .properties (ISO-8859-1 with \\uXXXX escapes, \\ line continuations)."""
    out: dict[str, str] = {}
    logical, buf = [], ""
    for line in text.splitlines():
        stripped = line.lstrip()
        if not buf and (not stripped or stripped[0] in "#!"):
            continue
        if stripped.endswith("\\") and not stripped.endswith("\\\\"):
            buf += stripped[:-1]
            continue
        logical.append(buf + stripped)
        buf = ""
    for line in logical:
        m = re.match(r"((?:\\.|[^=:\s\\])+)\s*[=:\s]\s*(.*)$", line)
        if not m:
            continue
        key, value = (re.sub(r"\\u([0-9a-fA-F]{4})", lambda u: chr(int(u.group(1), 16)), s) for s in m.groups())
        out[re.sub(r"\\(.)", r"\1", key)] = re.sub(r"\\(.)", r"\1", value)
    return out


def catalog(sh3f: zipfile.ZipFile, library: str) -> list[Entry]:
    props = read_properties(sh3f.read("PluginFurnitureCatalog.properties").decode("latin-1"))
    by: dict[str, dict[str, str]] = {}
    for key, value in props.items():
        field, _, number = key.partition("#")
        if number.isdigit():
            by.setdefault(number, {})[field] = value
    return [Entry(library, n, f) for n, f in sorted(by.items(), key=lambda kv: int(kv[0])) if "model" in f]


def read_obj(data: bytes) -> tuple[np.ndarray, list[tuple[str, list[list[int]]]]]:
    """Vertices and (group name, triangles) of an OBJ; polygons fanned, negative indices resolved."""
    verts: list[list[float]] = []
    groups: list[tuple[str, list[list[int]]]] = [("", [])]
    for raw in data.decode("utf-8", "replace").splitlines():
        w = raw.split("#", 1)[0].split()
        if not w:
            continue
        if w[0] == "v" and len(w) >= 4:
            verts.append([float(x) for x in w[1:4]])
        elif w[0] == "g":
            groups.append((" ".join(w[1:2]) or "", []))
        elif w[0] == "f" and len(w) >= 4:
            idx = [int(x.split("/")[0]) for x in w[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            groups[-1][1].extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    return np.asarray(verts, np.float64).reshape(-1, 3), [(n, f) for n, f in groups if f]


def place(v: np.ndarray, fields: dict[str, str]) -> np.ndarray:
    """Rotate by the catalog's modelRotation, then scale the bounding box to width x height x depth."""
    if "modelRotation" in fields:
        m = np.array([float(x) for x in fields["modelRotation"].split()]).reshape(3, 3)
        v = v @ m.T
    size = np.array([float(fields.get(k, 0) or 0) for k in ("width", "height", "depth")])
    lo, hi = v.min(axis=0), v.max(axis=0)
    ext = np.where(hi - lo > 0, hi - lo, 1.0)
    scale = np.where(size > 0, size / ext, 1.0)
    return (v - (lo + hi) / 2) * scale


def write_obj(path: Path, v: np.ndarray, groups: list[tuple[str, list[list[int]]]]) -> None:
    used = sorted({i for _, f in groups for t in f for i in t})
    new = {old: k + 1 for k, old in enumerate(used)}
    lines = [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in v[used]]
    for name, faces in groups:
        lines.append(f"g {name or 'default'}")
        lines += [f"f {new[a]} {new[b]} {new[c]}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def unpack(deb: Path | None, work: Path) -> Path:
    if deb is None:
        subprocess.run(["apt-get", "download", PACKAGE], cwd=work, check=True)
        deb = next(work.glob(f"{PACKAGE}_*.deb"))
    subprocess.run(["dpkg", "-x", str(deb), str(work / "x")], check=True)
    return work / "x" / LIBRARY_DIR


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--category", required=True, help=f"folder name; presets: {', '.join(PRESETS)}")
    ap.add_argument("--out", type=Path, required=True, help="source root: models go to OUT/CATEGORY/")
    ap.add_argument("--include", help="regex on catalog names (default: the category's preset)")
    ap.add_argument("--exclude", help="regex of catalog names to leave out (default: the preset's)")
    ap.add_argument("--deb", type=Path, help=f"an already downloaded {PACKAGE}_*.deb")
    ap.add_argument("--max-faces", type=int, default=200_000, help="skip models with more triangles")
    a = ap.parse_args(argv)
    include, exclude = PRESETS.get(a.category, (re.escape(a.category), r"^$"))
    include, exclude = re.compile(a.include or include, re.I), re.compile(a.exclude or exclude, re.I)
    folder = a.out / a.category
    folder.mkdir(parents=True, exist_ok=True)
    rows = ["model\tlibrary\tcatalog_id\tname\tcreator\tlicence"]
    with tempfile.TemporaryDirectory() as tmp:
        libs = unpack(a.deb, Path(tmp))
        for sh3f in sorted(libs.glob("*.sh3f")):
            with zipfile.ZipFile(sh3f) as z:
                for e in catalog(z, sh3f.stem):
                    name = e.fields.get("name", "")
                    if not include.search(name) or exclude.search(name):
                        continue
                    v, groups = read_obj(z.read(e.fields["model"].lstrip("/")))
                    n_faces = sum(len(f) for _, f in groups)
                    if not n_faces or n_faces > a.max_faces:
                        print(f"skip {sh3f.stem} #{e.number} {name!r}: {n_faces} triangles", file=sys.stderr)
                        continue
                    model = re.sub(
                        r"[^0-9a-z]+", "_", f"{sh3f.stem}_{e.fields.get('id', e.number).split('#')[-1]}".lower()
                    )
                    write_obj(folder / f"{model}.obj", place(v, e.fields), groups)
                    rows.append(
                        "\t".join(
                            [
                                model,
                                sh3f.stem,
                                e.fields.get("id", ""),
                                name,
                                e.fields.get("creator", ""),
                                LICENCES.get(sh3f.stem, "see the package's copyright file"),
                            ]
                        )
                    )
        shutil.copy(Path(tmp) / "x" / "usr/share/doc" / PACKAGE / "copyright", folder / "COPYRIGHT.debian")
    (folder / "SOURCES.tsv").write_text("\n".join(rows) + "\n")
    print(f"{len(rows) - 1} models -> {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
