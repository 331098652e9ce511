"""Names from outside the project (source folders, manifests) never become unsafe paths: odd model
and category names build, the preview writes only inside --out, Blender gets no template path.

Builds here use the embree backend (seconds); the one Freestyle build of odd names is slow-marked.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import luigi
import pytest
import trimesh

from pipeline.core.names import MAX_LEN, UnsafePath, inside, is_safe_component, safe_component
from pipeline.dataset.verify import verify_dataset
from pipeline.sources.layouts import list_categories, list_models, safe_category
from render.worker import BLENDER_PATH_SPECIAL, blender_scratch
from workflows import BuildDataset

ROOT = Path(__file__).resolve().parents[1]
EMBREE = '{"backend": "embree"}'
TINY = dict(models_per_category=0, views=1, variants=1, image_size=64, out_size=64, batch_size=16)
_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]*")

# Ids that are already safe stay as they are (procedural, ShapeNet, plain file names).
SAFE = ("00000", "00099", "1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d", "_batches", "a.b", "Box-1", "keep")
# File stems a user's folder can hold, one per kind of trouble.
ODD = {
    "space": "my mug",
    "unicode": "tëst ü",
    "newline": "new\nline",
    "backslash": "back\\slash",
    "braces": "br{1}ace",
    "long": "x" * 246,
    "windows": "CON",
    "schema": "manifest.json",
    "hash": "frame#1",
    "dash": "-rf",
    "undecodable": "bad\udcffbyte",
}


# ---------------------------------------------------------------- the name rules


@pytest.mark.parametrize("name", SAFE)
def test_safe_ids_are_kept_unchanged(name: str) -> None:
    assert safe_component(name) == name


def test_odd_names_become_short_distinct_safe_ids() -> None:
    ids = {kind: safe_component(name) for kind, name in ODD.items()}
    for kind, got in ids.items():
        assert _ID.fullmatch(got) and len(got) <= MAX_LEN and is_safe_component(got), (kind, got)
        assert got == safe_component(ODD[kind])  # deterministic
    assert len(set(ids.values())) == len(ids)
    assert ids["space"] == f"my_mug-{ids['space'][-8:]}" and ids["schema"].startswith("manifest_json-")
    assert safe_component("my mug ") != ids["space"]  # the hash keeps near names apart


@pytest.mark.parametrize("name", [".", "..", "", "_lists", "manifest.json", "../../x", "a/b", "lpt1.txt"])
def test_category_names_never_collide_with_bookkeeping(name: str) -> None:
    got = safe_category(name)
    assert got != name and not got.startswith(("_", ".")) and "/" not in got and _ID.fullmatch(got)


def test_inside_refuses_every_way_out(tmp_path: Path) -> None:
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "link").symlink_to(tmp_path)
    assert inside(tmp_path / "out", tmp_path / "out" / "a.png") == (tmp_path / "out" / "a.png").resolve()
    for path in (tmp_path / "out" / ".." / "x.png", Path("/etc/x.png"), tmp_path / "out" / "link" / "x.png"):
        with pytest.raises(UnsafePath, match="lies outside"):
            inside(tmp_path / "out", path)


def test_blender_never_gets_a_template_path(tmp_path: Path) -> None:
    odd = tmp_path / "w{1}#\\" / "scratch"
    with blender_scratch(odd) as scratch:
        assert scratch.is_dir() and not any(c in str(scratch) for c in BLENDER_PATH_SPECIAL)
    assert not scratch.exists() and not odd.exists()  # the private folder is removed after
    with blender_scratch(tmp_path / "plain") as scratch:
        assert scratch == tmp_path / "plain" and scratch.is_dir()


# ---------------------------------------------------------------- builds of odd names


def _box(path: Path, i: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(1.0, 0.5 + 0.03 * i, 0.4)).export(str(path))


CATEGORY_FOLDERS = ("manifest.json", "_x", "my cat", "é", "c" * 250, "new\nline", "b\\s{1}#", "NUL")


@pytest.fixture(scope="module")
def odd_build(tmp_path_factory) -> Path:
    """One category of odd model names, and odd category folder names, built with embree."""
    root = tmp_path_factory.mktemp("odd")
    for i, stem in enumerate(ODD.values()):
        _box(root / "src" / "mug" / f"{stem}.obj", i)
    for i, folder in enumerate(CATEGORY_FOLDERS):
        _box(root / "src" / folder / "a.obj", i)
    task = BuildDataset(
        source=str(root / "src"),
        work_dir=str(root / "work"),
        dataset_dir=str(root / "ds"),
        render_settings=EMBREE,
        **TINY,
    )
    assert luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING")
    return root


def test_odd_model_names_all_build_and_keep_their_names(odd_build: Path) -> None:
    ds = odd_build / "ds"
    mug = json.loads((ds / "manifest.json").read_text())["categories"]["mug"]
    assert mug["models_failed"] == 0 and mug["models_built"] == len(ODD)
    keys = sorted(k for s in mug["splits"].values() for sh in s["shards"] for k in sh["keys"])
    assert keys == sorted(f"mug_{safe_component(n)}".replace(".", "_") for n in ODD.values())
    sources = set()
    for shard in (ds / "mug").glob("*.tar"):
        with tarfile.open(shard) as tar:
            sources |= {json.loads(tar.extractfile(m).read())["source"] for m in tar if m.name.endswith(".meta.json")}
    assert sources == {f"mug/{n}.obj" for n in ODD.values()}  # the user's name, kept in meta.json
    assert verify_dataset(ds) == []


def test_odd_category_folders_become_safe_categories(odd_build: Path) -> None:
    ds = odd_build / "ds"
    cats = json.loads((ds / "manifest.json").read_text())["categories"]
    assert sorted(cats) == sorted(["mug", *(safe_category(f) for f in CATEGORY_FOLDERS)])
    assert all(c["models_built"] == 1 for name, c in cats.items() if name != "mug")
    assert (ds / "manifest.json").is_file() and (ds / safe_category("manifest.json") / "category.json").is_file()
    assert list_categories(str(odd_build / "src")) == sorted(cats)


def test_work_files_are_named_by_short_safe_ids(odd_build: Path) -> None:
    names = [p.name for p in (odd_build / "work").rglob("*")]
    assert max(len(n.encode()) for n in names) <= 100
    assert not any(c in n for n in names for c in "\n\\{}#é ")
    refs = list_models(str(odd_build / "src"), "mug", None, 0, odd_build / "work")
    assert {r.path.stem for r in refs} == set(ODD.values())  # ids are safe, paths the user's


def test_shapenet_and_registered_layouts_get_safe_ids_too(tmp_path: Path) -> None:
    from pipeline.core.records import ModelRef
    from pipeline.sources import layouts

    for folder in ("1a2b3c", "odd {1} plane"):
        (tmp_path / "sn" / "02691156" / folder / "models").mkdir(parents=True)
    ids = [r.model_id for r in list_models(str(tmp_path / "sn"), "airplane", None, 0, tmp_path / "w")]
    assert ids == ["1a2b3c", safe_component("odd {1} plane")]
    layout = layouts.register_layout(
        layouts.Layout(
            "odd-test",
            detect=lambda source: source == "odd-test",
            categories=lambda source: ["mug"],
            models=lambda source, category, seed, work_dir, count: iter([ModelRef("mug", "a\\b", tmp_path, "odd")]),
        )
    )
    try:
        assert [r.model_id for r in list_models("odd-test", "mug", None, 0, tmp_path)] == [safe_component("a\\b")]
    finally:
        del layouts.LAYOUTS[layout.name]


def test_rebuild_of_odd_names_has_nothing_to_do(odd_build: Path) -> None:
    before = {p: p.stat().st_mtime_ns for p in (odd_build / "ds").rglob("*") if p.is_file()}
    task = BuildDataset(
        source=str(odd_build / "src"),
        work_dir=str(odd_build / "work"),
        dataset_dir=str(odd_build / "ds"),
        render_settings=EMBREE,
        **TINY,
    )
    assert task.complete()
    assert {p: p.stat().st_mtime_ns for p in (odd_build / "ds").rglob("*") if p.is_file()} == before


# ---------------------------------------------------------------- preview of an untrusted manifest


def _preview(ds: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pipeline", "preview", str(ds), "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def _edit_manifest(ds: Path, edit) -> None:
    path = ds / "manifest.json"
    m = json.loads(path.read_text())
    edit(m["categories"])
    path.write_text(json.dumps(m))


def test_preview_of_odd_categories_writes_safe_names(odd_build: Path, tmp_path: Path) -> None:
    r = _preview(odd_build / "ds", tmp_path / "pv")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "pv").iterdir()) == sorted(
        f"{c}.png" for c in ["mug", *(safe_category(f) for f in CATEGORY_FOLDERS)]
    )


def test_preview_never_writes_outside_out(odd_build: Path, tmp_path: Path) -> None:
    ds = tmp_path / "ds"
    shutil.copytree(odd_build / "ds", ds)
    target = tmp_path / "deep" / "er"
    target.mkdir(parents=True)
    out = target / "pv"

    def edit(cats: dict) -> None:
        cats["../../x"] = cats.pop("mug")  # shards would be read from outside the dataset
        cats["mug/../mug"] = json.loads(json.dumps(cats["../../x"]))  # inside: read, written safely
        shards = [sh for s in cats[safe_category("my cat")]["splits"].values() for sh in s["shards"]]
        shards[0]["name"] = "../../../../etc/passwd"

    _edit_manifest(ds, edit)
    r = _preview(ds, out)
    assert r.returncode == 1
    refused = sorted(line for line in r.stderr.splitlines() if line.startswith("REFUSED"))
    assert len(refused) == 2 and "'../../x' refused" in refused[0] and "not a shard file name" in refused[1]
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.png"))
    assert all(p.startswith("deep/er/pv/") for p in written) and not (tmp_path / "x.png").exists()
    assert f"deep/er/pv/{safe_category('mug/../mug')}.png" in written


# ---------------------------------------------------------------- Freestyle (Blender)


@pytest.mark.slow
def test_freestyle_renders_names_with_braces_and_backslashes(tmp_path: Path) -> None:
    """Blender reads '{…}', '#' and '\\' in output paths: names and a work folder holding them."""
    for i, stem in enumerate(("br{1}ace", "back\\slash", "frame#1")):
        _box(tmp_path / "src" / "mug" / f"{stem}.obj", i)
    work = tmp_path / "work {1}#"
    task = BuildDataset(source=str(tmp_path / "src"), work_dir=str(work), dataset_dir=str(tmp_path / "ds"), **TINY)
    assert luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING")
    mug = json.loads((tmp_path / "ds" / "manifest.json").read_text())["categories"]["mug"]
    assert mug["models_built"] == 3 and mug["failed"] == []


def test_verify_never_reads_outside_the_dataset_folder(tmp_path: Path) -> None:
    """A manifest from elsewhere naming ../ paths is reported, not followed."""
    import json

    from pipeline.dataset.manifest import content_checksum
    from pipeline.dataset.verify import verify_dataset

    ds = tmp_path / "ds"
    ds.mkdir()
    (tmp_path / "secret").mkdir()
    (tmp_path / "secret" / "train-00000.tar").write_bytes(b"x")
    entry = {
        "splits": {
            s: {
                "samples": 1,
                "shards": [{"name": "../secret/train-00000.tar", "bytes": 1, "sha256": "0", "samples": 1}],
            }
            for s in ("train", "val", "test")
        }
    }
    body = {"categories": {"../secret": entry, "mug": entry}}
    (ds / "manifest.json").write_text(json.dumps({**body, "checksum": content_checksum(body)}))
    problems = verify_dataset(ds)
    assert any("category '../secret' is not a plain folder name; not read" in p for p in problems)
    assert any("shard name '../secret/train-00000.tar' is not a shard file name; not read" in p for p in problems)
