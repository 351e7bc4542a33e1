"""Training data: exploration episodes with exact point associations, in shards.

``generate(cfg, out_dir)`` runs episodes of the exploration policy (``sim.explore`` for pusher
controls, ``sim.joint_explore`` for joint-velocity controls) and stores, per frame, what
targets for any horizon need: the part each pixel sees, each point in its part's frame
(float16: under 0.13 mm of error for points within 0.5 m of their part's origin) and the parts'
poses (float64). The cloud at time t and its target after h steps both follow from these by
``T_cam_world · T_world_part(t or t+h) · p_part``, so one dataset serves every horizon.

Episode i depends only on (seed, i), and shards hold fixed ranges of episodes, so the bytes are
the same for any number of workers. Shards are written atomically and recorded with their
checksums in ``manifest.json``; an interrupted run started again with the same arguments skips
finished shards.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from scenarios import InputError, Scenario, check_seed, load_scenario
from scenarios.config import differences, scenario_dict
from sim.camera import associated_targets
from sim.controls import PUSHER_LAYOUT, control_layout
from sim.explore import MODES, ExplorationConfig, ExplorationPolicy, describe_exploration
from sim.folders import writes_folder
from sim.jobs import Backend, run_jobs
from sim.joint_explore import (
    JOINT_MODES,
    JointExploration,
    JointExplorationConfig,
    describe_joint_exploration,
)
from sim.shapes import DETAILED_SHAPES, MAX_OUTLINE, SHAPES, ObjectSpec
from sim.shards import DataError, atomic_write_json, sha256, write_shard
from sim.world import FIRST_OBJECT_PART, MAX_PARTS, PushWorld

DATA_FORMAT = 1
MANIFEST = "manifest.json"
CONTROL_LAYOUT = PUSHER_LAYOUT.names
"""the controls of pusher-velocity data (``sim.controls`` has every layout)"""
MOVED_M = 1e-3
"""an example shows object motion if some visible object point moves more than this"""
NONZERO_FLOW_M = 1e-4
"""points whose true flow exceeds this count as moving (the paper's 'non-zero flow')"""
HIST_BIN_M, HIST_BINS = 2.5e-4, 400


@dataclass(frozen=True)
class DataConfig:
    """What to generate; all of it identifies a dataset folder (``identity``: a folder resumes
    only with the arguments that made it)."""

    scenario: str
    """scenario name or TOML path"""
    episodes: int
    """number of episodes"""
    steps_per_episode: int = 20
    """actions per episode (frames = steps + 1)"""
    seed: int = 0
    """episode i is drawn from (seed, i)"""
    episodes_per_shard: int = 20
    """episodes in one shard file"""
    exploration: ExplorationConfig = field(default_factory=ExplorationConfig)
    """the exploration policy's mixture (scenarios of pusher controls)"""
    joint_exploration: JointExplorationConfig = field(default_factory=JointExplorationConfig)
    """the joint-velocity exploration's scenes (scenarios of 'joints' controls)"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        for name in ("episodes", "steps_per_episode", "episodes_per_shard"):
            if getattr(self, name) < 1:
                raise InputError(f"{name} must be a positive integer, got {getattr(self, name)}")

    @property
    def n_shards(self) -> int:
        return -(-self.episodes // self.episodes_per_shard)


def code_version() -> str:
    try:
        return metadata.version("se3push")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "unknown"


def identity(cfg: DataConfig, scenario: Scenario) -> dict[str, Any]:
    """The manifest's record of what the data is (JSON types, as stored); a folder only ever
    holds one identity."""
    joints = scenario.action.controls == "joints"
    ident = {
        "format": DATA_FORMAT,
        "scenario": scenario_dict(scenario),
        "seed": cfg.seed,
        "episodes": cfg.episodes,
        "steps_per_episode": cfg.steps_per_episode,
        "episodes_per_shard": cfg.episodes_per_shard,
        "exploration": describe_joint_exploration(cfg.joint_exploration)
        if joints
        else describe_exploration(cfg.exploration),
        "control_layout": list(control_layout(scenario).names),
    }
    return json.loads(json.dumps(ident))


# --------------------------------------------------------------------------- episodes
PLANNER_MODE = "planner"
"""the mode of steps recorded from closed-loop planning (``se3push improve``)"""
STEP_MODES = (*MODES, PLANNER_MODE, *(m for m in JOINT_MODES if m not in MODES))
"""every mode a recorded step can have (``modes`` holds indices into this; new modes go at
the end, so stored indices keep their meaning)"""


def with_shape_details(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Loaded episode arrays with the shape details (bar widths, outlines) that data of
    scenarios without hulls, L- or T-shapes does not store, filled in as absent, so that such
    data pools with data of those shapes."""
    n = len(arrays["n_objects"])
    out = dict(arrays)
    out.setdefault("object_arm", np.zeros((n, MAX_PARTS - 2)))
    out.setdefault("object_outline", np.full((n, MAX_PARTS - 2, MAX_OUTLINE, 2), np.nan))
    return out


def episode_objects(arrays: dict[str, np.ndarray], e: int) -> list[ObjectSpec]:
    """The objects of episode ``e`` of loaded dataset arrays, as :class:`EpisodeRecorder`
    stored them."""
    objects = []
    for i in range(int(arrays["n_objects"][e])):
        detail = {}
        if "object_arm" in arrays:  # data of scenarios with shapes beyond boxes and cylinders
            outline = arrays["object_outline"][e, i]
            outline = outline[~np.isnan(outline[:, 0])]
            detail = {"arm_m": float(arrays["object_arm"][e, i]),
                      "outline": tuple(tuple(float(c) for c in v) for v in outline)}  # fmt: skip
        objects.append(
            ObjectSpec(
                shape=SHAPES[int(arrays["object_shape"][e, i])],
                size_m=tuple(float(x) for x in arrays["object_size"][e, i]),
                mass_kg=float(arrays["object_mass"][e, i]),
                friction=float(arrays["object_friction"][e, i]),
                **detail,
            )
        )
    return objects


class EpisodeRecorder:
    """Fills one episode's arrays frame by frame, from observations of a world.

    The same record serves exploration episodes and closed-loop (planner-visited) ones, so
    both have the same format and the same exact associations.
    """

    def __init__(self, world: PushWorld, steps: int, obs) -> None:
        T, (H, W), n_obj = steps, obs.part.shape, len(world.objects)
        self.n_obj, self.length = n_obj, 0
        self.out = {
            "part": np.full((T + 1, H, W), -1, np.int8),
            "points_part": np.zeros((T + 1, 3, H, W), np.float16),
            "T_world_part": np.tile(np.eye(4), (T + 1, MAX_PARTS, 1, 1)),
            "object_poses": np.zeros((T + 1, MAX_PARTS - 2, 3)),
            "pusher_xy": np.zeros((T + 1, 2)),
            "joint_pos": np.zeros((T + 1, 4), np.float32),
            "joint_vel": np.zeros((T + 1, 4), np.float32),
            "actions": np.zeros((T, len(world.layout.commands))),
            "modes": np.full(T, -1, np.int8),
            "n_objects": np.array(n_obj, np.int8),
            "object_shape": np.array(
                [SHAPES.index(o.shape) for o in world.objects] + [-1] * (3 - n_obj), np.int8
            ),
            "object_size": np.array([o.size_m for o in world.objects] + [(0, 0, 0)] * (3 - n_obj)),
            "object_mass": np.array([o.mass_kg for o in world.objects] + [0] * (3 - n_obj), float),
            "object_friction": np.array(
                [o.friction for o in world.objects] + [0] * (3 - n_obj), float
            ),
        }
        if set(world.scenario.objects.shapes) & set(DETAILED_SHAPES):  # their bars and outlines
            pad = MAX_PARTS - 2 - n_obj
            self.out["object_arm"] = np.array([o.arm_m for o in world.objects] + [0] * pad, float)
            none = np.full((MAX_OUTLINE, 2), np.nan)
            self.out["object_outline"] = np.stack(
                [o.outline_array() for o in world.objects] + [none] * pad
            )
        self._frame(0, obs)

    def _frame(self, t: int, o) -> None:
        out = self.out
        out["part"][t] = o.part
        out["points_part"][t] = o.points_part
        out["T_world_part"][t, : len(o.T_world_part)] = o.T_world_part
        out["object_poses"][t, : self.n_obj] = o.object_poses
        out["pusher_xy"][t] = o.pusher_xy_m
        out["joint_pos"][t] = o.joint_pos_rad
        out["joint_vel"][t] = o.joint_vel_rad_s

    @property
    def full(self) -> bool:
        return self.length == len(self.out["actions"])

    def step(self, action: np.ndarray, mode: str, obs) -> None:
        """Record an action taken in the last recorded frame and the frame it led to."""
        t = self.length
        self.out["actions"][t], self.out["modes"][t] = action, STEP_MODES.index(mode)
        self._frame(t + 1, obs)
        self.length = t + 1

    def finish(self, qp_failures: int = 0) -> dict[str, np.ndarray]:
        """The episode's arrays (frames after ``length`` are padding)."""
        self.out["length"] = np.array(self.length, np.int32)
        self.out["qp_failures"] = np.array(qp_failures, np.int32)
        return self.out


def run_episode(scenario: Scenario, cfg: DataConfig, index: int) -> dict[str, np.ndarray]:
    """Simulate episode ``index`` (a function of ``(cfg.seed, index)`` alone).

    Returns arrays with a leading frame axis of ``T + 1`` (actions: ``T``); frames after an
    early end (object off the table, instability) are padded and ``length`` says how many
    steps are real. The frame at which the episode ended is dropped, as the paper discards
    such frames.
    """
    rng = np.random.default_rng([cfg.seed, index])
    world = PushWorld(scenario)
    obs = world.reset(rng)
    if world.joint_controls:
        policy = JointExploration(world, rng, cfg.joint_exploration)
        obs = world.set_arm(policy.start_configuration())
    else:
        policy = ExplorationPolicy(scenario, world.objects, rng, cfg.exploration)
        obs = world.teleport_pusher(policy.start_position(obs))
    rec = EpisodeRecorder(world, cfg.steps_per_episode, obs)
    for _ in range(cfg.steps_per_episode):
        action, mode = policy(obs)
        obs = world.step(action)
        if obs.done:
            break
        rec.step(action, mode, obs)
    return rec.finish(world.qp_failures)


def episode_stats(ep: dict[str, np.ndarray], T_cam_world: np.ndarray) -> dict[str, Any]:
    """One-step statistics: examples, examples with object motion, flow of moving points (the
    pusher's and the arm's included)."""
    hist = np.zeros(HIST_BINS + 1, np.int64)
    moved, n_moving, sum_f, sum_f2 = 0, 0, 0.0, 0.0
    length = int(ep["length"])
    objects = slice(FIRST_OBJECT_PART, FIRST_OBJECT_PART + int(ep["n_objects"]))
    for t in range(length):
        p = ep["points_part"][t].astype(np.float64)
        part = ep["part"][t]
        f = np.linalg.norm(
            associated_targets(p, part, ep["T_world_part"][t + 1], T_cam_world)
            - associated_targets(p, part, ep["T_world_part"][t], T_cam_world),
            axis=0,
        )
        moved += bool(np.any(f[(part >= objects.start) & (part < objects.stop)] > MOVED_M))
        fm = f[f > NONZERO_FLOW_M]
        n_moving += fm.size
        sum_f += float(fm.sum())
        sum_f2 += float((fm**2).sum())
        hist += np.bincount(
            np.minimum((fm / HIST_BIN_M).astype(int), HIST_BINS), minlength=HIST_BINS + 1
        )
    steps = np.bincount(ep["modes"][:length].astype(int), minlength=len(STEP_MODES))
    return {
        "examples": length,
        "moved_examples": moved,
        "moving_points": n_moving,
        "flow_sum_m": sum_f,
        "flow_sq_sum_m2": sum_f2,
        "flow_hist": hist.tolist(),
        "mode_steps": dict(zip(STEP_MODES, steps.tolist(), strict=True)),
        "qp_failures": int(ep["qp_failures"]),
    }


def merge_stats(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Sum per-episode or per-shard statistics."""
    out: dict[str, Any] = {}
    for s in parts:
        for k, v in s.items():
            if isinstance(v, dict):
                out[k] = {m: out.get(k, {}).get(m, 0) + n for m, n in v.items()}
            elif isinstance(v, list):
                out[k] = (
                    np.asarray(out.get(k, np.zeros(len(v), np.int64))) + np.asarray(v)
                ).tolist()
            else:
                out[k] = out.get(k, 0) + v
    return out


# ----------------------------------------------------------------------------- shards
def shard_name(i: int) -> str:
    return f"shard_{i:05d}.npz"


def shard_episodes(cfg: DataConfig, i: int) -> range:
    return range(i * cfg.episodes_per_shard, min((i + 1) * cfg.episodes_per_shard, cfg.episodes))


def make_shard(
    cfg: DataConfig, i: int, out_dir: str, scenario: Scenario
) -> tuple[int, str, dict[str, Any]]:
    """Generate and write shard i of ``scenario`` (the one the folder's identity was made
    from, not the file read again: an edit during the run must not change the data); returns
    (i, sha256, stats). Runs in worker processes."""
    T_cam_world = PushWorld(scenario).camera.T_cam_world
    episodes = [run_episode(scenario, cfg, e) for e in shard_episodes(cfg, i)]
    arrays = {k: np.stack([ep[k] for ep in episodes]) for k in episodes[0]}
    arrays["episode_index"] = np.array(list(shard_episodes(cfg, i)), np.int64)
    digest = write_shard(Path(out_dir) / shard_name(i), arrays)
    stats = merge_stats([episode_stats(ep, T_cam_world) for ep in episodes])
    stats["episodes"] = len(episodes)
    return i, digest, stats


def open_folder(out_dir: Path, ident: dict[str, Any]) -> dict[str, Any]:
    """Create or reopen a dataset folder for ``ident``; returns its manifest.

    Raises:
        DataError: the folder holds another dataset, or files that are not a dataset's.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)  # writable: generate() holds its lock
    path = out_dir / MANIFEST
    if path.exists():
        try:
            manifest = json.loads(path.read_text())
        except json.JSONDecodeError as err:
            raise DataError(
                f"{path} is corrupted ({err}); delete the folder and generate again"
            ) from None
        diffs = differences(manifest.get("identity"), ident)
        headline = ("scenario.name:", "seed:", "format:")  # the differences people look for first
        diffs.sort(key=lambda d: not d.startswith(headline))
        if diffs:
            raise DataError(
                f"{out_dir} holds a different dataset ({'; '.join(diffs[:3])}); "
                "use a new --out folder, or the original arguments to resume"
            )
        return manifest
    leftovers = [p.name for p in out_dir.iterdir() if not p.name.startswith(".")]
    if leftovers:
        raise DataError(
            f"{out_dir} is not empty and holds no dataset ({leftovers[0]}, ...); "
            "use a new --out folder"
        )
    manifest = {"identity": ident, "code_version": code_version(), "shards": {}, "complete": False}
    atomic_write_json(path, manifest)
    return manifest


@writes_folder(lambda a: a.arguments["out_dir"])
def generate(
    cfg: DataConfig,
    out_dir: str | Path,
    *,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Generate (or finish generating) a dataset; returns the manifest.

    Args:
        cfg: what to generate.
        out_dir: the dataset folder (created if needed).
        workers: processes (or Ray CPUs); the bytes do not depend on it.
        backend: ``local`` (forked processes) or ``ray`` (``sim.jobs``); the bytes do not
            depend on it either.
        address: an existing Ray cluster's address (its nodes must see ``out_dir``).
        progress: show a tqdm bar (episodes, examples, examples/s, ETA).
    """
    from tqdm import tqdm

    jobs = Backend(backend, workers, address)  # workers use numpy and MuJoCo only
    scenario = load_scenario(cfg.scenario)
    out_dir = Path(out_dir)
    manifest = open_folder(out_dir, identity(cfg, scenario))
    for name, entry in list(manifest["shards"].items()):  # recorded, but lost or damaged since
        path = out_dir / name
        if not path.is_file() or sha256(path) != entry["sha256"]:
            del manifest["shards"][name]
    for path in sorted(out_dir.glob("shard_*.npz")):  # written but never recorded
        if path.name not in manifest["shards"]:
            path.unlink()
    todo = [i for i in range(cfg.n_shards) if shard_name(i) not in manifest["shards"]]
    if todo and manifest["complete"]:  # a repair: readers refuse the folder until it is done
        manifest["complete"] = False
        atomic_write_json(out_dir / MANIFEST, manifest)
    bar = tqdm(
        total=cfg.episodes, unit="ep", disable=not progress, desc="episodes", dynamic_ncols=True
    )
    bar.update(sum(s["episodes"] for s in manifest["shards"].values()))
    examples = sum(s["examples"] for s in manifest["shards"].values())

    def record(i: int, digest: str, stats: dict[str, Any]) -> None:
        nonlocal examples
        manifest["shards"][shard_name(i)] = {"sha256": digest, **stats}
        atomic_write_json(out_dir / MANIFEST, manifest)
        examples += stats["examples"]
        bar.update(stats["episodes"])
        rate = bar.format_dict["rate"] or 0.0
        bar.set_postfix(examples=examples, ex_per_s=f"{rate * cfg.steps_per_episode:.0f}")

    shard_jobs = [(cfg, i, str(out_dir.resolve()), scenario) for i in todo]
    for shard in run_jobs(make_shard, shard_jobs, jobs):
        record(*shard)
    bar.close()
    manifest["complete"] = len(manifest["shards"]) == cfg.n_shards
    # in shard order, not the order the workers finished them in: float sums are summed in
    # one order, so the manifest's bytes do not depend on the workers' timing or on a resume
    manifest["stats"] = merge_stats(
        [
            {k: v for k, v in s.items() if k != "sha256"}
            for _, s in sorted(manifest["shards"].items())
        ]
    )
    atomic_write_json(out_dir / MANIFEST, manifest)
    return manifest
