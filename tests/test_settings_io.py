"""Settings are typed once: dicts come back through one type-checked ``from_dict``, the command
lines and Luigi parameters are made from the dataclass fields, stage defaults are the build's."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pytest

from augment.settings import AugmentSettings, VectorizeSettings
from pipeline.core.settings_io import SettingError, add_arguments, flag_name, from_args, from_dict, setting
from pipeline.dataset.shards import ShardSettings
from pipeline.prepare.settings import PrepareSettings
from render.settings import RenderSettings
from workflows.build_settings import BuildSettings


@dataclasses.dataclass(frozen=True)
class Inner:
    depth: int = 2


@dataclasses.dataclass(frozen=True)
class Probe:
    name: str = setting("a", "what it is called")
    count: int = 1
    scale: float = 1.0
    on: bool = False
    pair: tuple[float, float] = (0.0, 1.0)
    many: tuple[str, ...] = ("x",)
    maybe: int | None = None
    where: Path = Path("p")
    inner: Inner = Inner()
    n_points: int = dataclasses.field(default=5, metadata={"flag": "points", "help": "sample points"})


@pytest.mark.parametrize(
    "data, words",
    [
        ({"count": "3"}, "Probe.count must be an integer, got '3'"),
        ({"count": 2.5}, "Probe.count must be an integer, got 2.5"),
        ({"count": True}, "Probe.count must be an integer, got True"),
        ({"on": 1}, "Probe.on must be true/false, got 1"),
        ({"scale": "big"}, "Probe.scale must be a number, got 'big'"),
        ({"name": 3}, "Probe.name must be a string, got 3"),
        ({"pair": [1.0]}, "Probe.pair must be a list of 2 values, got [1.0]"),
        ({"pair": [1.0, "b"]}, "Probe.pair[1] must be a number, got 'b'"),
        ({"many": "x"}, "Probe.many must be a list, got 'x'"),
        ({"maybe": "no"}, "Probe.maybe must be an integer or null, got 'no'"),
        ({"inner": {"depth": "deep"}}, "Probe.inner: Inner.depth must be an integer, got 'deep'"),
        ({"inner": {"width": 1}}, "Probe.inner: Inner has no setting 'width'; it has: depth"),
        ({"nope": 1}, "Probe has no setting 'nope'; it has: name, count, scale"),
    ],
)
def test_from_dict_names_the_mistyped_setting(data: dict, words: str) -> None:
    with pytest.raises(SettingError) as err:
        from_dict(Probe, data)
    assert words in str(err.value)
    assert err.value.field == next(iter(data))


def test_from_dict_converts_json_values_so_equal_settings_are_equal() -> None:
    p = from_dict(
        Probe,
        json.loads(
            '{"scale": 2, "pair": [0, 3], "many": ["a", "b"], "maybe": null, "where": "q/r", "inner": {"depth": 4}}'
        ),
    )
    assert p == Probe(scale=2.0, pair=(0.0, 3.0), many=("a", "b"), where=Path("q/r"), inner=Inner(4))
    assert isinstance(p.scale, float) and isinstance(p.pair, tuple) and isinstance(p.where, Path)
    # a nested dict overrides the base's nested settings field by field
    a = from_dict(AugmentSettings, {"vectorize": {"spur_length": 4}}, base=AugmentSettings(variants=3))
    assert a.variants == 3 and a.vectorize == dataclasses.replace(VectorizeSettings(), spur_length=4.0)


def test_every_stage_reads_its_settings_back_through_from_dict() -> None:
    for settings in (PrepareSettings(), RenderSettings(), AugmentSettings(), ShardSettings()):
        data = json.loads(json.dumps(dataclasses.asdict(settings)))  # as a job file or manifest holds it
        assert from_dict(type(settings), data) == settings


def test_derived_flags_parse_into_the_same_settings() -> None:
    p = argparse.ArgumentParser()
    add_arguments(p, Probe, skip=("inner",))
    a = p.parse_args(["--count", "7", "--on", "--pair", "1", "2", "--many", "u", "v", "--points", "9", "--where", "w"])
    assert from_args(Probe, a, skip=("inner",)) == Probe(
        count=7, on=True, pair=(1.0, 2.0), many=("u", "v"), n_points=9, where=Path("w")
    )
    assert from_args(Probe, p.parse_args([]), skip=("inner",)) == Probe()
    text = p.format_help()
    assert "what it is called" in text and "sample points" in text  # help from setting(help=...)


def test_train_fit_has_a_flag_for_every_setting() -> None:
    from train.cli import _fit_args, fit_settings
    from train.fit import FitSettings
    from train.losses.weights import template_weights
    from train.templates import load_template

    p = argparse.ArgumentParser()
    _fit_args(p)
    flags = {a.option_strings[0] for a in p._actions if a.option_strings}
    wanted = {"--" + flag_name(f).replace("_", "-") for f in dataclasses.fields(FitSettings) if f.name != "weights"}
    assert wanted <= flags and "--points" in flags
    a = p.parse_args(
        [
            "--dataset",
            "d",
            "--category",
            "mug",
            "--template",
            "mug",
            "--out",
            "o",
            "--points",
            "123",
            "--lr",
            "0.5",
            "--device",
            "cpu",
        ]
    )
    s = fit_settings(a)  # the template file's defaults: its regularizers' weights, its matching λ
    mug = load_template("mug")
    assert s == FitSettings(
        dataset="d",
        category="mug",
        template="mug",
        out="o",
        n_points=123,
        lr=0.5,
        device="cpu",
        weights=template_weights(mug.regularizers),
        match_normals=mug.match_normals,
    )


def test_build_parameters_are_the_build_settings_fields() -> None:
    from workflows.make_dataset import main  # noqa: F401  (the module builds its parser from the task)
    from workflows.params import add_task_arguments
    from workflows.tasks import BuildDataset

    names = dict(BuildDataset.get_params())
    for f in dataclasses.fields(BuildSettings):
        assert flag_name(f) in names, f.name
    assert not names["batch_size"].significant and names["views"].significant
    p = argparse.ArgumentParser()
    add_task_arguments(p, BuildDataset)
    a = vars(
        p.parse_args(
            ["--views", "3", "--render-settings", '{"lens_mm": 35}', "--work-dir", "/w", "--categories", "mug"]
        )
    )
    assert BuildDataset(**a).build == BuildSettings(views=3, render_overrides='{"lens_mm": 35}', work_dir=Path("/w"))


def test_a_mistyped_build_parameter_names_its_flag() -> None:
    from workflows.validate import BuildParameterError, build_settings

    with pytest.raises(BuildParameterError, match=r"^--views: BuildSettings.views must be an integer, got 'four'$"):
        build_settings({"views": "four"})
    with pytest.raises(BuildParameterError, match=r"^--render-settings: "):
        build_settings({"render_overrides": 3})


def test_stage_defaults_are_the_build_defaults() -> None:
    b = BuildSettings()
    assert b.prepare_settings() == PrepareSettings()
    assert b.render_settings() == RenderSettings()
    assert b.augment_settings() == AugmentSettings()
    assert b.shard_settings() == ShardSettings()


def test_render_sheet_uses_the_build_stage_folders(tmp_path: Path) -> None:
    from workflows.sheets.render import render_procedural

    b = BuildSettings(work_dir=tmp_path, models_per_category=1, views=2)
    assert render_procedural(b, []) == b.stage_dir("render")


def test_a_setting_given_twice_is_an_error_naming_both(tmp_path):
    from workflows.build_settings import BuildSettings
    from workflows.validate import BuildParameterError, check_settings

    s = BuildSettings(views=8, render_overrides='{"views": 4}', work_dir=tmp_path)
    with pytest.raises(BuildParameterError, match=r"--render-settings: 'views' has its own flag \(--views\)"):
        check_settings(s)
    with pytest.raises(BuildParameterError, match=r"'out_size' has its own flag \(--out-size\)"):
        check_settings(BuildSettings(augment_overrides='{"out_size": 64}', work_dir=tmp_path))
    check_settings(BuildSettings(views=8, render_overrides='{"backend": "embree"}', work_dir=tmp_path))


def test_build_settings_check_their_ranges_for_library_callers_too(tmp_path):
    from pipeline.core.settings_io import SettingError
    from workflows.build_settings import BuildSettings

    with pytest.raises(SettingError, match=r"views must be an integer >= 1, got 0"):
        BuildSettings(views=0, work_dir=tmp_path)
    with pytest.raises(SettingError, match=r"models_per_category must be an integer >= 0 \(0 = every model\)"):
        BuildSettings(models_per_category=-1, work_dir=tmp_path)


def test_a_repeated_list_flag_gathers_its_values_and_a_default_list_is_replaced() -> None:
    import argparse
    import dataclasses

    from pipeline.core.settings_io import add_arguments, from_args, setting

    @dataclasses.dataclass(frozen=True)
    class S:
        names: tuple[str, ...] = setting((), "several")
        sizes: tuple[float, ...] = setting((1.0, 2.0), "with a default")

    p = argparse.ArgumentParser()
    add_arguments(p, S)
    assert from_args(S, p.parse_args(["--names", "a", "--names", "b", "c"])).names == ("a", "b", "c")
    assert from_args(S, p.parse_args([])) == S()
    assert from_args(S, p.parse_args(["--sizes", "3"])).sizes == (3.0,)
