"""Names of the part fields a shard sample carries, defined once for the writer and the trainer.

A model's parts come from the procedural generator's sidecar (labels such as ``wing_l``,
``engine0_r``). Both the shard writer and the trainer speak of part *families*: the label without
its side and instance suffixes, which is also what template patches are labelled with.

- ``meta.json[PRESENT_PARTS]``: sorted families the model has, or absent when the source has no
  part labels (then every template part counts as present).
- ``POINT_PARTS_MEMBER``: uint8 ``(N,)`` per surface point of ``points.npy``, an index into
  ``meta.json[POINT_PART_NAMES]`` (the same sorted families); absent without part labels.
"""

from __future__ import annotations

import re

PRESENT_PARTS = "present_parts"
POINT_PART_NAMES = "point_part_names"
POINT_PARTS_MEMBER = "point_parts.npy"


def part_family(label: str) -> str:
    """``wing_l`` → ``wing``, ``engine0_r`` → ``engine``, ``foot_front_l`` → ``foot_front``."""
    return re.sub(r"\d+$", "", re.sub(r"_(l|r|left|right)$", "", label))


def present_parts(labels: list[str] | None) -> list[str] | None:
    """Sorted distinct families of a model's part labels (None when it has none)."""
    return sorted({part_family(x) for x in labels}) if labels else None
