"""Each extension point is one registry: an entry registered here (and removed after) is picked up
by every consumer without touching any other code: source layouts, mesh formats, camera rigs,
loss terms."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.errors import ModelError
from pipeline.core.records import ModelRef
from pipeline.build.settings import BuildSettings
from pipeline.prepare.batch import prepare_model
from pipeline.prepare.settings import PrepareSettings
from pipeline.sources import layouts, mesh_io
from pipeline.build.listing import current_listing
from render import rigs
from render.cameras import rig
from render.settings import RenderSettings
from workflows.validate import BuildParameterError, check_categories, check_settings

ROOT = Path(__file__).resolve().parents[1]

CUBE_V = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_F = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
          (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]


# ---- source layouts --------------------------------------------------------------------------

@pytest.fixture
def list_file_layout():
    """A layout of our own: a folder holding ``models.txt`` with "<category> <relative path>" lines."""
    def models(source, category, seed, work_dir, count):
        for line in (Path(source) / "models.txt").read_text().splitlines():
            cat, rel = line.split()
            if cat == category:
                yield ModelRef(cat, Path(rel).stem, Path(source) / rel, "listfile")

    entry = layouts.register_layout(layouts.Layout(
        "listfile", detect=lambda source: (Path(source) / "models.txt").is_file(),
        categories=lambda source: sorted({line.split()[0] for line in (Path(source) / "models.txt").read_text().splitlines()}),
        models=models))
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
    fmt = mesh_io.register_format(mesh_io.MeshFormat(
        "tri", (".tri",), sniff=lambda head, size: head.startswith(b"TRI\n"), load=_load_tri, check=_check_tri))
    yield fmt
    del mesh_io.FORMATS["tri"]


def _tri_text() -> str:
    return "TRI\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in CUBE_V) + "".join(f"t {a} {b} {c}\n" for a, b, c in CUBE_F)


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
    def turntable(settings, seed, category, model_id):
        return [(360.0 * i / settings.views, 20.0) for i in range(settings.views)]

    yield turntable
    del rigs.RIGS["turntable"]


def test_a_registered_rig_is_accepted_by_the_settings_and_used_by_rig(tmp_path, turntable_rig):
    s = RenderSettings(rig="turntable", views=4)
    views = rig(s, 0, "car", "x")
    assert [(v.azimuth_deg, v.elevation_deg) for v in views] == [(0.0, 20.0), (90.0, 20.0), (180.0, 20.0), (270.0, 20.0)]
    assert np.allclose(views[1].eye, s.distance * np.array([np.cos(np.radians(20)), np.sin(np.radians(20)), 0.0]))
    # the build's render overrides accept it too (the stage key then differs from the default rig's)
    b = BuildSettings(render_overrides=json.dumps({"rig": "turntable"}), work_dir=tmp_path)
    check_settings(b)
    assert b.render_settings().rig == "turntable" and b.render_key() != BuildSettings(work_dir=tmp_path).render_key()


def test_unknown_rigs_are_refused_with_the_registered_names():
    assert "turntable" not in rigs.RIGS
    with pytest.raises(ValueError, match=r"rig must be one of \('random', 'front_side_top'\), got 'turntable'"):
        RenderSettings(rig="turntable")


# ---- loss terms ------------------------------------------------------------------------------

# LossWeights is a dataclass made from the table when train.losses.weights is first imported, so a
# term is registered in a fresh interpreter before that (a project term is a line in LOSS_TERMS).
LOSS_PROBE = textwrap.dedent('''
    import json, torch
    from train.losses.terms import LossTerm, register_term
    register_term(LossTerm("spread", lambda x: (x.ev.points ** 2).sum(-1).mean((1, 2)), 0.5))
    import argparse
    from train.cli import _fit_args, fit_settings
    from train.fit import CSV_FIELDS
    from train.losses.weights import LossWeights
    from train.losses.total import weighted_sum
    from train.objective import Objective
    from train.templates import load_template

    p = argparse.ArgumentParser()
    _fit_args(p)
    base = ["--dataset", "d", "--category", "knife", "--template", "sphere24", "--out", "o"]
    flags = sorted(o for a in p._actions for o in a.option_strings if "spread" in o)
    w_set = fit_settings(p.parse_args(base + ["--w-spread", "0.25"])).weights.spread
    w_off = fit_settings(p.parse_args(base + ["--no-spread"])).weights.spread
    t = load_template("sphere24")
    obj = Objective(t, n_points=200)
    prm = t.initial_params()[None]
    pts = torch.cat([torch.randn(1, 300, 3, generator=torch.Generator().manual_seed(0)), torch.zeros(1, 300, 3)], -1)
    st = obj.sample_st(None)
    terms = obj.terms(prm, pts, st, None, LossWeights())
    from train.geometry.coons import evaluate_patches
    spread = float((evaluate_patches(t.patches_from_params(prm), st).points ** 2).sum(-1).mean())
    off = obj.terms(prm, pts, st, None, LossWeights(spread=0.0))["spread"]
    total = weighted_sum(terms, LossWeights())
    print(json.dumps({"flags": flags, "default": LossWeights().spread, "w_set": w_set, "w_off": w_off,
                      "terms": list(terms), "value": float(terms["spread"]), "expected": spread,
                      "off": float(off), "csv": "spread" in CSV_FIELDS,
                      "total_minus": float(total - sum(getattr(LossWeights(), k) * v for k, v in terms.items() if k != "spread")),
                      }))
''')


def test_a_registered_loss_term_gets_flags_weights_and_a_place_in_the_objective():
    out = subprocess.run([sys.executable, "-c", LOSS_PROBE], cwd=ROOT, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["flags"] == ["--no-spread", "--w-spread"]
    assert r["default"] == 0.5 and r["w_set"] == 0.25 and r["w_off"] == 0.0
    assert r["terms"][-1] == "spread" and r["csv"]
    assert r["value"] == pytest.approx(r["expected"], rel=1e-6) and r["value"] > 0 and r["off"] == 0.0
    assert r["total_minus"] == pytest.approx(0.5 * r["value"], rel=1e-5)


def test_the_term_table_is_sealed_once_weights_exist_and_drives_the_built_in_flags():
    from train.cli import _fit_args
    from train.losses.terms import LOSS_TERMS, LossTerm, register_term
    from train.losses.weights import LossWeights

    with pytest.raises(RuntimeError, match="before importing train.losses.weights"):
        register_term(LossTerm("late", lambda x: None, 1.0))
    import argparse

    p = argparse.ArgumentParser()
    _fit_args(p)
    options = {o for a in p._actions for o in a.option_strings}
    for t in LOSS_TERMS:
        assert f"--w-{t.name.replace('_', '-')}" in options
        assert (f"--no-{t.name.replace('_', '-')}" in options) == t.ablation
    assert [t.name for t in LOSS_TERMS] == list(LossWeights.__dataclass_fields__)
    assert "--no-chamfer" not in options
