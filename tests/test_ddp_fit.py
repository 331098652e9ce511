"""Two-process CPU DDP (gloo on 127.0.0.1) through torch.multiprocessing.spawn."""

import json
import os
import socket
import sys
from pathlib import Path

import pytest
import torch.multiprocessing as mp

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(rank: int, world: int, port: int, dataset: str, out: str, report: str) -> None:
    import torch

    from train.fit import FitSettings, fit
    from train.losses.weights import LossWeights

    torch.set_num_threads(1)
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank))
    s = FitSettings(dataset=dataset, category="knife", template="sphere24", out=out, steps=2, batch_size=2, workers=0,
                    n_points=300, image_size=32, max_views=2, log_every=1, device="cpu",
                    weights=LossWeights(collision=0.0))  # fmt: skip
    res = fit(s, progress=False)
    Path(report, f"rank{rank}.json").write_text(json.dumps(res))


@pytest.mark.slow
def test_two_rank_ddp_stays_in_sync_and_rank0_checkpoints(tmp_path):
    ds = write_fixture_shards(tmp_path / "ds", n_points=800, size=32)
    out, report = tmp_path / "run", tmp_path / "report"
    report.mkdir()
    mp.spawn(_worker, args=(2, _free_port(), str(ds), str(out), str(report)), nprocs=2, join=True)
    r0, r1 = (json.loads((report / f"rank{r}.json").read_text()) for r in range(2))
    assert r0["param_digest"] == r1["param_digest"]
    assert r0["last_loss"] == r1["last_loss"]  # logged loss is averaged over ranks
    assert sorted(p.name for p in out.glob("*.pt")) == ["checkpoint.pt"]
    assert json.loads((out / "config.json").read_text())["world_size"] == 2
