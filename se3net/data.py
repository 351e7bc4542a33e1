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

from scenarios import InputError, NoiseConfig
from scenarios.config import differences, scenario_fingerprint
from se3net.device import check_device
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


PAPER_NOISE: dict[str, NoiseConfig | None] = {
    "none": None,
    "depth-scaled": NoiseConfig(
        depth_sd_m=0.0075, depth_sd_scaled=True, assoc_window=0, assoc_depth_threshold_m=0.1
    ),
    "depth": NoiseConfig(
        depth_sd_m=0.015, depth_sd_scaled=False, assoc_window=0, assoc_depth_threshold_m=0.1
    ),
    "assoc-9": NoiseConfig(
        depth_sd_m=0.0, depth_sd_scaled=False, assoc_window=9, assoc_depth_threshold_m=0.10
    ),
    "assoc-15": NoiseConfig(
        depth_sd_m=0.0, depth_sd_scaled=False, assoc_window=15, assoc_depth_threshold_m=0.20
    ),
    "assoc-3": NoiseConfig(
        depth_sd_m=0.0, depth_sd_scaled=False, assoc_window=3, assoc_depth_threshold_m=0.20
    ),
}
"""The paper's robustness noises (its Table 2), by name (``--noise``): depth noise of SD
0.75 cm scaled by the depth in metres, or 1.5 cm unscaled; association noise in 9x9 (within
10 cm of depth) and 15x15 (within 20 cm) pixel windows. The windows are the paper's in pixels;
at 64x64 a pixel spans about 5x more of the scene than at the paper's 320x240, so ``assoc-3``
is the 15x15 window scaled to 64x64 (3x3, within 20 cm)."""


def paper_noise(name: str) -> NoiseConfig | None:
    """The noise ``PAPER_NOISE`` names (None for ``none``).

    Raises:
        InputError: no such name; the message lists them.
    """
    if name not in PAPER_NOISE:
        raise InputError(f"--noise must be one of {', '.join(PAPER_NOISE)}, got {name!r}")
    return PAPER_NOISE[name]


IMAGE_KEYS = ("points", "valid", "target", "target_valid", "true_flow_m", "part")
"""the keys of a ``PushDataset`` batch that are images (the rest are per example)"""


def subsample_batch(b: dict[str, Any], stride: int) -> dict[str, Any]:
    """A batch with its images subsampled (``subsample``)."""
    return {k: subsample(v, stride) if k in IMAGE_KEYS else v for k, v in b.items()}


def poolable_manifests(roots: Sequence[str | Path]) -> list[dict]:
    """The manifests of dataset folders that can be pooled: one episode length, control
    layout, camera and action settings (other objects are welcome: that is what a generalist
    is trained on); else a DataError naming the first two that differ."""
    if not roots:
        raise DataError("no dataset folder given")
    manifests = [read_manifest(r) for r in roots]
    first = scenario_fingerprint(scenario_of(manifests[0]))
    for r, m in zip(roots[1:], manifests[1:], strict=True):
        for key in ("steps_per_episode", "control_layout"):
            if m["identity"][key] != manifests[0]["identity"][key]:
                raise DataError(
                    f"{r} and {roots[0]} differ in {key}; only datasets of one episode "
                    "length and control layout can be pooled"
                )
        diffs = differences(first, scenario_fingerprint(scenario_of(m)), old_has=str(roots[0]),
                            new_has=str(r))  # fmt: skip
        if diffs:
            raise DataError(
                f"{r} and {roots[0]} were recorded with other cameras or actions "
                f"({'; '.join(diffs[:3])}); only such data can be pooled"
            )
    return manifests


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
        device: where batches are assembled and returned: the recorded clouds and poses are
            held there, so on a GPU a batch's targets and visibility cost a fraction of what
            they cost on the CPU (training on ``cuda``). The figures are the same.

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
        ``true_flow_m`` (h,H,W) float32, how far each input point truly moves in 1..h steps,
        from the noise-free cloud and targets: which points move does not depend on the
        noise (``se3net.metrics.moving_points``);
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
        device: str | torch.device = "cpu",
    ):
        roots = [root] if isinstance(root, str | Path) else list(root)
        self.manifests = poolable_manifests(roots)
        self.manifest = self.manifests[0]
        self.scenario = scenario_of(self.manifest)
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
        self.device = check_device(device)
        # what batches are assembled from, on the device (on the CPU, views of the arrays);
        # the camera-frame part poses of every frame at once: the same float64 product a
        # batch took of its own rows
        T_cam_part = self._T_cam_world @ self.a["T_world_part"]  # (E,F,P,4,4)
        self._T_cam_part = torch.from_numpy(T_cam_part).float().to(self.device)
        self._part = torch.from_numpy(self.a["part"]).to(self.device)  # (E,F,H,W) int8
        self._points_part = torch.from_numpy(self.a["points_part"]).to(self.device)

    def __len__(self) -> int:
        return len(self.items)

    def set_epoch(self, epoch: int) -> None:
        """Draw fresh noise in each epoch (noise depends on (seed, epoch, item))."""
        self.epoch = epoch

    def _rows(self, *xs: np.ndarray) -> tuple[torch.Tensor, ...]:
        return tuple(torch.as_tensor(x, dtype=torch.int64, device=self.device) for x in xs)

    def clouds(self, e: np.ndarray, t: np.ndarray, at: np.ndarray | None = None) -> torch.Tensor:
        """Frame t's points (B,3,H,W) of episode rows e, placed with the parts' poses at frame
        ``at`` (default t): the observed clouds, or their exact targets after ``at - t`` steps."""
        e, t, at = self._rows(e, t, t if at is None else at)
        T = self._T_cam_part[e, at]  # (B,P,4,4)
        part = self._part[e, t].long()  # (B,H,W)
        p = self._points_part[e, t].float()  # (B,3,H,W)
        B, _, H, W = p.shape
        # every part's motion of every point, then each point's own part's (P is small): the
        # same products as gathering a transform per pixel, at about half the cost
        y = T[:, :, :3, :3] @ p.reshape(B, 1, 3, H * W) + T[:, :, :3, 3, None]  # (B,P,3,N)
        own = part.clamp_min(0).reshape(B, 1, 1, H * W).expand(B, 1, 3, H * W)
        y = y.gather(1, own).reshape(B, 3, H, W)
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
        b = torch.arange(B, device=self.device)[:, None, None]
        seen = self.clouds(e, t2)[:, 2][b, v, u]
        er, tr = self._rows(e, t2)
        same = self._part[er, tr].long()[b, v, u] == part
        return inside & same & ((seen - target[:, 2]).abs() < VISIBLE_DEPTH_TOL_M)

    def batch(self, indices: np.ndarray | list[int]) -> dict[str, Any]:
        """Items ``indices`` stacked into a batch (vectorised; see the class doc for keys).

        ``u`` is (B,h,n), ``actions`` (B,h,c), ``state`` (B,s), ``target`` (B,h,3,H,W),
        ``target_valid`` (B,h,H,W)."""
        idx = np.asarray(indices, dtype=np.int64)
        e, t = self.items[idx, 0], self.items[idx, 1]
        h = self.horizon
        part = self._part[self._rows(e, t)].long()
        valid = part >= 0
        points = self.clouds(e, t)
        targets = torch.stack([self.clouds(e, t, t + k) for k in range(1, h + 1)], 1)
        target_valid = torch.stack(
            [self._visible(targets[:, k - 1], part, e, t + k) for k in range(1, h + 1)], 1
        )
        true_flow = (targets - points[:, None]).norm(dim=2)  # before the noise
        if self.noise is not None:
            rngs = [np.random.default_rng([self.seed, self.epoch, int(i)]) for i in idx]
            points, targets, target_valid = apply_noise(
                points, targets, target_valid, valid, self.noise, rngs
            )
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
            "u": torch.from_numpy(u).float().to(self.device),
            "actions": torch.from_numpy(actions).float().to(self.device),
            "state": torch.from_numpy(state).float().to(self.device),
            "target": targets,
            "target_valid": target_valid,
            "true_flow_m": true_flow,
            "part": part,
            "episode": torch.from_numpy(self.episode_index[e]).to(self.device),
            "t": torch.from_numpy(t).to(self.device),
        }
        return subsample_batch(full, self.stride)  # visibility judged at the camera's resolution

    def __getitem__(self, i: int) -> dict[str, Any]:
        item = {k: v[0] for k, v in self.batch([i]).items()}
        item["episode"], item["t"] = int(item["episode"]), int(item["t"])
        return item


def _depth_noise(
    points: torch.Tensor, valid: torch.Tensor, eps: torch.Tensor, noise: NoiseConfig
) -> torch.Tensor:
    """Move each valid point of (B,3,H,W) along its ray by depth noise ``eps`` (B,H,W) standard
    normal draws, times the SD (scaled by the depth if set)."""
    z = points[:, 2]
    sd = noise.depth_sd_m * (z.abs() if noise.depth_sd_scaled else 1.0)
    z_new = z + eps * sd
    nonzero = z.abs() > 1e-9
    scale = torch.where(valid & nonzero, z_new / torch.where(nonzero, z, 1.0), 1.0)
    return points * scale[:, None]


def apply_noise(
    points: torch.Tensor,
    targets: torch.Tensor,
    target_valid: torch.Tensor,
    valid: torch.Tensor,
    noise: NoiseConfig,
    rngs: Sequence[np.random.Generator],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The paper's robustness noise on a batch: points (B,3,H,W), targets (B,h,3,H,W),
    target_valid (B,h,H,W), valid (B,H,W); ``rngs`` one generator an item, which alone draws
    that item's noise (so it does not depend on the batch it is in).

    Association noise (``assoc_window`` m > 1): each point's target is replaced by the target
    of a random pixel in the m x m window around it whose depth differs by at most
    ``assoc_depth_threshold_m`` (the point keeps its own target if the drawn pixel does not
    qualify). Depth noise (``depth_sd_m`` > 0): independent Gaussian noise along the rays of
    the input and of the targets.
    """
    B, h, _, H, W = targets.shape
    dev = points.device
    r = noise.assoc_window // 2 if noise.assoc_window > 1 else 0
    shifts, eps = [], []
    for rng in rngs:  # each item's draws in one order: window offsets, then depth noise
        if r:
            shifts.append(rng.integers(-r, r + 1, size=(2, H, W)))
        if noise.depth_sd_m > 0:
            eps.append(rng.normal(size=(1 + h, H, W)))
    if r:
        d = torch.from_numpy(np.stack(shifts)).to(dev)  # (B,2,H,W)
        v = torch.arange(H, device=dev)[:, None].expand(B, H, W)
        u = torch.arange(W, device=dev)[None].expand(B, H, W)
        v2, u2 = (v + d[:, 0]).clamp(0, H - 1), (u + d[:, 1]).clamp(0, W - 1)
        b = torch.arange(B, device=dev)[:, None, None]
        z = points[:, 2]
        ok = valid & valid[b, v2, u2] & ((z[b, v2, u2] - z).abs() <= noise.assoc_depth_threshold_m)
        v2, u2 = torch.where(ok, v2, v), torch.where(ok, u2, u)
        targets = targets[b, :, :, v2, u2].permute(0, 3, 4, 1, 2)  # (B,H,W,h,3) -> (B,h,3,H,W)
        target_valid = target_valid[b, :, v2, u2].permute(0, 3, 1, 2)
    if noise.depth_sd_m > 0:
        e = torch.from_numpy(np.stack(eps)).to(points)  # (B,1+h,H,W)
        points = _depth_noise(points, valid, e[:, 0], noise)
        targets = torch.stack(
            [_depth_noise(targets[:, k], valid, e[:, 1 + k], noise) for k in range(h)], 1
        )
    return points, targets.contiguous(), target_valid.contiguous()
