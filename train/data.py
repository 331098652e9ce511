"""Streams dataset shards into training / evaluation batches.

Shards: ``<dataset>/<category>/<split>-NNNNN.tar`` (WebDataset), members ``points.npy``,
``sketch_<view>_<variant>.png``, ``meta.json``, ``point_parts.npy``, ``fit_params.npy`` from a
``--fit-patches`` build (+ strokes/cameras, unused here); every name comes from
:mod:`pipeline.core.schema`.

Training streams never end: each epoch re-shuffles the shard order with a seeded generator and
each (rank, loader worker) slot reads a disjoint part (whole shards when there are enough, else
every n-th sample), so every rank can run exactly the same number of steps.
"""

from __future__ import annotations

import dataclasses
import io
import json
import warnings
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from pipeline.core.errors import ModelError
from pipeline.core.schema import (
    FIT_PARAMS_MEMBER,
    META_MEMBER,
    POINT_PARTS_MEMBER,
    POINTS_MEMBER,
    SPLITS,
    shard_glob,
    sketch_view_variant,
)
from pipeline.core.seeding import rng_for
from pipeline.core.settings_io import setting
from train.augmentation import Jitter, jitter_image
from train.errors import UsageError
from train.shard_reader import SampleSpan, index_shard, read_samples
from train.sketch_input import Framing, measure_framing
from train.templates import FreePoint, Template


@dataclasses.dataclass(frozen=True)
class DataSettings:
    max_views: int = setting(4, "training draws 1..max_views views per sample")
    # training also returns "pair_images" (1, S, S): another drawing of the same model (another
    # view or pencil variant than the first one drawn), for the contrastive term
    pair: bool = setting(False, "also return another drawing of the same model (the contrastive term)")
    eval_views: int = setting(1, "evaluation uses views 0..eval_views-1")
    eval_variant: int = setting(
        0,
        "evaluation draws this pencil variant of each view (0: the dark, thin line drawing; 1: the light, broad, shaded one)",
    )
    n_points: int = setting(7000, "target surface points per shape")
    image_size: int = setting(128, "sketches are resized to this square size")
    shuffle_buffer: int = setting(64, "samples held for shuffling the stream")
    jitter: Jitter = Jitter()

    def __post_init__(self) -> None:
        for name in ("max_views", "eval_views", "n_points", "image_size", "shuffle_buffer"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"DataSettings.{name} must be an integer >= 1, got {value!r}")
        if not (isinstance(self.eval_variant, int) and self.eval_variant >= 0):
            raise ValueError(f"DataSettings.eval_variant must be an integer >= 0, got {self.eval_variant!r}")


class NoShards(UsageError, ModelError):
    """The dataset folder, its category folder or the split's shards are not there (a
    ModelError too, naming the folder, for the callers that caught that before)."""

    def __init__(self, path: str | Path, reason: str):
        ModelError.__init__(self, path, reason)


ALL_SPLITS = "all"  # every split the dataset has, as one set (evaluate --split all)


def shard_urls(dataset: str | Path, category: str, split: str) -> list[str]:
    """The split's shard files, sorted (for ``ALL_SPLITS``: those of every split that has shards,
    in SPLITS order); raises NoShards (a UsageError and a ModelError) naming what is missing: the
    dataset folder, the category in it, or the split's shards."""
    return [u for urls in _shards_by_split(dataset, category, split).values() for u in urls]


def splits_with_shards(dataset: str | Path, category: str, split: str) -> list[str]:
    """``[split]``, or for ``ALL_SPLITS`` every split that has shards, in SPLITS order; raises
    NoShards naming what is missing when none has (or when ``split`` has none)."""
    return list(_shards_by_split(dataset, category, split))


def _shards_by_split(dataset: str | Path, category: str, split: str) -> dict[str, list[str]]:
    """{split name: its shard files} for ``split``, or for ``ALL_SPLITS`` each split that has
    shards (one glob a split); NoShards as ``shard_urls`` says."""
    if split != ALL_SPLITS:
        return {split: _one_split(dataset, category, split)}
    found, missing = {}, None
    for name in SPLITS:
        try:
            found[name] = _one_split(dataset, category, name)
        except NoShards as exc:
            missing = exc
    if not found:
        raise missing
    return found


def _one_split(dataset: str | Path, category: str, split: str) -> list[str]:
    root = Path(dataset)
    if not root.is_dir():
        raise NoShards(root, "the dataset folder does not exist" if not root.exists() else "not a folder")
    folder = root / category
    urls = sorted(str(p) for p in folder.glob(shard_glob(split)))
    if not urls and not folder.is_dir():
        there = sorted(p.name for p in root.iterdir() if p.is_dir())
        raise NoShards(
            folder,
            f"no {shard_glob(split)} shards: the dataset has no category {category!r} "
            f"(its categories: {', '.join(there) or 'none'})",
        )
    if not urls:
        raise NoShards(folder, f"no {shard_glob(split)} shards")
    return urls


def shard_framing(dataset: str | Path, category: str, image_size: int, limit: int = 256) -> Framing:
    """How the category's training sketches fill their frame (``train.sketch_input.Framing``),
    measured on its first ``limit`` train images: what a person's drawing is re-framed to."""
    images: list[np.ndarray] = []
    for url in shard_urls(dataset, category, "train"):
        for raw in _shard_samples(url):
            images += [read_png(raw[n], image_size) for names in sketch_table(raw).values() for n in names]
            if len(images) >= limit:
                return measure_framing(images[:limit])
    return measure_framing(images)


@dataclasses.dataclass(frozen=True)
class ParamMirror:
    """A template's parameter vector mirrored across x = 0: ``q = p[perm] * sign`` is the shape of
    ``p`` mirrored (each point takes its partner's mirrored place), so a flipped
    drawing's fitted parameters can follow the flipped target points."""

    perm: np.ndarray  # (D,) int64
    sign: np.ndarray  # (D,) float32: -1 on x coordinates and on junctions whose mirrored curve runs the other way

    def __call__(self, params: np.ndarray) -> np.ndarray:
        return (params[self.perm] * self.sign).astype(np.float32)


def param_mirror(template: Template, tol: float = 1e-4) -> ParamMirror | None:
    """The mirror of ``template``'s parameters across x = 0 (the plane the loader flips targets
    across), or None when the template declares no symmetry about that plane (within ``tol``),
    leaves a point without a partner, or its curves do not mirror onto curves (then a flipped
    sample has no fit target). Checked on a perturbed shape: the mirrored parameters must give
    the mirrored points."""
    sym = template.symmetry
    if sym is None or abs(sym.plane_x) > tol:
        return None
    partner = {k: k for k in sym.self_points}
    for i, j in sym.pairs:
        partner[i], partner[j] = j, i
    if len(partner) != template.num_points:
        return None
    offsets = np.cumsum([0] + [3 if isinstance(p, FreePoint) else 1 for p in template.points])
    perm = np.zeros(template.num_params, np.int64)
    sign = np.ones(template.num_params, np.float32)
    for i, p in enumerate(template.points):
        j = partner[i]
        if isinstance(p, FreePoint) != isinstance(template.points[j], FreePoint):
            return None
        if isinstance(p, FreePoint):
            perm[offsets[j] : offsets[j] + 3] = np.arange(offsets[i], offsets[i] + 3)
            sign[offsets[j]] = -1.0
        else:  # the partner sits on the mirrored curve at t, or at 1 - t when it runs the other way
            orient = _curve_image(template, partner, p.curve, template.points[j].curve)
            if orient is None:
                return None
            perm[offsets[j]], sign[offsets[j]] = offsets[i], orient  # logit(1 - t) = -logit(t)
    mirror = ParamMirror(perm, sign)
    gen = torch.Generator().manual_seed(0)
    p0 = template.initial_params(torch.float64)
    p1 = p0 + 0.05 * torch.randn(p0.shape, generator=gen, dtype=torch.float64)
    with torch.no_grad():
        a = template.points_from_params(p1[None])[0].numpy()
        b = template.points_from_params(torch.from_numpy(mirror(p1.numpy()).astype(np.float64))[None])[0].numpy()
    expect = a * np.array([-1.0, 1.0, 1.0])
    order = np.array([partner[k] for k in range(template.num_points)])
    shown = np.empty_like(b)
    shown[order] = expect
    return mirror if np.abs(b - shown).max() <= 1e-3 else None


def _curve_image(template: Template, partner: dict[int, int], ci: int, cj: int) -> int | None:
    """+1 when curve ``ci`` mirrors onto curve ``cj`` running the same way, -1 the other way,
    None when it does not mirror onto it."""
    a, b = template.curves[ci], template.curves[cj]
    if a.is_sub != b.is_sub:
        return None
    if not a.is_sub:
        image = [partner[k] for k in a.points]
        return 1 if image == list(b.points) else -1 if image[::-1] == list(b.points) else None
    ends = (partner[a.start], partner[a.end])
    if _curve_image(template, partner, a.parent, b.parent) is None:
        return None
    return 1 if ends == (b.start, b.end) else -1 if ends == (b.end, b.start) else None


def to_network(img: np.ndarray) -> np.ndarray:
    """8-bit black-on-white -> float32 with ink = 1, paper = 0."""
    return (1.0 - img.astype(np.float32) / 255.0)[None]


def read_png(data: bytes, size: int) -> np.ndarray:
    if not data:  # OpenCV meets an empty buffer with an assertion, not a None
        raise ValueError("empty file")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError("undecodable PNG")
    if img.shape != (size, size):
        img = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return img


def sketch_table(raw: dict) -> dict[int, list[str]]:
    """view index -> sorted member names of its variants."""
    table: dict[int, list[str]] = {}
    for name in raw:
        vv = sketch_view_variant(name)
        if vv is not None:
            table.setdefault(vv[0], []).append(name)
    return {v: sorted(names) for v, names in sorted(table.items())}


def variant_member(names: list[str], variant: int, key: str) -> str:
    """The member of one view's sketches drawn as pencil ``variant``."""
    for name in names:
        if sketch_view_variant(name)[1] == variant:
            return name
    raise ModelError(key, f"has no pencil variant {variant} (its views have {len(names)}: 0..{len(names) - 1})")


def eval_point_indices(key: str, stored: int, n_points: int) -> np.ndarray:
    """Which ``n_points`` of a sample's ``stored`` surface points evaluation takes as its target:
    seeded by the sample's key alone, so every evaluation of a shape measures against the same points."""
    return rng_for(0, "eval-points", key).choice(stored, size=n_points, replace=stored < n_points)


def eval_members(table: dict[int, list[str]], views: int, variant: int, key: str) -> list[str]:
    """The drawings an evaluation reads of one sample: pencil ``variant`` of its first ``views``
    views, in the table's order (``evaluate --views``, the figures)."""
    return [variant_member(table[v], variant, key) for v in list(table)[:views]]


def decode_sample(
    raw: dict,
    settings: DataSettings,
    rng: np.random.Generator,
    train: bool,
    flip_ok: bool,
    mirror: ParamMirror | None = None,
) -> dict:
    """Raw shard sample -> {"images" (V,1,S,S), "view_mask" (V,), "points" (n,6), "point_parts" (n,),
    "key", "meta"}, plus "fit_params" (D,) and "fit_valid" when the sample has a fit: a flipped
    sample's fit is mirrored by ``mirror``, or marked invalid without one."""
    key = raw.get("__key__", "?")
    try:
        points = np.load(io.BytesIO(raw[POINTS_MEMBER]), allow_pickle=False).astype(np.float32)
        meta = json.loads(raw[META_MEMBER]) if META_MEMBER in raw else {}
        part_ids = _point_parts(raw, len(points))
        table = sketch_table(raw)
        fit = _fit_params(raw)
    except Exception as exc:  # noqa: BLE001 - reported with the sample's name
        raise ModelError(key, f"unreadable sample: {exc}") from exc
    if points.ndim != 2 or points.shape[1] != 6 or not table:
        raise ModelError(key, f"needs {POINTS_MEMBER} (N,6) and at least one sketch")
    views = list(table)
    if train:
        n = int(rng.integers(1, min(settings.max_views, len(views)) + 1))
        chosen = sorted(rng.choice(views, size=n, replace=False).tolist())
        names = [table[v][int(rng.integers(len(table[v])))] for v in chosen]
        flip = bool(flip_ok and settings.jitter.flip and rng.random() < 0.5)
        idx = rng.choice(len(points), size=settings.n_points, replace=len(points) < settings.n_points)
        if settings.pair:
            others = [m for v in views for m in table[v] if m != names[0]] or [names[0]]
            pair_name = others[int(rng.integers(len(others)))]
    else:
        names = eval_members(table, settings.eval_views, settings.eval_variant, key)
        flip = False
        idx = eval_point_indices(key, len(points), settings.n_points)
    width = settings.max_views if train else settings.eval_views
    images = np.zeros((width, 1, settings.image_size, settings.image_size), np.float32)
    mask = np.zeros(width, bool)
    for i, name in enumerate(names):
        img = read_png(raw[name], settings.image_size)
        if train:
            img = jitter_image(img, rng, settings.jitter, flip)
        images[i] = to_network(img)
        mask[i] = True
    extra = {}
    if train and settings.pair:  # mirrored like the sample: it shows the same (mirrored) shape
        pair = jitter_image(read_png(raw[pair_name], settings.image_size), rng, settings.jitter, flip)
        extra["pair_images"] = to_network(pair)
    pts, part_ids = points[np.sort(idx)], part_ids[np.sort(idx)]
    if flip:  # a mirrored drawing shows the mirrored shape: mirror the target across x = 0
        pts = pts * np.array([-1, 1, 1, -1, 1, 1], np.float32)  # part families are side-free
    if fit is not None:
        usable = not flip or (mirror is not None and len(mirror.perm) == len(fit))
        extra["fit_params"] = mirror(fit) if flip and usable else fit
        extra["fit_valid"] = usable
    return {
        "images": images,
        "view_mask": mask,
        "points": pts,
        "point_parts": part_ids,
        "key": key,
        "meta": meta,
        **extra,
    }


def _point_parts(raw: dict, n: int) -> np.ndarray:
    """Per-point part family index (into meta's point_part_names), -1 where the sample has none."""
    if POINT_PARTS_MEMBER not in raw:
        return np.full(n, -1, np.int64)
    ids = np.load(io.BytesIO(raw[POINT_PARTS_MEMBER]), allow_pickle=False).astype(np.int64)
    if ids.shape != (n,):
        raise ValueError(f"{POINT_PARTS_MEMBER} has shape {ids.shape}, {POINTS_MEMBER} has {n} points")
    return ids


def _fit_params(raw: dict) -> np.ndarray | None:
    """The sample's fitted template parameters (D,), None when the build did not fit patches."""
    if FIT_PARAMS_MEMBER not in raw:
        return None
    params = np.load(io.BytesIO(raw[FIT_PARAMS_MEMBER]), allow_pickle=False).astype(np.float32)
    if params.ndim != 1 or not np.isfinite(params).all():
        raise ValueError(f"{FIT_PARAMS_MEMBER} must be a finite vector, got shape {params.shape}")
    return params


def _collate_fit(samples: list[dict]) -> dict[str, torch.Tensor]:
    """The batch's fit targets, when some sample has one: "fit_params" (B, D) and "fit_valid" (B,)
    (zeros and False for the samples without); nothing when none has."""
    fits = [s["fit_params"] for s in samples if "fit_params" in s]
    if not fits:
        return {}
    if len({len(f) for f in fits}) > 1:
        keys = ", ".join(s["key"] for s in samples)
        raise UsageError(f"samples {keys}: fitted parameter vectors of different lengths in one batch")
    zero = np.zeros_like(fits[0])
    return {
        "fit_params": torch.from_numpy(np.stack([s.get("fit_params", zero) for s in samples])),
        "fit_valid": torch.tensor([bool(s.get("fit_valid", False)) for s in samples]),
    }


def collate(samples: list[dict]) -> dict[str, Any]:
    return {
        "images": torch.from_numpy(np.stack([s["images"] for s in samples])),
        "view_mask": torch.from_numpy(np.stack([s["view_mask"] for s in samples])),
        "points": torch.from_numpy(np.stack([s["points"] for s in samples])),
        "point_parts": torch.from_numpy(np.stack([s["point_parts"] for s in samples])),
        "key": [s["key"] for s in samples],
        "meta": [s["meta"] for s in samples],
        **(
            {"pair_images": torch.from_numpy(np.stack([s["pair_images"] for s in samples]))}
            if "pair_images" in samples[0]
            else {}
        ),
        **_collate_fit(samples),
    }


class ShardStream(IterableDataset):
    """Decoded samples of a shard list for one rank (and, inside, one loader worker)."""

    def __init__(
        self,
        urls: list[str],
        settings: DataSettings,
        seed: int,
        train: bool,
        rank: int = 0,
        world: int = 1,
        flip_ok: bool = False,
        mirror: ParamMirror | None = None,
    ):
        super().__init__()
        self.urls, self.settings, self.seed, self.train = list(urls), settings, seed, train
        self.rank, self.world, self.flip_ok, self.mirror = rank, world, flip_ok, mirror
        self._spans: dict[str, list[SampleSpan]] = {}  # per worker process: filled on its first epoch

    def _slot(self) -> tuple[int, int]:
        info = get_worker_info()
        workers, worker = (info.num_workers, info.id) if info else (1, 0)
        return self.rank * workers + worker, self.world * workers

    def _raw(self, urls: list[str], slot: int, n_slots: int) -> Iterator[dict]:
        """This slot's raw samples of one pass over urls: its own shards, or, with fewer shards
        than slots, every n_slots-th sample of all of them (only those are read)."""
        if len(urls) >= n_slots:
            mine, every = urls[slot::n_slots], 1
        else:
            mine, every = urls, n_slots
        i = 0
        for url in mine:  # one shard at a time, so a read error can name its shard
            spans = self._index(url)
            yield from _shard_samples(url, [s for k, s in enumerate(spans, i) if k % every == slot % every])
            i += len(spans)

    def _index(self, url: str) -> list[SampleSpan]:
        """The shard's samples (kept: later epochs read them without walking the tar again)."""
        if url not in self._spans:
            self._spans[url] = _shard_index(url)
        return self._spans[url]

    def __iter__(self) -> Iterator[dict]:
        slot, n_slots = self._slot()
        if not self.train:
            rng = rng_for(self.seed, "eval-data", slot)
            for raw in self._raw(self.urls, slot, n_slots):
                yield decode_sample(raw, self.settings, rng, False, False)
            return
        epoch = 0
        while True:
            produced = 0
            # Shard order is the same for all slots (keyed by epoch only) so their parts stay disjoint.
            order = rng_for(self.seed, "shard-order", epoch).permutation(len(self.urls))
            rng = rng_for(self.seed, "train-data", slot, epoch)
            buffer: list[dict] = []
            for raw in self._raw([self.urls[i] for i in order], slot, n_slots):
                produced += 1
                buffer.append(raw)
                if len(buffer) >= self.settings.shuffle_buffer:
                    yield from self._decoded(buffer.pop(int(rng.integers(len(buffer)))), rng)
            while buffer:
                yield from self._decoded(buffer.pop(int(rng.integers(len(buffer)))), rng)
            if produced == 0:  # an endless loop over nothing would hang the trainer
                # a UsageError: unlike ModelError it survives the trip back from a loader worker
                raise UsageError(
                    f"{Path(self.urls[0]).parent}: data slot {slot}/{n_slots} has no samples "
                    f"({len(self.urls)} shards); use fewer --workers or ranks"
                )
            epoch += 1

    def _decoded(self, raw: dict, rng: np.random.Generator) -> Iterator[dict]:
        """One decoded training sample, or nothing (with a warning) when the sample is bad."""
        try:
            yield decode_sample(raw, self.settings, rng, True, self.flip_ok, self.mirror)
        except ModelError as exc:
            warnings.warn(f"skipping bad sample {exc}")


class ShardError(UsageError):
    """A shard that cannot be read to its end (truncated, corrupt)."""


def _shard_samples(url: str, spans: list[SampleSpan] | None = None) -> Iterator[dict]:
    """The raw samples of one shard (those of ``spans`` from ``_shard_index``, else all); a
    truncated or corrupt shard raises ShardError naming it."""
    try:
        yield from read_samples(url, _shard_index(url) if spans is None else spans)
    except ShardError:
        raise
    except Exception as exc:  # noqa: BLE001 - tarfile, OSError: all mean "cannot read it"
        raise ShardError(_unreadable(url, exc)) from None


def _shard_index(url: str) -> list[SampleSpan]:
    """``index_shard``, a truncated or corrupt shard raising ShardError naming it."""
    try:
        return index_shard(url)
    except Exception as exc:  # noqa: BLE001 - tarfile, OSError: all mean "cannot read it"
        raise ShardError(_unreadable(url, exc)) from None


def _unreadable(url: str, exc: Exception) -> str:
    return f"{url}: unreadable shard ({type(exc).__name__}: {exc.args[0] if exc.args else 'no detail'})"


def make_loader(
    dataset: str | Path,
    category: str,
    split: str,
    settings: DataSettings,
    seed: int,
    batch_size: int,
    workers: int = 0,
    train: bool = True,
    rank: int = 0,
    world: int = 1,
    flip_ok: bool = False,
    mirror: ParamMirror | None = None,
    pin_memory: bool = False,
) -> DataLoader:
    """A DataLoader of collated batches; the training one is endless, the eval one a single pass.
    ``mirror`` (``param_mirror``) mirrors the fit targets of flipped samples. ``pin_memory``: batches
    in page-locked memory (a GPU run: the step's copies to the device then need not wait)."""
    stream = ShardStream(shard_urls(dataset, category, split), settings, seed, train, rank, world, flip_ok, mirror)
    return DataLoader(
        stream,
        batch_size=batch_size,
        num_workers=workers,
        collate_fn=collate,
        drop_last=train,
        persistent_workers=False,
        pin_memory=pin_memory,
    )
