"""Every byte a model is built from is in its key: a glTF's external buffers, a file's mode after
a permission fix, and copies of one file in a category are one model (embree builds, seconds)."""

from __future__ import annotations

import json
import os
import pwd
import shutil
import sys
import tempfile
from pathlib import Path

import luigi
import numpy as np
import pytest
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from as_user import call_as  # noqa: E402

from pipeline.dataset.verify import verify_dataset  # noqa: E402
from pipeline.sources.mesh_io import gltf_external_files, load_mesh  # noqa: E402
from workflows import BuildDataset  # noqa: E402
from workflows.build_settings import BuildSettings  # noqa: E402
from workflows.listing import current_listing, file_key, model_key  # noqa: E402

EMBREE = '{"backend": "embree"}'
TINY = dict(
    models_per_category=0, views=1, variants=1, image_size=64, out_size=64, batch_size=4, render_settings=EMBREE
)


def _params(src: Path, root: Path) -> dict:
    return dict(source=str(src), work_dir=str(root / "work"), dataset_dir=str(root / "ds"), **TINY)


def settings(src: Path, root: Path) -> BuildSettings:
    """The settings of ``build(src, root)`` as far as listing and prepare use them."""
    return BuildSettings(source=str(src), work_dir=root / "work", dataset_dir=root / "ds", models_per_category=0)


def build(src: Path, root: Path) -> dict:
    """Build with embree; returns the manifest's "categories"."""
    assert luigi.build([BuildDataset(**_params(src, root))], local_scheduler=True, workers=1, log_level="WARNING")
    return json.loads((root / "ds" / "manifest.json").read_text())["categories"]


def tree(ds: Path) -> dict[str, bytes]:
    return {p.relative_to(ds).as_posix(): p.read_bytes() for p in sorted(ds.rglob("*.tar"))}


def box(path: Path, extents=(1.0, 0.6, 0.4)) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=extents).export(str(path))


def gltf_with_buffers(folder: Path, stem: str, extents=(1.0, 0.7, 0.5)) -> list[Path]:
    """A .gltf whose buffers are separate ``<stem>_N.bin`` files; returns the buffer paths."""
    folder.mkdir(parents=True, exist_ok=True)
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(trimesh.creation.box(extents=extents)))
    doc = json.loads(files.pop("model.gltf"))
    bins = []
    for i, b in enumerate(doc["buffers"]):
        bins.append(folder / f"{stem}_{i}.bin")
        bins[-1].write_bytes(files[b["uri"]])
        b["uri"] = bins[-1].name
    (folder / f"{stem}.gltf").write_text(json.dumps(doc))
    return bins


# ---------------------------------------------------------------- glTF external buffers


def test_gltf_buffers_are_in_the_key(tmp_path: Path) -> None:
    src = tmp_path / "src"
    bins = gltf_with_buffers(src / "mug", "car")
    gltf = src / "mug" / "car.gltf"
    assert [(k, u) for k, u, _ in gltf_external_files(gltf)] == [("buffers", b.name) for b in bins]
    cache: dict = {}
    before = model_key(gltf, cache, str(src))
    assert before.content and before == model_key(gltf, cache, str(src))
    # same JSON, other bytes in one buffer (vertices of a longer box, same length)
    other = tmp_path / "other"
    other_bins = gltf_with_buffers(other, "car", extents=(2.0, 0.7, 0.5))
    edited = next(b for b, o in zip(bins, other_bins) if b.read_bytes() != o.read_bytes())
    edited.write_bytes(next(o for b, o in zip(bins, other_bins) if b == edited).read_bytes())
    assert model_key(gltf, cache, str(src)).sha != before.sha
    # a file with only embedded data keeps its own sha256 as key (old work folders stay valid)
    embedded = trimesh.exchange.gltf.export_gltf(trimesh.Scene(trimesh.creation.box()), embed_buffers=True)
    (src / "mug" / "emb.gltf").write_bytes(embedded["model.gltf"])
    assert gltf_external_files(src / "mug" / "emb.gltf") == []
    assert model_key(src / "mug" / "emb.gltf", {}, str(src)) == file_key(src / "mug" / "emb.gltf", {}, "x")


def test_edited_gltf_buffer_rebuilds_the_model(tmp_path: Path) -> None:
    src = tmp_path / "src"
    bins = gltf_with_buffers(src / "mug", "car")
    box(src / "mug" / "plain.obj")
    build(src, tmp_path / "a")
    first = tree(tmp_path / "a" / "ds")
    other_bins = gltf_with_buffers(tmp_path / "other", "car", extents=(2.0, 0.7, 0.5))
    for b, o in zip(bins, other_bins):
        b.write_bytes(o.read_bytes())  # same file names and sizes, other vertices
    cats = build(src, tmp_path / "a")
    assert cats["mug"]["models_built"] == 2 and tree(tmp_path / "a" / "ds") != first  # not the stale shards
    build(src, tmp_path / "clean")
    assert tree(tmp_path / "a" / "ds") == tree(tmp_path / "clean" / "ds")
    assert verify_dataset(tmp_path / "a" / "ds") == []


@pytest.mark.parametrize(
    "uri, words",
    [
        ("gone.bin", "missing glTF buffer 'gone.bin'"),
        ("../outside.bin", "missing glTF buffer '../outside.bin'"),  # never read from outside its folder
    ],
)
def test_missing_or_escaping_buffer_fails_that_model_only(tmp_path: Path, uri: str, words: str) -> None:
    src = tmp_path / "src"
    bins = gltf_with_buffers(src / "mug", "car")
    (src / "outside.bin").write_bytes(bins[0].read_bytes())
    doc = json.loads((src / "mug" / "car.gltf").read_text())
    doc["buffers"][0]["uri"] = uri
    (src / "mug" / "car.gltf").write_text(json.dumps(doc))
    box(src / "mug" / "plain.obj")
    cats = build(src, tmp_path)
    assert cats["mug"]["models_built"] == 1
    [failed] = cats["mug"]["failed"]
    assert failed["model_id"] == "car" and failed["stage"] == "prepare" and words in failed["reason"]


def test_obj_material_files_do_not_change_the_geometry(tmp_path: Path) -> None:
    """Why an OBJ's .mtl and textures are not in its key: the loaded mesh is the same without them."""
    mesh = trimesh.creation.box()
    lines = ["mtllib box.mtl"] + [f"v {x} {y} {z}" for x, y, z in mesh.vertices] + ["vt 0 0", "vt 1 0", "vt 0 1"]
    lines += ["usemtl paint"] + [f"f {a + 1}/1 {b + 1}/2 {c + 1}/3" for a, b, c in mesh.faces]
    (tmp_path / "box.obj").write_text("\n".join(lines) + "\n")
    (tmp_path / "box.mtl").write_text("newmtl paint\nKd 1 0 0\nmap_Kd tex.png\n")
    from PIL import Image

    Image.new("RGB", (4, 4), (200, 10, 10)).save(tmp_path / "tex.png")
    with_mtl = load_mesh(tmp_path / "box.obj")
    (tmp_path / "box.mtl").unlink()
    (tmp_path / "tex.png").unlink()
    without = load_mesh(tmp_path / "box.obj")
    assert all(np.array_equal(a, b) for a, b in zip(with_mtl, without))


# ---------------------------------------------------------------- a permission fix re-runs


def test_mode_is_part_of_the_cache_signature(tmp_path: Path, monkeypatch) -> None:
    """A failed read is never cached, and chmod alone (no new mtime) misses the cache."""
    import workflows.listing as listing

    path = tmp_path / "a.obj"
    box(path)
    real = listing.file_sha256

    def as_if_not_root(p):  # root reads mode-000 files; the listing must see what a user sees
        if not os.stat(p).st_mode & 0o444:
            raise PermissionError(13, "Permission denied", str(p))
        return real(p)

    monkeypatch.setattr(listing, "file_sha256", as_if_not_root)
    cache: dict = {}
    good = file_key(path, cache, "a.obj")
    path.chmod(0)
    locked = file_key(path, cache, "a.obj")
    assert not locked.content and locked.sha != good.sha
    path.chmod(0o644)
    assert file_key(path, cache, "a.obj") == good


def _nobody() -> tuple[int, int] | None:
    """Who the permission build runs as: 'nobody' when we are root (root reads mode-000 files)."""
    if os.geteuid() != 0:
        return None
    try:
        entry = pwd.getpwnam("nobody")
    except KeyError:
        pytest.skip("running as root and there is no 'nobody' user to drop privileges to")
    return entry.pw_uid, entry.pw_gid


def test_fixed_permission_rebuilds_the_model(tmp_path: Path) -> None:
    """A user lists and prepares a folder with a mode-000 file (it fails, permission denied),
    fixes the mode, and the next build builds it instead of reusing the failure."""
    from pipeline.prepare.batch import prepare_batch
    from workflows.listing import listed_models

    who = _nobody()
    root = Path(tempfile.mkdtemp(prefix="trust-keys-"))  # a folder "nobody" may write in
    try:
        root.chmod(0o777)
        src = root / "src"
        box(src / "mug" / "locked.obj")
        box(src / "mug" / "open.obj", (0.5, 0.5, 1.0))
        for p in (src, src / "mug"):
            p.chmod(0o755)
        (src / "mug" / "locked.obj").chmod(0)
        s = settings(src, root)

        def prepare_as_user() -> str:  # the build's first two steps (its renders need the venv)
            refs = listed_models(s, "mug")
            recs = prepare_batch(refs, s.stage_dir("prepare"), s.prepare_settings())
            return json.dumps(
                {r.model_id.rsplit("-", 1)[0]: rec.get("error", {}).get("reason", "ok") for r, rec in zip(refs, recs)}
            )

        assert json.loads(call_as(who, prepare_as_user)) == {
            "locked": "unreadable: permission denied (check the owner and mode of the file and its folders)",
            "open": "ok",
        }
        (src / "mug" / "locked.obj").chmod(0o644)  # the fix: size, mtime and inode stay the same
        cats = build(src, root)
        assert cats["mug"]["failed"] == [] and cats["mug"]["models_built"] == 2
    finally:
        shutil.rmtree(root, ignore_errors=True)


# ---------------------------------------------------------------- copies in one category


def test_identical_files_are_one_model(tmp_path: Path, caplog) -> None:
    src = tmp_path / "src"
    box(src / "mug" / "b.obj")
    shutil.copy(src / "mug" / "b.obj", src / "mug" / "a copy.obj")
    shutil.copy(src / "mug" / "b.obj", src / "mug" / "c.obj")
    box(src / "mug" / "d.obj", (0.3, 0.3, 1.0))
    box(src / "knife" / "b.obj")  # the same file in another category is that category's model
    s = settings(src, tmp_path)
    with caplog.at_level("WARNING"):
        lst = current_listing(s, "mug")
    copies = {m["model_id"]: m.get("duplicate_of") for m in lst["models"]}
    first = "a_copy-" + lst["models"][0]["model_id"].split("-")[1]
    assert copies == {first: None, "b": "mug/a copy.obj", "c": "mug/a copy.obj", "d": None}
    assert "mug/b.obj is a copy of mug/a copy.obj" in caplog.text
    cats = build(src, tmp_path)
    assert cats["mug"]["models_built"] == 2 and cats["knife"]["models_built"] == 1
    assert [(f["model_id"], f["stage"], f["path"], f["reason"]) for f in cats["mug"]["failed"]] == [
        ("b", "source", "mug/b.obj", "duplicate of mug/a copy.obj (same content)"),
        ("c", "source", "mug/c.obj", "duplicate of mug/a copy.obj (same content)"),
    ]
    keys = sorted(k for sp in cats["mug"]["splits"].values() for sh in sp["shards"] for k in sh["keys"])
    assert keys == [f"mug_{first}", "mug_d"]
