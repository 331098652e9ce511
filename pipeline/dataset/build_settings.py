"""User-facing build settings → per-stage settings, stage keys and stage folders.

Stage keys chain: source ← (source, seed); prepare ← prepare settings + source key; render ←
render settings + seed + prepare key; augment ← augment settings + seed + render key; shards ←
shard settings + seed + augment key. Changing the pencil settings therefore changes only the
augment and shard keys: prepared meshes and renders are found again under their old keys.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

from pipeline.core.stage_keys import settings_dict, settings_hash, stage_key
from pipeline.dataset.shards import ShardSettings

DEFAULT_WORK_DIR = Path("data/work")
DEFAULT_DATASET_DIR = Path("data/dataset")


def _type_name(value: Any) -> str:
    return {bool: "true/false", int: "an integer", float: "a number", str: "a string"}.get(
        type(value), type(value).__name__)


def _check_type(owner: str, name: str, current: Any, value: Any) -> Any:
    """``value`` for a setting whose default is ``current``, of the same kind (an integer where
    an integer is expected, not "abc" or 2.5), lists turned into tuples; else ValueError."""
    if isinstance(current, tuple):
        if not isinstance(value, (list, tuple)) or len(value) != len(current):
            raise ValueError(f"{owner}.{name} must be a list of {len(current)} values, got {value!r}")
        return tuple(_check_type(owner, f"{name}[{i}]", c, v) for i, (c, v) in enumerate(zip(current, value)))
    if isinstance(current, bool) or isinstance(value, bool):
        ok = isinstance(current, bool) and isinstance(value, bool)
    elif isinstance(current, int):
        ok = isinstance(value, int)
    elif isinstance(current, float):
        ok = isinstance(value, (int, float))
    elif isinstance(current, str):
        ok = isinstance(value, str)
    else:
        ok = True  # None or another kind: the settings class checks it
    if not ok:
        raise ValueError(f"{owner}.{name} must be {_type_name(current)}, got {value!r}")
    return value


def _replace(cls_instance: Any, overrides: dict) -> Any:
    """``dataclasses.replace`` with every value type-checked against the field's default; accepts
    lists for tuple fields and dicts for nested ones."""
    fields = {f.name: f for f in dataclasses.fields(cls_instance)}
    owner = type(cls_instance).__name__
    clean = {}
    for name, value in overrides.items():
        if name not in fields:
            raise ValueError(f"{owner} has no setting {name!r}; it has: {', '.join(fields)}")
        current = getattr(cls_instance, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            value = _replace(current, value)
        else:
            value = _check_type(owner, name, current, value)
        clean[name] = value
    return dataclasses.replace(cls_instance, **clean)


def parse_overrides(text: str | dict | None) -> dict:
    """Overrides given as a JSON object string (Luigi parameter) or a dict."""
    if not text:
        return {}
    if isinstance(text, dict):
        return dict(text)
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"not valid JSON ({exc}): {text!r}") from None
    if not isinstance(value, dict):
        raise ValueError(f"settings overrides must be a JSON object, got {text!r}")
    return value


@dataclasses.dataclass(frozen=True)
class BuildSettings:
    """Everything a dataset build depends on. Paths are not part of any hash."""

    source: str = "procedural"
    models_per_category: int = 16  # 0 = every model of the source
    views: int = 4
    variants: int = 2
    image_size: int = 256  # render size; sketches are written at out_size
    out_size: int = 128
    seed: int = 0
    prepare_overrides: str = ""  # JSON objects of further per-stage settings
    render_overrides: str = ""
    augment_overrides: str = ""
    shard_overrides: str = ""
    work_dir: Path = DEFAULT_WORK_DIR
    dataset_dir: Path = DEFAULT_DATASET_DIR
    batch_size: int = 16  # models per Luigi batch task; changes scheduling only, never outputs

    # ---- per-stage settings
    @property
    def limit(self) -> int | None:
        return self.models_per_category if self.models_per_category > 0 else None

    def prepare_settings(self):
        from pipeline.prepare.settings import PrepareSettings

        return _replace(PrepareSettings(seed=self.seed), parse_overrides(self.prepare_overrides))

    def render_settings(self):
        from render.settings import RenderSettings

        return _replace(RenderSettings(views=self.views, image_size=self.image_size),
                        parse_overrides(self.render_overrides))

    def augment_settings(self):
        from augment.settings import AugmentSettings

        return _replace(AugmentSettings(variants=self.variants, out_size=self.out_size),
                        parse_overrides(self.augment_overrides))

    def shard_settings(self) -> ShardSettings:
        return _replace(ShardSettings(), parse_overrides(self.shard_overrides))

    # ---- source
    @property
    def is_procedural(self) -> bool:
        return self.source == "procedural"

    @property
    def source_root(self) -> Path | None:
        return None if self.is_procedural else Path(self.source).resolve()

    def source_id(self) -> str:
        """How the source is named in hashes and the manifest."""
        return "procedural" if self.is_procedural else str(self.source_root)

    # ---- keys and folders
    def source_key(self) -> str:
        if self.is_procedural:
            from pipeline.sources.layouts import procedural_source_dir

            return procedural_source_dir(Path("."), self.seed).name
        return stage_key("source", {"source": self.source_id(), "seed": self.seed})

    def prepare_key(self) -> str:
        return stage_key("prepare", self.prepare_settings(), self.source_key())

    def render_key(self) -> str:
        return stage_key("render", {"render": settings_dict(self.render_settings()), "seed": self.seed},
                         self.prepare_key())

    def augment_key(self) -> str:
        return stage_key("augment", {"augment": settings_dict(self.augment_settings()), "seed": self.seed},
                         self.render_key())

    def shards_key(self) -> str:
        return stage_key("shards", {"shards": settings_dict(self.shard_settings()), "seed": self.seed},
                         self.augment_key())

    def stage_dir(self, stage: str) -> Path:
        key = {"source": self.source_key, "prepare": self.prepare_key, "render": self.render_key,
               "augment": self.augment_key, "shards": self.shards_key}[stage]()
        return Path(self.work_dir) / key

    # ---- what the manifest records
    def manifest_settings(self) -> dict:
        """All settings a category's shards depend on, with no paths of this machine."""
        return {
            "source": "procedural" if self.is_procedural else Path(self.source).name,
            "models_per_category": self.models_per_category,
            "seed": self.seed,
            "prepare": settings_dict(self.prepare_settings()),
            "render": settings_dict(self.render_settings()),
            "augment": settings_dict(self.augment_settings()),
            "shards": settings_dict(self.shard_settings()),
            "stage_keys": {s: self.stage_dir(s).name for s in ("source", "prepare", "render", "augment", "shards")},
        }

    def category_settings_hash(self) -> str:
        return settings_hash(self.manifest_settings())

    def portable_path(self, path: str | Path | None) -> str | None:
        """``path`` relative to the work folder or the source root, so manifests and meta.json
        are the same wherever the build ran; other paths are kept as they are."""
        if path is None:
            return None
        p = Path(os.path.abspath(path))
        roots = [Path(os.path.abspath(self.work_dir))]
        if self.source_root is not None:
            roots.append(self.source_root)
        for root in roots:
            try:
                return p.relative_to(root).as_posix()
            except ValueError:
                continue
        return str(path)
