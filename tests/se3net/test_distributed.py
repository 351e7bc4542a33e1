"""Data-parallel training (torchrun, DDP over gloo) with 2 CPU processes."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from scenarios import InputError
from se3net.checkpoint import read_checkpoint
from se3net.distributed import Ranks, end_process, join, shard
from se3net.train import TrainConfig, train


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rank_main(rank: int, world: int, port: int, cfg: dict, resume: bool, stop_at, log: str):
    """One training process, as torchrun starts it, that logs what it writes and draws."""
    os.environ.update(RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank),
                      MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))  # fmt: skip
    torch.set_num_threads(1)
    import se3net.train as tm

    real_save, real_shard, real_lr = tm.save_checkpoint, tm.shard, tm.learning_rate

    def note(**kw):
        with open(log, "a") as f:
            f.write(json.dumps({"rank": rank, **kw}) + "\n")

    def save(path, *a, **kw):
        note(saved=Path(path).name)
        return real_save(path, *a, **kw)

    def my_shard(indices, ranks):
        out = real_shard(indices, ranks)
        note(batch=indices.tolist(), shard=out.tolist())
        return out

    def lr(c, it):
        if it == stop_at:
            raise KeyboardInterrupt
        return real_lr(c, it)

    tm.save_checkpoint, tm.shard, tm.learning_rate = save, my_shard, lr
    try:
        tm.train(TrainConfig(**cfg), resume=resume, progress=False)
    except KeyboardInterrupt:
        pass
    end_process(0)  # as se3push train ends a torchrun process


def _run_ranks(cfg: dict, log: Path, *, resume=False, stop_at=None, world=2) -> None:
    ctx = torch.multiprocessing.get_context("spawn")
    port = _free_port()
    procs = [ctx.Process(target=_rank_main, args=(r, world, port, cfg, resume, stop_at, str(log)))
             for r in range(world)]  # fmt: skip
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=300)
    assert [p.exitcode for p in procs] == [0] * world


def _cfg(tiny_data, out) -> dict:
    return dict(data=str(tiny_data), out=str(out), iters=4, batch=4, eval_every=2,
                val_examples=8, k=3)  # fmt: skip


def test_shards_are_disjoint_and_make_the_whole_batch():
    idx = np.array([7, 3, 3, 9, 1, 4])
    parts = [shard(idx, Ranks(rank=r, world=3)) for r in range(3)]
    assert sorted(np.concatenate(parts).tolist()) == sorted(idx.tolist())
    assert [len(p) for p in parts] == [2, 2, 2]
    assert shard(idx, Ranks()).tolist() == idx.tolist()


def test_a_batch_that_does_not_split_over_the_processes_is_refused(monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    with pytest.raises(InputError, match="--batch 3 does not split evenly over 2 processes"):
        join("cpu", 3)


def test_more_processes_on_a_machine_than_gpus_is_refused(monkeypatch):
    from se3net.distributed import rank_device

    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert rank_device("cuda", Ranks(rank=1, world=2, local_rank=1)) == "cuda:1"
    with pytest.raises(InputError, match="4 processes but this machine has 2 GPU"):
        rank_device("cuda", Ranks(rank=2, world=4, local_rank=2))
    assert rank_device("cpu", Ranks(rank=2, world=4, local_rank=2)) == "cpu"


def test_ddp_ranks_draw_their_own_shards_rank_0_writes_and_resume_is_exact(tiny_data, tmp_path):
    _run_ranks(_cfg(tiny_data, tmp_path / "a"), tmp_path / "a.log")
    notes = [json.loads(x) for x in (tmp_path / "a.log").read_text().splitlines()]
    # rank 0 alone writes: its checkpoints at iterations 2 and 4, one metrics line each
    assert {n["rank"] for n in notes if "saved" in n} == {0}
    lines = (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in lines] == [2, 4]
    # each step, both ranks draw the same batch and keep disjoint halves of it
    draws = {r: [n for n in notes if n["rank"] == r and "batch" in n] for r in (0, 1)}
    assert len(draws[0]) == len(draws[1]) == 4
    for d0, d1 in zip(draws[0], draws[1], strict=True):
        assert d0["batch"] == d1["batch"] and len(d0["shard"]) == len(d1["shard"]) == 2
        assert sorted(d0["shard"] + d1["shard"]) == sorted(d0["batch"])
        assert d0["shard"] == d0["batch"][0::2] and d1["shard"] == d1["batch"][1::2]
    # interrupted after its first checkpoint and resumed on 2 processes: the same weights
    b = _cfg(tiny_data, tmp_path / "b")
    _run_ranks(b, tmp_path / "b.log", stop_at=2)
    assert read_checkpoint(tmp_path / "b" / "last.pt")["train_state"]["iteration"] == 2
    _run_ranks(b, tmp_path / "b.log", resume=True)
    wa = read_checkpoint(tmp_path / "a" / "last.pt")["state_dict"]
    wb = read_checkpoint(tmp_path / "b" / "last.pt")["state_dict"]
    for k in wa:
        assert torch.equal(wa[k], wb[k]), k
    # and a 2-process run is not resumed on 1 process (it would not continue exactly)
    with pytest.raises(InputError, match="trained on 2; resume it with torchrun"):
        train(TrainConfig(**b), resume=True, progress=False)


def test_torchrun_trains_with_two_processes_from_the_command_line(tiny_data, tmp_path):
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
           "2", "-m", "se3push", "train", "--data", str(tiny_data), "--out", str(tmp_path / "r"),
           "--iters", "2", "--batch", "4", "--eval-every", "2", "--k", "3"]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    # both streams: torchrun's agent and the ranks report a failure on either
    assert done.returncode == 0, f"stdout: {done.stdout[-2000:]}\nstderr: {done.stderr[-4000:]}"
    assert done.stdout.count("done: ") == 1  # rank 0 speaks for the run
    blob = read_checkpoint(tmp_path / "r" / "last.pt")
    assert blob["train_state"]["world_size"] == 2 and blob["extra"]["examples"] == 8
    assert len((tmp_path / "r" / "metrics.jsonl").read_text().splitlines()) == 1


def test_a_process_ended_past_the_interpreter_s_exit_keeps_its_status_and_its_output():
    """``end_process`` skips the interpreter's finalization, but what the process printed to a
    pipe (block-buffered) still arrives, and the status is the one given."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    code = "from se3net.distributed import end_process; print('done', end=''); end_process(3)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert (run.returncode, run.stdout) == (3, "done")
