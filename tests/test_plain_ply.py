"""pipeline.core.plain_ply reads the prepare stage's PLY exactly as trimesh does, declines
anything else, and lets the embree render worker start without trimesh."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh

from pipeline.core.plain_ply import read_plain_ply
from pipeline.sources.mesh_io import ply_bytes, write_ply
from render.worker import load_mesh

ROOT = Path(__file__).resolve().parents[1]


def test_reads_what_write_ply_writes_as_trimesh_does(tmp_path):
    mesh = trimesh.creation.icosphere(2)
    rng = np.random.default_rng(0)
    v = mesh.vertices * rng.uniform(0.5, 2.0) + rng.normal(size=3)
    path = tmp_path / "m.ply"
    write_ply(path, v, mesh.faces)
    got = read_plain_ply(path)
    want = trimesh.load(str(path), force="mesh", process=False)
    assert got is not None
    assert got[0].dtype == np.float64 and got[1].dtype == np.int64
    assert np.array_equal(got[0], np.asarray(want.vertices, np.float64))
    assert np.array_equal(got[1], np.asarray(want.faces, np.int64))
    vw, fw = load_mesh(path)  # the render worker's loader takes the same path
    assert np.array_equal(vw, got[0]) and np.array_equal(fw, got[1])


def test_declines_other_layouts_and_damaged_files(tmp_path):
    mesh = trimesh.creation.box()
    good = ply_bytes(mesh.vertices, mesh.faces)
    cases = {
        "truncated.ply": good[:-5],
        "longer.ply": good + b"\0",
        "ascii.ply": trimesh.exchange.ply.export_ply(mesh, encoding="ascii"),
        "normals.ply": trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=True),
        "noheader.ply": b"\0" * 100,
    }
    # a face with 4 corners: same size, count byte changed on the first face
    header_end = good.index(b"end_header\n") + len(b"end_header\n")
    quad = bytearray(good)
    quad[header_end + 12 * len(mesh.vertices)] = 4
    cases["quad.ply"] = bytes(quad)
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        assert read_plain_ply(tmp_path / name) is None, name
    # the worker still reads another layout, through trimesh
    v, f = load_mesh(tmp_path / "ascii.ply")
    assert len(f) == 12


def test_embree_worker_starts_without_trimesh(tmp_path):
    path = tmp_path / "m.ply"
    write_ply(path, *(lambda m: (m.vertices, m.faces))(trimesh.creation.icosphere(1)))
    code = (
        "import sys; import render.worker, render.edge_lines; "
        f"v, f = render.worker.load_mesh({str(path)!r}); "
        "assert len(f) == 80; print('trimesh' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
