"""A pose-space model: the pushed object's planar pose rolled forward by a small network.

The SE3-Pose-Nets idea (Byravan et al., 2018) cut to what the planner uses: encode the scene
once, then roll poses, not clouds. The tracker's pose of the object stands in for the
encoder's poses (as ``PlanState`` already does for the SE3-Net), and the object's shape is
encoded once, from its observed points, as its *support function*: how far its footprint
reaches in each of ``DIRECTIONS`` directions of its own frame. Each step the network maps,
in the object's frame at the step's start,

    (pusher position, commanded pusher velocity, support function, gap now, gap after)
        -> (dx, dy, dyaw) of the object over the step,

where a gap is the pusher's distance from the object's centre less the support function
toward it and the pusher's radius (``_reach``: a distance to the surface along a face's
normal, a feature elsewhere). A rollout of H candidates' steps is H small matrix products,
so a 1.2 s plan costs far less than one pass of the SE3-Net's convolutions.

Trained on the same exploration data as the SE3-Net (``sim.dataset``: the parts' poses, the
pusher's path and each frame's points in their part's frame), on rollouts of ``horizon``
steps fed back through the network, the pusher's path integrated from the commands as the
planner integrates it (``se3net.rollout.pusher_path``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from scenarios import InputError, check_seed
from se3net.rollout import pusher_path
from sim.folders import writes_folder
from sim.planar import wrap_angle

POSE_VARIANT = "pose"
DIRECTIONS = 16
"""directions of the support function (evenly spaced over the turn)"""
YAW_RADIUS_M = 0.05
"""a yaw error counts as the arc it sweeps at this radius (the loss and the scale)"""
STEP_SCALE = torch.tensor([0.01, 0.01, 0.1])
"""the network's output units: 1 cm, 1 cm, 0.1 rad a step"""


@dataclass(frozen=True)
class PoseModelConfig:
    """A pose model's size, and the pusher and control step it was trained for (stored in its
    checkpoint, as ``se3net.model.ModelConfig`` is for the cloud networks)."""

    variant: str = POSE_VARIANT
    """what tells a pose checkpoint from a cloud network's"""
    hidden: int = 128
    """width of the hidden layers"""
    layers: int = 3
    """hidden layers"""
    pusher_radius_m: float = 0.01
    """the pusher's radius (the gaps are to its surface)"""
    dt_s: float = 0.15
    """the control step"""

    def to_dict(self) -> dict:
        return asdict(self)


def support_function(xy: torch.Tensor, fallback_m: float) -> torch.Tensor:
    """(DIRECTIONS,) the furthest reach of points ``xy`` (N,2, object frame) along each
    direction: their support function; every direction ``fallback_m`` for fewer than 3
    points (an object out of sight)."""
    if len(xy) < 3:
        return torch.full((DIRECTIONS,), float(fallback_m), dtype=torch.float32)
    a = torch.arange(DIRECTIONS, dtype=xy.dtype) * (2 * math.pi / DIRECTIONS)
    d = torch.stack([a.cos(), a.sin()], 1)  # (D,2)
    return (xy @ d.T).amax(0).float()


def _reach(support: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """(...) the footprint's reach toward ``rel`` (...,2): the support function interpolated
    at its angle. It is the footprint's radial extent only where the support point lies on
    the ray (a box's face normals); elsewhere it is further (a 10 x 5 cm box: 5.3 cm at 45
    degrees, where its edge is 3.5 cm away), so a gap is a feature the network learns to read,
    not a distance."""
    angle = torch.atan2(rel[..., 1], rel[..., 0]) % (2 * math.pi)
    pos = angle / (2 * math.pi / DIRECTIONS)
    i0 = pos.floor().long() % DIRECTIONS
    w = pos - pos.floor()
    s0 = support.gather(-1, i0[..., None])[..., 0]
    s1 = support.gather(-1, ((i0 + 1) % DIRECTIONS)[..., None])[..., 0]
    return s0 * (1 - w) + s1 * w


def rotate(v: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Planar vectors (...,2) turned by ``yaw`` (...)."""
    c, s = yaw.cos(), yaw.sin()
    return torch.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)


class PoseModel(nn.Module):
    """The step network and its rollout (see the module's docstring)."""

    def __init__(self, cfg: PoseModelConfig):
        super().__init__()
        self.cfg = cfg
        n_in = 2 + 2 + DIRECTIONS + 2
        layers: list[nn.Module] = []
        for _ in range(cfg.layers):
            layers += [nn.Linear(n_in, cfg.hidden), nn.SiLU()]
            n_in = cfg.hidden
        out = nn.Linear(n_in, 3)
        nn.init.zeros_(out.weight)  # starts predicting no motion
        nn.init.zeros_(out.bias)
        self.net = nn.Sequential(*layers, out)

    def step(
        self, pose: torch.Tensor, pusher: torch.Tensor, velocity: torch.Tensor,
        support: torch.Tensor,
    ) -> torch.Tensor:  # fmt: skip
        """(B,3) the pose after one step from ``pose`` (B,3, world), with the pusher at
        ``pusher`` (B,2) commanded at ``velocity`` (B,2), for footprints ``support`` (B,D)."""
        rel = rotate(pusher - pose[:, :2], -pose[:, 2])
        vel = rotate(velocity, -pose[:, 2])
        after = rel + vel * self.cfg.dt_s
        r = self.cfg.pusher_radius_m
        gap_now = rel.norm(dim=-1) - _reach(support, rel) - r
        gap_after = after.norm(dim=-1) - _reach(support, after) - r
        x = torch.cat(
            [rel / 0.1, vel / 0.1, support / 0.1, gap_now[:, None] / 0.01,
             gap_after[:, None] / 0.01], 1,
        )  # fmt: skip
        d = self.net(x) * STEP_SCALE.to(x)
        xy = pose[:, :2] + rotate(d[:, :2], pose[:, 2])
        return torch.cat([xy, pose[:, 2:] + d[:, 2:]], 1)

    def rollout(
        self, pose: torch.Tensor, pusher_xy: torch.Tensor, actions: torch.Tensor,
        support: torch.Tensor,
    ) -> torch.Tensor:  # fmt: skip
        """(B,H,3) the poses after each of H steps of ``actions`` (B,H,2) from ``pose`` (B or
        1, 3), the pusher starting at ``pusher_xy`` (B or 1, 2) and following its commands."""
        B, H, _ = actions.shape
        path = pusher_path(actions, pusher_xy, self.cfg.dt_s)  # after each step
        start = pusher_xy.to(actions).expand(B, 2)
        pose, support = pose.expand(B, 3), support.expand(B, -1)
        out = []
        for h in range(H):
            at = start if h == 0 else path[:, h - 1]
            pose = self.step(pose, at, actions[:, h], support)
            out.append(pose)
        return torch.stack(out, 1)


# --------------------------------------------------------------------------- training data
@dataclass
class Windows:
    """Rollout windows of exploration data, one object each."""

    pose: torch.Tensor  # (N,H+1,3) the object's poses, the first the start
    pusher: torch.Tensor  # (N,2) the pusher's position at the start
    actions: torch.Tensor  # (N,H,2)
    support: torch.Tensor  # (N,D) from the first frame's points

    def __len__(self) -> int:
        return len(self.pose)


def windows(folders: list[str], split: str, horizon: int) -> Windows:
    """Every ``horizon``-step window of every object of every episode of a split."""
    from sim.datastore import load_episodes
    from sim.world import object_part

    pose, pusher, actions, support = [], [], [], []
    for folder in folders:
        a = load_episodes(folder, split).arrays
        for e in range(len(a["length"])):
            n_steps = int(a["length"][e])
            for i in range(int(a["n_objects"][e])):
                radius = 0.5 * float(np.hypot(*a["object_size"][e, i, :2]))
                for t in range(0, n_steps - horizon + 1):
                    seen = a["part"][e, t] == object_part(i)
                    xy = torch.from_numpy(a["points_part"][e, t][:2, seen].T.astype(np.float64))
                    support.append(support_function(xy, radius))
                    pose.append(a["object_poses"][e, t : t + horizon + 1, i])
                    pusher.append(a["pusher_xy"][e, t])
                    actions.append(a["actions"][e, t : t + horizon])
    if not pose:
        raise InputError(f"no {horizon}-step windows in {', '.join(folders)} ({split}): make "
                         f"data with --steps-per-episode {horizon} or more, and enough episodes "
                         "for every split")  # fmt: skip
    f = lambda x: torch.from_numpy(np.asarray(x)).float()  # noqa: E731
    return Windows(f(pose), f(pusher), f(actions), torch.stack(support))


def pose_loss(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """Mean squared pose error over a rollout: position (m) and yaw as its arc at
    ``YAW_RADIUS_M``."""
    d = pred - true
    yaw = wrap_angle(d[..., 2])
    return ((d[..., :2] ** 2).sum(-1) + (YAW_RADIUS_M * yaw) ** 2).mean()


def rollout_error(
    model: PoseModel, w: Windows, pred: torch.Tensor | None = None
) -> dict[str, float]:
    """Mean position error (mm) after the first and last step of the windows, the model's
    and predicting no motion's; ``pred``: the model's rollout of them, where already made."""
    if pred is None:
        with torch.no_grad():
            pred = model.rollout(w.pose[:, 0], w.pusher, w.actions, w.support)
    err = (pred[..., :2] - w.pose[:, 1:, :2]).norm(dim=-1)
    still = (w.pose[:, :1, :2] - w.pose[:, 1:, :2]).norm(dim=-1)
    return {"first_mm": 1e3 * float(err[:, 0].mean()), "last_mm": 1e3 * float(err[:, -1].mean()),
            "still_first_mm": 1e3 * float(still[:, 0].mean()),
            "still_last_mm": 1e3 * float(still[:, -1].mean())}  # fmt: skip


@writes_folder(lambda a: a.arguments["out"])
def train_pose_model(
    data: list[str], out: str | Path, *, iters: int = 6000, batch: int = 256, lr: float = 1e-3,
    horizon: int = 8, seed: int = 0, progress: bool = True,
) -> dict[str, Any]:  # fmt: skip
    """Train a pose model on ``data`` (exploration folders of pusher controls, one arm and
    control step; the scenario of the first), validated every 500 steps; writes
    ``out``/best.pt, the weights of the lowest validation loss, and returns their metrics.
    It holds ``out`` while it runs (``sim.folders.exclusive``)."""
    from tqdm import tqdm

    from se3net.checkpoint import manifest_hash, save_checkpoint
    from se3net.data import poolable_manifests
    from se3net.train import TrainingDiverged
    from sim.controls import PUSHER_LAYOUT, control_layout
    from sim.datastore import scenario_of

    for name, value in (("iters", iters), ("batch", batch), ("lr", lr)):
        if not value > 0:
            raise InputError(f"--{name} must be positive, got {value}")
    check_seed(seed)
    out = Path(out)
    if (out / "best.pt").exists():
        raise InputError(f"{out} holds a run already; choose another --out (a pose model "
                         "trains from scratch in minutes)")  # fmt: skip
    torch.manual_seed(seed)
    manifests = poolable_manifests(data)
    scenario = scenario_of(manifests[0])
    if control_layout(scenario) != PUSHER_LAYOUT:
        raise InputError(f"{data[0]} holds data of joint-velocity controls; a pose model takes "
                         "pusher velocities")  # fmt: skip
    radii = {scenario_of(m).arm.pusher_radius_m for m in manifests}
    if len(radii) > 1:  # the arm is not in the fingerprint: the gaps are to the pusher's surface
        raise InputError(f"{', '.join(data)} were recorded with pushers of radii "
                         f"{sorted(radii)}; pool folders of one pusher")  # fmt: skip
    cfg = PoseModelConfig(pusher_radius_m=scenario.arm.pusher_radius_m,
                          dt_s=scenario.action.dt_control_s)  # fmt: skip
    train, val = windows(data, "train", horizon), windows(data, "val", horizon)
    model = PoseModel(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, iters, eta_min=0.05 * lr)
    gen = torch.Generator().manual_seed(seed)
    best = math.inf
    data_hash = "+".join(manifest_hash(m) for m in manifests)
    for it in tqdm(range(1, iters + 1), disable=not progress, desc="pose model"):
        idx = torch.randint(len(train), (batch,), generator=gen)
        pred = model.rollout(train.pose[idx, 0], train.pusher[idx], train.actions[idx],
                             train.support[idx])  # fmt: skip
        loss = pose_loss(pred, train.pose[idx, 1:])
        if not torch.isfinite(loss):
            raise TrainingDiverged(f"the loss is {loss.item()} at step {it}; nothing was "
                                   "written: run again with a lower --lr")  # fmt: skip
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if it % 500 == 0 or it == iters:
            with torch.no_grad():
                seen = model.rollout(val.pose[:, 0], val.pusher, val.actions, val.support)
            v = float(pose_loss(seen, val.pose[:, 1:]))
            if not math.isfinite(v):  # training's loss was finite, the validation's is not
                raise TrainingDiverged(f"the validation loss is {v} at step {it}; nothing was "
                                       "written: run again with a lower --lr")  # fmt: skip
            if v < best:
                best = v
                metrics = {"iteration": it, "val_loss": v, **rollout_error(model, val, seen)}
                kept = copy.deepcopy(model.state_dict())
    # written once, at the end: an interrupted run leaves no run behind, and runs again whole
    model.load_state_dict(kept)
    save_checkpoint(out / "best.pt", model, scenario=scenario, data_hash=data_hash,
                    extra={"metrics": metrics, "horizon": horizon})  # fmt: skip
    return metrics


def load_pose_model(blob: dict[str, Any]) -> PoseModel:
    """The pose model of a checkpoint's contents (``se3net.checkpoint.read_checkpoint``)."""
    fields = {k: v for k, v in blob["model"].items() if k != "variant"}
    model = PoseModel(PoseModelConfig(**fields))
    model.load_state_dict(blob["state_dict"])
    return model.eval().requires_grad_(False)
