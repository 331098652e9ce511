"""Two-process CPU DDP (gloo on 127.0.0.1) through torch.multiprocessing.spawn."""

import json
import os
import socket
import sys
import time
from pathlib import Path

import pytest
import torch.multiprocessing as mp

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(
    rank: int, world: int, port: int, dataset: str, out: str, report: str, overrides: dict | None = None
) -> None:
    import torch

    from train.errors import UsageError
    from train.fit import FitSettings, fit
    from train.losses.weights import LossWeights

    torch.set_num_threads(1)
    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank)
    )
    base = dict(
        dataset=dataset,
        category="knife",
        template="sphere24",
        out=out,
        steps=2,
        batch_size=2,
        workers=0,
        n_points=300,
        image_size=32,
        max_views=2,
        log_every=1,
        device="cpu",
        weights=LossWeights(collision=0.0),
    )
    try:
        res = fit(FitSettings(**{**base, **(overrides or {})}), progress=False)
    except UsageError as exc:  # reported, so a test sees what each rank said
        res = {"error": str(exc)}
    Path(report, f"rank{rank}.json").write_text(json.dumps(res))


def _spawn_within(seconds: float, *args) -> None:
    """Two ranks of ``_worker(*args)``; fails the test when they have not ended after ``seconds``
    (a collective one rank never reaches waits forever), killing the processes it started."""
    ctx = mp.spawn(_worker, args=(2, _free_port(), *args), nprocs=2, join=False)
    deadline = time.monotonic() + seconds
    while not ctx.join(timeout=1.0):  # raises when a rank failed (and stops the other)
        if time.monotonic() > deadline:
            for proc in ctx.processes:
                proc.kill()
            pytest.fail(f"the two ranks did not finish within {seconds} s: a hang")


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


@pytest.mark.slow
def test_validation_steps_that_are_not_logging_steps_do_not_hang(tmp_path):
    """Only rank 0 validates; steps 1, 2 and 4 validate but are no --log-every 3 steps, so the
    ranks must still agree on entering the logging branch and its collectives."""
    ds = write_fixture_shards(tmp_path / "ds", n_points=800, size=32)
    out, report = tmp_path / "run", tmp_path / "report"
    report.mkdir()
    _spawn_within(120, str(ds), str(out), str(report), dict(steps=4, log_every=3, val_every=1, encoder_width=8))
    r0, r1 = (json.loads((report / f"rank{r}.json").read_text()) for r in range(2))
    assert r0["param_digest"] == r1["param_digest"] and r0["step"] == r1["step"] == 4
    rows = (out / "log.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == [1, 2, 3, 4]  # every validation step logged
    assert (out / "best.pt").exists()


@pytest.mark.slow
def test_a_rank_failing_alone_ends_the_run_instead_of_hanging(tmp_path):
    """A truncated shard only one rank reads: that rank stops naming it, without waiting for the
    other at the closing barrier, so the launcher (here spawn, else torchrun) ends both."""
    ds = write_fixture_shards(tmp_path / "ds", n_points=800, size=32)
    shard = ds / "knife" / "train-00001.tar"
    shard.write_bytes(shard.read_bytes()[:20000])
    report = tmp_path / "report"
    report.mkdir()
    try:
        _spawn_within(120, str(ds), str(tmp_path / "run"), str(report), dict(encoder_width=8))
    except mp.ProcessRaisedException:  # the other rank, cut off when the failed one left
        pass
    said = [json.loads(p.read_text()).get("error", "") for p in report.iterdir()]
    # the failing rank names the shard; the other is cut off, or (on a slow machine) has reached
    # the same shard by then and names it too: never another error, never a hang
    assert said and set(said) == {f"{shard}: unreadable shard (ReadError: unexpected end of data)"}


@pytest.mark.slow
def test_every_rank_stops_at_the_same_diverging_step(tmp_path):
    """The non-finite check reads the gradient norm after DDP averaged the gradients: the same
    number on every rank, so all ranks stop together (none is left waiting in a collective)."""
    ds = write_fixture_shards(tmp_path / "ds", n_points=800, size=32)
    out, report = tmp_path / "run", tmp_path / "report"
    report.mkdir()
    _spawn_within(120, str(ds), str(out), str(report), dict(steps=6, lr=1e12, checkpoint_every=1, encoder_width=8))
    errors = [json.loads((report / f"rank{r}.json").read_text())["error"] for r in range(2)]
    assert errors[0] == errors[1] and "step 2: training diverged" in errors[0]
    assert f"{out / 'checkpoint.pt'} keeps step 1" in errors[0]


@pytest.mark.slow
def test_only_rank0_fits_the_shape_basis_and_every_rank_trains_with_it(tmp_path):
    ds = write_fixture_shards(tmp_path / "ds", n_points=800, size=32)
    out, report = tmp_path / "run", tmp_path / "report"
    report.mkdir()
    _spawn_within(300, str(ds), str(out), str(report), dict(shape_basis=4, basis_directions=2, encoder_width=8))
    r0, r1 = (json.loads((report / f"rank{r}.json").read_text()) for r in range(2))
    assert "error" not in r0 and r0["param_digest"] == r1["param_digest"]
    summary = json.loads((out / "shape_basis.json").read_text())
    assert summary["shapes"] == 4 and 1 <= summary["directions"] <= 2


def test_from_main_without_a_process_group_is_the_tensor_as_float32():
    import torch

    from train.distributed import DistInfo, from_main

    alone = DistInfo(0, 1, 0, torch.device("cpu"))
    t = torch.rand(3, 5)
    assert torch.equal(from_main(t, alone), t)
    assert from_main(t.double(), alone).dtype == torch.float32  # what the ranks of a group get
    with pytest.raises(ValueError):
        from_main(None, alone)
