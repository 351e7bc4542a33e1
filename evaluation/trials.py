"""Closed-loop trials: a seeded set of starts and goals, run with any model and planner.

Trial i depends only on (scenario, seed, i): the world's reset seed and a goal drawn
uniformly over the scenario's goal region, at least ``min_distance_m`` or ``min_yaw_deg`` away
from the object's start and at most ``max_distance_m`` (not drawn from demonstrations). So
the same seed gives the same trial set for every model and planner, and results compare pair
by pair. Finished trials are appended to ``trials.jsonl``; a run started again skips them.
The set is the same prefix for any ``n``, so a folder can be extended to more trials, or
summarised over its first ``n`` (a study reuses a larger trial run that way).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.diagnostics import path_efficiency, pooled, unseen_share
from evaluation.records import SCHEMA, migrate_config
from planner.base import ONE_PLANNER_SETTINGS
from planner.loop import TIGHT, TOLERANCES, PushConfig, check_tolerance, push_scenario, run_push
from planner.settings import PlanSettings
from scenarios import InputError, Scenario, check_seed, load_scenario
from scenarios.config import differences
from sim import PushWorld
from sim.folders import writes_folder
from sim.jobs import Backend, run_jobs
from sim.planar import pose_errors
from sim.shards import append_text, atomic_write_bytes, atomic_write_json


@dataclass(frozen=True)
class TrialsConfig:
    """A set of closed-loop trials."""

    scenario: str
    """scenario name or TOML path"""
    n: int
    """number of trials"""
    model: str = "default"
    """dynamics: default, a checkpoint path, checkpoints joined by "+" (an ensemble), oracle or
    no-motion"""
    seed: int = 0
    """seed of the trial set (and of each trial's planner)"""
    max_steps: int = 60
    """control steps per trial"""
    plan: PlanSettings = PlanSettings()
    """the planning settings (each trial's optimiser is seeded with its world's seed)"""
    tolerance: tuple[float, float] = TIGHT
    """each trial goes on until the object is within this position (m) and yaw (deg) of its
    goal (``planner.loop.TOLERANCES``): success at a tighter tolerance is measured only by
    trials that ran to it"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        object.__setattr__(self, "tolerance", check_tolerance(self.tolerance))
        if self.n < 1 or self.max_steps < 1:
            raise InputError(
                f"--n and --max-steps must be positive, got {self.n} and {self.max_steps}"
            )


TRIAL_SET = 2
"""version of the trial draw, stored in a folder's config.json: 2 measures a goal's turn with
the object's symmetry, as success does (1 took it over 360°, so some goals were closer than
``goals.min_*`` allow); a folder of another version holds other trials and is refused"""


def draw_trial(scenario: Scenario, seed: int, i: int) -> dict[str, Any]:
    """Trial i of the set: the world's reset seed, the object's start pose and the goal."""
    rng = np.random.default_rng([seed, i, 7])
    reset_seed = int(rng.integers(1 << 31))
    start, goal = draw_goal(scenario, reset_seed, rng)
    return {"trial": i, "reset_seed": reset_seed, "start": start.tolist(), "goal": goal.tolist()}


def draw_goal(
    scenario: Scenario, reset_seed: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The pushed object's start pose in the world reset with ``reset_seed``, and a goal drawn
    with ``rng`` that the scenario's ``goals`` allow from it (far or turned enough, not too
    far)."""
    world = PushWorld(scenario)
    start = world.reset(reset_seed).object_poses[0]
    period = world.objects[0].yaw_period_rad  # success measures the turn with this symmetry
    g = scenario.goals
    x0, x1, y0, y1 = g.region_m
    for _ in range(10_000):
        goal = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1), rng.uniform(-math.pi, math.pi)])
        dist, turn = pose_errors(goal, start, period)
        if dist <= g.max_distance_m and (dist >= g.min_distance_m or turn >= g.min_yaw_deg):
            return start, goal
    raise InputError(
        f"scenario {scenario.name}: no goal satisfies goals.* from start {start.tolist()}"
    )


def same_trial(ra: dict[str, Any], rb: dict[str, Any]) -> bool:
    """Whether two trial records (or :func:`draw_trial` results) are the same trial: the same
    reset seed, start and goal."""
    return ra["reset_seed"] == rb["reset_seed"] and all(
        np.shape(ra[k]) == np.shape(rb[k]) and np.allclose(ra[k], rb[k], rtol=0, atol=1e-6)
        for k in ("start", "goal")
    )


def check_draws(
    records: dict[int, dict[str, Any]], scenario: Scenario, seed: int, out: Path
) -> None:
    """Refuse a folder whose records are not the trials the scenario draws today: its file
    changed since they ran (a folder is compared by the scenario's name), and a set that mixed
    the two would measure neither."""
    for i in sorted(records):
        if not same_trial(records[i], draw_trial(scenario, seed, i)):
            raise InputError(
                f"{out} holds trials that scenario {scenario.name!r} no longer draws (trial "
                f"{i}'s world, start or goal differs: the scenario changed since they ran); "
                "use a new --out folder"
            )


def write_log(log: Path, records: dict[int, dict[str, Any]]) -> None:
    """``trials.jsonl`` rewritten in trial order, atomically: an interruption leaves the old
    log or the new one, never a cut one."""
    text = "".join(json.dumps(records[i]) + "\n" for i in sorted(records))
    atomic_write_bytes(log, text.encode())


def run_trial(cfg: TrialsConfig, i: int) -> dict[str, Any]:
    """Run trial i; returns its JSONL record."""
    trial = draw_trial(load_scenario(cfg.scenario), cfg.seed, i)
    push = PushConfig(
        goal=tuple(trial["goal"]),
        scenario=cfg.scenario,
        model=cfg.model,
        seed=trial["reset_seed"],
        max_steps=cfg.max_steps,
        plan=cfg.plan,
        tolerance=cfg.tolerance,
    )
    result = run_push(push)
    path = [trial["start"][:2]] + [r.object_pose[:2] for r in result.records]
    return {**trial, **result.summary(), "path": path, "schema": SCHEMA}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate k/n."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Success rates (with 95 % intervals) and medians of a set of trial records."""
    n = len(records)
    out: dict[str, Any] = {"trials": n}
    for tol, (pos, yaw) in TOLERANCES.items():
        # measured where every trial ran on until within it (older records: to tight)
        ran_to = [r.get("tolerance", TIGHT) for r in records]
        if not all(p <= pos and y <= yaw for p, y in ran_to):
            out[f"success_{tol}"] = out[f"success_{tol}_ci95"] = None
            continue
        k = sum(r[f"success_{tol}"] for r in records)
        out[f"success_{tol}"] = k / max(n, 1)
        out[f"success_{tol}_ci95"] = list(wilson(k, n))
    for key in ("final_pos_err_m", "final_yaw_err_deg", "steps", "replan_ms_median"):
        out[f"median_{key}"] = float(np.median([r[key] for r in records])) if records else None
    moved = [r["others_moved_m"] for r in records if r.get("others_moved_m") is not None]
    out["trials_among_others"] = len(moved)
    out["median_others_moved_m"] = float(np.median(moved)) if moved else None
    out["others_moved_over_1cm"] = float(np.mean(np.array(moved) > 0.01)) if moved else None
    out["diagnostics"] = pooled(r["diagnostics"] for r in records)
    # records from before the per-step figures were kept have none to pool
    out["path_efficiency"] = path_efficiency(r["per_step"] for r in records if "per_step" in r)
    for outcome, won in (("successes", True), ("failures", False)):
        steps = (r["per_step"] for r in records if "per_step" in r and r["success_tight"] == won)
        out[f"pusher_unseen_{outcome}"] = unseen_share(steps)
    # where generalisation stops: successes by the pushed object's shape, size and mass
    pushed = [r for r in records if "pushed_object" in r]
    for key, group in GROUPINGS.items():
        out[f"by_{key}"] = tally(pushed, group)
    return out


MASS_BIN_KG = 0.1
"""width of the pushed-mass bins of trial summaries"""


def mass_bin(obj: dict[str, Any]) -> str:
    """The pushed object's mass bin, e.g. ``"0.5-0.6 kg"`` (bins of ``MASS_BIN_KG``)."""
    # the 1e-9 puts a mass on a bin edge into the bin it starts: 0.3 / 0.1 is 2.999...
    lo = math.floor(obj["mass_kg"] / MASS_BIN_KG + 1e-9) * MASS_BIN_KG
    return f"{lo:.1f}-{lo + MASS_BIN_KG:.1f} kg"


SIZE_BIN_M = 0.02
"""width of the pushed-size bins of trial summaries (the footprint's longer extent)"""


def size_bin(obj: dict[str, Any]) -> str:
    """The pushed object's size bin by its footprint's longer extent (a box's longer side, a
    cylinder's diameter), e.g. ``"10-12 cm"`` (bins of ``SIZE_BIN_M``)."""
    extent = max(obj["size_m"][:2])
    lo = math.floor(extent / SIZE_BIN_M + 1e-9) * SIZE_BIN_M
    return f"{100 * lo:.0f}-{100 * (lo + SIZE_BIN_M):.0f} cm"


def label_order(label: str) -> list[Any]:
    """Sort key of group labels that orders their numbers by value: ``"8-10 cm"`` before
    ``"10-12 cm"``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", label)]


GROUPINGS: dict[str, Callable[[dict[str, Any]], str]] = {
    "shape": lambda obj: obj["shape"],
    "size": size_bin,
    "mass": mass_bin,
}
"""how trials may be grouped by their pushed object (``compare --by``)"""


def tally(
    records: list[dict[str, Any]], key: Callable[[dict[str, Any]], str]
) -> dict[str, dict[str, Any]]:
    """Tight and loose successes and trials per ``key(pushed_object)``, in sorted key order."""
    rows: dict[str, dict[str, Any]] = {}
    for r in records:
        k = key(r["pushed_object"])
        row = rows.setdefault(k, {"tight": 0, "loose": 0, "trials": 0})
        row["tight"] += int(r["success_tight"])
        row["loose"] += int(r["success_loose"])
        row["trials"] += 1
    return dict(sorted(rows.items(), key=lambda item: label_order(item[0])))


def worker_threads(threads: int | None = None) -> int:
    """torch threads for each worker process: ``threads`` if given, else one.

    One by default, whatever the number of workers: workers on their own cores do not fight,
    and the records are the same for any ``--workers`` (a different thread count sums floats
    in another order, and a closed loop can grow a 1e-7 difference into another trial)."""
    if threads is None:
        return 1
    if threads < 1:
        raise InputError(f"--threads must be at least 1, got {threads}")
    return threads


def worker_backend(workers: int, threads: int | None, backend: str, address: str | None) -> Backend:
    """The backend of closed-loop jobs: ``workers`` workers of ``threads`` torch threads
    (:func:`worker_threads`) on ``backend`` (local or ray, at ``address``)."""
    return Backend(backend, workers, address, worker_threads(threads))


def weights_of(model: str) -> str | None:
    """Which weights a trial folder's model names (a shipped name such as ``default`` may
    change between versions): the checkpoints' SHA-256, joined like the model; None for the
    simulator and no-motion backends."""
    if model in ("oracle", "no-motion"):
        return None
    from planner.dynamics import ENSEMBLE_SEP
    from se3net.checkpoint import model_sha256, resolve_model

    parts = [model] if resolve_model(model).exists() else model.split(ENSEMBLE_SEP)
    return ENSEMBLE_SEP.join(model_sha256(p) for p in parts)


def _names_shipped_weights(model: str) -> bool:
    """Whether ``model`` names a shipped checkpoint (``default``, ``se3net/weights/NAME.pt``),
    in part for an ensemble."""
    from planner.dynamics import ENSEMBLE_SEP
    from se3net.checkpoint import DEFAULT_MODEL, resolve_model

    shipped = DEFAULT_MODEL.parent.resolve()
    return any(resolve_model(m).resolve().parent == shipped for m in model.split(ENSEMBLE_SEP))


def _compared(meta: dict) -> dict:
    """What makes two trial folders the same set: the configuration (in today's schema,
    ``evaluation.records``) but ``n`` (the set is a prefix: any n extends or summarises it)
    and the optimiser settings only other optimisers read; the disturbance weight not at all
    where the pushed object is always alone, and the rollout settings not for the simulator
    backends. The optimiser's seed does not count: each trial seeds its planner with its
    world's reset seed."""
    meta = migrate_config(meta)
    out = {k: v for k, v in meta.items() if k not in ("n", "plan")}
    plan = {**meta["plan"], "cost": dict(meta["plan"]["cost"])}
    mine = plan["planner"]
    plan["optimiser"] = {
        k: v
        for k, v in plan["optimiser"].items()
        if ONE_PLANNER_SETTINGS.get(k, mine) == mine and k != "seed"
    }
    if meta.get("model") in ("oracle", "no-motion"):  # how a learned model is rolled
        del plan["rollout"]
        out["retired"] = {k: v for k, v in out["retired"].items() if k != "motion_gain"}
    if load_scenario(meta["scenario"]).objects.count[1] == 1:  # alone: the term is inert
        plan["cost"].pop("w_disturb", None)
    return {**out, "plan": plan}


@writes_folder(lambda a: a.arguments["out"])
def run_trials(
    cfg: TrialsConfig,
    out: str | Path,
    *,
    workers: int = 1,
    threads: int | None = None,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run (or finish) a trial set into ``out`` with ``workers`` workers of ``threads`` torch
    threads each (one by default) on ``backend`` (``sim.jobs``: the local process pool, or Ray
    at ``address``); returns the summary. The records are the same for any backend and number
    of workers, and ``trials.jsonl`` ends in trial order.

    Asked for fewer trials than the folder holds, it summarises the first ``n`` and leaves the
    folder's ``summary.json`` and ``paths.png`` (which describe the whole set) as they are.

    Raises:
        InputError: ``out`` holds trials of another configuration, or bad settings.
    """
    from tqdm import tqdm

    jobs = worker_backend(workers, threads, backend, address)
    # fail early on an unknown scenario, or one of joint controls
    scenario = push_scenario(cfg.scenario)
    cfg.plan.optimiser.steps(scenario.action.dt_control_s)  # refuse more knots than steps
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta_path, log = out / "config.json", out / "trials.jsonl"
    meta = {"schema": SCHEMA, **asdict(cfg), "retired": {}, "trial_set": TRIAL_SET,
            "model_sha256": weights_of(cfg.model)}  # fmt: skip
    meta = json.loads(json.dumps(meta))  # as the folder will hold it (a tuple is a list)
    old_meta = json.loads(meta_path.read_text()) if meta_path.exists() else None
    if old_meta is not None:
        old, new = _compared(old_meta), _compared(meta)
        if "model_sha256" not in old:  # folders from before weights were recorded
            if _names_shipped_weights(cfg.model):
                raise InputError(
                    f"{out} predates the record of its model's weights, and {cfg.model!r} names "
                    "shipped weights that have changed since; use a new --out folder"
                )
            new.pop("model_sha256")
        if old != new:
            raise InputError(
                f"{out} holds other trials ({'; '.join(differences(old, new))}); "
                "use a new --out folder"
            )
    prefix = old_meta is not None and cfg.n < old_meta["n"]
    if not prefix:
        atomic_write_json(meta_path, meta)
    records = {}
    if log.exists():
        for line in log.read_text().splitlines():
            if line.strip():
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut by an interruption: that trial runs again
                records[rec["trial"]] = rec
        check_draws(records, scenario, cfg.seed, out)
        write_log(log, records)
    todo = [i for i in range(cfg.n) if i not in records]
    bar = tqdm(
        total=cfg.n, initial=cfg.n - len(todo), unit="trial", disable=not progress, desc="trials"
    )

    def record(rec: dict[str, Any]) -> None:
        records[rec["trial"]] = rec
        append_text(log, json.dumps(rec) + "\n")
        bar.update(1)
        bar.set_postfix(
            success=f"{sum(r['success_tight'] for r in records.values())}/{len(records)}"
        )

    for rec in run_jobs(run_trial, [(cfg, i) for i in todo], jobs):
        record(rec)
    bar.close()
    if todo:  # appended as they finished; kept in trial order, whatever ran them
        write_log(log, records)
    ordered = [records[i] for i in range(cfg.n)]
    summary = {"config": asdict(cfg), **summarize(ordered)}
    if not prefix:  # the folder's files describe its whole set, not a prefix asked of it
        atomic_write_json(out / "summary.json", summary)
        plot_paths(
            ordered, out / "paths.png", title=f"{cfg.model} / {cfg.plan.planner} on {cfg.scenario}"
        )
    return summary


def plot_paths(records: list[dict[str, Any]], out: Path, *, title: str) -> None:
    """Object paths (start dot, path line) against their goals (crosses), coloured by success."""
    from sim.render import pyplot, save_figure

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 6))
    for r in records:
        path = np.array(r["path"])
        colour = (
            "tab:green" if r["success_tight"] else "tab:orange" if r["success_loose"] else "tab:red"
        )
        ax.plot(path[:, 0], path[:, 1], color=colour, lw=1)
        ax.plot(*path[0], "o", color=colour, ms=3)
        ax.plot(r["goal"][0], r["goal"][1], "x", color=colour, ms=6)
        ax.plot([path[-1, 0], r["goal"][0]], [path[-1, 1], r["goal"][1]], ":", color=colour, lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{title}: green tight, orange loose, red failed")
    save_figure(fig, out)
