"""Reading push datasets: clouds, controls and exact targets for any horizon.

Targets are computed at load time from the stored associations (``sim.dataset``), so one
dataset serves every horizon h; splits are by episode (``sim.datastore.split_of``). Noise, as
in the paper's robustness study, is optional and off by default.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from scenarios import NoiseConfig
from scenarios.config import differences, scenario_fingerprint
from sim.camera import DepthCamera
from sim.controls import layout_named
from sim.dataset import with_shape_details
from sim.datastore import load_episodes, read_manifest, scenario_of
from sim.shards import DataError

VISIBLE_DEPTH_TOL_M = 0.01
"""a target stays visible if the pixel it lands on sees the same part within this depth"""


def evenly_spaced(n: int, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` items spread evenly over ``n`` (all of them if fewer)."""
    return np.linspace(0, n - 1, min(n, limit)).round().astype(int)


def subsample(x: torch.Tensor, stride: int) -> torch.Tensor:
    """Every ``stride``-th pixel of an image-shaped tensor (..., H, W) in each direction: what
    a planning-resolution model (``ModelConfig.stride``) sees of a camera image. Pixels keep
    their identity, so associations and targets stay exact."""
    return x if stride == 1 else x[..., ::stride, ::stride].contiguous()


IMAGE_KEYS = ("points", "valid", "target", "target_valid", "part")
"""the keys of a ``PushDataset`` batch that are images (the rest are per example)"""


def subsample_batch(b: dict[str, Any], stride: int) -> dict[str, Any]:
    """A batch with its images subsampled (``subsample``)."""
    return {k: subsample(v, stride) if k in IMAGE_KEYS else v for k, v in b.items()}


class PushDataset(Dataset):
    """Examples ``(cloud at t, controls t..t+h-1) -> targets at t+1..t+h``.

    Args:
        root: dataset folder, or several (say exploration data and planner-visited data from
            ``se3push improve``): their episodes are pooled; they must share the scenario
            and the episode length.
        split: ``"train"``, ``"val"``, ``"test"``, or ``"all"`` (every episode: a dataset
            made to be held out).
        horizon: h, the number of steps to predict (targets for every step 1..h).
        noise: depth and association noise (the scenario's ``NoiseConfig`` shape); None = off.
        seed: seed of the noise; item i's noise depends only on (seed, epoch, i).
        verify: check shard checksums.
        stride: give every stride-th pixel of the camera's image in each direction
            (``subsample``), for a planning-resolution model.

    Each item is a dict of tensors:
        ``points`` (3,H,W) float32, the input cloud in the camera frame (m);
        ``valid`` (H,W) bool, input pixels that hit something;
        ``u`` (h,n) float32, per step: the controls (``control_layout``): the action (vx, vy)
        and the pusher position (x, y) at its start, or the 4 joint velocities;
        ``actions`` (h,c) float32, the commanded part of ``u``; ``state`` (s,) float32, the
        rest of ``u`` at the first step (the pusher position; empty for joint velocities), from
        which a rollout integrates the later steps' (``se3net.rollout``);
        ``target`` (h,3,H,W) float32, where each input point is after 1..h steps;
        ``target_valid`` (h,H,W) bool, input points still visible after 1..h steps;
        ``part`` (H,W) int64, true segmentation (-1 none, 0 static, 1 pusher, 2+ objects),
        for evaluation only; ``episode``, ``t`` ints.

    Attributes:
        control_layout: the names of the entries of ``u`` (``sim.controls``), as the
            manifest records them.
    """

    def __init__(
        self,
        root: str | Path | Sequence[str | Path],
        *,
        split: str = "train",
        horizon: int = 1,
        noise: NoiseConfig | None = None,
        seed: int = 0,
        verify: bool = True,
        stride: int = 1,
    ):
        roots = [root] if isinstance(root, str | Path) else list(root)
        if not roots:
            raise DataError("no dataset folder given")
        self.manifests = [read_manifest(r) for r in roots]
        self.manifest = self.manifests[0]
        self.scenario = scenario_of(self.manifest)
        first = scenario_fingerprint(self.scenario)
        for r, m in zip(roots[1:], self.manifests[1:], strict=True):
            for key in ("steps_per_episode", "control_layout"):
                if m["identity"][key] != self.manifest["identity"][key]:
                    raise DataError(
                        f"{r} and {roots[0]} differ in {key}; only datasets of one episode "
                        "length and control layout can be pooled"
                    )
            diffs = differences(first, scenario_fingerprint(scenario_of(m)), old_has=str(roots[0]),
                                new_has=str(r))  # fmt: skip
            if diffs:  # other objects are welcome: that is what a generalist is trained on
                raise DataError(
                    f"{r} and {roots[0]} were recorded with other cameras or actions "
                    f"({'; '.join(diffs[:3])}); only such data can be pooled"
                )
        self.control_layout = tuple(self.manifest["identity"]["control_layout"])
        self.layout = layout_named(self.control_layout)
        if self.layout is None:
            raise DataError(
                f"{roots[0]} holds controls {list(self.control_layout)}, which this code does not "
                "know; regenerate it with `se3push data`"
            )
        steps = self.manifest["identity"]["steps_per_episode"]
        if not 1 <= horizon <= steps:
            raise DataError(
                f"horizon {horizon} does not fit episodes of {steps} steps in {root}; "
                f"choose 1..{steps} or generate longer episodes (--steps-per-episode)"
            )
        cam = self.scenario.camera
        if stride < 1 or cam.height % stride or cam.width % stride:
            raise DataError(
                f"stride {stride} does not divide the {cam.width}x{cam.height} images of {root}; "
                "choose a positive divisor of both"
            )
        self.stride = stride
        self.camera = DepthCamera(cam)
        self._T_cam_world = self.camera.T_cam_world
        self.horizon, self.noise, self.seed, self.epoch = horizon, noise, seed, 0
        parts = [load_episodes(r, split, verify=verify) for r in roots]
        arrays = [p.arrays if len(parts) == 1 else with_shape_details(p.arrays) for p in parts]
        self.a = {k: np.concatenate([a[k] for a in arrays]) for k in arrays[0]}
        self.episode_index = np.concatenate([p.index for p in parts])
        lengths = self.a["length"].astype(int)
        source = np.repeat(np.arange(len(parts)), [len(p.index) for p in parts])
        self.items = np.array(
            [(e, t) for e in range(len(lengths)) for t in range(lengths[e] - horizon + 1)],
            dtype=np.int64,
        ).reshape(-1, 2)
        if len(self.items) == 0:
            raise DataError(f"split {split!r} of {root} has no examples of horizon {horizon}")
        self.source = source[self.items[:, 0]]
        """per item, which of the dataset folders it comes from (0: the first)"""

    def __len__(self) -> int:
        return len(self.items)

    def set_epoch(self, epoch: int) -> None:
        """Draw fresh noise in each epoch (noise depends on (seed, epoch, item))."""
        self.epoch = epoch

    def clouds(self, e: np.ndarray, t: np.ndarray, at: np.ndarray | None = None) -> torch.Tensor:
        """Frame t's points (B,3,H,W) of episode rows e, placed with the parts' poses at frame
        ``at`` (default t): the observed clouds, or their exact targets after ``at - t`` steps."""
        at = t if at is None else at
        T = torch.from_numpy(self._T_cam_world @ self.a["T_world_part"][e, at]).float()  # (B,P,4,4)
        part = torch.from_numpy(self.a["part"][e, t].astype(np.int64))  # (B,H,W)
        p = torch.from_numpy(self.a["points_part"][e, t]).float()  # (B,3,H,W)
        idx = part.clamp_min(0)
        Tp = T[torch.arange(len(e))[:, None, None], idx]  # (B,H,W,4,4)
        y = torch.einsum("bhwij,bjhw->bihw", Tp[..., :3, :3], p) + Tp[..., :3, 3].permute(
            0, 3, 1, 2
        )
        return y * (part >= 0)[:, None]

    def _visible(
        self, target: torch.Tensor, part: torch.Tensor, e: np.ndarray, t2: np.ndarray
    ) -> torch.Tensor:
        """Which targets (B,3,H,W) land on a pixel of frame t2 that sees their part at their
        depth."""
        B, H, W = part.shape
        K = self.camera.K
        z = target[:, 2].clamp_min(1e-6)
        u = torch.floor(target[:, 0] / z * K[0, 0] + K[0, 2]).long()
        v = torch.floor(target[:, 1] / z * K[1, 1] + K[1, 2]).long()
        inside = (u >= 0) & (u < W) & (v >= 0) & (v < H) & (part >= 0)
        u, v = u.clamp(0, W - 1), v.clamp(0, H - 1)
        b = torch.arange(B)[:, None, None]
        seen = self.clouds(e, t2)[:, 2][b, v, u]
        same = torch.from_numpy(self.a["part"][e, t2].astype(np.int64))[b, v, u] == part
        return inside & same & ((seen - target[:, 2]).abs() < VISIBLE_DEPTH_TOL_M)

    def batch(self, indices: np.ndarray | list[int]) -> dict[str, Any]:
        """Items ``indices`` stacked into a batch (vectorised; see the class doc for keys).

        ``u`` is (B,h,n), ``actions`` (B,h,c), ``state`` (B,s), ``target`` (B,h,3,H,W),
        ``target_valid`` (B,h,H,W)."""
        idx = np.asarray(indices, dtype=np.int64)
        e, t = self.items[idx, 0], self.items[idx, 1]
        h = self.horizon
        part = torch.from_numpy(self.a["part"][e, t].astype(np.int64))
        valid = part >= 0
        points = self.clouds(e, t)
        targets = torch.stack([self.clouds(e, t, t + k) for k in range(1, h + 1)], 1)
        target_valid = torch.stack(
            [self._visible(targets[:, k - 1], part, e, t + k) for k in range(1, h + 1)], 1
        )
        if self.noise is not None:
            for n, i in enumerate(idx):
                rng = np.random.default_rng([self.seed, self.epoch, int(i)])
                pt, tg = points[n].double().numpy(), targets[n].double().numpy()
                tv, va = target_valid[n].numpy(), valid[n].numpy()
                noisy = apply_noise(pt, tg, tv, va, self.noise, rng)
                points[n], targets[n], target_valid[n] = (torch.from_numpy(x) for x in noisy)
        steps = t[:, None] + np.arange(h)
        actions = self.a["actions"][e[:, None], steps]
        key = self.layout.state_key  # the integrated state's record, if the controls have one
        if key is None:
            state, u = np.zeros((len(e), 0)), actions
        else:
            state = self.a[key][e, t]
            u = np.concatenate([actions, self.a[key][e[:, None], steps]], -1)
        full = {
            "points": points,
            "valid": valid,
            "u": torch.from_numpy(u).float(),
            "actions": torch.from_numpy(actions).float(),
            "state": torch.from_numpy(state).float(),
            "target": targets,
            "target_valid": target_valid,
            "part": part,
            "episode": torch.from_numpy(self.episode_index[e]),
            "t": torch.from_numpy(t),
        }
        return subsample_batch(full, self.stride)  # visibility judged at the camera's resolution

    def __getitem__(self, i: int) -> dict[str, Any]:
        item = {k: v[0] for k, v in self.batch([i]).items()}
        item["episode"], item["t"] = int(item["episode"]), int(item["t"])
        return item


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
