"""Template construction from cuboids: lattice quad mesh, merging, built category templates, median."""

from __future__ import annotations

import numpy as np
import pytest

from train.data import param_mirror
from train.templates.authoring.build import DATA_DIR, MIRROR_PLANE
from train.templates.authoring.checks import (
    closed_manifold_problems,
    euler_characteristic,
    junction_errors,
    self_intersections,
)
from train.templates.authoring.from_cuboids import TemplateSettings, template_from_boxes
from train.templates.authoring.lattice import (
    Box,
    boundary_quads,
    build_lattice,
    edge_use_counts,
)
from train.templates.authoring.lattice import (
    euler_characteristic as quad_euler,
)
from train.templates.authoring.median import chamfer_matrix, median_index
from train.templates.authoring.merge import merge_quads, rects_from_quads
from train.templates.authoring.part_boxes import BOTTOM, WALL, handle_loop, hollow_box
from train.templates.template import JunctionPoint, load_template_file

CATEGORIES = ("airplane", "bathtub", "bottle", "car", "guitar", "gun", "knife", "mug")


def B(label, lo, hi):
    return Box(label, np.array(lo, float), np.array(hi, float))


def mug_boxes():
    cup = B("cup", [-0.5, -0.5, -0.5], [0.5, 0.5, 0.5])
    return hollow_box(cup, WALL, BOTTOM) + handle_loop(B("handle", [-0.05, -0.3, 0.4], [0.05, 0.3, 0.8]), cup)


def quad_mesh_is_manifold(quads):
    counts = edge_use_counts(quads)
    directed = {(int(q[k]), int(q[(k + 1) % 4])) for q in quads for k in range(4)}
    opposite = all((b, a) in directed for a, b in directed)
    return set(counts.values()) == {2} and opposite


def test_overlapping_cuboids_give_closed_manifold_without_interior_faces():
    boxes = [B("a", [0, 0, 0], [2, 1, 1]), B("b", [1, 0.5, 0.5], [3, 2, 2])]
    mesh = boundary_quads(build_lattice(boxes, 1e-3))
    assert quad_mesh_is_manifold(mesh.quads)
    assert quad_euler(mesh.quads) == 2
    pos = mesh.positions()[mesh.quads].mean(axis=1)  # quad centres
    inside_a = np.all((pos > [0, 0, 0]) & (pos < [2, 1, 1]), axis=1)
    inside_b = np.all((pos > [1, 0.5, 0.5]) & (pos < [3, 2, 2]), axis=1)
    assert not np.any(inside_a | inside_b)  # no face strictly inside the union
    # total area = union surface area: 2*(2+2+1) + 2*(4+4+2.25) - 2*(1*0.5 overlap faces...)
    areas = sum(_quad_area(mesh.positions()[q]) for q in mesh.quads)
    assert areas == pytest.approx(_union_area_by_voxels(boxes), rel=1e-9)


def _quad_area(p):
    return float(np.linalg.norm(np.cross(p[1] - p[0], p[3] - p[0])))


def _union_area_by_voxels(boxes):
    lat = build_lattice(boxes, 1e-3)
    return sum(_quad_area(q) for q in boundary_quads(lat).positions()[boundary_quads(lat).quads])


@pytest.mark.parametrize(
    "boxes",
    [
        [B("a", [0, 0, 0], [1, 1, 1]), B("b", [1, 1, 0], [2, 2, 1])],  # touching along an edge
        [B("a", [0, 0, 0], [1, 1, 1]), B("b", [1, 1, 1], [2, 2, 2])],  # touching at a corner
    ],
)
def test_nonmanifold_contacts_are_repaired(boxes):
    lat = build_lattice(boxes, 1e-3)
    assert lat.filled >= 1
    assert quad_mesh_is_manifold(boundary_quads(lat).quads)


def test_mug_union_has_genus_one():
    mesh = boundary_quads(build_lattice(mug_boxes(), 1e-3, symmetric_x=True))
    assert quad_mesh_is_manifold(mesh.quads)
    assert quad_euler(mesh.quads) == 0  # handle hole: genus 1


def test_merging_reduces_faces_and_keeps_the_surface():
    mesh = boundary_quads(build_lattice(mug_boxes(), 1e-3, symmetric_x=True))
    ps = merge_quads(mesh, mirror=True)
    before = rects_from_quads(mesh)
    assert len(ps.rects) < len(before) / 2
    assert ps.valid()
    assert sum(ps.area(r) for r in ps.rects.values()) == pytest.approx(sum(ps.area(r) for r in before), rel=1e-12)
    # same point set: every original quad lies inside exactly one merged rectangle
    for q in before:
        hosts = [
            r
            for r in ps.rects.values()
            if (r.axis, r.sign, r.k, r.label) == (q.axis, q.sign, q.k, q.label)
            and r.b0 <= q.b0
            and q.b1 <= r.b1
            and r.c0 <= q.c0
            and q.c1 <= r.c1
        ]
        assert len(hosts) == 1


def test_template_from_cuboids_is_closed_with_junctions_on_parents():
    tpl = template_from_boxes(mug_boxes(), "mug", TemplateSettings(snap_tol=1e-3))
    assert closed_manifold_problems(tpl) == []
    assert euler_characteristic(tpl) == 0
    assert any(isinstance(p, JunctionPoint) for p in tpl.points)
    assert junction_errors(tpl).max() < 1e-9
    assert self_intersections(tpl) == []
    # symmetric construction: every point has a mirror partner or lies on x = 0
    sym = tpl.symmetry
    assert 2 * len(sym.pairs) + len(sym.self_points) == tpl.num_points


def test_self_intersection_check_detects_crossing_patches():
    boxes = [B("a", [-1.5, -0.5, -0.5], [-0.5, 0.5, 0.5]), B("b", [0.5, -0.3, -0.3], [1.1, 0.3, 0.3])]
    tpl = template_from_boxes(boxes, "two", TemplateSettings(snap_tol=1e-3, symmetric=False))
    assert self_intersections(tpl) == []
    from train.templates.authoring.checks import point_positions
    from train.templates.template import FreePoint, Template

    pos = point_positions(tpl)
    pos[pos[:, 0] > 0, 0] -= 1.2  # slide box b into box a: their patches now cross
    moved = Template(points=[FreePoint(tuple(map(float, q))) for q in pos], curves=tpl.curves, patches=tpl.patches)
    hits = self_intersections(moved)
    assert hits and all(tpl.patches[i].label != tpl.patches[j].label for i, j in hits)


@pytest.mark.parametrize("category", CATEGORIES)
def test_built_category_template_is_valid(category):
    path = DATA_DIR / f"{category}.json"
    tpl = load_template_file(path)
    assert tpl.num_patches >= 6
    assert closed_manifold_problems(tpl) == []
    errs = junction_errors(tpl)
    assert errs.size == 0 or errs.max() < 1e-9
    assert self_intersections(tpl) == []
    chi = euler_characteristic(tpl)
    assert chi % 2 == 0 and chi <= 2 * 8  # closed orientable surfaces
    if category == "mug":
        assert chi == 0  # the handle's hole
    if category in MIRROR_PLANE:  # declared: flipped drawings in training, --mirror-average
        assert 2 * len(tpl.symmetry.pairs) + len(tpl.symmetry.self_points) == tpl.num_points
        assert param_mirror(tpl) is not None
    else:
        assert tpl.symmetry is None
    # the paper's symmetry loss: airplanes and cars only
    assert ("symmetry" in tpl.regularizers) == (category in ("airplane", "car"))
    assert (DATA_DIR / f"{category}.png").exists()


def test_airplane_template_marks_engine_patches_optional():
    tpl = load_template_file(DATA_DIR / "airplane.json")
    engines = tpl.optional_parts.get("engine", [])
    assert engines and all(tpl.patches[i].label == "engine" for i in engines)


def test_median_picks_the_central_model():
    rng = np.random.default_rng(0)
    base = rng.normal(size=(300, 3))
    clouds = [base + s for s in ([0, 0, 0], [0.2, 0, 0], [0.4, 0, 0], [0.6, 0, 0], [0.8, 0, 0])]
    d = chamfer_matrix(clouds)
    assert np.allclose(d, d.T) and np.all(np.diag(d) == 0)
    assert median_index(d) == 2
    assert median_index(np.array([[0, 1.0], [1.0, 0]])) == 0  # ties → lowest index


@pytest.mark.slow
def test_build_is_deterministic(tmp_path):
    from train.templates.authoring.build import BuildSettings, build_all

    a = build_all(["knife"], tmp_path / "a", BuildSettings(n_models=4), spheres=False)
    build_all(["knife"], tmp_path / "b", BuildSettings(n_models=4), spheres=False)
    assert (tmp_path / "a/knife.json").read_bytes() == (tmp_path / "b/knife.json").read_bytes()
    assert (tmp_path / "a/knife.png").read_bytes() == (tmp_path / "b/knife.png").read_bytes()
    assert a["knife"].chosen in a["knife"].model_ids


def _combination_problems(tpl, alpha=4.0):
    """Per on/off combination: template-level problems and the exported mesh's edge report."""
    import torch

    from train.export.obj import edge_report
    from train.export.quadmesh import quad_mesh
    from train.templates.authoring.checks import part_combinations

    patches = tpl.patches_from_params(tpl.initial_params(torch.float64)[None])[0].numpy()
    out = []
    for combo in part_combinations(tpl):
        act = tpl.active_patches(combo)
        report = edge_report(quad_mesh(patches[act], alpha=alpha).triangles())
        out.append((combo, closed_manifold_problems(tpl, act), report))
    return out


def test_optional_part_gets_closing_patches_and_every_combination_is_closed():
    # a body with a pod hanging under it (an airplane engine) and a knob on top of the pod
    boxes = [
        B("body", [-1, 0, -0.3], [1, 0.4, 0.3]),
        B("pod", [0.3, -0.5, -0.2], [0.7, 0.1, 0.2]),
        B("knob", [0.4, -0.7, -0.1], [0.6, -0.4, 0.1]),
    ]
    tpl = template_from_boxes(boxes, "pod", TemplateSettings(snap_tol=1e-3, optional_labels=("pod", "knob")))
    assert set(tpl.optional_parts) == {"pod", "knob"} and set(tpl.closing_patches) == {"pod", "knob"}
    closing = tpl.closing_patches["pod"]
    # the body's underside where the pod was, and the knob's top when the knob stays alone
    assert {tpl.patches[i].label for i in closing} == {"body", "knob"}
    assert all(i in tpl.optional_parts["knob"] for i in closing if tpl.patches[i].label == "knob")
    combos = _combination_problems(tpl)
    assert len(combos) == 4
    for combo, problems, report in combos:
        assert problems == [] and report["boundary_edges"] == 0 and report["watertight"], combo
    # without the closing patches the pod's removal leaves a hole (what exports did before)
    no_pod = [
        i
        for i in range(tpl.num_patches)
        if i not in tpl.optional_parts["pod"] + tpl.optional_parts["knob"] and i not in closing
    ]
    assert closed_manifold_problems(tpl, no_pod) != []


@pytest.mark.parametrize("category", CATEGORIES)
def test_every_part_combination_of_a_shipped_template_is_closed(category):
    tpl = load_template_file(DATA_DIR / f"{category}.json")
    for combo, problems, report in _combination_problems(tpl):
        assert problems == [], (combo, problems[:3])
        assert report["boundary_edges"] == 0 and report["watertight"], (combo, report)
    # a part attached to the body needs closing patches (airplane engines, knife guard, ...)
    assert bool(tpl.closing_patches) == bool(tpl.optional_parts)


def test_patch_budget_picks_a_closed_template_within_the_budget():
    from train.templates.authoring.budget import candidates, pareto, template_chamfer, within_budget

    boxes = mug_boxes() + [B("rim", [-0.55, 0.45, -0.55], [0.55, 0.5, 0.55])]
    settings = TemplateSettings(snap_tol=1e-3)
    full = template_from_boxes(boxes, "mug", settings)
    from train.templates.authoring.checks import conforming_mesh
    from train.templates.authoring.median import sample_surface

    v, f, _ = conforming_mesh(full)
    target = sample_surface(v, f, 1500, np.random.default_rng(0))
    cands = candidates(boxes, target, settings, "mug", 0, snap_tols=(1e-3, 0.1, 0.2), min_volumes=(0.0, 0.05))
    budget = full.num_patches - 10
    pick = within_budget(cands, budget)
    assert pick.patches <= budget < full.num_patches
    assert closed_manifold_problems(pick.template) == []
    exact = next(
        c
        for c in cands
        if c.coarsening.snap_tol == 1e-3 and c.coarsening.min_volume == 0 and not c.coarsening.merge_labels
    )
    assert exact.patches == full.num_patches and exact.chamfer <= pick.chamfer
    assert exact.chamfer == pytest.approx(template_chamfer(full, target, np.random.default_rng([0, 7919])))
    front = pareto(cands)
    assert [c.patches for c in front] == sorted(c.patches for c in front)
    assert all(a.chamfer > b.chamfer for a, b in zip(front, front[1:]))


def test_coarsening_drops_only_small_optional_parts():
    from train.templates.authoring.budget import Coarsening, coarsen_boxes

    boxes = [
        B("body", [0, 0, 0], [4, 1, 1]),
        B("fin", [0, 1, 0], [0.3, 1.3, 0.1]),
        B("pod", [1, -0.2, 0], [1.2, 0, 0.2]),
        B("tank", [2, -1, 0], [3, 0, 1]),
    ]
    out = coarsen_boxes(
        boxes, Coarsening(0.01, 0.05, merge_labels=True), keep=["pod", "tank"], droppable=["pod", "tank"]
    )
    assert [b.label for b in out] == ["body", "body", "tank"]  # the tiny fin stays (required), relabelled
    assert [b.label for b in coarsen_boxes(boxes, Coarsening(0.01, 0.0), ["pod", "tank"], ["pod", "tank"])] == [
        "body",
        "fin",
        "pod",
        "tank",
    ]


def test_a_thin_box_snapped_onto_the_last_grid_line_keeps_its_cells():
    # the tailplane on top of a fin, thinner than the snap tolerance: it must not vanish
    boxes = [B("fin", [0, 0, 0], [1, 1, 1]), B("tail", [0.2, 1.0, 0.2], [0.8, 1.02, 0.8])]
    lat = build_lattice(boxes, 0.05)
    assert (lat.owner == lat.labels.index("tail")).any()


def test_wheels_snapped_into_the_body_are_refused_and_the_shipped_car_keeps_them():
    from train.templates.authoring.budget import candidates, protruding_labels

    # a body with four wheels whose bottoms hang 0.08 below it (as the procedural car's do)
    boxes = [B("body", [-0.4, -0.2, -0.9], [0.4, 0.1, 0.9])]
    for lab, z in (("wheel_front", -0.6), ("wheel_rear", 0.5)):
        boxes.append(B(lab, [0.25, -0.28, z - 0.18], [0.4, 0.05, z + 0.18]))
    groups = (("wheels", ("wheel_front", "wheel_rear")),)
    fine = template_from_boxes(boxes, "car", TemplateSettings(snap_tol=0.01, part_groups=groups))
    coarse = template_from_boxes(boxes, "car", TemplateSettings(snap_tol=0.1, part_groups=groups))
    assert protruding_labels(fine) == {"wheel_front", "wheel_rear"}
    assert protruding_labels(coarse) == set()  # 0.08 < 0.1: the bottoms snapped onto the body's
    settings = TemplateSettings(part_groups=groups)
    target = np.random.default_rng(0).uniform(-0.5, 0.5, (500, 3))
    cands = candidates(boxes, target, settings, "car", 0, snap_tols=(0.01, 0.1), min_volumes=(0.0,))
    assert {c.coarsening.snap_tol for c in cands} == {0.01}
    assert protruding_labels(load_template_file(DATA_DIR / "car.json")) == {"wheel_front", "wheel_rear"}


def test_a_part_group_inside_the_rest_from_the_start_refuses_no_construction():
    from train.templates.authoring.budget import candidates

    # a user's "cushion" group on a seat, within the box of the back and legs: never sticks out
    boxes = [
        B("seat", [-0.5, 0.0, -0.5], [0.5, 0.1, 0.5]),
        B("back", [-0.5, 0.1, 0.4], [0.5, 1.0, 0.5]),
        B("leg", [0.4, -0.6, -0.5], [0.5, 0.0, -0.4]),
        B("cushion", [-0.3, 0.1, -0.3], [0.3, 0.15, 0.3]),
    ]
    settings = TemplateSettings(optional_labels=(), part_groups=(("soft", ("cushion",)),))
    target = np.random.default_rng(0).uniform(-0.5, 0.5, (500, 3))
    cands = candidates(boxes, target, settings, "chair", 0, snap_tols=(0.01, 0.06), min_volumes=(0.0,))
    assert {c.coarsening.snap_tol for c in cands} == {0.01, 0.06}
