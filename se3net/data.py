"""Reading push datasets: clouds, controls and exact targets for any horizon.

Targets are computed at load time from the stored associations (``sim.dataset``), so one
dataset serves every horizon h; splits are by episode (``sim.datastore.split_of``). Noise, as
in the paper's robustness study, is optional and off by default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from scenarios import NoiseConfig
from sim.camera import DepthCamera
from sim.dataset import CONTROL_LAYOUT
from sim.datastore import frame_cloud, load_episodes, read_manifest, scenario_of
from sim.shards import DataError

VISIBLE_DEPTH_TOL_M = 0.01
"""a target stays visible if the pixel it lands on sees the same part within this depth"""


class PushDataset(Dataset):
    """Examples ``(cloud at t, controls t..t+h-1) -> targets at t+1..t+h``.

    Args:
        root: dataset folder.
        split: ``"train"``, ``"val"`` or ``"test"``.
        horizon: h, the number of steps to predict (targets for every step 1..h).
        noise: depth and association noise (the scenario's ``NoiseConfig`` shape); None = off.
        seed: seed of the noise; item i's noise depends only on (seed, epoch, i).
        verify: check shard checksums.

    Each item is a dict of tensors:
        ``points`` (3,H,W) float32, the input cloud in the camera frame (m);
        ``valid`` (H,W) bool, input pixels that hit something;
        ``u`` (h,4) float32, per step: action (vx, vy) and pusher position (x, y) at its start;
        ``target`` (h,3,H,W) float32, where each input point is after 1..h steps;
        ``target_valid`` (h,H,W) bool, input points still visible after 1..h steps;
        ``part`` (H,W) int64, true segmentation (-1 none, 0 static, 1 pusher, 2+ objects),
        for evaluation only; ``episode``, ``t`` ints.
    """

    control_layout = CONTROL_LAYOUT

    def __init__(
        self,
        root: str | Path,
        *,
        split: str = "train",
        horizon: int = 1,
        noise: NoiseConfig | None = None,
        seed: int = 0,
        verify: bool = True,
    ):
        self.manifest = read_manifest(root)
        steps = self.manifest["identity"]["steps_per_episode"]
        if not 1 <= horizon <= steps:
            raise DataError(
                f"horizon {horizon} does not fit episodes of {steps} steps in {root}; "
                f"choose 1..{steps} or generate longer episodes (--steps-per-episode)"
            )
        self.scenario = scenario_of(self.manifest)
        self.camera = DepthCamera(self.scenario.camera)
        self.horizon, self.noise, self.seed, self.epoch = horizon, noise, seed, 0
        eps = load_episodes(root, split, verify=verify)
        self.a, self.episode_index = eps.arrays, eps.index
        lengths = self.a["length"].astype(int)
        self.items = np.array(
            [(e, t) for e in range(len(lengths)) for t in range(lengths[e] - horizon + 1)],
            dtype=np.int64,
        ).reshape(-1, 2)
        if len(self.items) == 0:
            raise DataError(f"split {split!r} of {root} has no examples of horizon {horizon}")

    def __len__(self) -> int:
        return len(self.items)

    def set_epoch(self, epoch: int) -> None:
        """Draw fresh noise in each epoch (noise depends on (seed, epoch, item))."""
        self.epoch = epoch

    def cloud(self, e: int, t: int, *, at: int | None = None) -> np.ndarray:
        """Frame t's points (3,H,W) placed with the parts' poses at frame ``at`` (default t)."""
        return frame_cloud(self.a, e, t, self.camera.T_cam_world, at=at)

    def _visible(self, target: np.ndarray, part: np.ndarray, e: int, t2: int) -> np.ndarray:
        """Which targets (3,H,W) land on a pixel of frame t2 that sees their part at their depth."""
        H, W = part.shape
        uv = np.floor(self.camera.project(np.moveaxis(target, 0, -1))).astype(int)
        inside = (
            (uv[..., 0] >= 0)
            & (uv[..., 0] < W)
            & (uv[..., 1] >= 0)
            & (uv[..., 1] < H)
            & (part >= 0)
        )
        u, v = np.clip(uv[..., 0], 0, W - 1), np.clip(uv[..., 1], 0, H - 1)
        seen = self.cloud(e, t2)[2][v, u]
        same = self.a["part"][e, t2][v, u] == part
        return inside & same & (np.abs(seen - target[2]) < VISIBLE_DEPTH_TOL_M)

    def __getitem__(self, i: int) -> dict[str, Any]:
        e, t = (int(x) for x in self.items[i])
        h = self.horizon
        part = self.a["part"][e, t]
        valid = part >= 0
        points = self.cloud(e, t)
        targets = np.stack([self.cloud(e, t, at=t + k) for k in range(1, h + 1)])
        target_valid = np.stack(
            [self._visible(targets[k - 1], part, e, t + k) for k in range(1, h + 1)]
        )
        if self.noise is not None:
            rng = np.random.default_rng([self.seed, self.epoch, i])
            points, targets, target_valid = apply_noise(
                points, targets, target_valid, valid, self.noise, rng
            )
        u = np.concatenate(
            [self.a["actions"][e, t : t + h], self.a["pusher_xy"][e, t : t + h]], axis=1
        )
        return {
            "points": torch.from_numpy(points.astype(np.float32)),
            "valid": torch.from_numpy(valid),
            "u": torch.from_numpy(u.astype(np.float32)),
            "target": torch.from_numpy(targets.astype(np.float32)),
            "target_valid": torch.from_numpy(target_valid),
            "part": torch.from_numpy(part.astype(np.int64)),
            "episode": int(self.episode_index[e]),
            "t": t,
        }


def _depth_noise(
    points: np.ndarray, valid: np.ndarray, noise: NoiseConfig, rng: np.random.Generator
) -> np.ndarray:
    """Move each valid point along its ray by Gaussian depth noise (SD scaled by depth if set)."""
    z = points[2]
    sd = noise.depth_sd_m * (np.abs(z) if noise.depth_sd_scaled else 1.0)
    z_new = z + rng.normal(size=z.shape) * sd
    scale = np.where(valid & (np.abs(z) > 1e-9), z_new / np.where(np.abs(z) > 1e-9, z, 1.0), 1.0)
    return points * scale


def apply_noise(
    points: np.ndarray,
    targets: np.ndarray,
    target_valid: np.ndarray,
    valid: np.ndarray,
    noise: NoiseConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The paper's robustness noise.

    Association noise (``assoc_window`` m > 1): each point's target is replaced by the target
    of a random pixel in the m x m window around it whose depth differs by at most
    ``assoc_depth_threshold_m`` (the point keeps its own target if the drawn pixel does not
    qualify). Depth noise (``depth_sd_m`` > 0): independent Gaussian noise along the rays of
    the input and of the targets.
    """
    H, W = valid.shape
    if noise.assoc_window > 1:
        r = noise.assoc_window // 2
        v, u = np.mgrid[0:H, 0:W]
        dv, du = rng.integers(-r, r + 1, size=(2, H, W))
        v2, u2 = np.clip(v + dv, 0, H - 1), np.clip(u + du, 0, W - 1)
        ok = (
            valid
            & valid[v2, u2]
            & (np.abs(points[2][v2, u2] - points[2]) <= noise.assoc_depth_threshold_m)
        )
        v2, u2 = np.where(ok, v2, v), np.where(ok, u2, u)
        targets = targets[:, :, v2, u2]
        target_valid = target_valid[:, v2, u2]
    if noise.depth_sd_m > 0:
        points = _depth_noise(points, valid, noise, rng)
        targets = np.stack([_depth_noise(tg, valid, noise, rng) for tg in targets])
    return points, targets, target_valid
