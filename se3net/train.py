"""Training: Adam on the point loss, the sharpening ramp, validation, exact resume.

A run folder holds ``last.pt`` (with optimiser and random states, to resume exactly),
``best.pt`` (the checkpoint with the lowest validation flow MSE), ``metrics.jsonl`` (one line
per evaluation: train and validation loss, flow MSE and its ratio to no-motion) and, with
``keep_every``, ``iter_NNNNNN.pt`` snapshots for studies.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from se3net.checkpoint import manifest_hash, read_checkpoint, save_checkpoint
from se3net.data import PushDataset
from se3net.metrics import FlowStats, point_loss
from se3net.model import ModelConfig, build_model, sharpening
from sim.dataset import differences


class TrainingDiverged(RuntimeError):
    """The loss became NaN or infinite; the last good checkpoint is kept."""


@dataclass(frozen=True)
class TrainConfig:
    """One training run."""

    data: str
    """dataset folder"""
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
    horizon: int = 1
    """prediction horizon in control steps"""
    seed: int = 0
    """seed of initialisation, batch sampling and sharpening noise"""
    device: str = "cpu"
    """torch device"""
    k: int = 4
    """number of masks (SE3-Net variants)"""
    eval_every: int = 250
    """iterations between validations and checkpoints"""
    val_examples: int = 512
    """validation examples (a fixed, evenly spaced subset)"""
    keep_every: int = 0
    """also keep a checkpoint every N iterations (0: never)"""

    def __post_init__(self) -> None:
        for name in ("iters", "batch", "eval_every", "val_examples", "horizon"):
            if getattr(self, name) < 1:
                raise ValueError(
                    f"--{name.replace('_', '-')} must be positive, got {getattr(self, name)}"
                )
        if not self.lr > 0:
            raise ValueError(f"--lr must be positive, got {self.lr}")


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
    model: torch.nn.Module, ds: PushDataset, indices: np.ndarray, batch: int, device: str
) -> dict[str, float]:
    """Loss and flow MSE (one step) on fixed validation examples."""
    model.eval()
    stats, loss_sum, n = FlowStats(), 0.0, 0
    for s in range(0, len(indices), batch):
        b = {k: v.to(device) for k, v in ds.batch(indices[s : s + batch]).items()}
        pred = model(b["points"], b["u"][:, 0], b["valid"]).points
        loss_sum += float(
            point_loss(pred, b["target"][:, 0], b["target_valid"][:, 0], b["points"])
        ) * len(pred)
        n += len(pred)
        stats.add(pred, b["points"], b["target"][:, 0], b["target_valid"][:, 0])
    model.train()
    return {
        "val_loss": loss_sum / n,
        "val_flow_mse_cm2": stats.mse_cm2,
        "val_no_motion_cm2": stats.no_motion_cm2,
        "val_ratio": stats.ratio,
    }


def train(cfg: TrainConfig, *, resume: bool = False, progress: bool = True) -> dict[str, Any]:
    """Train (or resume) a run; returns the last validation figures.

    Raises:
        TrainingDiverged: NaN or infinite loss (``last.pt`` keeps the last good state).
        FileExistsError: the run folder already holds a run and ``resume`` is False.
    """
    from tqdm import tqdm

    out = Path(cfg.out)
    last = out / "last.pt"
    if last.exists() and not resume:
        raise FileExistsError(
            f"{out} already holds a run; pass --resume to continue it or choose another --out"
        )
    if resume and not last.exists():
        raise FileNotFoundError(f"nothing to resume: {last} does not exist")
    torch.manual_seed(cfg.seed)
    ds = PushDataset(cfg.data, split="train", horizon=cfg.horizon)
    val = PushDataset(cfg.data, split="val", horizon=cfg.horizon)
    data_hash = manifest_hash(ds.manifest)
    cam = ds.scenario.camera
    mcfg = ModelConfig(
        variant=cfg.variant,
        k=cfg.k,
        height=cam.height,
        width=cam.width,
        control_dim=len(ds.control_layout),
    )
    model = build_model(mcfg).to(cfg.device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    rng = np.random.default_rng(cfg.seed)
    gen = torch.Generator(device=cfg.device).manual_seed(cfg.seed)
    start, best = 0, math.inf
    if resume:
        blob = read_checkpoint(last)
        state = blob["train_state"]
        if state["config"] != asdict(cfg):
            diffs = differences(state["config"], asdict(cfg), old_has="the run has")
            raise ValueError(
                f"--resume with other settings than the run's ({'; '.join(diffs)}); "
                "use the original ones"
            )
        if blob["data_hash"] != data_hash:
            raise ValueError(
                f"--resume with other data than the run was trained on ({cfg.data} changed)"
            )
        model.load_state_dict(blob["state_dict"])
        opt.load_state_dict(state["optimizer"])
        rng.bit_generator.state = state["rng"]
        gen.set_state(state["torch_gen"])
        start, best = state["iteration"], state["best"]
        resumed_figures = blob["extra"]
        log = out / "metrics.jsonl"  # drop evaluations logged after the resumed checkpoint
        lines = [ln for ln in log.read_text().splitlines() if json.loads(ln)["iteration"] <= start]
        log.write_text("".join(ln + "\n" for ln in lines))
    else:
        out.mkdir(parents=True, exist_ok=True)
        fit_normalisation(model, ds, rng)
        (out / "metrics.jsonl").write_text("")
    val_idx = np.linspace(0, len(val) - 1, min(cfg.val_examples, len(val))).round().astype(int)
    model.train()

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
            }
        extra = {"iteration": it, "data": str(cfg.data), **figures}
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
        sigma, gamma = sharpening(it, cfg.iters, mcfg)
        b = {
            k: v.to(cfg.device) for k, v in ds.batch(rng.integers(len(ds), size=cfg.batch)).items()
        }
        pred = model(
            b["points"], b["u"][:, 0], b["valid"], sigma=sigma, gamma=gamma, generator=gen
        ).points
        loss = point_loss(pred, b["target"][:, 0], b["target_valid"][:, 0], b["points"])
        if not torch.isfinite(loss):
            raise TrainingDiverged(
                f"loss became {float(loss.detach())} at step {it + 1}; {last} keeps the last "
                f"good state (iteration {figures.get('iteration', start)}); lower --lr and --resume"
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
            figures = {
                "iteration": done,
                "train_loss": running / n_running,
                **validate(model, val, val_idx, cfg.batch, cfg.device),
                "sigma": sigma,
                "gamma": gamma,
                "lr": learning_rate(cfg, it),
                "elapsed_s": time.time() - t0,
            }
            running, n_running = 0.0, 0
            with open(out / "metrics.jsonl", "a") as f:
                f.write(json.dumps(figures) + "\n")
            if figures["val_flow_mse_cm2"] < best:
                best = figures["val_flow_mse_cm2"]
                checkpoint(out / "best.pt", done, figures, with_state=False)
            checkpoint(last, done, figures, with_state=True)
            if cfg.keep_every and done % cfg.keep_every == 0:
                checkpoint(out / f"iter_{done:06d}.pt", done, figures, with_state=False)
            bar.write(
                f"it {done}: train {figures['train_loss']:.4f}, val flow MSE "
                f"{figures['val_flow_mse_cm2']:.4f} cm^2 "
                f"(ratio to no-motion {figures['val_ratio']:.3f})"
            )
    bar.close()
    return figures
