"""The cuboid file: a category's part boxes written by hand or exported from CAD (YAML or JSON).

One model (a top-level ``cuboids`` list) or several (``models``, each with an ``id`` and its
``cuboids``; the median model is then chosen as for meshes)::

    category: chair            # optional: the template's name (else --category, else the file name)
    symmetry: auto             # optional: auto (detect the x = 0 mirror plane) | x (force) | none
    hollow:                    # optional: parts built as a floor + four walls, open at +y (a cup, a tub)
      basin: {wall: 0.15, bottom: 0.2}   # fractions, as the built-in mug/bathtub (part_boxes.py)
    part_groups:               # optional: patch labels with their own Chamfer/normal terms
      wheels: [wheel]
    cuboids:
      - {label: seat, center: [0, 0.45, 0], size: [0.9, 0.08, 0.9]}
      - {label: leg, min: [0.35, 0, 0.35], max: [0.43, 0.45, 0.43], mirror: true}
      - {label: arm, center: [0.45, 0.6, 0], size: [0.06, 0.2, 0.8], id: arm_r, mirror: arm_l, optional: true}
      - {label: arm, center: [-0.45, 0.6, 0], size: [0.06, 0.2, 0.8], id: arm_l, optional: true}

A cuboid has a ``label`` and either ``center`` + ``size`` or ``min`` + ``max`` (any units: the
boxes are normalized like the prepare stage, union's bounding-box centre at the origin and
farthest corner at radius 1; y is up). Cuboids are axis-aligned: ``rotation`` is accepted only
as [0, 0, 0]. ``optional: true`` makes its label an optional part (with closing patches);
``mirror: true`` adds the box's mirror image across x = 0 of the file's frame; ``mirror: ID``
names the box's partner, checked to be its mirror image about the boxes' centre plane. Every
other key, a zero or negative size, and a malformed value is an error naming the file and line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from train.templates.authoring.lattice import Box

if TYPE_CHECKING:
    from train.templates.authoring.user import ModelBoxes

TOP_KEYS = {"format", "version", "category", "symmetry", "hollow", "part_groups", "cuboids", "models"}
MODEL_KEYS = {"id", "cuboids"}
CUBOID_KEYS = {"label", "center", "size", "min", "max", "rotation", "optional", "mirror", "id"}
SYMMETRY_MODES = ("auto", "x", "none")
PAIR_TOL = 0.02  # a declared mirror pair may differ by this fraction of the boxes' extent


class CuboidFileError(ValueError):
    """A problem in a cuboid file; the message starts with ``FILE:LINE:``."""


@dataclass
class FileModel:
    model_id: str
    boxes: list[Box]  # in the file's units
    optional: set[str] = field(default_factory=set)


@dataclass
class CuboidFile:
    path: Path
    models: list[FileModel]
    category: str | None = None
    symmetry: str = "auto"
    hollow: dict[str, tuple[float, float]] = field(default_factory=dict)
    part_groups: dict[str, list[str]] = field(default_factory=dict)


class _Reader:
    """Constructs values from YAML nodes, keeping each node's line for messages."""

    def __init__(self, path: Path, text: str):
        self.path = path
        self.loader = yaml.SafeLoader(text)
        try:
            self.root = self.loader.get_single_node()
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = mark.line + 1 if mark is not None else 1
            raise CuboidFileError(f"{path}:{line}: not valid YAML/JSON: {getattr(exc, 'problem', exc)}") from None
        if self.root is None:
            raise CuboidFileError(f"{path}:1: the file is empty")

    def fail(self, node: yaml.Node, message: str) -> CuboidFileError:
        return CuboidFileError(f"{self.path}:{node.start_mark.line + 1}: {message}")

    def mapping(self, node: yaml.Node, what: str, known: set[str]) -> dict[str, yaml.Node]:
        if not isinstance(node, yaml.MappingNode):
            raise self.fail(node, f"{what} must be a mapping of keys to values")
        out: dict[str, yaml.Node] = {}
        for k, v in node.value:
            key = str(k.value)
            if key not in known:
                raise self.fail(k, f"unknown key {key!r} in {what} (known: {', '.join(sorted(known))})")
            if key in out:
                raise self.fail(k, f"key {key!r} given twice in {what}")
            out[key] = v
        return out

    def sequence(self, node: yaml.Node, what: str) -> list[yaml.Node]:
        if not isinstance(node, yaml.SequenceNode):
            raise self.fail(node, f"{what} must be a list")
        return list(node.value)

    def scalar(self, node: yaml.Node, what: str) -> Any:
        if not isinstance(node, yaml.ScalarNode):
            raise self.fail(node, f"{what} must be a single value")
        return self.loader.construct_object(node, deep=True)

    def text(self, node: yaml.Node, what: str) -> str:
        value = self.scalar(node, what)
        if not isinstance(value, (str, int)) or isinstance(value, bool) or str(value).strip() == "":
            raise self.fail(node, f"{what} must be a non-empty name, not {value!r}")
        return str(value).strip()

    def number(self, node: yaml.Node, what: str) -> float:
        value = self.scalar(node, what)
        try:  # YAML 1.1 reads JSON's 1e-3 as a string: accept any number spelling
            if isinstance(value, bool):
                raise ValueError
            x = float(value)
        except (TypeError, ValueError):
            raise self.fail(node, f"{what} must be a number, not {value!r}") from None
        if not np.isfinite(x):
            raise self.fail(node, f"{what} must be finite, not {value!r}")
        return x

    def vector(self, node: yaml.Node, what: str) -> np.ndarray:
        items = self.sequence(node, what)
        if len(items) != 3:
            raise self.fail(node, f"{what} needs 3 numbers [x, y, z], got {len(items)}")
        return np.array([self.number(n, f"{what}[{i}]") for i, n in enumerate(items)])

    def flag(self, node: yaml.Node, what: str) -> bool:
        value = self.scalar(node, what)
        if not isinstance(value, bool):
            raise self.fail(node, f"{what} must be true or false, not {value!r}")
        return value


def read_cuboid_file(path: str | Path) -> CuboidFile:
    """Parse and check a cuboid file (see the module docstring); raises CuboidFileError."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise CuboidFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    r = _Reader(path, text)
    top = r.mapping(r.root, "the file", TOP_KEYS)
    out = CuboidFile(path, [])
    if "format" in top and r.text(top["format"], "format") != "cuboids":
        raise r.fail(top["format"], "format must be 'cuboids'")
    if "version" in top and r.number(top["version"], "version") != 1:
        raise r.fail(top["version"], "only version 1 is known")
    if "category" in top:
        out.category = r.text(top["category"], "category")
    if "symmetry" in top:
        out.symmetry = r.text(top["symmetry"], "symmetry")
        if out.symmetry not in SYMMETRY_MODES:
            raise r.fail(top["symmetry"], f"symmetry must be one of {', '.join(SYMMETRY_MODES)}")
    if "hollow" in top:
        for k, v in r.mapping(top["hollow"], "hollow", _AnyKey()).items():
            fr = r.mapping(v, f"hollow part {k!r}", {"wall", "bottom"})
            wall, bottom = (
                r.number(fr[x], f"{x} of {k!r}") if x in fr else d for x, d in (("wall", 0.12), ("bottom", 0.12))
            )
            if not (0 < wall < 1 and 0 < bottom < 1):
                raise r.fail(v, f"hollow part {k!r}: wall and bottom are fractions in (0, 1)")
            out.hollow[k] = (wall, bottom)
    if "part_groups" in top:
        for k, v in r.mapping(top["part_groups"], "part_groups", _AnyKey()).items():
            out.part_groups[k] = [r.text(n, f"a label of group {k!r}") for n in r.sequence(v, f"group {k!r}")]
    if ("cuboids" in top) == ("models" in top):
        raise r.fail(r.root, "give either 'cuboids' (one model) or 'models' (several), not both or neither")
    if "cuboids" in top:
        out.models.append(_model(r, top["cuboids"], path.stem))
    else:
        seen: dict[str, yaml.Node] = {}
        for i, node in enumerate(r.sequence(top["models"], "models")):
            m = r.mapping(node, f"model {i + 1}", MODEL_KEYS)
            if "cuboids" not in m:
                raise r.fail(node, f"model {i + 1} has no 'cuboids'")
            mid = r.text(m["id"], "id") if "id" in m else f"model{i + 1:03d}"
            if mid in seen:
                raise r.fail(node, f"model id {mid!r} already used on line {seen[mid].start_mark.line + 1}")
            seen[mid] = node
            out.models.append(_model(r, m["cuboids"], mid))
    if not out.models:
        raise r.fail(r.root, "no models")
    return out


class _AnyKey(set):
    """Key set accepting every key (user-named mappings: hollow parts, part groups)."""

    def __contains__(self, item: object) -> bool:
        return True


def _model(r: _Reader, node: yaml.Node, model_id: str) -> FileModel:
    items = r.sequence(node, f"cuboids of {model_id!r}")
    if not items:
        raise r.fail(node, f"model {model_id!r} has no cuboids")
    boxes: list[Box] = []
    lines: list[yaml.Node] = []
    ids: dict[str, int] = {}
    mirrors: list[tuple[int, str, yaml.Node]] = []
    optional: set[str] = set()
    generated: list[Box] = []
    for k, cnode in enumerate(items):
        what = f"cuboid {k + 1} of {model_id!r}"
        c = r.mapping(cnode, what, CUBOID_KEYS)
        if "label" not in c:
            raise r.fail(cnode, f"{what} has no label")
        label = r.text(c["label"], "label")
        if "center" in c or "size" in c:
            if not ("center" in c and "size" in c) or "min" in c or "max" in c:
                raise r.fail(cnode, f"{what}: give center + size or min + max")
            center, size = r.vector(c["center"], "center"), r.vector(c["size"], "size")
            lo, hi = center - size / 2, center + size / 2
            extent_node = c["size"]
        elif "min" in c and "max" in c:
            lo, hi = r.vector(c["min"], "min"), r.vector(c["max"], "max")
            size, extent_node = hi - lo, c["max"]
        else:
            raise r.fail(cnode, f"{what}: give center + size or min + max")
        if np.any(size <= 0):
            axis = "xyz"[int(np.argmin(size))]
            raise r.fail(extent_node, f"{what} ({label!r}) has zero or negative size along {axis}: {size.tolist()}")
        if "rotation" in c and np.any(r.vector(c["rotation"], "rotation") != 0):
            raise r.fail(c["rotation"], f"{what}: rotated cuboids are not supported (export axis-aligned boxes)")
        if "optional" in c and r.flag(c["optional"], "optional"):
            optional.add(label)
        if "id" in c:
            cid = r.text(c["id"], "id")
            if cid in ids:
                raise r.fail(c["id"], f"cuboid id {cid!r} used twice in model {model_id!r}")
            ids[cid] = k
        box = Box(label, lo, hi)
        boxes.append(box)
        lines.append(cnode)
        if "mirror" in c:
            value = r.scalar(c["mirror"], "mirror")
            if value is True:
                mlo, mhi = lo.copy(), hi.copy()
                mlo[0], mhi[0] = -hi[0], -lo[0]
                generated.append(Box(label, mlo, mhi))
            elif value is not False:
                mirrors.append((k, r.text(c["mirror"], "mirror"), c["mirror"]))
    all_boxes = boxes + generated
    plane = _centre_x(all_boxes)
    for k, other, node in mirrors:
        if other not in ids:
            raise r.fail(node, f"mirror partner {other!r} is no cuboid id of model {model_id!r} (ids: {sorted(ids)})")
        a, b = boxes[k], boxes[ids[other]]
        if a.label != b.label:
            raise r.fail(node, f"mirror partners must share a label: {a.label!r} vs {b.label!r}")
        mlo, mhi = 2 * plane - b.hi[0], 2 * plane - b.lo[0]
        tol = PAIR_TOL * float(np.max([h - l for bx in all_boxes for l, h in zip(bx.lo, bx.hi)]))
        off = max(abs(a.lo[0] - mlo), abs(a.hi[0] - mhi), *np.abs(a.lo[1:] - b.lo[1:]), *np.abs(a.hi[1:] - b.hi[1:]))
        if off > tol:
            raise r.fail(
                node,
                f"cuboid {k + 1} and its mirror partner {other!r} (line {lines[ids[other]].start_mark.line + 1}) "
                f"are not mirror images about x = {plane:g} (off by {off:.3g})",
            )
    return FileModel(model_id, all_boxes, optional)


def _centre_x(boxes: list[Box]) -> float:
    """x of the boxes' bounding-box centre: the mirror plane after normalization."""
    return float((min(b.lo[0] for b in boxes) + max(b.hi[0] for b in boxes)) / 2)


def file_models(cf: CuboidFile, n_points: int = 2048, seed: int = 0) -> list[ModelBoxes]:
    """The file's models in the normalized frame, with samples of their box unions (for the median)."""
    from pipeline.core.seeding import rng_for
    from train.templates.authoring.box_surface import box_union_samples
    from train.templates.authoring.from_cuboids import box_normalization, normalize_boxes
    from train.templates.authoring.user import ModelBoxes

    out = []
    for m in cf.models:
        center, scale = box_normalization(m.boxes)
        boxes = normalize_boxes(m.boxes, center, scale)
        cloud = box_union_samples(boxes, n_points, rng_for(seed, "templates", "cuboids", m.model_id))
        out.append(ModelBoxes(m.model_id, boxes, cloud, set(m.optional), "cuboids"))
    return out
