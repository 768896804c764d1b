"""One process or many: what the trainer needs to know about torchrun and DistributedDataParallel.

``torchrun --nproc_per_node=N -m svbrdf_train fit ...`` starts N processes with ``RANK``,
``LOCAL_RANK`` and ``WORLD_SIZE`` set; :func:`init` joins them into a process group (gloo on
CPU, nccl on CUDA). Rank 0 alone logs, validates and writes checkpoints; every rank agrees
on when to stop through :meth:`Dist.any`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as torch_dist

from ..errors import TrainingError

__all__ = ["Dist", "init", "pick_device"]


def pick_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto`` (CUDA when there is one), ``cpu``, ``cuda`` or ``cuda:K``; under torchrun each
    process takes the GPU of its local rank (:func:`svbrdf_render.plumbing.pick_device`, whose
    refusals are :class:`TrainingError` here)."""
    from svbrdf_render import SVBRDFError
    from svbrdf_render.plumbing import pick_device as pick

    try:
        return pick(name, local_rank)
    except SVBRDFError as e:
        raise TrainingError(str(e)) from None


@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")

    @property
    def main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1

    def any(self, *flags: bool) -> list[bool]:
        """Each flag OR-ed over all ranks (one all-reduce; free with one process)."""
        if not self.active:
            return [bool(f) for f in flags]
        t = torch.tensor([int(bool(f)) for f in flags], dtype=torch.int32, device=self._comm_device)
        torch_dist.all_reduce(t, op=torch_dist.ReduceOp.MAX)
        return [bool(v) for v in t.tolist()]

    def gather(self, obj) -> list:
        """``obj`` of every rank, in rank order (all ranks get the list)."""
        if not self.active:
            return [obj]
        out = [None] * self.world
        torch_dist.all_gather_object(out, obj)
        return out

    def barrier(self) -> None:
        if self.active:
            torch_dist.barrier()

    @property
    def _comm_device(self) -> torch.device:
        return self.device if torch_dist.get_backend() == "nccl" else torch.device("cpu")

    def close(self) -> None:
        if self.active and torch_dist.is_initialized():
            torch_dist.destroy_process_group()


def init(device: str = "auto") -> Dist:
    """Join torchrun's process group if there is one; else a single process."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = pick_device(device, local_rank)
    if world > 1:
        backend = "nccl" if dev.type == "cuda" else "gloo"
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        torch_dist.init_process_group(backend=backend)
    return Dist(rank=rank, world=world, local_rank=local_rank, device=dev)
