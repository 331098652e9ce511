"""The on-disk schema end to end: a real tiny build writes every name and field that
pipeline.core.schema declares, and the trainer's loader and objective read only what was written.

A field the trainer reads but nobody writes (the old ``meta["has_parts"]``) fails here, as does a
declared field the writer leaves out or an undeclared one it adds.
"""

from __future__ import annotations

import ast
import io
import json
from pathlib import Path

import luigi
import numpy as np
import pytest
import torch
import webdataset as wds

from pipeline.core import schema
from pipeline.dataset.manifest import read_fragment, read_manifest
from pipeline.dataset.shards import iter_shard, list_shards
from pipeline.dataset.verify import verify_dataset
from train.data import DataSettings, collate, decode_sample
from train.losses.weights import template_weights
from train.objective import Objective
from train.templates import load_template
from workflows import BuildCategory

# car: its template has optional parts (read through present_parts) and part groups (read through
# point_part_names and point_parts.npy), so the objective consumes every part field.
CATEGORY = "car"
MODELS = 2
ROOT = Path(__file__).resolve().parents[1]


class Reads(dict):
    """A dict that notes every key looked up in it, so the test sees what a reader consumed."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.read: set[str] = set()

    def __getitem__(self, key):
        self.read.add(key)
        return super().__getitem__(key)

    def get(self, key, default=None):
        self.read.add(key)
        return super().get(key, default)

    # ``in`` is not noted: asking whether an optional member (the fit stage's, say) is there is
    # not reading it


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("schema")
    task = BuildCategory(
        category=CATEGORY,
        models_per_category=MODELS,
        views=2,
        variants=1,
        image_size=64,
        out_size=64,
        batch_size=MODELS,
        render_settings='{"backend": "embree"}',
        work_dir=str(root / "work"),
        dataset_dir=str(root / "ds"),
    )
    assert luigi.build([task], local_scheduler=True, workers=1, log_level="WARNING")
    return root / "ds"


def _samples(ds: Path) -> list[tuple[str, str, dict[str, bytes]]]:
    return [(p.name, key, members) for p in list_shards(ds / CATEGORY) for key, members in iter_shard(p)]


def test_writer_writes_exactly_the_declared_members_and_fields(built: Path) -> None:
    samples = _samples(built)
    assert len(samples) == MODELS
    for shard, key, members in samples:
        split = schema.SHARD_RE.match(shard).group(1)
        sketches = sorted(m for m in members if schema.sketch_view_variant(m) is not None)
        assert sketches == [schema.sketch_name(v, 0) for v in range(2)]
        # every member is declared: required, one sketch per view and variant, part labels (procedural)
        assert set(members) == {*schema.REQUIRED_MEMBERS, *sketches, schema.POINT_PARTS_MEMBER}
        meta = json.loads(members[schema.META_MEMBER])
        assert set(meta) == set(schema.META_FIELDS)  # nothing missing, nothing undeclared
        assert schema.SampleMeta(**meta).to_json() == meta
        assert meta["key"] == key == schema.sample_key(CATEGORY, meta["model_id"])
        assert meta["split"] == split and split in schema.SPLITS
        assert meta["sketches"] == sketches
        # a procedural model has part labels: every part field is filled
        for name in (
            "part_labels",
            schema.PRESENT_PARTS,
            schema.POINT_PART_NAMES,
            "source",
            "source_sha256",
            "normalization",
            "bodies",
        ):
            assert meta[name] is not None, name
        points = np.load(io.BytesIO(members[schema.POINTS_MEMBER]))
        assert points.shape == (meta["points"], 6)


def test_manifest_fields_are_the_declared_ones(built: Path) -> None:
    assert verify_dataset(built) == []  # the verifier reads the same names (key, split, members)
    manifest = read_manifest(built)
    assert set(manifest) == set(schema.MANIFEST_FIELDS)
    frag = read_fragment(built / CATEGORY)
    assert frag == manifest["categories"][CATEGORY]
    assert set(frag) == set(schema.FRAGMENT_FIELDS) - {"listing"}  # listing: file sources only
    assert set(frag["splits"]) == set(schema.SPLITS)
    for entry in frag["splits"].values():
        assert set(entry) == set(schema.SPLIT_FIELDS)
        for info in entry["shards"]:
            assert set(info) == set(schema.SHARD_FIELDS) and schema.SHARD_RE.match(info["name"])
    assert all(set(f) == set(schema.FAILED_FIELDS) for f in frag["failed"])


def test_trainer_reads_only_what_the_writer_wrote(built: Path) -> None:
    urls = [str(p) for p in list_shards(built / CATEGORY)]
    settings = DataSettings(max_views=2, eval_views=2, n_points=2000, image_size=64)
    raws = [Reads(raw) for raw in wds.WebDataset(urls, shardshuffle=False, empty_check=False)]
    rng = np.random.default_rng(0)
    decoded = [decode_sample(raw, settings, rng, True, False) for raw in raws]
    for s in decoded:
        s["meta"] = Reads(s["meta"])
    batch = collate(decoded)

    template = load_template(CATEGORY)
    objective = Objective(template, n_points=settings.n_points)
    params = template.initial_params()[None].expand(len(decoded), -1)
    terms = objective.batch_terms(params, batch, objective.sample_st(None), template_weights(template.regularizers))
    assert all(torch.isfinite(v).all() for v in terms.values())
    assert objective.groups(batch, torch.device("cpu")) is not None  # the part labels reached the loss

    written_members = [set(raw) - {"__key__", "__url__", "__local_path__"} for raw in raws]
    for raw, written in zip(raws, written_members):
        read = raw.read - {"__key__"}
        assert read <= written, f"loader reads members nobody writes: {sorted(read - written)}"
        assert {schema.POINTS_MEMBER, schema.META_MEMBER, schema.POINT_PARTS_MEMBER} <= read
    for s in decoded:
        meta = s["meta"]
        assert meta.read <= set(meta), f"trainer reads meta fields nobody writes: {sorted(meta.read - set(meta))}"
        assert meta.read <= set(schema.META_FIELDS)
        assert {schema.PRESENT_PARTS, schema.POINT_PART_NAMES} <= meta.read  # really consumed
        assert set(meta) == set(schema.META_FIELDS)  # the loader hands the trainer every field


def test_no_module_but_the_schema_spells_an_on_disk_name() -> None:
    """File, member and field names are imported from the schema, never typed again as literals."""
    names = {v for k, v in vars(schema).items() if k.isupper() and isinstance(v, str)}
    assert {"meta.json", "points.npy", "record.json", "present_parts"} <= names
    found = []
    for pkg in ("pipeline", "render", "augment", "train", "workflows"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path == ROOT / "pipeline" / "core" / "schema.py":
                continue
            tree = ast.parse(path.read_text())
            docs = {
                id(n.body[0].value)
                for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and n.body
                and isinstance(n.body[0], ast.Expr)
                and isinstance(n.body[0].value, ast.Constant)
            }
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and id(node) not in docs and node.value in names:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.value!r}")
                if isinstance(node, ast.Tuple) and [getattr(e, "value", None) for e in node.elts] == list(
                    schema.SPLITS
                ):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} the split names")
    assert found == []
