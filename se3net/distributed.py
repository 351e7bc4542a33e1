"""Data-parallel training under ``torchrun``: which process this is, its device and its share
of every batch.

``torchrun --nproc_per_node N -m se3push train …`` starts N processes with ``RANK``,
``WORLD_SIZE``, ``LOCAL_RANK`` and a rendezvous address in their environment; each joins the
process group (gloo on CPU, NCCL on GPU). Every process draws the same batch indices from the
same seeded generator and keeps its own shard of them (``indices[rank::world]``), so the
processes together see exactly the batch one process would draw, the random state stays the
same in all of them (and in the checkpoint), and ``--resume`` is as exact as before. Without
those variables (a plain ``se3push train``) this is one process of one.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from typing import NoReturn

import numpy as np
import torch

from scenarios import InputError


@dataclass(frozen=True)
class Ranks:
    """This process's place among the training processes."""

    rank: int = 0
    """global rank (0 writes checkpoints, logs and validates)"""
    world: int = 1
    """number of processes"""
    local_rank: int = 0
    """rank on this machine (which GPU it uses)"""

    @property
    def main(self) -> bool:
        return self.rank == 0


def ranks_from_env() -> Ranks:
    """The ranks ``torchrun`` set in the environment (one process of one without them)."""
    env = os.environ
    return Ranks(
        rank=int(env.get("RANK", 0)),
        world=int(env.get("WORLD_SIZE", 1)),
        local_rank=int(env.get("LOCAL_RANK", 0)),
    )


def rank_device(device: str, ranks: Ranks) -> str:
    """The device of this process: ``cuda`` becomes ``cuda:LOCAL_RANK`` with several
    processes (one GPU each); an explicit ``cuda:N`` is refused there (all would share it)."""
    if ranks.world == 1 or not device.startswith("cuda"):
        return device
    if device != "cuda":
        raise InputError(
            f"--device {device} names one GPU for {ranks.world} processes; give --device cuda "
            "and each process takes the GPU of its local rank"
        )
    gpus = torch.cuda.device_count()
    if ranks.local_rank >= gpus:
        raise InputError(
            f"{ranks.world} processes but this machine has {gpus} GPU(s); start at most {gpus} "
            "per machine (torchrun --nproc_per_node)"
        )
    return f"cuda:{ranks.local_rank}"


def join(device: str, batch: int) -> Ranks:
    """Join the process group of a ``torchrun`` launch (gloo on CPU, NCCL on CUDA); returns
    this process's ranks.

    Raises:
        InputError: ``batch`` does not split evenly over the processes.
    """
    ranks = ranks_from_env()
    if ranks.world == 1:
        return ranks
    if batch % ranks.world:
        raise InputError(
            f"--batch {batch} does not split evenly over {ranks.world} processes; give a "
            f"multiple of {ranks.world} (the batch is the total over the processes)"
        )
    import torch.distributed as dist

    if not dist.is_initialized():
        backend = "nccl" if device.startswith("cuda") else "gloo"
        if backend == "nccl":
            torch.cuda.set_device(rank_device(device, ranks))
        dist.init_process_group(backend=backend)
    return ranks


def leave(ranks: Ranks, *, finished: bool) -> None:
    """Leave the process group joined by :func:`join` (nothing for one process).

    ``finished``: every process got to the end of its work. They then wait for each other
    before the group goes, so that none tears it down while another still writes its
    checkpoint. (The wait came in against an abort at exit that it made rarer but did not
    end; the abort's cause and its mend are :func:`end_process`'s.) After an error there is
    no waiting (the others may never get there)."""
    if ranks.world > 1:
        import torch.distributed as dist

        if dist.is_initialized():
            if finished:
                dist.barrier()
            dist.destroy_process_group()


def end_process(code: int) -> NoReturn:
    """End a process that was one of several (under ``torchrun``) with exit status ``code``,
    its output flushed, without the interpreter's finalization.

    The process group's gloo worker threads outlive :func:`leave`: DistributedDataParallel
    keeps the group referenced from C++ after ``destroy_process_group``, so they are never
    joined. A worker that is still freeing a finished collective's work when the interpreter
    finalizes (the work's tensor has a Python object, so freeing it takes the GIL) is made to
    exit there, and the unwinding aborts the process: "terminate called without an active
    exception", SIGABRT, and torchrun fails a run that had finished (a core dump of it:
    ``ProcessGroupGloo::runLoop`` -> ``~AsyncAllreduceWork`` -> ``take_gil`` ->
    ``pthread_exit`` -> ``std::terminate``; about 1 in 30 test runs here). Nothing is left to
    write by then: checkpoints and logs are written, and closed, before."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def shard(indices: np.ndarray, ranks: Ranks) -> np.ndarray:
    """This process's share of a batch: every ``world``-th index from its ``rank``; the
    shards of all processes are disjoint and together the whole batch."""
    return indices[ranks.rank :: ranks.world]


def mean_over_ranks(x: float, ranks: Ranks) -> float:
    """The mean of ``x`` over the processes (``x`` for one); every process must call it."""
    if ranks.world == 1:
        return x
    import torch.distributed as dist

    t = torch.tensor([x], dtype=torch.float64)
    if dist.get_backend() == "nccl":
        t = t.cuda()
    dist.all_reduce(t)
    return float(t.item()) / ranks.world


def broadcast(obj: object, ranks: Ranks) -> object:
    """Rank 0's ``obj`` in every process (``obj`` for one); every process must call it."""
    if ranks.world == 1:
        return obj
    import torch.distributed as dist

    box = [obj]
    dist.broadcast_object_list(box, src=0)
    return box[0]
