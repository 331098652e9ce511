"""Part labels of a user's folder source, from the mesh's segmentation to the loss: the prepare
stage names parts as the template builder does, the shards carry present parts and per-point
labels, and a template built from the same folder switches its optional part off for a model
that lacks it."""

from __future__ import annotations

from pathlib import Path

import luigi
import numpy as np
import pytest
import torch
import trimesh
import webdataset as wds

from pipeline.core.records import ModelRef
from pipeline.core.schema import POINT_PART_NAMES, PRESENT_PARTS, SAMPLE_PARTS_FILE
from pipeline.dataset.shards import list_shards
from pipeline.prepare.batch import prepare_model
from pipeline.prepare.settings import PrepareSettings
from pipeline.sources import part_names, segmentation
from pipeline.sources.segmentation import PartLabelSettings
from train.data import DataSettings, collate, decode_sample
from train.objective import Objective
from train.templates import load_template
from train.templates.__main__ import main as templates_main
from workflows import BuildDataset
from workflows.build_settings import BuildSettings
from workflows.validate import BuildParameterError, check_settings

# model id -> has a back; "c" lacks the optional part
CHAIRS = {"a": (0.8, True), "b": (1.0, True), "c": (1.1, False), "d": (1.3, True)}
TINY = dict(
    models_per_category=0,
    views=1,
    variants=1,
    image_size=64,
    out_size=64,
    batch_size=4,
    render_settings='{"backend": "embree"}',
)
FAST = PrepareSettings(resolution=1000, n_samples=8000)


def box_mesh(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def chair(width: float, back: bool, names=("Seat", "Leg", "Back")) -> list[tuple[str, trimesh.Trimesh]]:
    """A seat, four legs (``Leg.000``...: exporter-decorated names of one part) and maybe a back."""
    w = width / 2
    parts = [(names[0], box_mesh([-w, 0.4, -0.5], [w, 0.5, 0.5]))]
    for i, (sx, sz) in enumerate(((-1, -1), (1, -1), (-1, 1), (1, 1))):
        x, z = sx * (w - 0.08), sz * 0.42
        parts.append((f"{names[1]}.{i:03d}", box_mesh([x - 0.05, 0, z - 0.05], [x + 0.05, 0.4, z + 0.05])))
    if back:
        parts.append((names[2], box_mesh([0.02 - w, 0.5, -0.48], [w - 0.02, 1.3, -0.38])))
    return parts


def write_obj(path: Path, parts) -> None:
    lines, base = [], 0
    for name, m in parts:
        lines.append(f"g {name}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in m.vertices]
        lines += [f"f {a + base + 1} {b + base + 1} {c + base + 1}" for a, b, c in m.faces]
        base += len(m.vertices)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def chair_source(root: Path) -> Path:
    for mid, (width, back) in CHAIRS.items():
        write_obj(root / "chair" / f"{mid}.obj", chair(width, back))
    return root


def _map(folder: Path, text: str, name: str = "map.yaml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------- one reader, no copies


def test_templates_read_parts_with_the_pipelines_reader() -> None:
    from train.templates.authoring import mesh_boxes

    assert mesh_boxes.read_segmentation is segmentation.read_segmentation
    assert mesh_boxes.map_name is part_names.map_name


def test_shapenet_groups_are_materials_its_points_files_are_parts(tmp_path: Path) -> None:
    model = tmp_path / "03001627" / "1a2b" / "models" / "model_normalized.obj"
    write_obj(model, chair(1.0, True))
    whole = trimesh.util.concatenate([m for _, m in chair(1.0, True)])
    assert segmentation.read_segmentation(model, whole.vertices, whole.faces) is None  # groups ignored
    labels = tmp_path / "part"  # ShapeNet-part: points/<id>.pts + points_label/<id>.seg, by the folder's id
    pts, face = whole.sample(2000, return_index=True, seed=0)
    (labels / "points").mkdir(parents=True)
    (labels / "points_label").mkdir()
    (labels / "points" / "1a2b.pts").write_text("".join(f"{x} {y} {z}\n" for x, y, z in pts))
    (labels / "points_label" / "1a2b.seg").write_text(
        "".join(f"{1 + int(f >= 12)}\n" for f in face)
    )  # seat: faces 0-11
    found = segmentation.named_parts(
        model,
        whole.vertices,
        whole.faces,
        "1a2b-0123456789ab",
        PartLabelSettings(labels_dir=str(labels), part_map=(("seg1", "seat"),)),
    )
    assert found is not None and found[1] == "points file"
    assert sorted({p.name for p in found[0]}) == ["seat", "seg2"]  # mapped; an unmapped id keeps its digits


def _binary_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray | None) -> None:
    """A little-endian binary PLY, with a ``label`` face property when given (what Blender and
    most exporters write: trimesh reads each element as one structured array)."""
    face_props = "property list uchar int vertex_indices\n" + ("property int label\n" if labels is not None else "")
    head = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\n{face_props}end_header\n"
    )
    body = bytearray(np.asarray(vertices, "<f4").tobytes())
    for k, f in enumerate(faces):
        body += np.uint8(3).tobytes() + np.asarray(f, "<i4").tobytes()
        if labels is not None:
            body += np.asarray(labels[k], "<i4").tobytes()
    path.write_bytes(head.encode() + bytes(body))


def test_binary_ply_face_labels_are_parts_and_a_plain_binary_ply_has_none(tmp_path: Path) -> None:
    whole = trimesh.util.concatenate([m for _, m in chair(1.0, True)])
    labels = (np.arange(len(whole.faces)) >= 12).astype(int)  # seat: faces 0-11
    labelled, plain = tmp_path / "labelled.ply", tmp_path / "plain.ply"
    _binary_ply(labelled, whole.vertices, whole.faces, labels)
    _binary_ply(plain, whole.vertices, whole.faces, None)
    seg = segmentation.read_segmentation(labelled, whole.vertices, whole.faces)
    assert seg is not None and sorted(p.name for p in seg.parts) == ["seg0", "seg1"]
    assert segmentation.read_segmentation(plain, whole.vertices, whole.faces) is None
    rec = prepare_model(ModelRef("chair", "plain", plain, "folder"), tmp_path / "out", FAST, PartLabelSettings())
    assert rec["status"] == "ok" and "parts" not in rec


# ---------------------------------------------------------------- prepare (no renderer)


def test_prepare_labels_samples_by_mapped_group_names(tmp_path: Path) -> None:
    src = tmp_path / "x.obj"
    write_obj(src, chair(1.0, True, names=("Sitz", "Bein", "Screw")))  # the "back" box: dropped by the map
    part_map = part_names.read_part_map(_map(tmp_path, "sitz: seat\nbein*: leg\nscrew*: null\n"))
    parts = PartLabelSettings(part_map=tuple(part_map.items()))
    rec = prepare_model(ModelRef("chair", "x", src, "folder"), tmp_path / "out", FAST, parts)
    assert rec["part_labels"] == {"origin": "obj groups", "names": ["leg", "seat"]}
    assert {p["label"]: p["family"] for p in rec["parts"]} == {
        "Sitz": "seat",
        **{f"Bein.{i:03d}": "leg" for i in range(4)},
        "Screw": None,
    }
    ids = np.load(tmp_path / "out" / SAMPLE_PARTS_FILE)
    y = np.load(tmp_path / "out" / "samples.npy")[:, 1]
    assert ids.dtype == np.uint8 and len(ids) == len(y) == FAST.n_samples
    leg, seat = ids == 0, ids == 1
    assert leg.sum() > 100 and seat.sum() > 100
    assert y[leg].mean() < y[seat].mean()  # legs hang below the seat
    # without segmentation: no labels at all (every template part then counts as present)
    rec = prepare_model(
        ModelRef("chair", "x", src, "folder"), tmp_path / "off", FAST, PartLabelSettings(segmentation=False)
    )
    assert "parts" not in rec and not (tmp_path / "off" / SAMPLE_PARTS_FILE).exists()


# ---------------------------------------------------------------- settings and keys


def test_part_map_and_choice_key_the_prepare_stage(tmp_path: Path) -> None:
    src = chair_source(tmp_path / "src")

    def keys(**kw) -> tuple[str, str]:
        s = BuildSettings(source=str(src), work_dir=tmp_path / "w", **kw)
        return s.prepare_key(), s.category_settings_hash()

    plain = keys()
    pm = _map(tmp_path, "sitz: seat\n")
    mapped = keys(part_map=str(pm))
    assert len({plain, mapped, keys(part_labels="none")}) == 3
    pm.write_text("# the same map, commented\nsitz: seat\n")
    assert keys(part_map=str(pm)) == mapped  # content, not bytes
    pm.write_text("sitz: seat\nbein: leg\n")
    assert keys(part_map=str(pm))[0] != mapped[0]  # a changed map rebuilds
    manifest = BuildSettings(source=str(src), part_map=str(pm)).manifest_settings()
    assert manifest["parts"]["part_map_sha256"] and str(tmp_path) not in str(manifest["parts"])
    # the procedural build's settings do not mention parts at all (its bytes stay as they were)
    assert "parts" not in BuildSettings().manifest_settings()


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"part_labels": "groups"}, "--part-labels: must be one of segmentation, none"),
        ({"part_map": "{bad"}, "--part-map:"),
        ({"part_map": "list"}, "--part-map: "),
        ({"labels_dir": "nowhere"}, "--labels-dir: 'nowhere' is not a folder"),
    ],
)
def test_bad_part_settings_name_their_flag(tmp_path: Path, kw: dict, words: str, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    _map(tmp_path, "[seat, leg]\n", "list")  # a list, not a mapping
    s = BuildSettings(source=str(chair_source(tmp_path / "src")), **kw)
    with pytest.raises(BuildParameterError, match=words):
        check_settings(s)
    with pytest.raises(BuildParameterError, match="--part-map: applies to a file source"):
        check_settings(BuildSettings(part_map=str(tmp_path / "list")))


# ---------------------------------------------------------------- build -> shards -> template -> loss


@pytest.fixture(scope="module")
def chair_build(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("chairs")
    src = chair_source(root / "src")
    ok = luigi.build(
        [BuildDataset(source=str(src), work_dir=str(root / "work"), dataset_dir=str(root / "ds"), **TINY)],
        local_scheduler=True,
        workers=1,
        log_level="WARNING",
    )
    assert ok
    urls = [str(p) for p in list_shards(root / "ds" / "chair")]
    settings = DataSettings(eval_views=1, n_points=4000, image_size=64)
    rng = np.random.default_rng(0)
    samples = [decode_sample(raw, settings, rng, False, False) for raw in wds.WebDataset(urls, shardshuffle=False)]
    assert len(samples) == len(CHAIRS)
    return src, collate(sorted(samples, key=lambda s: s["key"]))


def test_folder_shards_carry_present_parts_and_point_labels(chair_build) -> None:
    _, batch = chair_build
    for b, meta in enumerate(batch["meta"]):
        has_back = CHAIRS[meta["model_id"].split("-")[0]][1]
        assert meta[PRESENT_PARTS] == (["back", "leg", "seat"] if has_back else ["leg", "seat"])
        assert meta[POINT_PART_NAMES] == meta[PRESENT_PARTS]
        assert sorted(meta["part_labels"]) == sorted(
            ["Seat", *(f"Leg.{i:03d}" for i in range(4))] + ["Back"] * has_back
        )
        labels, y = batch["point_parts"][b], batch["points"][b, :, 1]
        names = meta[POINT_PART_NAMES]
        assert len(torch.unique(labels)) == len(names)  # every present part owns points
        mean = {n: float(y[labels == names.index(n)].mean()) for n in names}
        assert mean["leg"] < mean["seat"] < mean.get("back", 2.0)


def test_template_from_the_folder_turns_the_missing_part_off(chair_build, tmp_path: Path) -> None:
    src, batch = chair_build
    assert (
        templates_main(
            [
                "build",
                "--source",
                str(src),
                "--category",
                "chair",
                "--out",
                str(tmp_path),
                "--no-png",
                "--part-group",
                "legs=leg",
            ]
        )
        == 0
    )
    tpl = load_template(tmp_path / "chair.json")
    assert tpl.part_names == ["back"]
    shard_names = set().union(*(m[POINT_PART_NAMES] for m in batch["meta"]))
    assert shard_names == set(tpl.patch_labels)  # the shard labels are the template's
    obj = Objective(tpl, n_points=500)
    mask = obj.patch_mask(batch["meta"], torch.device("cpu"))
    back = torch.tensor(tpl.optional_parts["back"])
    closing = torch.tensor(tpl.closing_patches.get("back", []), dtype=torch.long)
    for b, meta in enumerate(batch["meta"]):
        has_back = "back" in meta[PRESENT_PARTS]
        assert has_back == CHAIRS[meta["model_id"].split("-")[0]][1]
        assert bool(mask[b, back].any()) == has_back and (bool(mask[b, back].all()) or not has_back)
        assert bool(mask[b, closing].all()) == (not has_back) or not len(closing)  # the seat is sealed
    assert not mask[[m["model_id"].startswith("c-") for m in batch["meta"]]][:, back].any()
    # part groups: the leg points form the "legs" group, everything else the rest
    groups = obj.groups(batch, torch.device("cpu"))
    assert groups is not None
    for b, meta in enumerate(batch["meta"]):
        is_leg = batch["point_parts"][b] == meta[POINT_PART_NAMES].index("leg")
        assert torch.equal(groups.target[b] == obj.group_of_label["leg"], is_leg)
