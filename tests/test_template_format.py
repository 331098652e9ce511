"""Template format: sphere templates, junction curves, JSON round trip, symmetry, bad input."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from train.geometry import bezier_eval, coons_points, evaluate_patches, grid_params, welded_mesh
from train.templates import (
    Curve,
    FreePoint,
    JunctionPoint,
    Patch,
    Template,
    TemplateError,
    load_template,
    load_template_file,
    save_template,
)

torch.set_num_threads(1)


@pytest.mark.parametrize("name,patches,params,points", [("sphere24", 24, 366, 122), ("sphere54", 54, 816, 272)])
def test_sphere_templates_match_paper_sizes_and_are_closed(name, patches, params, points):
    t = load_template(name)
    assert (t.num_patches, t.num_params, t.num_points) == (patches, params, points)
    # closed: every curve bounds exactly two patches, with opposite orientations
    uses: dict[int, list[bool]] = {}
    for p in t.patches:
        for c, r in zip(p.curves, p.reverse):
            uses.setdefault(c, []).append(r)
    assert len(uses) == len(t.curves)
    assert all(sorted(v) == [False, True] for v in uses.values())
    prm = t.initial_params(torch.float64)[None]
    ev = evaluate_patches(t.patches_from_params(prm), grid_params(7, dtype=torch.float64))
    r = ev.points.norm(dim=-1)
    assert r.min() > 0.985 and r.max() < 1.001  # close to the unit sphere
    assert ((ev.normals * ev.points).sum(-1) > 0.98).all()  # P_s × P_t points outward
    v, f = welded_mesh(t.patches_from_params(prm)[0], k=5)
    assert len(v) - len(f) * 3 // 2 + len(f) == 2  # closed genus-0 mesh


def test_sphere_symmetry_pairs_mirror_across_x0():
    t = load_template("sphere24")
    pos = t.points_from_params(t.initial_params(torch.float64)[None])[0]
    pairs = t.symmetry_pairs()
    assert len(t.symmetry.pairs) * 2 + len(t.symmetry.self_points) == t.num_points
    mirrored = pos[pairs[:, 1]] * torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)
    torch.testing.assert_close(pos[pairs[:, 0]], mirrored)


def _xyz(p):
    return np.array(p.xyz) if isinstance(p, FreePoint) else np.array([2.0 * p.t, 1.0, 0.0])  # J on y = 1


def _line_points(points, a, b):
    pa, pb = _xyz(points[a]), _xyz(points[b])
    i = len(points)
    points += [FreePoint(tuple((2 * pa + pb) / 3)), FreePoint(tuple((pa + 2 * pb) / 3))]
    return i, i + 1


J = 9  # index of the junction point in junction_template()


def junction_template() -> Template:
    """Patch A on top; below it two patches B1, B2 whose top edges are pieces of A's bottom curve
    split at a junction point J (t = 0.4) — a T-junction."""
    pts = [FreePoint(p) for p in [(0, 0, 0), (0.8, 0, 0), (2, 0, 0), (0, 1, 0), (2, 1, 0), (2, 2, 0), (0, 2, 0)]]
    curves: list[Curve] = []

    def line(a, b):
        i, j = _line_points(pts, a, b)
        curves.append(Curve(points=(a, i, j, b)))
        return len(curves) - 1

    d = line(3, 4)  # curve 0: A's bottom, the parent
    jpt = len(pts)  # J at (0.8, 1, 0)
    pts.append(JunctionPoint(curve=d, t=0.4))
    a2, a3, a4 = line(4, 5), line(5, 6), line(6, 3)
    b1c1 = line(0, 1)
    mid = line(1, jpt)  # from (0.8,0) up to the junction
    curves.append(Curve(parent=d, start=jpt, end=3))
    b1c3 = len(curves) - 1
    b1c4 = line(3, 0)
    b2c1, b2c2 = line(1, 2), line(2, 4)
    curves.append(Curve(parent=d, start=4, end=jpt))
    b2c3 = len(curves) - 1
    patches = [
        Patch((d, a2, a3, a4), label="top"),
        Patch((b1c1, mid, b1c3, b1c4), label="left"),
        Patch((b2c1, b2c2, b2c3, mid), (False, False, False, True), label="right"),
    ]
    return Template(pts, curves, patches, name="tjunction", optional_parts={"right": [2]})


def test_junction_curves_lie_on_parent_and_follow_the_junction_parameter():
    t = junction_template()
    assert t.num_params == 3 * (t.num_points - 1) + 1
    assert isinstance(t.points[J], JunctionPoint)
    col = t._offsets[J]
    prm = t.initial_params(torch.float64)[None].repeat(2, 1)
    gen = torch.Generator().manual_seed(0)
    prm[1] += 0.2 * torch.randn(prm.shape[1], generator=gen, dtype=torch.float64)  # bend everything
    prm[1, col] = 1.3  # and move the junction along the curve (t = sigmoid(1.3))
    curves = t.curves_from_params(prm)
    pos = t.points_from_params(prm)
    u = torch.linspace(0, 1, 9, dtype=torch.float64)
    for b in range(2):
        tj = torch.sigmoid(prm[b, col])
        parent = curves[b, 0]
        torch.testing.assert_close(pos[b, J], bezier_eval(parent, tj[None])[0])
        torch.testing.assert_close(bezier_eval(curves[b, 6], u), bezier_eval(parent, tj + (0 - tj) * u))  # J → start
        torch.testing.assert_close(bezier_eval(curves[b, 10], u), bezier_eval(parent, 1 + (tj - 1) * u))  # end → J
    # watertight T-junction: the lower patches' top edges cover A's bottom edge exactly
    patches = t.patches_from_params(prm)
    top_edge = coons_points(patches[:, 0], torch.stack([u, torch.zeros_like(u)], -1))
    lower = torch.cat([coons_points(patches[:, k], torch.stack([u, torch.ones_like(u)], -1)) for k in (1, 2)], -2)
    gap = torch.cdist(top_edge.flatten(0, 1), lower.flatten(0, 1)).min(-1).values
    assert gap.max() < 0.2  # sampled, so compare densely below
    dense = torch.linspace(0, 1, 401, dtype=torch.float64)
    lower_dense = torch.cat(
        [coons_points(patches[1:, k], torch.stack([dense, torch.ones_like(dense)], -1)) for k in (1, 2)], -2
    )[0]
    top_dense = coons_points(patches[1:, 0], torch.stack([dense, torch.zeros_like(dense)], -1))[0]
    assert torch.cdist(top_dense, lower_dense).min(-1).values.max() < 5e-3


def test_junction_template_gradcheck_and_adjacency():
    t = junction_template()
    prm = t.initial_params(torch.float64)[None].requires_grad_(True)
    assert torch.autograd.gradcheck(t.patches_from_params, (prm,))
    assert t.adjacency() == [(0, 1), (0, 2), (1, 2)]
    sides, corners = t.shared_features(0, 1)
    assert sides == [True, False, False, False]  # A's bottom curve is B1's parent
    sides, corners = t.shared_features(1, 0)
    assert sides == [False, False, True, False] and corners[2]  # B1's top edge and its corner at J


def test_json_round_trip_is_byte_stable(tmp_path):
    t = junction_template().with_symmetry(plane_x=1.0, tol=1e-6)
    path = tmp_path / "t.json"
    save_template(t, path)
    again = load_template_file(path)
    save_template(again, tmp_path / "u.json")
    assert path.read_bytes() == (tmp_path / "u.json").read_bytes()
    assert again.optional_parts == {"right": [2]} and again.patch_labels == ["top", "left", "right"]
    prm = t.initial_params(torch.float64)[None]
    torch.testing.assert_close(again.patches_from_params(prm), t.patches_from_params(prm))
    assert load_template(str(path)).num_params == t.num_params


def test_mirror_symmetry_pairs_points_across_the_plane():
    t = junction_template()
    sym = t.mirror_symmetry(plane_x=1.0, tol=1e-6)
    pos = t.points_from_params(t.initial_params(torch.float64)[None])[0]
    assert (0, 2) in sym.pairs and (3, 4) in sym.pairs  # (0,0)↔(2,0), (0,1)↔(2,1)
    for i, j in sym.pairs:
        assert abs(pos[i, 0] + pos[j, 0] - 2.0) < 1e-6
    assert J not in sym.self_points and all(J not in p for p in sym.pairs)  # J at x = 0.8: no partner


def test_bad_templates_raise_named_errors(tmp_path):
    t = junction_template()
    data = t.to_json()
    data["patches"][0]["reverse"] = [True, False, False, False]  # breaks the loop
    with pytest.raises(TemplateError, match="does not end"):
        Template.from_json(data)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(TemplateError, match="bad.json"):
        load_template_file(bad)
    with pytest.raises(TemplateError):
        load_template("no-such-template")
    with pytest.raises(TemplateError, match="parameters"):
        t.patches_from_params(torch.zeros(1, 5))


def test_active_patches_follow_optional_and_closing_parts(tmp_path):
    t = dataclasses.replace(
        junction_template(),
        closing_patches={"right": [1]},  # stand-in: patch 1 only while "right" is off
        part_groups={"body": ["a", "b"], "side": ["c"]},
    )
    assert t.part_names == ["right"]
    assert t.active_patches() == [0, 2] and t.active_patches({"right": True}) == [0, 2]
    assert t.active_patches({"right": False}) == [0, 1]
    with pytest.raises(ValueError, match="no optional part"):
        t.active_patches({"wheel": False})
    save_template(t, tmp_path / "t.json")
    again = load_template_file(tmp_path / "t.json")
    assert again.closing_patches == {"right": [1]} and again.part_groups == {"body": ["a", "b"], "side": ["c"]}
    data = t.to_json()
    data["closing_patches"] = {"right": [7]}
    with pytest.raises(TemplateError, match="closing patches of 'right'"):
        Template.from_json(data)
    # templates without them keep the old file layout
    assert "closing_patches" not in junction_template().to_json()


def test_a_template_is_never_changed_after_it_is_made():
    t = junction_template()
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.symmetry = None
    with pytest.raises(TemplateError, match="bad patch index"):  # a changed copy is validated again
        dataclasses.replace(t, optional_parts={"right": [99]})
    assert t.with_symmetry(plane_x=1.0, tol=1e-6).symmetry is not None and t.symmetry is None
