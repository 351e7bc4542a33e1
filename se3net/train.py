"""Training: Adam on the point loss, the sharpening ramp, validation, exact resume.

A run folder holds ``last.pt`` (with optimiser and random states, to resume exactly),
``best.pt`` (the checkpoint with the lowest validation flow MSE), ``metrics.jsonl`` (one line
per evaluation: train and validation loss, flow MSE and its ratio to no-motion) and, with
``keep_every``, ``iter_NNNNNN.pt`` snapshots for studies.

The loss is taken through the planner's rollout (``se3net.rollout``) over one step, the
pusher position in the controls integrated from the commanded velocities, as the planner rolls
the model (multi-step training was tried and not kept: docs/experiments). ``init`` starts from
a checkpoint's weights (fine-tuning).

Under ``torchrun`` the run is data-parallel (``se3net.distributed``): every process draws the
same batch and trains on its shard of it in a DistributedDataParallel step; rank 0 alone
validates and writes the run folder. ``batch`` is the total over the processes, so a run of N
processes sees the same examples per step as a run of one.
"""

from __future__ import annotations

import json
import math
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch

from scenarios import InputError, check_seed
from scenarios.config import differences
from se3net.checkpoint import manifest_hash, read_checkpoint, save_checkpoint
from se3net.data import PushDataset, paper_noise
from se3net.device import check_device
from se3net.distributed import Ranks, broadcast, join, leave, mean_over_ranks, rank_device, shard
from se3net.metrics import FlowStats, point_loss, true_flow
from se3net.model import ModelConfig, build_model, sharpening
from se3net.rollout import rollout
from sim.folders import exclusive
from sim.shards import DataError, append_text, atomic_write_bytes, portable_path


class TrainingDiverged(RuntimeError):
    """The loss became NaN or infinite; the last good checkpoint is kept."""


@dataclass(frozen=True)
class TrainConfig:
    """One training run."""

    data: str | tuple[str, ...]
    """dataset folder, or several pooled (exploration plus planner-visited data)"""
    out: str
    """run folder"""
    variant: str = "se3net"
    """model variant (see se3net.model.VARIANTS)"""
    iters: int = 6000
    """optimiser steps"""
    batch: int = 32
    """examples per step"""
    lr: float = 1e-3
    """peak learning rate (cosine decay to 5 %)"""
    weight_decay: float = 1e-4
    """Adam weight decay"""
    seed: int = 0
    """seed of initialisation, batch sampling and sharpening noise"""
    device: str = "cpu"
    """torch device (cpu, cuda, cuda:N, mps), checked to exist"""
    k: int = 4
    """number of masks (SE3-Net variants)"""
    eval_every: int = 250
    """iterations between validations and checkpoints"""
    val_examples: int = 512
    """validation examples (a fixed, evenly spaced subset)"""
    keep_every: int = 0
    """also keep a checkpoint every N iterations (0: never)"""
    init: str | None = None
    """checkpoint whose weights (and normalisation) the run starts from"""
    later_fraction: float = 0.0
    """share of each batch drawn from the later data folders (planner-visited data, a small
    pool beside the exploration data); 0: every example equally likely"""
    later_from: int = 1
    """index of the first of the later data folders (1: the second and later; 2 when two
    exploration folders come first)"""
    stride: int = 1
    """the network sees every stride-th pixel of the camera's image in each direction (2: a
    32x32 planning-resolution model of 64x64 data, about 4x fewer pixels a prediction)"""
    noise: str = "none"
    """the paper's robustness noise on the training and validation data
    (a name of ``se3net.data.PAPER_NOISE``), fresh in each pass over the data"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        for name in ("iters", "batch", "eval_every", "val_examples", "stride"):
            if getattr(self, name) < 1:
                raise InputError(
                    f"--{name.replace('_', '-')} must be positive, got {getattr(self, name)}"
                )
        if self.keep_every < 0:
            raise InputError(
                f"--keep-every must be 0 (no snapshots) or more, got {self.keep_every}"
            )
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise InputError(f"--lr must be a positive number, got {self.lr}")
        if not 0.0 <= self.later_fraction < 1.0:
            raise InputError(f"--later-fraction must be in [0, 1), got {self.later_fraction}")
        if self.later_from < 1:
            raise InputError(f"--later-from must be positive, got {self.later_from}")
        folders = 1 if isinstance(self.data, str | Path) else len(self.data)
        if self.later_fraction > 0 and folders <= self.later_from:
            raise InputError(
                f"--later-fraction draws from the --data folders after the first "
                f"{self.later_from}, and there are {folders}: give more folders or a lower "
                "--later-from"
            )
        paper_noise(self.noise)
        check_device(self.device)


_LATER_SETTINGS = ("stride", "noise", "later_from")
RETIRED_SETTINGS = {"deflected_fraction": 0.0, "loss": "moving", "controls": "fused",
                    "valid_channel": False, "full_res_head": False, "rollout_steps": 1,
                    "feedback": "grid"}  # fmt: skip
"""options tried and not kept, with the value that means "not used": a run that did not use
them resumes (one that did differs, and is refused, naming them)"""
"""settings added after runs were made: a run that has none ran at its default"""


def rollout_loss(
    model: torch.nn.Module, b: dict[str, torch.Tensor], dt: float, **sharpen: Any
) -> torch.Tensor:
    """The point loss of one step through the planner's rollout (``se3net.rollout``): the
    pusher position in the controls integrated from the commands, as the planner does."""
    (cloud,) = rollout(model, b["points"], b["valid"], b["actions"][:, :1], b["state"], dt,
                       **sharpen)  # fmt: skip
    return point_loss(cloud, b["target"][:, 0], b["target_valid"][:, 0], b["points"],
                      true_flow_m=true_flow(b, 0))  # fmt: skip


class StepLoss(torch.nn.Module):
    """The loss of one training batch (:func:`rollout_loss`) as a module: DistributedDataParallel
    synchronises gradients through a module's forward, and the rollout calls the network's
    parts (encode, predict) rather than its forward, so the whole loss is what it wraps."""

    def __init__(self, model: torch.nn.Module, dt: float) -> None:
        super().__init__()
        self.model, self.dt = model, dt

    def forward(self, b: dict[str, torch.Tensor], sharpen: dict[str, Any]) -> torch.Tensor:
        return rollout_loss(self.model, b, self.dt, **sharpen)


def _logged_by(line: str, iteration: int) -> bool:
    """Whether a line of ``metrics.jsonl`` is an evaluation at or before ``iteration``; a line
    cut by an interruption is not (it was being written before its checkpoint, so the resumed
    run evaluates that iteration again)."""
    try:
        return json.loads(line)["iteration"] <= iteration
    except json.JSONDecodeError:
        return False


def learning_rate(cfg: TrainConfig, it: int) -> float:
    return cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(it / cfg.iters, 1.0))))


def fit_normalisation(
    model: torch.nn.Module, ds: PushDataset, rng: np.random.Generator, n: int = 2048
) -> None:
    """Set the model's input and control normalisation from training examples."""
    b = ds.batch(rng.choice(len(ds), size=min(n, len(ds)), replace=False))
    pts = b["points"].permute(0, 2, 3, 1)[b["valid"]]
    u = b["u"][:, 0]
    norm = model.norm
    norm.points_mean.copy_(pts.mean(0))
    norm.points_std.copy_(pts.std(0).clamp_min(1e-3))
    norm.u_mean.copy_(u.mean(0))
    norm.u_std.copy_(u.std(0).clamp_min(1e-3))


@torch.no_grad()
def validate(
    model: torch.nn.Module,
    ds: PushDataset,
    indices: np.ndarray,
    batch: int,
    device: str,
) -> dict[str, float]:
    """Loss and flow MSE (one step) on fixed validation examples, and the rollout loss."""
    model.eval()
    dt = ds.scenario.action.dt_control_s
    stats, loss_sum, rollout_sum, n = FlowStats(), 0.0, 0.0, 0
    for s in range(0, len(indices), batch):
        b = {k: v.to(device) for k, v in ds.batch(indices[s : s + batch]).items()}
        pred = model(b["points"], b["u"][:, 0], b["valid"]).points
        loss_sum += float(
            point_loss(pred, b["target"][:, 0], b["target_valid"][:, 0], b["points"],
                       true_flow_m=true_flow(b, 0))
        ) * len(pred)  # fmt: skip
        rolled = rollout_loss(model, b, dt)
        rollout_sum += float(rolled) * len(pred)
        n += len(pred)
        stats.add(pred, b["points"], b["target"][:, 0], b["target_valid"][:, 0], true_flow(b, 0))
    model.train()
    return {
        "val_loss": loss_sum / n,
        "val_rollout_loss": rollout_sum / n,
        "val_flow_mse_cm2": stats.mse_cm2,
        "val_no_motion_cm2": stats.no_motion_cm2,
        "val_ratio": stats.ratio,
    }


def draw_batch(ds: PushDataset, cfg: TrainConfig, rng: np.random.Generator) -> np.ndarray:
    """Indices of one batch: uniform over all examples; or with ``cfg.later_fraction`` of it
    drawn from the later data folders, so a small pool of planner-visited steps is seen."""
    if cfg.later_fraction == 0:
        return rng.integers(len(ds), size=cfg.batch)
    later = np.flatnonzero(ds.source >= cfg.later_from)
    if len(later) == 0:
        raise DataError("--later-fraction: the later --data folders have no training examples")
    first = np.flatnonzero(ds.source < cfg.later_from)
    n_later = round(cfg.later_fraction * cfg.batch)
    return np.concatenate([first[rng.integers(len(first), size=cfg.batch - n_later)],
                           later[rng.integers(len(later), size=n_later)]])  # fmt: skip


def init_weights(
    cfg: TrainConfig, mcfg: ModelConfig, ds: PushDataset
) -> tuple[dict[str, Any], str]:
    """The weights of ``cfg.init`` and the hash of the data they learnt from, refused unless it
    is the same network for the same data setup (variant, masks, camera, controls)."""
    from se3net.checkpoint import CheckpointError, load_checkpoint

    net, blob = load_checkpoint(cfg.init, scenario=ds.scenario)
    theirs = net.cfg.to_dict()  # settings added later at their defaults
    if theirs != mcfg.to_dict():
        diffs = differences(theirs, mcfg.to_dict(), old_has="--init has",
                            new_has="this run has")  # fmt: skip
        raise CheckpointError(f"--init {cfg.init} is another network: {'; '.join(diffs)}")
    return net.state_dict(), str(blob.get("data_hash", ""))


def train(cfg: TrainConfig, *, resume: bool = False, progress: bool = True) -> dict[str, Any]:
    """Train (or resume) a run; returns the last validation figures (in every process of a
    ``torchrun`` launch: rank 0's).

    Raises:
        TrainingDiverged: NaN or infinite loss (``last.pt`` keeps the last good state).
        FileExistsError: the run folder already holds a run and ``resume`` is False.
        InputError: bad settings; under torchrun, a batch that does not split over the
            processes, or a resume with another number of processes than the run had.
    """
    ranks = join(cfg.device, cfg.batch)
    finished = False
    try:
        # rank 0 alone writes the run folder (the other processes of a torchrun launch read it)
        with exclusive(cfg.out) if ranks.main else nullcontext():
            result = _train(cfg, ranks, resume=resume, progress=progress and ranks.main)
        finished = True
        return result
    finally:
        leave(ranks, finished=finished)


def _train(cfg: TrainConfig, ranks: Ranks, *, resume: bool, progress: bool) -> dict[str, Any]:
    from tqdm import tqdm

    out = Path(cfg.out)
    last = out / "last.pt"
    if last.exists() and not resume:
        raise FileExistsError(
            f"{out} already holds a run; pass --resume to continue it or choose another --out"
        )
    if resume and not last.exists():
        raise FileNotFoundError(f"nothing to resume: {last} does not exist")
    device = rank_device(cfg.device, ranks)
    torch.manual_seed(cfg.seed)
    data = {
        "horizon": 1, "stride": cfg.stride, "noise": paper_noise(cfg.noise),
        "seed": cfg.seed, "device": device,
    }  # fmt: skip
    ds = PushDataset(cfg.data, split="train", **data)
    val = PushDataset(cfg.data, split="val", **data)
    dt = ds.scenario.action.dt_control_s
    # what the weights learnt from: this run's data, and with --init the data its start did
    # (so that --split all refuses a fine-tuned model on its starting point's data too)
    data_hash = own_hash = "+".join(manifest_hash(m) for m in ds.manifests)
    cam = ds.scenario.camera
    mcfg = ModelConfig(
        variant=cfg.variant,
        k=cfg.k,
        height=cam.height // cfg.stride,
        width=cam.width // cfg.stride,
        control_dim=len(ds.control_layout),
        stride=cfg.stride,
    )
    model = build_model(mcfg).to(device)
    if cfg.init is not None:
        weights, learnt_from = init_weights(cfg, mcfg, ds)
        model.load_state_dict(weights)
        parts = [*data_hash.split("+"), *learnt_from.split("+")]
        data_hash = "+".join(dict.fromkeys(h for h in parts if h))  # each once, in order
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    rng = np.random.default_rng(cfg.seed)
    gen = torch.Generator(device=device).manual_seed(cfg.seed)
    start, best = 0, math.inf
    if resume:
        blob = read_checkpoint(last)
        state = blob["train_state"]
        run_cfg = dict(state["config"])
        if run_cfg.get("horizon") == 1:  # a setting of old runs that changed nothing at 1
            del run_cfg["horizon"]
        defaults = {f.name: f.default for f in fields(TrainConfig)}
        for key in _LATER_SETTINGS:
            run_cfg.setdefault(key, defaults[key])
        for key, unused in RETIRED_SETTINGS.items():  # options retired since, if not used
            if key in run_cfg and run_cfg[key] == unused:
                del run_cfg[key]
        # where the folders are is not a setting: the data hash (below) checks what they hold,
        # in order, so a path spelt another way, or a moved run, resumes
        asked = {k: v for k, v in asdict(cfg).items() if k not in ("data", "out")}
        run_cfg = {k: v for k, v in run_cfg.items() if k not in ("data", "out")}
        if run_cfg != asked:
            diffs = differences(run_cfg, asked, old_has="the run has")
            raise InputError(
                f"--resume with other settings than the run's ({'; '.join(diffs)}); "
                "use the original ones"
            )
        if state.get("world_size", 1) != ranks.world:
            raise InputError(
                f"--resume with {ranks.world} process(es), but the run was trained on "
                f"{state.get('world_size', 1)}; resume it with torchrun --nproc_per_node "
                f"{state.get('world_size', 1)} (1: plain se3push train) to continue it exactly"
            )
        if blob["data_hash"] not in (data_hash, own_hash):  # own: a run from before --init's
            raise InputError(
                f"--resume with other data than the run was trained on ({cfg.data} changed)"
            )
        model.load_state_dict(blob["state_dict"])
        opt.load_state_dict(state["optimizer"])
        rng.bit_generator.state = state["rng"]
        gen.set_state(state["torch_gen"])
        start, best = state["iteration"], state["best"]
        resumed_figures = blob["extra"]
        log = out / "metrics.jsonl"  # drop evaluations logged after the resumed checkpoint
        if ranks.main:
            lines = [ln for ln in log.read_text().splitlines() if _logged_by(ln, start)]
            atomic_write_bytes(log, "".join(ln + "\n" for ln in lines).encode())
    else:
        if cfg.init is None:
            fit_normalisation(model, ds, rng)
        if ranks.main:
            out.mkdir(parents=True, exist_ok=True)
            (out / "metrics.jsonl").write_text("")
    val_idx = np.linspace(0, len(val) - 1, min(cfg.val_examples, len(val))).round().astype(int)
    model.train()
    step_loss: torch.nn.Module = StepLoss(model, dt)
    if ranks.world > 1:  # each step's gradients averaged over the processes' shards
        from torch.nn.parallel import DistributedDataParallel

        step_loss = DistributedDataParallel(
            step_loss, device_ids=[device] if device.startswith("cuda") else None
        )

    def checkpoint(path: Path, it: int, figures: dict[str, float], *, with_state: bool) -> None:
        state = None
        if with_state:
            state = {
                "config": asdict(cfg),
                "optimizer": opt.state_dict(),
                "rng": rng.bit_generator.state,
                "torch_gen": gen.get_state(),
                "iteration": it,
                "best": best,
                "world_size": ranks.world,
            }
        folders = [cfg.data] if isinstance(cfg.data, str | Path) else cfg.data
        # no wall clock in a checkpoint: the same training gives the same bytes (metrics.jsonl
        # keeps the time)
        timeless = {k: v for k, v in figures.items() if k != "elapsed_s"}
        extra = {
            "iteration": it, "data": [portable_path(d) for d in folders],
            **timeless,
        }  # fmt: skip
        save_checkpoint(
            path, model, scenario=ds.scenario, data_hash=data_hash, extra=extra, train_state=state
        )

    bar = tqdm(
        total=cfg.iters,
        initial=start,
        disable=not progress,
        desc=f"train {cfg.variant}",
        dynamic_ncols=True,
    )
    running, n_running, t0 = 0.0, 0, time.time()
    figures = resumed_figures if resume else {}
    for it in range(start, cfg.iters):
        for group in opt.param_groups:
            group["lr"] = learning_rate(cfg, it)
        # a fine-tuned model keeps the sharpening it ended with (its masks are already binary)
        sigma, gamma = sharpening(cfg.iters if cfg.init else it, cfg.iters, mcfg)
        ds.set_epoch(it * cfg.batch // len(ds))  # fresh noise in each pass over the data
        b = ds.batch(shard(draw_batch(ds, cfg, rng), ranks))  # this process's share
        loss = step_loss(b, {"sigma": sigma, "gamma": gamma, "generator": gen})
        if not torch.isfinite(loss):
            kept = (
                f"; --init {last} starts it from the last good state (iteration "
                f"{figures['iteration']})"
                if "iteration" in figures
                else ""
            )
            raise TrainingDiverged(
                f"loss became {float(loss.detach())} at step {it + 1}: train again with a lower "
                f"--lr into a new --out folder{kept}"
            )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if hasattr(model, "gamma"):
            model.gamma.fill_(gamma)
        running += float(loss.detach())
        n_running += 1
        bar.update(1)
        bar.set_postfix(loss=f"{running / n_running:.4f}")
        done = it + 1
        if done % cfg.eval_every == 0 or done == cfg.iters:
            train_loss = mean_over_ranks(running / n_running, ranks)
            running, n_running = 0.0, 0
            if not ranks.main:  # rank 0 alone validates and writes the run folder
                continue
            figures = {
                "iteration": done,
                "train_loss": train_loss,
                **validate(model, val, val_idx, cfg.batch, device),  # fmt: skip
                "sigma": sigma,
                "gamma": gamma,
                "lr": learning_rate(cfg, it),
                "elapsed_s": time.time() - t0,
                "examples": done * cfg.batch,
            }
            append_text(out / "metrics.jsonl", json.dumps(figures) + "\n")
            score = figures["val_flow_mse_cm2"]
            if score < best:
                best = score
                checkpoint(out / "best.pt", done, figures, with_state=False)
            if cfg.keep_every and done % cfg.keep_every == 0:
                checkpoint(out / f"iter_{done:06d}.pt", done, figures, with_state=False)
            # last: a run killed before it resumes from the previous one and writes these again
            checkpoint(last, done, figures, with_state=True)
            bar.write(
                f"it {done}: train {figures['train_loss']:.4f}, val flow MSE "
                f"{figures['val_flow_mse_cm2']:.4f} cm^2 "
                f"(ratio to no-motion {figures['val_ratio']:.3f})"
            )
    bar.close()
    return broadcast(figures, ranks)
