"""Part names made comparable across models, and the user's mapping file.

Exporters decorate names ("Leg.003", "chair_leg_L", "Seat 2"): a name is lower-cased, runs of
non-alphanumerics become "_", and the side / instance suffixes the built-in categories drop
(``pipeline.core.schema.part_family``) go too, so mirror parts share a label. A mapping file
then renames what still differs, a JSON or YAML mapping from a name (or a glob pattern, matched
after the normalization above) to a common name; ``null`` or "" drops the part::

    {"seat_cushion": "seat", "leg_*": "leg", "seg1": "back", "screw*": null}
"""

from __future__ import annotations

import fnmatch
import re
from pathlib import Path

import yaml

from pipeline.core.schema import part_family


class PartMapError(ValueError):
    """The mapping file is not a name -> name mapping."""


def normalize_name(raw: str) -> str:
    """``"Leg.003"`` → ``leg``, ``"Chair Back_L"`` → ``chair_back``, ``"wing_left"`` → ``wing``."""
    s = re.sub(r"[^0-9a-z]+", "_", str(raw).strip().lower()).strip("_")
    s = re.sub(r"(_\d+)+$", "", s)  # Blender/Maya instance counters: leg_001
    return part_family(s).strip("_") or s or "part"


def read_part_map(path: str | Path) -> dict[str, str | None]:
    """The mapping file's {pattern: name or None}, keys normalized like part names."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8-sig"))
    except (OSError, yaml.YAMLError) as exc:
        raise PartMapError(f"{path}: cannot read the part map: {exc}") from None
    if not isinstance(data, dict):
        raise PartMapError(f"{path}: the part map must be a mapping of names to names")
    out: dict[str, str | None] = {}
    for k, v in data.items():
        if v is not None and not isinstance(v, (str, int)):
            raise PartMapError(f"{path}: {k!r} maps to {v!r}, not a name")
        # patterns and ids (seg3) are kept as written; other names normalized like part names
        raw = str(k).strip().lower()
        key = raw if any(ch in raw for ch in "*?[") or re.fullmatch(r"seg\d+", raw) else normalize_name(raw)
        out[key] = normalize_name(str(v)) if v not in (None, "") else None
    return out


def map_name(raw: str, part_map: dict[str, str | None] | None = None, normalize: bool = True) -> str | None:
    """The common name of a raw part name (None: dropped by the map). ``normalize=False`` for
    names that are ids (a points file's ``seg3``), whose digits must stay."""
    name = normalize_name(raw) if normalize else str(raw)
    if not part_map:
        return name
    if name in part_map:
        return part_map[name]
    for pattern, target in part_map.items():
        if fnmatch.fnmatchcase(name, pattern):
            return target
    return name
