"""Pictures people would rather see than read: depth, segmentation and true flow, as PNGs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from scenarios import InputError, check_seed, load_scenario
from sim.camera import DepthCamera
from sim.dataset import MOVED_M
from sim.joint_explore import JointExploration
from sim.world import MAX_PARTS, Observation, PushWorld, part_names


def push_toward_object(world: PushWorld, obs: Observation, rng: np.random.Generator) -> np.ndarray:
    """An action aimed from the pusher at a random object's centre, with a noisy heading, at
    a random speed between half and full bound."""
    target = obs.object_poses[int(rng.integers(len(obs.object_poses))), :2]
    heading = np.arctan2(*(target - obs.pusher_xy_m)[::-1]) + rng.normal(0.0, 0.15)
    bound = world.scenario.action.max_speed_m_s
    speed = bound * rng.uniform(0.5, 1.0)
    return np.clip(speed * np.array([np.cos(heading), np.sin(heading)]), -bound, bound)


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_example(
    fig: Any,
    axes: Any,
    camera: DepthCamera,
    points: np.ndarray,
    part: np.ndarray,
    flow: np.ndarray,
    title: str,
    *,
    names: list[str] | None = None,
) -> None:
    """Depth, segmentation and true flow of one example on three axes.

    Args:
        points: (3,H,W) input cloud, camera frame; part: (H,W) part labels (-1 none);
        flow: (3,H,W) true flow (target - input), metres.
        names: the name of each part label 0, 1, ... (``sim.world.part_names``; default: the
            static world, the pusher and objects).
    """
    plt = pyplot()
    valid = part >= 0
    im = axes[0].imshow(np.where(valid, points[2], np.nan), cmap="viridis")
    fig.colorbar(im, ax=axes[0], label="depth (m)")
    axes[0].set_title(title)
    default = ["static", "pusher"] + [f"object {i}" for i in range(MAX_PARTS - 2)]
    labels = ["none", *(names or default)]
    cmap = plt.get_cmap("tab10", len(labels))
    im = axes[1].imshow(part.astype(int) + 1, cmap=cmap, vmin=-0.5, vmax=len(labels) - 0.5)
    cb = fig.colorbar(im, ax=axes[1], ticks=range(len(labels)))
    cb.ax.set_yticklabels(labels)
    axes[1].set_title("segmentation (part hit by each ray)")
    flow_mm = np.where(valid, np.linalg.norm(flow, axis=0) * 1e3, np.nan)
    im = axes[2].imshow(flow_mm, cmap="magma")
    fig.colorbar(im, ax=axes[2], label="|flow| (mm)")
    uv0 = camera.project(np.moveaxis(points, 0, -1))
    uv1 = camera.project(np.moveaxis(points + flow, 0, -1))
    every = max(1, camera.width // 32)
    grid = np.add.outer(np.arange(part.shape[0]), np.arange(part.shape[1])) % every == 0
    sel = valid & (np.nan_to_num(flow_mm) > 1.0) & grid
    d = uv1[sel] - uv0[sel]
    axes[2].quiver(uv0[sel][:, 0] - 0.5, uv0[sel][:, 1] - 0.5, d[:, 0], d[:, 1], color="cyan",
                   angles="xy", scale_units="xy", scale=0.5, width=0.004)  # fmt: skip
    axes[2].set_title("true flow (arrows x2)")
    for a in axes:
        a.set_xticks([])
        a.set_yticks([])


def save_figure(fig: Any, out: str | Path) -> None:
    """Write ``fig`` to ``out`` (its format from the suffix) atomically, and close it: an
    interrupted command leaves the earlier picture or none, never a cut one."""
    import io

    from sim.shards import atomic_write_bytes

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=100, format=out.suffix.lstrip(".") or "png")
    pyplot().close(fig)
    atomic_write_bytes(out, buf.getvalue())


def check_figure_path(out: str | Path) -> None:
    """Refuse, before any work, a picture's path that is a folder or names a format matplotlib
    cannot write."""
    from matplotlib.figure import Figure

    out = Path(out)
    if out.is_dir():
        raise InputError(f"{out} is a folder; give the picture's file name, e.g. {out}/scene.png")
    formats = Figure().canvas.get_supported_filetypes()
    if out.suffix.lstrip(".").lower() not in formats:
        known = ", ".join("." + f for f in sorted(formats))
        raise InputError(f"{out}: a picture is one of {known}; got {out.suffix or 'no suffix'!r}")


def render_scene(scenario: str, seed: int, out: str | Path, *, max_steps: int = 40) -> dict:
    """Reset ``scenario`` with ``seed``, push toward an object until it moves (at most
    ``max_steps`` steps), and write depth, segmentation and that step's flow to ``out``. With
    joint-velocity controls, the arm starts in a random pose and the step shown is the first
    of a scene of the data's exploration (``sim.joint_explore``).

    Returns:
        a summary: steps taken, pixels per part, max flow (m) of the shown step.
    """
    check_seed(seed)
    check_figure_path(out)
    world = PushWorld(load_scenario(scenario))
    rng = np.random.default_rng(seed)
    before = after = world.reset(rng)
    if world.joint_controls:  # the arm moves at once
        policy = JointExploration(world, rng)
        before = world.set_arm(policy.start_configuration())
        after, step = world.step(policy(before)[0]), 1
    else:
        for step in range(1, max_steps + 1):  # noqa: B007 (step is reported below)
            before, after = after, world.step(push_toward_object(world, after, rng))
            moved = np.linalg.norm(after.object_poses[:, :2] - before.object_poses[:, :2], axis=1)
            if after.done or moved.max() > MOVED_M:
                break
    flow = world.targets(before, after) - before.points_cam
    fig, axes = pyplot().subplots(1, 3, figsize=(13, 4.4))
    title = f"{scenario} seed {seed}, step {step}"
    names = part_names(world.scenario, len(world.objects))
    draw_example(fig, axes, world.camera, before.points_cam, before.part, flow, title, names=names)
    save_figure(fig, out)
    counts = {name: int((before.part == k - 1).sum()) for k, name in enumerate(["none", *names])}
    valid_flow = np.linalg.norm(flow, axis=0)[before.valid]
    return {"steps": step, "pixels": counts, "max_flow_m": float(valid_flow.max())}


def dataset_examples_png(root: str | Path, out: str | Path, *, n: int = 4, seed: int = 0) -> list:
    """Write ``n`` examples of a dataset (drawn among those where an object moves; without
    objects, where a part moves) as rows of depth, segmentation and true one-step flow.
    Returns the (episode, t) shown."""
    from sim.datastore import frame_cloud, load_episodes, read_manifest, scenario_of

    scenario = scenario_of(read_manifest(root))
    camera = DepthCamera(scenario.camera)
    eps = load_episodes(root, verify=False)
    a = eps.arrays

    def moves(e: int, t: int) -> bool:
        if a["n_objects"][e] == 0:  # the arm alone: any entry of a part's pose
            return np.abs(a["T_world_part"][e, t + 1] - a["T_world_part"][e, t]).max() > MOVED_M
        poses = a["object_poses"][e]
        return np.linalg.norm(poses[t + 1, :, :2] - poses[t, :, :2], axis=1).max() > MOVED_M

    moving = [
        (e, t)
        for e in range(min(len(eps.index), 60))
        for t in range(int(a["length"][e]))
        if moves(e, t)
    ]
    rng = np.random.default_rng(seed)
    picks = [
        moving[i] for i in sorted(rng.choice(len(moving), size=min(n, len(moving)), replace=False))
    ]
    fig, axes = pyplot().subplots(
        max(len(picks), 1), 3, figsize=(13, 4.2 * max(len(picks), 1)), squeeze=False
    )
    for row, (e, t) in zip(axes, picks, strict=False):
        points = frame_cloud(a, e, t, camera.T_cam_world)
        flow = frame_cloud(a, e, t, camera.T_cam_world, at=t + 1) - points
        title = f"episode {int(eps.index[e])}, t = {t}"
        names = part_names(scenario, scenario.objects.count[1])
        draw_example(fig, row, camera, points, a["part"][e, t], flow, title, names=names)
    save_figure(fig, out)
    return [(int(eps.index[e]), t) for e, t in picks]
