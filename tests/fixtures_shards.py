"""A tiny but valid shard set in the dataset's shard format, for trainer tests and benches.

Each sample is an axis-aligned box of random proportions (normalized so its farthest vertex is at
radius 1), its surface points + normals, and line sketches of its 12 edges from a few views —
learnable (the sketch determines the proportions) yet cheap to make without Blender.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np
import webdataset as wds

from pipeline.core.atomic import write_json
from pipeline.core.schema import (
    CAMERAS_MEMBER,
    MANIFEST,
    META_MEMBER,
    POINTS_MEMBER,
    STROKES_MEMBER,
    SampleMeta,
    sample_key,
    shard_name,
    sketch_name,
)
from pipeline.core.seeding import rng_for

_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(_CORNERS[a] != _CORNERS[b]) == 1]


def box_points(half: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n area-uniform samples (xyz + outward unit normal) on the box [-half, half]."""
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]]).repeat(2)
    face = rng.choice(6, size=n, p=areas / areas.sum())
    axis, sign = face // 2, np.where(face % 2 == 0, -1.0, 1.0)
    xyz = rng.uniform(-1, 1, size=(n, 3)) * half
    xyz[np.arange(n), axis] = sign * half[axis]
    normals = np.zeros((n, 3))
    normals[np.arange(n), axis] = sign
    return np.concatenate([xyz, normals], 1).astype(np.float32)


def camera(azimuth_deg: float, elevation_deg: float, size: int, distance: float = 3.0) -> np.ndarray:
    """3x4 pinhole projection (OpenCV convention) of a camera looking at the origin."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    eye = distance * np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    rot = np.stack([right, down, fwd])
    f = size * 1.2
    k = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]])
    return k @ np.concatenate([rot, -rot @ eye[:, None]], 1)


def box_sketch(half: np.ndarray, proj: np.ndarray, size: int, width: int) -> np.ndarray:
    """Black-on-white 8-bit drawing of the box's edges."""
    img = np.full((size, size), 255, np.uint8)
    pts = np.concatenate([_CORNERS * half, np.ones((8, 1))], 1) @ proj.T
    uv = pts[:, :2] / pts[:, 2:]
    for a, b in _EDGES:
        cv2.line(img, tuple(int(round(c)) for c in uv[a]), tuple(int(round(c)) for c in uv[b]), 0, width, cv2.LINE_AA)
    return img


def _png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


def write_fixture_shards(
    root: Path,
    category: str = "knife",
    counts: dict[str, int] | None = None,
    views: int = 2,
    variants: int = 2,
    size: int = 64,
    n_points: int = 8192,
    per_shard: int = 4,
    seed: int = 0,
) -> Path:
    """Write <root>/<category>/<split>-NNNNN.tar + <root>/manifest.json; returns root."""
    counts = counts or {"train": 8, "val": 2, "test": 2}
    root = Path(root)
    manifest: dict = {"categories": {category: {}}}
    index = 0
    for split, n in counts.items():
        shards = []
        for start in range(0, n, per_shard):
            name = shard_name(split, start // per_shard)
            path = root / category / name
            path.parent.mkdir(parents=True, exist_ok=True)
            count = min(per_shard, n - start)
            with open(path, "wb") as f, wds.TarWriter(f, mtime=0) as sink:
                for _ in range(count):
                    sink.write(_sample(category, split, index, views, variants, size, n_points, seed))
                    index += 1
            shards.append({"path": f"{category}/{name}", "samples": count})
        manifest["categories"][category][split] = shards
    write_json(root / MANIFEST, manifest)
    return root


def _sample(
    category: str, split: str, index: int, views: int, variants: int, size: int, n_points: int, seed: int
) -> dict:
    model_id = f"{index:05d}"
    rng = rng_for(seed, "fixture", category, model_id, 0, 0)
    half = rng.uniform(0.2, 1.0, size=3)
    half /= np.linalg.norm(half)  # farthest vertex at radius 1, as the prepare stage normalizes
    buf = io.BytesIO()
    np.save(buf, box_points(half, n_points, rng))
    key = sample_key(category, model_id)
    sample = {"__key__": key, POINTS_MEMBER: buf.getvalue()}
    cams = []
    for v in range(views):
        az, el = 30.0 + 360.0 * v / views, 20.0
        proj = camera(az, el, size)
        cams.append({"azimuth_deg": az, "elevation_deg": el, "projection": proj.tolist()})
        for w in range(variants):
            sample[sketch_name(v, w)] = _png(box_sketch(half, proj, size, 1 + w))
    sample[CAMERAS_MEMBER] = json.dumps({"image_size": size, "views": cams}).encode()
    sample[STROKES_MEMBER] = json.dumps({"out_size": size, "views": []}).encode()
    # a box has no part labels: every part-dependent field is None, as for an unlabelled source
    meta = SampleMeta(
        key=key,
        category=category,
        model_id=model_id,
        source=None,
        source_sha256=None,
        normalization={"center": [0.0, 0.0, 0.0], "scale": 1.0},
        part_labels=None,
        present_parts=None,
        point_part_names=None,
        bodies=1,
        seed=seed,
        settings_hash="fixture",
        split=split,
        sketches=[sketch_name(v, w) for v in range(views) for w in range(variants)],
        points=n_points,
    )
    sample[META_MEMBER] = json.dumps(meta.to_json()).encode()
    return sample


def tiny_run(dataset: Path, out: Path, **fields) -> dict:
    """The fields of a training run on these shards that takes about a second a step on one core
    (knife, sphere24, 32 px, width-8 encoder, no collision term); ``fields`` override them."""
    from train.losses.weights import LossWeights

    base = dict(
        dataset=str(dataset),
        category="knife",
        template="sphere24",
        out=str(out),
        steps=2,
        batch_size=2,
        workers=0,
        n_points=300,
        image_size=32,
        max_views=1,
        encoder_width=8,
        weights=LossWeights(collision=0.0),
    )
    return {**base, **fields}
