"""Named build presets: the data half of a recipe's quality row (pipeline.core.build_presets)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline.core.build_presets import BUILD_PRESETS, PRESETS
from workflows.build_settings import BuildSettings

SPELLED_OUT = dict(
    models_per_category=2000, fit_patches=True, render_overrides='{"backend": "embree", "elevation_range": [20, 60]}'
)


def test_a_preset_is_the_same_build_as_its_settings_spelled_out(tmp_path: Path) -> None:
    b = BuildSettings(preset="bathtub", work_dir=tmp_path)
    assert (b.models_per_category, b.views, b.variants) == (2000, 4, 2)
    assert (b.render_settings().backend, b.render_settings().elevation_range) == ("embree", (20.0, 60.0))
    plain = BuildSettings(**SPELLED_OUT, work_dir=tmp_path)
    for stage in plain.stages():  # the preset's name keys nothing: the same stage folders
        assert b.stage_dir(stage) == plain.stage_dir(stage)
    assert b.manifest_settings() == plain.manifest_settings()
    # tasks hand their settings on to the tasks they require: resolving again changes nothing
    again = BuildSettings(**{k: getattr(b, k) for k in b.__dataclass_fields__})
    assert again == b


def test_flags_and_json_keys_win_over_the_preset(tmp_path: Path) -> None:
    b = BuildSettings(
        preset="airplane", models_per_category=50, render_overrides='{"backend": "freestyle"}', work_dir=tmp_path
    )
    r = b.render_settings()
    assert b.models_per_category == 50 and r.backend == "freestyle" and r.view_area_fraction == 0.8
    assert BuildSettings(preset="guitar", work_dir=tmp_path).render_settings().view_area_fraction == 0.0


def test_an_unknown_preset_names_its_flag_and_the_choices() -> None:
    from workflows.validate import BuildParameterError, build_settings

    with pytest.raises(BuildParameterError, match=r"^--preset: unknown preset 'chair': expected one of airplane, "):
        build_settings({"preset": "chair"})
    with pytest.raises(BuildParameterError, match=r"^--render-settings: "):  # named as without a preset
        build_settings({"preset": "bathtub", "render_overrides": 3})


def test_the_luigi_task_builds_the_preset(tmp_path: Path) -> None:
    from workflows.tasks import BuildCategory, CategoryShards

    common = dict(category="bathtub", work_dir=str(tmp_path / "w"), dataset_dir=str(tmp_path / "d"))
    root = BuildCategory(preset="bathtub", **common)
    assert root.build.render_settings().elevation_range == (20.0, 60.0)
    shards = [t for t in root.requires() if isinstance(t, CategoryShards)]
    assert shards and all(t.build == root.build for t in shards)
    # the name is significant: a preset build and a default one are different tasks
    assert root.task_id != BuildCategory(**common).task_id


def test_every_recipe_has_its_build_preset() -> None:
    from train.recipes import RECIPES

    assert PRESETS == RECIPES


def _category(root: Path, build: BuildSettings, name: str = "bathtub") -> Path:
    (root / name).mkdir(parents=True)
    (root / name / "category.json").write_text(json.dumps({"category": name, "settings": build.manifest_settings()}))
    return root


def test_fit_says_when_its_dataset_was_not_built_with_the_recipes_preset(tmp_path: Path, capsys) -> None:
    from tests.test_recipes import _fit
    from train.recipes import dataset_note

    other = _category(tmp_path / "default", BuildSettings(work_dir=tmp_path))
    note = dataset_note("bathtub", other)
    assert note is not None and "--preset bathtub" in note
    for words in ("render.elevation_range [-10.0, 40.0] (preset [20.0, 60.0])", "render.backend 'freestyle'"):
        assert words in note
    assert "models_per_category 16 (preset 2000)" in note and "fit_patches False (preset True)" in note
    _fit(["--recipe", "bathtub", "--dataset", str(other), "--out", "o"])
    assert "--preset bathtub" in capsys.readouterr().err
    same = _category(tmp_path / "preset", BuildSettings(preset="bathtub", work_dir=tmp_path))
    assert dataset_note("bathtub", same) is None
    assert dataset_note("bathtub", tmp_path / "missing") is None  # fit itself says the data is missing


def test_every_presets_build_agrees_with_the_preset(tmp_path: Path) -> None:
    from pipeline.core.build_presets import manifest_differences

    # each preset field has its place in the manifest, and its own build reads back as itself
    for name in PRESETS:
        built = json.loads(json.dumps(BuildSettings(preset=name, work_dir=tmp_path).manifest_settings()))
        assert manifest_differences(name, built) == [], name
    assert manifest_differences("airplane", built)  # the mug's build is not the airplane's


def test_per_category_gives_each_category_the_preset_of_its_name(tmp_path: Path) -> None:
    from workflows.validate import BuildParameterError, category_build

    each = BuildSettings(preset="per-category", models_per_category=3, work_dir=tmp_path)
    assert each.render_settings().elevation_range == (-10.0, 40.0)  # the build itself resolves nothing
    for name in PRESETS:
        assert each.for_category(name) == BuildSettings(preset=name, models_per_category=3, work_dir=tmp_path)
    assert each.for_category("airplane").render_settings().view_area_fraction == 0.8
    assert each.for_category("bathtub").render_settings().elevation_range == (20.0, 60.0)
    plain = BuildSettings(preset="mug", work_dir=tmp_path)
    assert plain.for_category("airplane") is plain  # a named preset applies to every category
    with pytest.raises(BuildParameterError, match=r"^--preset: per-category: category 'chair' has no build preset"):
        category_build(each, "chair")


def test_a_folder_category_without_a_preset_stops_a_per_category_build(tmp_path: Path) -> None:
    from workflows.tasks import BuildDataset
    from workflows.validate import BuildParameterError

    for name in ("mug", "chair"):
        (tmp_path / "src" / name).mkdir(parents=True)
        (tmp_path / "src" / name / "a.obj").write_text(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"
        )
    dirs = dict(work_dir=str(tmp_path / "w"), dataset_dir=str(tmp_path / "d"), source=str(tmp_path / "src"))
    with pytest.raises(BuildParameterError, match="'chair' has no build preset"):
        BuildDataset(preset="per-category", **dirs)
    assert BuildDataset(preset="per-category", categories="mug", **dirs).requires()[0].build.views == 4


def test_one_build_dataset_builds_every_category_with_its_preset(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys

    from pipeline.core.build_presets import manifest_differences
    from workflows.tasks import BuildCategory

    small = dict(models_per_category=1, views=1, variants=1, image_size=64, out_size=64)
    dirs = dict(work_dir=str(tmp_path / "w"), dataset_dir=str(tmp_path / "d"))
    flags = [f"--{k.replace('_', '-')}={v}" for k, v in {**small, **dirs}.items()]
    root = Path(__file__).resolve().parents[1]
    cmd = [str(Path(sys.executable).parent / "luigi"), "--module", "workflows", "BuildDataset", "--local-scheduler"]
    env = {**os.environ, "PYTHONPATH": str(root)}
    run = subprocess.run(
        cmd + ["--preset", "per-category", "--categories", "airplane,bathtub", *flags],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    for name in ("airplane", "bathtub"):
        assert f"\n{name:<12}     1      0" in run.stdout  # the summary counts both
        settings = json.loads((tmp_path / "d" / name / "category.json").read_text())["settings"]
        # what differs from the category's own preset is the user's flags, nothing of the other's
        assert manifest_differences(name, settings) == [
            f"models_per_category 1 (preset {BUILD_PRESETS[name]['models_per_category']})",
            "render.views 1 (preset 4)",
            "augment.variants 1 (preset 2)",
        ]
        assert ("fit" in settings) == (name == "bathtub")  # the bathtub's preset fits every model
        # the same data as the category built on its own with its preset: nothing left to do
        assert BuildCategory(category=name, preset=name, **small, **dirs).complete()
    assert not BuildCategory(category="bathtub", **small, **dirs).complete()
    # the progress line counts each category in its own stages: the fit stage is the bathtub's only
    from workflows.console import StageCounter, batch_task_ids, stage_counts
    from workflows.tasks import BuildDataset

    both = BuildDataset(preset="per-category", categories="airplane,bathtub", **small, **dirs)
    listings = both.listings()
    want = {"prepare": (2, 2), "render": (2, 2), "augment": (2, 2), "fit": (1, 1), "shards": (2, 2)}
    assert stage_counts(both.build, listings) == want
    assert StageCounter(both.build, listings, batch_task_ids(both, listings)).counts() == want
