"""Stage settings and their hashes.

Each stage's output folder is keyed by ``stage_key(settings, upstream_key)`` so changing one
setting re-runs exactly the stages it affects (and everything downstream of them).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any


def settings_dict(settings: Any) -> dict:
    if dataclasses.is_dataclass(settings):
        return dataclasses.asdict(settings)
    return dict(settings)


def settings_hash(settings: Any, upstream: str = "", length: int = 10) -> str:
    """Short stable hash of a settings object (dataclass or dict) chained with upstream's hash."""
    payload = json.dumps({"s": settings_dict(settings), "up": upstream}, sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:length]


# What each stage's code writes, numbered. Bump a stage's number with any change to its code that
# changes its outputs: its folder and every downstream one get new keys, so a work folder from
# older code is never taken for current outputs (settings alone cannot tell them apart).
# prepare 5: binary PLY sources, recorded failed by version 4, build. render 3, augment 4: PNGs
# written with zlib's run-length strategy, strokes.json without white space (same pixels, points).
# render 4: the embree backend draws only the edge_types asked for (it drew all three before).
STAGE_VERSIONS = {"source": 3, "prepare": 5, "render": 4, "augment": 4, "shards": 2, "fit": 1}


def stage_key(stage: str, settings: Any, upstream: str = "") -> str:
    """Folder name for a stage's outputs: ``<stage>-<hash>`` of its settings, its code version
    (``STAGE_VERSIONS``) and the upstream key."""
    return f"{stage}-{settings_hash(settings, f'{upstream}|{stage} v{STAGE_VERSIONS[stage]}')}"
