"""Person-like variants of a training sketch and how far they move a trained network's prediction.

A variant is the same drawing as a person might hand it in: a transparent PNG, a photographed
grey page with a light gradient (JPEG), white on black, small and off-centre on a large canvas,
on a non-square canvas, at 64 × 64, or drawn with a thick marker. The criterion of issue 32:
the mean control-point distance between the prediction for a variant and for the clean sketch
is at most a quarter of the mean distance between the predictions for two different test models.

``measure`` reads each variant through ``predict``'s own input path (``load_sketches``:
normalization with the checkpoint's framing) and through the old path (grey + resize, nothing
else) for comparison. Used by tests/test_sketch_variants.py and bench/bench_sketch_variants.py.
"""

from __future__ import annotations

import itertools
import tarfile
from pathlib import Path

import cv2
import numpy as np
import torch

from pipeline.core.schema import shard_glob, sketch_name

VARIANTS = (
    "transparent PNG",
    "grey-paper JPEG",
    "inverted",
    "off-centre on a large canvas",
    "non-square canvas",
    "64x64",
    "thick marker",
)


def split_sketches(dataset: str | Path, category: str, count: int, view: int = 0) -> list[np.ndarray]:
    """The first ``count`` test models' sketches (``view``, pencil variant 0), uint8 black on white."""
    found = []
    member = "." + sketch_name(view, 0)
    for shard in sorted((Path(dataset) / category).glob(shard_glob("test"))):
        with tarfile.open(shard) as tar:
            for info in tar:
                if info.name.endswith(member):
                    data = np.frombuffer(tar.extractfile(info).read(), np.uint8)
                    found.append(cv2.imdecode(data, cv2.IMREAD_GRAYSCALE))
                    if len(found) == count:
                        return found
    return found


def _encode(img: np.ndarray, ext: str = ".png", params: tuple = ()) -> bytes:
    ok, buf = cv2.imencode(ext, img, list(params))
    assert ok
    return buf.tobytes()


def variants(g: np.ndarray) -> dict[str, tuple[str, bytes]]:
    """name -> (file suffix, file bytes) for an 8-bit black-on-white sketch ``g``."""
    h, w = g.shape
    rgba = np.zeros((h, w, 4), np.uint8)
    rgba[..., 3] = 255 - g  # black ink whose alpha is its darkness on transparent paper
    big = cv2.resize(g, (w * 4, h * 4), interpolation=cv2.INTER_CUBIC)
    yy, xx = np.mgrid[0 : h * 4, 0 : w * 4]
    paper = 0.5 + 0.3 * xx / (w * 4) + 0.1 * yy / (h * 4)  # a photo: grey paper, a light gradient
    photo = np.clip(big / 255.0 * paper * 255, 0, 255).astype(np.uint8)
    canvas = np.full((900, 1200), 255, np.uint8)  # the drawing at 2x, in the top-right corner
    canvas[40 : 40 + 2 * h, 800 : 800 + 2 * w] = cv2.resize(g, (2 * w, 2 * h), interpolation=cv2.INTER_CUBIC)
    wide = np.full((h, 3 * w), 255, np.uint8)
    wide[:, 10 : 10 + w] = g
    marker = cv2.erode(big, np.ones((9, 9), np.uint8))  # strokes ~2 px wide at the sketch's size
    return {
        "transparent PNG": (".png", _encode(rgba)),
        "grey-paper JPEG": (".jpg", _encode(photo, ".jpg", (cv2.IMWRITE_JPEG_QUALITY, 80))),
        "inverted": (".png", _encode(255 - g)),
        "off-centre on a large canvas": (".png", _encode(canvas)),
        "non-square canvas": (".png", _encode(wide)),
        "64x64": (".png", _encode(cv2.resize(g, (64, 64), interpolation=cv2.INTER_AREA))),
        "thick marker": (".png", _encode(marker)),
    }


def old_path(data: bytes, size: int) -> torch.Tensor:
    """How ``predict`` read a sketch before issue 32: grey, resized, nothing else. (1, 1, 1, S, S)."""
    img = cv2.resize(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE), (size, size))
    return torch.from_numpy(1.0 - img.astype(np.float32) / 255.0)[None, None, None]


def control_points(run, tensor: torch.Tensor, steady: bool = True) -> np.ndarray:
    """The predicted surface's control points ``(P, 16, 3)`` for one network input: as ``predict``
    computes them (``steady``), or the network's plain output (how predict read it before)."""
    from train.predict import predict_params

    with torch.no_grad():
        params = predict_params(run, tensor) if steady else run.model(tensor)
        return run.template.patches_from_params(params.double())[0].reshape(-1, 16, 3).numpy()


def point_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean Euclidean distance between corresponding control points."""
    return float(np.linalg.norm(a - b, axis=-1).mean())


def measure(run, sketches: list[np.ndarray], work: Path) -> dict:
    """For clean test sketches of different models (uint8, black on white): the mean
    control-point distance between the predictions of two different models (``between``),
    and per variant the mean distance between its prediction and its clean sketch's, read
    through ``predict``'s path (``after``) and through the old one (``before``)."""
    from train.predict import load_sketches

    size = run.settings.image_size
    work.mkdir(parents=True, exist_ok=True)

    def read(name: str, suffix: str, data: bytes) -> np.ndarray:
        path = work / f"{name}{suffix}"
        path.write_bytes(data)
        return control_points(run, load_sketches([path], size, run.framing).tensor)

    clean = [read(f"clean{i}", ".png", _encode(g)) for i, g in enumerate(sketches)]
    between = float(np.mean([point_distance(a, b) for a, b in itertools.combinations(clean, 2)]))
    after = {n: [] for n in VARIANTS}
    before = {n: [] for n in VARIANTS}
    for i, g in enumerate(sketches):
        old_clean = control_points(run, old_path(_encode(g), size), steady=False)
        for name, (suffix, data) in variants(g).items():
            after[name].append(point_distance(read(f"v{i}-{VARIANTS.index(name)}", suffix, data), clean[i]))
            before[name].append(point_distance(control_points(run, old_path(data, size), steady=False), old_clean))
    return {
        "models": len(sketches),
        "between": between,
        "after": {n: float(np.mean(v)) for n, v in after.items()},
        "before": {n: float(np.mean(v)) for n, v in before.items()},
    }


def table(m: dict) -> str:
    """The figures as a Markdown table: distance and its ratio to ``between`` per variant."""
    b = m["between"]
    lines = [
        f"between two different test models: {b:.4f} (mean control-point distance, {m['models']} models; "
        f"goal: each variant <= {b / 4:.4f}, a ratio <= 0.25)",
        "",
        "| variant | old path (grey + resize) | ratio | normalized (predict) | ratio |",
        "|---|---:|---:|---:|---:|",
    ]
    for n in VARIANTS:
        lines.append(
            f"| {n} | {m['before'][n]:.4f} | {m['before'][n] / b:.2f} | {m['after'][n]:.4f} | {m['after'][n] / b:.2f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------- the cheapest run that reads them

CATEGORY = "knife"  # the category whose network reads its sketches best (BENCHMARKS.md quality table)
# The knife recipe (contrast 1.0, cosine decay, width-32 encoder), shortened: 64² sketches, 2,000
# target points, 2,000 steps, the loader in the training process (one core).
CHEAP_RUN = dict(steps=2000, image_size=64, n_points=2000, workers=0, val_every=250, checkpoint_every=500)
CHEAP_MODELS = 200


def cheap_knife_run(work: Path, models: int = CHEAP_MODELS, **overrides) -> tuple[Path, Path]:
    """Build ``models`` procedural knives (4 views) and train the shortened knife recipe on them
    under ``work`` (both reused when already there); returns (best.pt, dataset folder)."""
    import dataclasses
    import subprocess
    import sys

    from train.fit import fit
    from train.recipes import recipe

    dataset, out = work / "dataset", work / "run"
    if not (dataset / CATEGORY / "category.json").exists():
        cmd = [sys.executable, "-m", "workflows.make_dataset", "--categories", CATEGORY]
        cmd += ["--models-per-category", str(models), "--views", "4", "--variants", "1", "--workers", "1"]
        cmd += ["--work-dir", str(work / "build"), "--dataset-dir", str(dataset)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    settings = dataclasses.replace(recipe(CATEGORY, str(dataset), str(out)), **{**CHEAP_RUN, **overrides})
    fit(settings, progress=False)
    return out / "best.pt", dataset
