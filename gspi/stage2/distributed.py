"""Data-parallel Stage II training on ``torch.distributed`` (issue #16), one process per GPU
under ``torchrun`` (or SLURM's ``srun torchrun``); one process = the plain run, unchanged.

Sharded sampling that keeps the global batch: every rank draws the SAME global batch of
``stage2.train.batch_size`` items from the same seeded data RNG and keeps its contiguous
slice ``[rank*b, (rank+1)*b)`` (b = batch / world); the diffusion noise and timesteps are drawn
for the global batch and sliced the same way (``denoising_loss(shard=...)``). After backward the
gradients are averaged over ranks (one all-reduce per parameter, the DDP reduction without
DDP's wrapper, so ``model.config`` and the no-grad self-conditioning pass work as in one
process). So N ranks take the same steps as one process on the same global batch, to float
rounding (tests/test_stage2_distributed.py). Drawing the global batch on every rank costs the
CPU-side sampling N times; the network work is what is split.

Rank 0 alone writes ``metrics.jsonl``, ``checkpoint.pt`` and the loss curve; every rank reads
the checkpoint on resume (the RNG states in it are the global ones), so resume is exact.
"""
from __future__ import annotations

import dataclasses
import datetime
import os
from dataclasses import dataclass
from typing import Optional

import torch
import torch.distributed as dist
from torch import Tensor

from gspi.stage2.inputs import Stage2Inputs


@dataclass(frozen=True)
class DistContext:
    """Where this process sits: ``rank`` of ``world_size``, and its torch device."""

    rank: int = 0
    world_size: int = 1
    device: torch.device = torch.device("cpu")

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world_size > 1

    def local_batch(self, global_batch: int) -> int:
        if global_batch % self.world_size:
            raise ValueError(f"stage2.train.batch_size={global_batch} must be divisible by the "
                             f"{self.world_size} training processes (WORLD_SIZE)")
        return global_batch // self.world_size

    def shard(self, f0: Tensor, inputs: Stage2Inputs) -> tuple[Tensor, Stage2Inputs]:
        """This rank's slice of the global batch, on this rank's device (a no-op for one CPU process)."""
        if self.active:
            b = self.local_batch(f0.shape[0])
            lo, hi = self.rank * b, (self.rank + 1) * b
            f0 = f0[lo:hi]
            inputs = dataclasses.replace(inputs, **{
                f.name: getattr(inputs, f.name)[lo:hi] for f in dataclasses.fields(inputs)
                if isinstance(getattr(inputs, f.name), Tensor)})
        if self.device.type != "cpu":
            f0, inputs = f0.to(self.device), inputs.to(self.device)
        return f0, inputs

    @property
    def loss_shard(self) -> Optional[tuple[int, int]]:
        """``(rank, world_size)`` for ``denoising_loss``, None in one process."""
        return (self.rank, self.world_size) if self.active else None

    def average_gradients(self, model: torch.nn.Module) -> None:
        """grad <- mean over ranks (every rank then takes the same optimizer step)."""
        if not self.active:
            return
        for p in model.parameters():
            if p.grad is not None:
                dist.all_reduce(p.grad, op=dist.ReduceOp.SUM)
                p.grad.div_(self.world_size)

    def mean(self, value: float) -> float:
        """The mean of a scalar over ranks (the global batch's loss for the log)."""
        if not self.active:
            return value
        t = torch.tensor([value], dtype=torch.float64, device=self.device)
        dist.all_reduce(t, op=dist.ReduceOp.SUM)
        return float(t) / self.world_size

    def any(self, flag: bool) -> bool:
        """True on every rank when it is True on one (a wall-clock stop all ranks take together)."""
        if not self.active:
            return flag
        t = torch.tensor([1.0 if flag else 0.0], device=self.device)
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t.item() > 0)

    def barrier(self) -> None:
        if self.active:
            dist.barrier()


def from_env(device: torch.device) -> DistContext:
    """The context torchrun describes (``RANK``/``WORLD_SIZE``/``LOCAL_RANK``); one plain process
    without them. Starts the process group: NCCL on CUDA (one GPU per local rank), gloo on the CPU."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistContext(device=device)
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    if device.type == "cuda":
        if local_rank >= torch.cuda.device_count():
            raise RuntimeError(f"LOCAL_RANK={local_rank} but only {torch.cuda.device_count()} CUDA devices here")
        device = torch.device("cuda", local_rank)
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo", rank=rank, world_size=world,
                                timeout=datetime.timedelta(minutes=30))
    return DistContext(rank=rank, world_size=world, device=device)


def shutdown(ctx: DistContext) -> None:
    if ctx.active and dist.is_initialized():
        dist.destroy_process_group()
