"""Named build presets: the data half of a category's quality-table row (the training half is
``train.recipes``).

``luigi --module workflows BuildCategory --category bathtub --preset bathtub --local-scheduler``
builds the data the bathtub recipe was measured on (``BuildDataset --preset per-category``: every
category's at once); ``python -m train fit --recipe bathtub`` then
reproduces its row, and says so when the dataset it is given was built otherwise. A preset
fills the build settings the user left at their defaults; a flag given another value wins, and
keys of a settings JSON (``--render-settings``) win over the preset's keys of that stage. The
resolved settings, not the preset's name, key the stages: a preset build and the same settings
spelled out share every stage folder.

Values are by BuildSettings field; the ``*_overrides`` fields are JSON objects of a stage's settings.
"""

from __future__ import annotations

from typing import Any

# What every quality-table build shares: 1,000 procedural models (the bathtub 2,000), 4 views x 2 pencil variants,
# drawn by the embree backend (BENCHMARKS.md, "Quality per category").
_ROW: dict[str, Any] = {"models_per_category": 1000, "views": 4, "variants": 2}
_EMBREE = {"backend": "embree"}

BUILD_PRESETS: dict[str, dict[str, Any]] = {
    # views whose silhouette hull covers >= 0.8 of the largest candidate's: no wings seen edge-on
    # (BENCHMARKS.md, "The airplane: its build, its seeds and the options beside its recipe")
    "airplane": {**_ROW, "render_overrides": {**_EMBREE, "view_area_fraction": 0.8}},
    # views from above 20°, where the drawing shows the basin (BENCHMARKS.md, "The bathtub: views
    # that show its basin"); 54 % of the default rig's views came from below. The fit stage's fits
    # are what its recipe's readout is taught (--fit-readout, better at each of three seeds). Twice
    # the models: with its recipe's 6,000 steps 1.2-1.7 points nearer its blind goal at each of three
    # seeds (BENCHMARKS.md, same section); it reads its training drawings better than unseen ones.
    "bathtub": {
        **_ROW,
        "models_per_category": 2000,
        "fit_patches": True,
        "render_overrides": {**_EMBREE, "elevation_range": [20.0, 60.0]},
    },
    **{c: {**_ROW, "render_overrides": dict(_EMBREE)} for c in ("bottle", "car", "guitar", "gun", "knife", "mug")},
}
PRESETS: tuple[str, ...] = tuple(sorted(BUILD_PRESETS))
# Not a preset of its own: each category of a build takes the preset of its name, so one
# BuildDataset builds every category's quality-table data (the airplane's views for the airplane,
# the bathtub's for the bathtub).
PER_CATEGORY = "per-category"

# Where each preset value lands in a category's manifest settings (manifest.json "categories").
_MANIFEST_PATH = {
    "models_per_category": ("models_per_category",),
    "views": ("render", "views"),
    "variants": ("augment", "variants"),
}
# A switch that lands in the manifest as the presence of its stage's settings.
_MANIFEST_SWITCH = {"fit_patches": "fit"}
_MANIFEST_STAGE = {
    "prepare_overrides": "prepare",
    "render_overrides": "render",
    "augment_overrides": "augment",
    "shard_overrides": "shards",
    "fit_overrides": "fit",
}


class UnknownPreset(ValueError):
    def __init__(self, name: str) -> None:
        super().__init__(f"unknown preset {name!r}: expected one of {', '.join(PRESETS + (PER_CATEGORY,))}")


class NoCategoryPreset(ValueError):
    def __init__(self, category: str) -> None:
        super().__init__(
            f"{PER_CATEGORY}: category {category!r} has no build preset (presets: {', '.join(PRESETS)}); "
            "build it on its own, or name one preset for every category"
        )


def category_preset(name: str, category: str) -> str:
    """The preset a build named ``name`` applies to ``category``: ``category`` itself under
    PER_CATEGORY (NoCategoryPreset when there is none of that name), else ``name``."""
    if name != PER_CATEGORY:
        return name
    if category not in BUILD_PRESETS:
        raise NoCategoryPreset(category)
    return category


def preset(name: str) -> dict[str, Any]:
    """The settings of build preset ``name`` (a copy)."""
    if name not in BUILD_PRESETS:
        raise UnknownPreset(name)
    return {k: dict(v) if isinstance(v, dict) else v for k, v in BUILD_PRESETS[name].items()}


def apply_preset(name: str, values: dict[str, Any], defaults: dict[str, Any]) -> dict[str, Any]:
    """``values`` (build settings by field; JSON fields as dicts) with preset ``name`` filling each
    field still at its ``defaults`` value, and under the user's keys of each stage's JSON."""
    out = dict(values)
    for field, value in preset(name).items():
        if isinstance(value, dict):
            out[field] = {**value, **(values.get(field) or {})}
        elif values[field] == defaults[field]:
            out[field] = value
    return out


def manifest_differences(name: str, settings: dict[str, Any]) -> list[str]:
    """How a category's manifest ``settings`` differ from build preset ``name``: one
    ``"where built value (preset value)"`` item per difference; [] when they agree. Both sides
    are JSON values (the presets spell ranges as lists), so ``==`` compares them."""
    out = []
    for field, value in preset(name).items():
        if isinstance(value, dict):
            stage = settings.get(_MANIFEST_STAGE[field], {})
            pairs = [(f"{_MANIFEST_STAGE[field]}.{k}", stage.get(k), v) for k, v in value.items()]
        elif field in _MANIFEST_SWITCH:
            pairs = [(field, _MANIFEST_SWITCH[field] in settings, value)]
        else:
            node: Any = settings
            for part in _MANIFEST_PATH[field]:
                node = node.get(part) if isinstance(node, dict) else None
            pairs = [(".".join(_MANIFEST_PATH[field]), node, value)]
        out += [f"{where} {built!r} (preset {want!r})" for where, built, want in pairs if built != want]
    return out
