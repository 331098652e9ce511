"""Part structure from a real build to the loss: present parts and per-point part labels in the
shards, the patch mask in every loss term, and part groups in Chamfer / normal terms."""

from __future__ import annotations

import dataclasses

import luigi
import numpy as np
import pytest
import torch
import webdataset as wds

from pipeline.core.schema import POINT_PART_NAMES, PRESENT_PARTS, part_family, present_parts
from pipeline.dataset.shards import list_shards
from pipeline.shapes import generate
from train.data import DataSettings, collate, decode_sample
from train.losses import Groups, chamfer_loss, match_points, normal_alignment_loss
from train.losses.weights import template_weights
from train.objective import Objective
from train.templates import load_template
from train.templates.template import TemplateError
from workflows import BuildCategory

N_MODELS = 9  # among them airplanes without engines (00008 at seed 0)


def test_part_family_strips_side_and_instance() -> None:
    assert [part_family(x) for x in ("wing_l", "engine0_r", "foot_front_l", "peg12", "body")] == [
        "wing",
        "engine",
        "foot_front",
        "peg",
        "body",
    ]
    assert present_parts(["wing_r", "wing_l", "engine1_l", "fuselage"]) == ["engine", "fuselage", "wing"]
    assert present_parts([]) is None


@pytest.fixture(scope="module")
def airplane_batch(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("parts")
    ok = luigi.build(
        [
            BuildCategory(
                category="airplane",
                models_per_category=N_MODELS,
                views=1,
                variants=1,
                image_size=64,
                out_size=64,
                batch_size=N_MODELS,
                work_dir=str(root / "work"),
                dataset_dir=str(root / "ds"),
            )
        ],
        local_scheduler=True,
        workers=1,
        log_level="WARNING",
    )
    assert ok
    urls = [str(p) for p in list_shards(root / "ds" / "airplane")]
    settings = DataSettings(eval_views=1, n_points=4000, image_size=64)
    rng = np.random.default_rng(0)
    samples = [decode_sample(raw, settings, rng, False, False) for raw in wds.WebDataset(urls, shardshuffle=False)]
    assert len(samples) == N_MODELS
    return collate(sorted(samples, key=lambda s: s["key"]))


@pytest.mark.slow  # a real Blender build of 9 airplanes (~2 min on a shared 2-core machine)
def test_shards_say_which_parts_each_airplane_has(airplane_batch: dict) -> None:
    for b, meta in enumerate(airplane_batch["meta"]):
        has_engine = any(p.label.startswith("engine") for p in generate("airplane", int(meta["model_id"])).parts)
        assert ("engine" in meta[PRESENT_PARTS]) == has_engine
        assert meta[POINT_PART_NAMES] == meta[PRESENT_PARTS]
        labels = airplane_batch["point_parts"][b]
        assert labels.min() >= 0 and labels.max() < len(meta[POINT_PART_NAMES])
        # every present part owns some surface points; wing points lie farther from x = 0 than fuselage ones
        assert len(torch.unique(labels)) == len(meta[POINT_PART_NAMES])
        x = airplane_batch["points"][b, :, 0].abs()
        names = meta[POINT_PART_NAMES]
        assert x[labels == names.index("wing")].mean() > 2 * x[labels == names.index("fuselage")].mean()


@pytest.mark.slow
def test_engine_patches_masked_off_in_every_term(airplane_batch: dict) -> None:
    tpl = load_template("airplane")
    obj = Objective(tpl, n_points=2000)
    mask = obj.patch_mask(airplane_batch["meta"], torch.device("cpu"))
    engine = torch.tensor(tpl.optional_parts["engine"])
    closing = torch.tensor(tpl.closing_patches.get("engine", []), dtype=torch.long)
    without = [b for b, m in enumerate(airplane_batch["meta"]) if "engine" not in m[PRESENT_PARTS]]
    expected = [
        m["model_id"]
        for m in airplane_batch["meta"]
        if not any(p.label.startswith("engine") for p in generate("airplane", int(m["model_id"])).parts)
    ]
    assert without and [airplane_batch["meta"][b]["model_id"] for b in without] == expected
    for b in range(N_MODELS):
        assert bool(mask[b, engine].any()) == (b not in without)
        assert bool(mask[b, closing].all()) == (b in without)  # closing patches seal the nacelle mounts
        assert int((~mask[b]).sum()) == (len(engine) if b in without else len(closing))
    # Move the points only engine patches use: no term of an engine-less airplane may change.
    others = torch.ones(tpl.num_patches, dtype=torch.bool)
    others[engine] = False
    only_engine = obj.patch_points[engine].any(0) & ~obj.patch_points[others].any(0)
    assert only_engine.sum() > 10
    base = tpl.initial_params()
    moved_xyz = tpl.points_from_params(base[None])[0].detach().numpy().copy()
    moved_xyz[only_engine.numpy()] += np.array([0.3, -0.2, 0.25])
    moved = tpl.params_from_points(moved_xyz).float()
    weights = template_weights(tpl.regularizers, {"collision": 1.0})
    assert weights.symmetry == 1.0 and weights.template_normal > 0
    st = obj.sample_st(None)
    batch = {
        k: (v[without] if isinstance(v, torch.Tensor) else [v[b] for b in without]) for k, v in airplane_batch.items()
    }
    a = obj.batch_terms(base.expand(len(without), -1), batch, st, weights)
    c = obj.batch_terms(moved.expand(len(without), -1), batch, st, weights)
    for name in a:
        assert torch.allclose(a[name], c[name], rtol=1e-5, atol=1e-7), name
    # ... while an airplane with engines sees the move in its Chamfer and symmetry terms
    with_engine = [b for b in range(N_MODELS) if b not in without][:1]
    batch = {
        k: (v[with_engine] if isinstance(v, torch.Tensor) else [v[b] for b in with_engine])
        for k, v in airplane_batch.items()
    }
    a = obj.batch_terms(base[None], batch, st, weights)
    c = obj.batch_terms(moved[None], batch, st, weights)
    assert c["chamfer"] > a["chamfer"] and c["symmetry"] > a["symmetry"]


def test_closing_patches_on_only_when_part_absent() -> None:
    tpl = load_template("knife")
    optional = {i for ids in tpl.optional_parts.values() for i in ids}
    closing = [i for i in range(tpl.num_patches) if i not in optional][:2]
    tpl = dataclasses.replace(tpl, closing_patches={"guard": closing})  # which patches close is irrelevant here
    obj = Objective(tpl, n_points=500)
    guard = tpl.optional_parts["guard"]
    assert obj.mask_for(["blade", "handle"])[closing].all() and not obj.mask_for(["blade", "handle"])[guard].any()
    m = obj.mask_for(["blade", "guard", "handle"])
    assert not m[closing].any() and m[guard].all()
    assert not obj.mask_for(None)[closing].any()  # no part labels: every part present, nothing to close


def test_regularizers_follow_the_template_file() -> None:
    assert template_weights(load_template("airplane").regularizers).symmetry == 1.0
    assert template_weights(load_template("car").regularizers).symmetry == 1.0
    assert template_weights(load_template("knife").regularizers).symmetry == 0.0
    assert template_weights(load_template("knife").regularizers).template_normal == pytest.approx(1e-4)
    sphere = template_weights(load_template("sphere24").regularizers)
    assert sphere.symmetry == 0.0 and sphere.template_normal == 0.0
    assert template_weights(load_template("knife").regularizers, {"symmetry": 0.5}).symmetry == 0.5


def test_grouped_chamfer_matches_within_groups() -> None:
    # two unit squares (patch samples) far apart; the target has one point set per square but
    # swaps which group each lies in: ungrouped Chamfer is ~0, grouped Chamfer sees the swap
    g = torch.linspace(0, 1, 8)
    sq = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    flat = torch.cat([sq, torch.zeros(len(sq), 1)], -1)
    patches = torch.stack([flat, flat + torch.tensor([3.0, 0, 0])])[None]  # (1, 2, S, 3)
    jac = torch.ones(1, 2, len(sq))
    target = patches.reshape(1, -1, 3)
    same = Groups(torch.tensor([0, 1]), torch.tensor([[0] * len(sq) + [1] * len(sq)]), 2)
    swapped = Groups(torch.tensor([0, 1]), torch.tensor([[1] * len(sq) + [0] * len(sq)]), 2)
    assert chamfer_loss(patches, jac, target) < 1e-6
    assert chamfer_loss(patches, jac, target, groups=same) < 1e-6
    assert chamfer_loss(patches, jac, target, groups=swapped) > 2 * 2.9  # both groups, both ways
    normals = torch.zeros_like(patches)
    normals[..., 2] = 1
    tn = torch.zeros_like(target)
    tn[..., 2] = 1
    m = match_points(patches, target, groups=swapped)
    assert normal_alignment_loss(normals, jac, tn, m, groups=swapped) == 0


def test_car_groups_wheels_from_point_labels() -> None:
    tpl = load_template("car")
    obj = Objective(tpl, n_points=500)
    wheels = [i for i, lab in enumerate(tpl.patch_labels) if lab.startswith("wheel")]
    assert obj.n_groups == 2 and (obj.patch_group[wheels] == 0).all() and (obj.patch_group == 0).sum() == len(wheels)
    meta = {POINT_PART_NAMES: ["body", "cabin", "wheel_front", "wheel_rear"]}
    batch = {"meta": [meta], "point_parts": torch.tensor([[0, 1, 2, 3, 2]])}
    assert obj.groups(batch, torch.device("cpu")).target.tolist() == [[1, 1, 0, 0, 0]]
    assert obj.groups({"meta": [meta], "point_parts": torch.tensor([[-1] * 5])}, torch.device("cpu")) is None


def test_fit_flags_take_match_normals_from_the_template_file() -> None:
    import argparse

    from train.cli import _fit_args, fit_settings

    parser = argparse.ArgumentParser()
    _fit_args(parser)

    def settings(*flags: str):
        return fit_settings(parser.parse_args(["--dataset", "d", "--category", "c", "--out", "o", *flags]))

    assert settings("--template", "bathtub").match_normals == 0.1  # hollowed part: thin walls
    assert settings("--template", "mug").match_normals == 0.1
    assert settings("--template", "airplane").match_normals == 0.0
    assert settings("--template", "bathtub", "--match-normals", "0").match_normals == 0.0
    air = settings("--template", "airplane", "--w-symmetry", "0.5")
    assert air.weights.symmetry == 0.5 and air.weights.template_normal == pytest.approx(1e-4)


def test_unknown_or_negative_regularizer_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match=r"template regularizers \['chamfer'\]"):
        template_weights({"chamfer": 1.0})  # a loss term, but not a regularizer
    knife = load_template("knife")
    with pytest.raises(TemplateError, match="regularizer 'symmetry': expected a weight >= 0"):
        dataclasses.replace(knife, regularizers={"symmetry": -1.0})


def test_labels_foreign_to_the_template_switch_no_part_off() -> None:
    """A folder's own part names (a chair's "seat", "leg") under the knife template: unknown,
    so every part counts as present, not as absent."""
    obj = Objective(load_template("knife"), n_points=500)
    assert torch.equal(obj.mask_for(["seat", "leg"]), obj.mask_for(None))
    assert not torch.equal(obj.mask_for(["blade", "handle"]), obj.mask_for(None))  # the template's names still count


def test_a_left_out_optional_part_is_measured_as_a_model_without_it() -> None:
    """Engines left out (the GL-117 fighters have none under their wings): the engine's patches
    off and the wing's closing patches on where the pylons met it, the mask of a procedural
    airliner without engines, whatever the target's labels say."""
    air = load_template("airplane")
    plain, left = Objective(air, 200), Objective(air, 200, leave_out=("engine",))
    closing = torch.zeros(air.num_patches, dtype=torch.bool)
    closing[air.closing_patches["engine"]] = True
    engines = torch.from_numpy(np.array(air.patch_labels) == "engine")
    without = plain.mask_for(["fuselage", "wing", "horizontal_tail", "vertical_tail"])
    assert without[closing].all() and not without[engines].any()
    for present in (None, ["fuselage", "wing", "engine", "horizontal_tail", "vertical_tail"]):
        assert torch.equal(left.mask_for(present), without)
    assert not plain.mask_for(None)[closing].any()  # with its engines a model keeps the wing open


def test_left_out_labels_are_off_for_every_model() -> None:
    # real car bodies without wheels (TORCS): evaluate leaves the template's wheel patches out
    car = load_template("car")
    labels = np.array(car.patch_labels)
    wheels = torch.from_numpy(np.isin(labels, ["wheel_front", "wheel_rear"]))
    plain, left = Objective(car, 200), Objective(car, 200, leave_out=("wheel_front", "wheel_rear"))
    for present in (None, ["body", "wheel_front", "wheel_rear"], ["body", "spoiler", "wheel_front", "wheel_rear"]):
        assert plain.mask_for(present)[wheels].all()
        assert not left.mask_for(present)[wheels].any()
        assert torch.equal(left.mask_for(present)[~wheels], plain.mask_for(present)[~wheels])
    assert not left.patch_mask([{}, {PRESENT_PARTS: None}], torch.device("cpu"))[:, wheels].any()
    # a template without optional parts gets a mask only when something is left out
    sphere = load_template("sphere24")
    assert Objective(sphere, 200).patch_mask([{}], torch.device("cpu")) is None
    with pytest.raises(ValueError, match="no patches labelled wings"):
        Objective(car, 200, leave_out=("wings",))
