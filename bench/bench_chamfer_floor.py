"""The L_Ch a perfect answer scores: the quality table's floor, set by how many points it samples.

L_Ch compares two finite samplings of surfaces, so even the target's own surface, sampled
afresh, lies about half a sample spacing from the evaluation's target points in each direction.
For each shape of a split this compares the points `train evaluate` uses as the target (the
same seeded choice of the stored surface samples) with as many *other* stored samples of the
same surface (a perfect answer sampled at random; the network's patches are sampled on a
midpoint grid, whose floor is a little lower), both directions summed as in L_Ch.

With an `evaluate` JSON of the same split it also says how much of the measurable error the
"−25 % vs blind" goal asks the network to remove: (blind − goal) / (blind − floor), and how much
the network removed: (blind − network) / (blind − floor).

Usage: OMP_NUM_THREADS=1 .venv/bin/python bench/bench_chamfer_floor.py --dataset DS --category CAT
       [--split test] [--points 4000] [--eval bench/results/eval_CAT.json] [--out bench/results/floor_CAT.json]
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
from pathlib import Path

import numpy as np
import torch

from pipeline.core.atomic import dumps_json, write_bytes
from pipeline.core.schema import POINTS_MEMBER
from pipeline.core.seeding import rng_for
from train.data import eval_point_indices
from train.losses.chamfer import chamfer_loss
from train.shard_reader import index_shard, read_samples


def surface_samples(dataset: str | Path, category: str, split: str) -> list[tuple[str, np.ndarray]]:
    """(key, stored surface points (M, 3)) of every shape of a split, in shard order."""
    out = []
    for shard in sorted(Path(dataset, category).glob(f"{split}-*.tar")):
        for sample in read_samples(shard, index_shard(shard)):
            pts = np.load(io.BytesIO(sample[POINTS_MEMBER]), allow_pickle=False)[:, :3].astype(np.float32)
            out.append((sample["__key__"], pts))
    if not out:
        raise FileNotFoundError(f"no {split} shards of {category!r} under {dataset}")
    return out


def floor_chamfer(key: str, points: np.ndarray, n_points: int) -> float:
    """L_Ch between the evaluation's ``n_points`` target points of shape ``key`` (`train.data`'s
    seeded choice) and ``n_points`` of the shape's other stored points."""
    m = len(points)
    if m < 2 * n_points:
        raise ValueError(f"{key}: {m} stored points, fewer than twice {n_points}")
    target = eval_point_indices(key, m, n_points)
    rest = np.setdiff1d(np.arange(m), target)
    answer = rng_for(0, "floor-points", key).choice(rest, size=n_points, replace=False)
    # the answer as one patch of equally weighted samples: L_Ch exactly as training computes it
    a = torch.from_numpy(points[np.sort(answer)])[None, None]
    t = torch.from_numpy(points[np.sort(target)])[None]
    return float(chamfer_loss(a, torch.ones(a.shape[:3]), t)[0])


def chamfer_floor(dataset: str, category: str, split: str = "test", n_points: int = 4000) -> dict:
    """The floor of every shape of a split, summarised."""
    floors = [floor_chamfer(key, pts, n_points) for key, pts in surface_samples(dataset, category, split)]
    return {
        "category": category,
        "split": split,
        "shapes": len(floors),
        "points": n_points,
        "floor_chamfer": statistics.fmean(floors),
        "floor_chamfer_median": statistics.median(floors),
    }


def goal_share(floor: float, blind: float, network: float, goal: float = 0.25) -> dict:
    """How much of the error above the floor the goal asks removed, and how much the network removed."""
    room = blind - floor
    return {
        "goal_share_of_room": goal * blind / room,
        "network_share_of_room": (blind - network) / room,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", default="data/dataset", help="dataset folder (default: the one `make dataset` builds)")
    p.add_argument("--category", default="knife")
    p.add_argument("--split", default="test")
    p.add_argument("--points", type=int, default=4000, help="points a side, as `evaluate --points`")
    p.add_argument("--eval", default=None, help="an evaluate JSON of the same split and points: adds the shares")
    p.add_argument("--out", default=None)
    a = p.parse_args()
    torch.set_num_threads(1)
    res = chamfer_floor(a.dataset, a.category, a.split, a.points)
    if a.eval:
        ev = json.load(open(a.eval))
        if ev.get("points") != a.points:
            raise SystemExit(f"{a.eval} was measured at {ev.get('points')} points, not {a.points}")
        res["eval"] = a.eval
        res["network_chamfer"], res["blind_chamfer"] = ev["model"]["chamfer"], ev["blind"]["chamfer"]
        res.update(goal_share(res["floor_chamfer"], res["blind_chamfer"], res["network_chamfer"]))
    print(json.dumps(res, indent=1))
    if a.out:
        write_bytes(a.out, dumps_json(res).encode())


if __name__ == "__main__":
    main()
