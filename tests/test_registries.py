"""Each extension point is one registry: an entry registered here (and removed after) is picked up
by every consumer without touching any other code: source layouts, mesh formats, camera rigs.
A loss term is a table entry plus a LossWeights field, checked to agree."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.errors import ModelError
from pipeline.core.records import ModelRef
from pipeline.prepare.batch import prepare_model
from pipeline.prepare.settings import PrepareSettings
from pipeline.sources import layouts, mesh_io
from render import rigs
from render.cameras import rig
from render.settings import RenderSettings
from workflows.build_settings import BuildSettings
from workflows.listing import current_listing
from workflows.validate import BuildParameterError, check_categories, check_settings

ROOT = Path(__file__).resolve().parents[1]

CUBE_V = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_F = [
    (0, 1, 3),
    (0, 3, 2),
    (4, 6, 7),
    (4, 7, 5),
    (0, 4, 5),
    (0, 5, 1),
    (2, 3, 7),
    (2, 7, 6),
    (0, 2, 6),
    (0, 6, 4),
    (1, 5, 7),
    (1, 7, 3),
]


# ---- source layouts --------------------------------------------------------------------------


@pytest.fixture
def list_file_layout():
    """A layout of our own: a folder holding ``models.txt`` with "<category> <relative path>" lines."""

    def models(source, category, seed, work_dir, count):
        for line in (Path(source) / "models.txt").read_text().splitlines():
            cat, rel = line.split()
            if cat == category:
                yield ModelRef(cat, Path(rel).stem, Path(source) / rel, "listfile")

    entry = layouts.register_layout(
        layouts.Layout(
            "listfile",
            detect=lambda source: (Path(source) / "models.txt").is_file(),
            categories=lambda source: sorted(
                {line.split()[0] for line in (Path(source) / "models.txt").read_text().splitlines()}
            ),
            models=models,
        )
    )
    yield entry
    del layouts.LAYOUTS["listfile"]


def test_a_registered_layout_is_detected_listed_validated_and_hashed(tmp_path, list_file_layout):
    src = tmp_path / "src"
    (src / "meshes").mkdir(parents=True)  # a plain sub-folder: without the entry this would be "folder"
    (src / "meshes" / "cup.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (src / "models.txt").write_text("mug meshes/cup.obj\n")
    assert layouts.detect_layout(str(src)) == "listfile"
    assert layouts.list_categories(str(src)) == ["mug"]
    refs = layouts.list_models(str(src), "mug", None, 0, tmp_path / "work")
    assert refs == [ModelRef("mug", "cup", src / "meshes" / "cup.obj", "listfile")]
    s = BuildSettings(source=str(src), work_dir=tmp_path / "work")
    check_settings(s)
    check_categories(s, ["mug"])
    with pytest.raises(BuildParameterError, match="unknown 'meshes'"):
        check_categories(s, ["meshes"])
    listing = current_listing(s, "mug")
    assert [m["model_id"] for m in listing["models"]] == ["cup"] and listing["models"][0]["source"] == "listfile"
    assert listing["models"][0]["work_id"].startswith("cup-")


def test_removing_the_layout_restores_the_built_in_ones(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "models.txt").write_text("mug meshes/cup.obj\n")
    assert "listfile" not in layouts.LAYOUTS
    assert layouts.detect_layout(str(tmp_path)) == "folder"
    assert list(layouts.LAYOUTS) == ["procedural", "shapenet", "folder"]
    with pytest.raises(ValueError, match="already registered"):
        layouts.register_layout(layouts.LAYOUTS["folder"])


# ---- mesh formats ----------------------------------------------------------------------------


def _load_tri(path: Path, head: bytes) -> tuple[np.ndarray, np.ndarray]:
    rows = [line.split() for line in path.read_text().splitlines()[1:] if line.strip()]
    v = np.array([[float(w) for w in r[1:]] for r in rows if r[0] == "v"])
    f = np.array([[int(w) for w in r[1:]] for r in rows if r[0] == "t"])
    return v, f


def _check_tri(path: Path, head: bytes, size: int, found: str | None) -> None:
    if b"\nt " not in head:
        raise ModelError(path, "truncated: TRI file without triangles")


@pytest.fixture
def tri_format():
    """A text format of our own: a "TRI" line, then "v x y z" and "t i j k" (0-based) lines."""
    fmt = mesh_io.register_format(
        mesh_io.MeshFormat(
            "tri", (".tri",), sniff=lambda head, size: head.startswith(b"TRI\n"), load=_load_tri, check=_check_tri
        )
    )
    yield fmt
    del mesh_io.FORMATS["tri"]


def _tri_text() -> str:
    return (
        "TRI\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in CUBE_V) + "".join(f"t {a} {b} {c}\n" for a, b, c in CUBE_F)
    )


def test_a_registered_format_is_listed_sniffed_checked_loaded_and_prepared(tmp_path, tri_format):
    cat = tmp_path / "src" / "box"
    cat.mkdir(parents=True)
    (cat / "cube.TRI").write_text(_tri_text())  # extensions match in any case
    (cat / "notes.txt").write_text("not a mesh")
    refs = layouts.list_models(str(tmp_path / "src"), "box", None, 0, tmp_path / "w")
    assert [r.model_id for r in refs] == ["cube"]
    v, f = mesh_io.load_mesh(refs[0].path)
    assert v.shape == (8, 3) and f.shape == (12, 3) and v.dtype == np.float64 and f.dtype == np.int64
    # the sniff test takes part in the wrong-extension check both ways, the format's own check runs
    (tmp_path / "cube.obj").write_text(_tri_text())
    with pytest.raises(ModelError, match="named .obj but the content is TRI data"):
        mesh_io.load_mesh(tmp_path / "cube.obj")
    (tmp_path / "tri.tri").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ModelError, match="named .tri but the content is OBJ data"):
        mesh_io.load_mesh(tmp_path / "tri.tri")
    (tmp_path / "short.tri").write_text("TRI\nv 0 0 0\n")
    with pytest.raises(ModelError, match="TRI file without triangles"):
        mesh_io.load_mesh(tmp_path / "short.tri")
    # and the prepare stage turns it into a prepared mesh like any other source file
    rec = prepare_model(refs[0], tmp_path / "prepared", PrepareSettings())
    assert rec["status"] == "ok" and (tmp_path / "prepared" / "mesh.ply").is_file()


def test_without_the_format_its_files_are_neither_listed_nor_loaded(tmp_path):
    assert "tri" not in mesh_io.FORMATS
    (tmp_path / "box").mkdir()
    (tmp_path / "box" / "cube.tri").write_text(_tri_text())
    assert layouts.list_models(str(tmp_path), "box", None, 0, tmp_path / "w") == []
    with pytest.raises(ModelError, match="unsupported extension '.tri'"):
        mesh_io.load_mesh(tmp_path / "box" / "cube.tri")
    assert mesh_io.mesh_extensions() == (".ply", ".glb", ".off", ".stl", ".gltf", ".obj")


# ---- camera rigs -----------------------------------------------------------------------------


@pytest.fixture
def turntable_rig():
    @rigs.register_rig("turntable")
    def turntable(settings, seed, category, model_id, vertices):
        return [(360.0 * i / settings.views, 20.0) for i in range(settings.views)]

    yield turntable
    del rigs.RIGS["turntable"]


def test_a_registered_rig_is_accepted_by_the_settings_and_used_by_rig(tmp_path, turntable_rig):
    s = RenderSettings(rig="turntable", views=4)
    views = rig(s, 0, "car", "x", np.zeros((1, 3)))
    assert [(v.azimuth_deg, v.elevation_deg) for v in views] == [
        (0.0, 20.0),
        (90.0, 20.0),
        (180.0, 20.0),
        (270.0, 20.0),
    ]
    assert np.allclose(views[1].eye, s.distance * np.array([np.cos(np.radians(20)), np.sin(np.radians(20)), 0.0]))
    # the build's render overrides accept it too (the stage key then differs from the default rig's)
    b = BuildSettings(render_overrides=json.dumps({"rig": "turntable"}), work_dir=tmp_path)
    check_settings(b)
    assert b.render_settings().rig == "turntable" and b.render_key() != BuildSettings(work_dir=tmp_path).render_key()


def test_unknown_rigs_are_refused_with_the_registered_names():
    assert "turntable" not in rigs.RIGS
    with pytest.raises(
        ValueError, match=r"rig must be one of \('random', 'representative', 'front_side_top'\), got 'turntable'"
    ):
        RenderSettings(rig="turntable")


# ---- loss terms ------------------------------------------------------------------------------


def test_loss_weights_match_the_term_table_and_the_table_drives_the_flags():
    """A term is one LOSS_TERMS entry and one LossWeights field, in the same order."""
    import dataclasses

    from train.cli import _fit_args
    from train.fit import CSV_FIELDS
    from train.losses.terms import LOSS_TERMS
    from train.losses.weights import LossWeights

    assert [t.name for t in LOSS_TERMS] == [f.name for f in dataclasses.fields(LossWeights)]
    assert LossWeights() == LossWeights(
        chamfer=1.0, normal=0.008, flat=2.0, collision=1.0, template_normal=1e-4, symmetry=1.0
    )  # the paper's (collision: ours)
    import argparse

    p = argparse.ArgumentParser()
    _fit_args(p)
    options = {o for a in p._actions for o in a.option_strings}
    for t in LOSS_TERMS:
        assert f"--w-{t.name.replace('_', '-')}" in options
        assert (f"--no-{t.name.replace('_', '-')}" in options) == t.ablation
        assert t.name in CSV_FIELDS
    assert "--no-chamfer" not in options
