"""The package layout is the data flow: every import points down the stage order.

base (pipeline.core, pipeline.shapes) <- sources <- prepare <- render <- augment
<- dataset writing and the shards' preview <- workflows (the build's settings and listing, the
stages' sheets, the Luigi tasks); ``train`` sees only the base layer. Between top-level
packages every arrow points one way (no package imports one that imports it).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# (package prefix, level); the longest matching prefix wins.
LEVELS = {
    "pipeline.core": 0,
    "pipeline.shapes": 0,
    "pipeline.sources": 1,
    "pipeline.prepare": 2,
    "render": 3,
    "augment": 4,
    "pipeline.dataset": 5,
    "pipeline.sheets": 5,
    "pipeline.__main__": 6,
    "workflows": 6,
}
TRAIN_MAY_IMPORT = ("pipeline.core", "pipeline.shapes", "train")
# Template authoring reads a user's mesh folder with the pipeline's own layouts and mesh readers
# (the same files, the same normalization as the prepare stage); nothing else in train/ does.
TRAIN_ALSO_MAY_IMPORT = {"train.templates": ("pipeline.sources",)}
# Inside train/, structures <- ops <- losses <- model <- commands: geometry knows no template,
# templates no loss, losses no network; the commands sit on top.
TRAIN_LEVELS = {
    "train.errors": 0,
    "train.grid_nn": 0,
    "train.nn_search": 0,
    "train.resnet": 0,
    "train.augmentation": 0,
    "train.distributed": 0,
    "train.plots": 0,
    "train.weight_average": 0,
    "train.sketch_input": 0,
    "train.shard_reader": 0,  # a shard's samples, only those a loader slot takes
    "train.precision": 0,  # the network's arithmetic on a GPU (fp32 or bf16)
    "train.geometry": 1,
    "train.export": 2,  # CAD files and mesh checks of patch arrays
    "train.templates": 3,  # the runtime format; train.templates.authoring builds templates offline
    "train.losses": 4,
    "train.metrics": 5,
    "train.model": 5,
    "train.objective": 5,
    "train.data": 5,
    "train.template_fit": 5,  # a template fitted to shapes (the fit stage's and the shape basis' fit)
    "train.shape_basis": 6,
    "train.fit": 6,
    "train.mirror_average": 7,  # inference through the flipped drawing too (evaluate, predict)
    "train.patch_fit": 7,  # the fit stage (a template fitted to shapes, no network) and its export
    "train.evaluate": 7,
    "train.predict": 7,
    "train.interpolate": 7,
    "train.recipes": 7,
    "train.serve": 7,  # the browser testbed: predict's path behind a web page
    "train.cli": 8,
    "train.__main__": 8,
    "train": 8,
}
PACKAGES = ("pipeline", "render", "augment", "train", "workflows")


def level_of(module: str, levels: dict[str, int] = LEVELS) -> int | None:
    best = None
    for prefix, level in levels.items():
        if module == prefix or module.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, level)
    return None if best is None else best[1]


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """Every project module a file imports (function-level imports too), with its line."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
            # `from pipeline import x` names a submodule when x is one
            found += [
                (node.lineno, f"{node.module}.{a.name}")
                for a in node.names
                if (ROOT / node.module.replace(".", "/") / a.name).exists()
                or (ROOT / node.module.replace(".", "/") / f"{a.name}.py").exists()
            ]
    return [(line, m) for line, m in found if m.split(".")[0] in PACKAGES]


def project_files() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def upward_imports(files: dict[str, Path] | None = None) -> list[str]:
    """Imports against the stage order, for ``{module name: file}`` (default: the whole project)."""
    files = files if files is not None else {module_name(p): p for p in project_files()}
    bad = []
    for me, path in files.items():
        for line, target in imported_modules(path):
            where = f"{path.name if not path.is_relative_to(ROOT) else path.relative_to(ROOT)}:{line} imports {target}"
            if me.startswith("train"):
                extra = next((v for k, v in TRAIN_ALSO_MAY_IMPORT.items() if me.startswith(k + ".")), ())
                if not target.startswith(TRAIN_MAY_IMPORT + extra):
                    bad.append(where + " (train may import only the base layer)")
                mine, theirs = level_of(me, TRAIN_LEVELS), level_of(target, TRAIN_LEVELS)
                if target.startswith("train") and mine is not None and theirs is not None and theirs > mine:
                    bad.append(where + f" (train level {mine} importing train level {theirs})")
                continue
            mine, theirs = level_of(me), level_of(target)
            if target.startswith("train"):
                bad.append(where + " (the dataset side never imports the trainer)")
            elif mine is not None and theirs is not None and theirs > mine:
                bad.append(where + f" (level {mine} importing level {theirs})")
    return bad


def test_every_module_has_a_level():
    unplaced = [
        module_name(p)
        for p in project_files()
        if not module_name(p).startswith("train") and level_of(module_name(p)) is None and module_name(p) != "pipeline"
    ]
    assert unplaced == []
    assert [
        module_name(p)
        for p in project_files()
        if module_name(p).startswith("train") and level_of(module_name(p), TRAIN_LEVELS) is None
    ] == []


def test_imports_point_down_the_stage_order():
    assert upward_imports() == []


def test_the_check_sees_upward_imports(tmp_path):
    # The walker must catch what it is for, function-level imports included.
    base = tmp_path / "probe.py"
    base.write_text("import numpy\ndef f():\n    from render.settings import RenderSettings\n")
    trainer = tmp_path / "trainer_probe.py"
    trainer.write_text("from augment.pencil import draw_pencil\nfrom pipeline.core.atomic import write_json\n")
    geometry = tmp_path / "geometry_probe.py"
    geometry.write_text("from train.losses.collision import collision_loss\n")
    bad = upward_imports({"pipeline.core.probe": base, "train.probe": trainer, "train.geometry.probe": geometry})
    assert bad == [
        "probe.py:3 imports render.settings (level 0 importing level 3)",
        "trainer_probe.py:1 imports augment.pencil (train may import only the base layer)",
        "geometry_probe.py:1 imports train.losses.collision (train level 1 importing train level 4)",
    ]


def package_graph() -> dict[str, set[str]]:
    """Top-level package -> the top-level packages its modules import."""
    graph: dict[str, set[str]] = {p: set() for p in PACKAGES}
    for path in project_files():
        me = module_name(path).split(".")[0]
        for _, target in imported_modules(path):
            if target.split(".")[0] != me:
                graph[me].add(target.split(".")[0])
    return graph


def test_package_arrows_point_one_way():
    graph = package_graph()
    both = sorted((a, b) for a in graph for b in graph[a] if a < b and a in graph.get(b, set()))
    assert both == [], f"packages importing each other: {both}"
    assert graph["pipeline"] == set()  # the stages before and after drawing need no drawing code


def test_training_and_export_never_import_template_authoring():
    """Only the templates' own command line (and tests, bench) build templates; everything that
    trains, evaluates or exports loads a finished one."""
    allowed = ("train.templates.authoring", "train.templates.__main__")
    bad = [
        f"{path.relative_to(ROOT)}:{line} imports {target}"
        for path in project_files()
        if module_name(path).startswith("train") and not module_name(path).startswith(allowed)
        for line, target in imported_modules(path)
        if target.startswith("train.templates.authoring")
    ]
    assert bad == []
