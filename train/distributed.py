"""Distributed training plumbing: one process per rank under torchrun (env:// rendezvous).

gloo on CPU, nccl on CUDA. Only rank 0 writes checkpoints and logs.
"""

from __future__ import annotations

import dataclasses
import os

import torch
import torch.distributed as dist

from train.errors import UsageError


@dataclasses.dataclass(frozen=True)
class DistInfo:
    rank: int
    world: int
    local_rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world > 1


def setup(device: str | None = None) -> DistInfo:
    """Read torchrun's RANK/WORLD_SIZE/LOCAL_RANK and join the process group when world > 1."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if device is None:
        device = f"cuda:{local}" if torch.cuda.is_available() else "cpu"
    dev = device_of(device, local)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if dev.type == "cuda" else "gloo", rank=rank, world_size=world)
    return DistInfo(rank, world, local, dev)


def device_of(name: str, local_rank: int = 0) -> torch.device:
    """The ``--device`` to run on; plain "cuda" means this rank's GPU. UsageError for a name
    torch does not know or a GPU this machine does not have."""
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise UsageError(f"--device {name}: not a device name (cpu, cuda, cuda:N)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise UsageError(f"--device {name}: CUDA is not available on this machine (use --device cpu)")
        dev = torch.device("cuda", local_rank if dev.index is None else dev.index)
        if dev.index >= torch.cuda.device_count():
            raise UsageError(f"--device {name}: this machine has {torch.cuda.device_count()} GPU(s)")
    return dev


def barrier(info: DistInfo) -> None:
    if info.enabled and dist.is_initialized():
        dist.barrier()


def teardown(info: DistInfo, wait: bool = True) -> None:
    """Leave the process group; ``wait``: first meet the other ranks (a clean finish only: after
    an error the others may never come)."""
    if info.enabled and dist.is_initialized():
        if wait:
            dist.barrier()
        dist.destroy_process_group()


def mean_over_ranks(value: torch.Tensor, info: DistInfo) -> torch.Tensor:
    """Average a scalar over ranks (for logging the same number everywhere)."""
    if not info.enabled:
        return value
    v = value.detach().clone()
    dist.all_reduce(v, op=dist.ReduceOp.SUM)
    return v / info.world


def from_main(value: torch.Tensor | None, info: DistInfo) -> torch.Tensor:
    """Rank 0's tensor (float32, on the CPU) on every rank; the other ranks pass None. Its shape
    travels first (at most 8 dimensions), so they need not know it: a shape basis keeps as many
    directions as rank 0's fits need."""
    if info.is_main and value is None:
        raise ValueError("from_main needs the tensor on rank 0")
    if not info.enabled:
        return value.to("cpu", torch.float32)
    shape = torch.zeros(9, dtype=torch.int64)
    if info.is_main:
        shape[0] = value.dim()
        shape[1 : 1 + value.dim()] = torch.tensor(value.shape)
    shape = shape.to(info.device)
    dist.broadcast(shape, 0)
    dims = shape[1 : 1 + int(shape[0])].tolist()
    data = value.to(info.device, torch.float32) if info.is_main else torch.empty(dims, device=info.device)
    dist.broadcast(data, 0)
    return data.cpu()
