"""A look at the world: depth, segmentation and one step's ground-truth flow, as a PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenarios import load_scenario
from sim.world import Observation, PushWorld

MOVED_M = 1e-3


def push_toward_object(world: PushWorld, obs: Observation, rng: np.random.Generator) -> np.ndarray:
    """An action aimed from the pusher at a random object's centre, with a noisy heading, at
    a random speed between half and full bound."""
    target = obs.object_poses[int(rng.integers(len(obs.object_poses))), :2]
    heading = np.arctan2(*(target - obs.pusher_xy_m)[::-1]) + rng.normal(0.0, 0.15)
    speed = world.scenario.action.max_speed_m_s * rng.uniform(0.5, 1.0)
    bound = world.scenario.action.max_speed_m_s
    return np.clip(speed * np.array([np.cos(heading), np.sin(heading)]), -bound, bound)


def render_scene(scenario: str, seed: int, out: str | Path, *, max_steps: int = 40) -> dict:
    """Reset ``scenario`` with ``seed``, push toward an object until it moves (at most
    ``max_steps`` steps), and write depth, segmentation and that step's flow to ``out``.

    Returns:
        a summary: steps taken, pixels per part, max flow (m) of the shown step.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    world = PushWorld(load_scenario(scenario))
    rng = np.random.default_rng(seed)
    obs = world.reset(rng)
    before, after = obs, obs
    for step in range(1, max_steps + 1):  # noqa: B007 (step is reported below)
        before, after = after, world.step(push_toward_object(world, after, rng))
        moved = np.linalg.norm(after.object_poses[:, :2] - before.object_poses[:, :2], axis=1)
        if after.done or moved.max() > MOVED_M:
            break
    flow = world.targets(before, after) - before.points_cam  # (3,H,W)
    flow_mm = np.linalg.norm(flow, axis=0) * 1e3
    flow_mm[~before.valid] = np.nan

    fig, ax = plt.subplots(1, 3, figsize=(13, 4.4))
    depth = np.where(before.valid, before.points_cam[2], np.nan)
    im = ax[0].imshow(depth, cmap="viridis")
    fig.colorbar(im, ax=ax[0], label="depth (m)")
    ax[0].set_title(f"depth, {scenario} seed {seed}")
    labels = ["none", "static", "pusher"] + [f"object {i}" for i in range(len(obs.object_poses))]
    cmap = plt.get_cmap("tab10", len(labels))
    im = ax[1].imshow(before.part.astype(int) + 1, cmap=cmap, vmin=-0.5, vmax=len(labels) - 0.5)
    cb = fig.colorbar(im, ax=ax[1], ticks=range(len(labels)))
    cb.ax.set_yticklabels(labels)
    ax[1].set_title("segmentation (part hit by each ray)")
    im = ax[2].imshow(flow_mm, cmap="magma")
    fig.colorbar(im, ax=ax[2], label="|flow| (mm)")
    uv0 = world.camera.project(np.moveaxis(before.points_cam, 0, -1))
    uv1 = world.camera.project(np.moveaxis(before.points_cam + flow, 0, -1))
    moving = before.valid & (np.nan_to_num(flow_mm) > 1.0)
    step_px = max(1, world.camera.width // 32)
    sel = moving & (
        np.add.outer(np.arange(moving.shape[0]), np.arange(moving.shape[1])) % step_px == 0
    )
    d = uv1[sel] - uv0[sel]
    ax[2].quiver(uv0[sel][:, 0] - 0.5, uv0[sel][:, 1] - 0.5, d[:, 0], d[:, 1], color="cyan",
                 angles="xy", scale_units="xy", scale=0.5, width=0.004)  # fmt: skip
    ax[2].set_title(f"true flow, step {step} (arrows x2)")
    for a in ax:
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    counts = {name: int((before.part == k - 1).sum()) for k, name in enumerate(labels)}
    return {"steps": step, "pixels": counts, "max_flow_m": float(np.nanmax(flow_mm) / 1e3)}
