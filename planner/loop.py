"""The closed loop: observe, plan, apply the first action, repeat until the object is at the
goal (tight tolerance) or the step budget is spent. Returns data; printing is the caller's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import torch

from planner import (
    PlanInfo,
    Planner,
    PushCost,
    make_dynamics,
    make_planner,
    plan_state,
)
from planner.diagnostics import STEP_FIGURES, exploitation, step_figures
from planner.settings import PlanSettings
from scenarios import InputError, Scenario, check_seed, load_scenario
from se3net.device import check_device
from sim import Observation, PushWorld
from sim.planar import pose_errors

TOLERANCES = {"precise": (0.01, 5.0), "tight": (0.02, 10.0), "loose": (0.05, 20.0)}
"""the named success tolerances: position (m) and yaw (deg) of the object's final pose"""
PRECISE, TIGHT, LOOSE = TOLERANCES["precise"], TOLERANCES["tight"], TOLERANCES["loose"]


def check_tolerance(tolerance: tuple[float, float] | list[float] | str) -> tuple[float, float]:
    """A tolerance by name (``precise``, ``tight``, ``loose``) or as (position m, yaw deg), or
    an InputError saying what is wrong."""
    if isinstance(tolerance, str):
        if tolerance not in TOLERANCES:
            raise InputError(f"--tolerance is {', '.join(TOLERANCES)} or two numbers (metres, "
                             f"degrees), got {tolerance!r}")  # fmt: skip
        return TOLERANCES[tolerance]
    pos, yaw = (float(x) for x in tolerance)
    if not (math.isfinite(pos) and math.isfinite(yaw) and pos > 0 and yaw > 0):
        raise InputError(f"--tolerance takes a position (m) and a yaw (deg) above 0, got "
                         f"{pos:g} {yaw:g}")  # fmt: skip
    return pos, yaw


class NullVisualiser:
    """Does nothing: the loop never checks whether visualisation is on. A visualiser is any
    object with these three methods (``integrations.viz.MeshcatVisualiser``)."""

    frames = 0

    def start(self, world: PushWorld, obs: Observation, goal: np.ndarray, **_: Any) -> None:
        pass

    def step(self, obs: Observation, info: PlanInfo) -> None:
        pass

    def finish(self) -> None:
        pass


@dataclass(frozen=True)
class PushConfig:
    """One closed-loop push."""

    goal: tuple[float, float, float]
    """goal pose: x_m, y_m, yaw_rad (world frame)"""
    scenario: str = "single_box"
    """scenario name or TOML path"""
    object_index: int = 0
    """which object to push"""
    model: str = "default"
    """dynamics: the shipped model ("default"), a checkpoint path, checkpoints joined by "+" (an
    ensemble, its disagreement penalised), "oracle" or "no-motion\""""
    seed: int = 0
    """seed of the world's reset and of the planner"""
    max_steps: int = 60
    """control steps before giving up"""
    device: str = "cpu"
    """device of a learned model"""
    action_noise: float = 0.0
    """SD of Gaussian noise added to each executed action, as a fraction of the action bound
    (exploration when collecting planner-visited data; 0 = the plan's action as it is)"""
    plan: PlanSettings = PlanSettings()
    """the planning settings: optimiser, cost, rollout (the optimiser's seed is ``seed``)"""
    tolerance: tuple[float, float] = TIGHT
    """the push ends once the object is within this position (m) and yaw (deg) of the goal"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        object.__setattr__(self, "tolerance", check_tolerance(self.tolerance))
        if not 0.0 <= self.action_noise <= 1.0:
            raise InputError(f"action noise must be in [0, 1], got {self.action_noise}")
        if self.max_steps < 1:
            raise InputError(f"--max-steps must be a positive integer, got {self.max_steps}")
        check_device(self.device)


@dataclass
class StepRecord:
    """One control step of the loop."""

    step: int
    action: list[float]
    object_pose: list[float]
    pos_err_m: float
    yaw_err_deg: float
    replan_ms: float
    predicted_poses: list[list[float]]
    """(H,3) the chosen plan's predicted object poses"""
    predicted_disp_m: float
    """the object's displacement the plan predicted for its first action (the executed one,
    but for ``PushConfig.action_noise``, whose noise the prediction does not see)"""
    actual_disp_m: float
    """the displacement that happened"""
    predicted_progress_m: float
    """progress toward the goal position the plan predicted for the executed action"""
    actual_progress_m: float
    """the progress that happened"""
    pusher_seen: bool
    """whether the camera saw the pusher when the plan was made (``Observation.pusher_seen``)"""
    cost_terms: dict[str, float] = field(default_factory=dict)
    """the chosen plan's cost, term by term (``PlanInfo.cost_terms``): which term dominated"""


@dataclass
class PushResult:
    """Outcome of a closed-loop push."""

    seed: int
    success_precise: bool
    """the final pose is within 1 cm and 5 deg (:data:`PRECISE`)"""
    success_tight: bool
    """within 2 cm and 10 deg (:data:`TIGHT`)"""
    success_loose: bool
    """within 5 cm and 20 deg (:data:`LOOSE`)"""
    final_pos_err_m: float
    final_yaw_err_deg: float
    steps: int
    sim_time_s: float
    replan_ms_median: float
    reason: str
    """"reached" (``tolerance``), "budget", or why the episode ended"""
    tolerance: tuple[float, float] = TIGHT
    """the tolerance the push ran to (it went on until the object was within it): a success
    at a tighter one than this is not measured by the push"""
    others_moved_m: float | None = None
    """how far the push moved the other objects: the largest planar displacement of any of
    them from where it started (None: it was alone)"""
    pushed_object: dict = field(default_factory=dict)
    """the pushed object's shape, size, mass and friction (``sim.shapes.ObjectSpec``)"""
    diagnostics: dict = field(default_factory=dict)
    """exploitation diagnostics over the executed steps (``planner.diagnostics``)"""
    records: list[StepRecord] = field(default_factory=list)

    def summary(self) -> dict:
        """The result line's fields, with each step's predicted and actual motion and its plan's
        cost term by term (not the full per-step records)."""
        keys = ("step", *STEP_FIGURES, "pusher_seen", "cost_terms")
        per_step = [{k: getattr(r, k) for k in keys} for r in self.records]
        return {**{k: v for k, v in asdict(self).items() if k != "records"}, "per_step": per_step}


def disturbance(start: np.ndarray, end: np.ndarray) -> float | None:
    """The largest planar displacement (m) of the other objects from ``start`` (M,2) to ``end``
    (M,2); None when there are none."""
    if len(start) == 0:
        return None
    return float(np.linalg.norm(end - start, axis=1).max())


def push_scenario(name_or_path: str) -> Scenario:
    """A scenario to plan pushes in: loaded, and refused unless its actions are pusher
    velocities (the planner's actions; a scenario of joint-velocity controls is for data and
    training only)."""
    scenario = load_scenario(name_or_path)
    if scenario.action.controls != "pusher":
        raise InputError(
            f"scenario {scenario.name!r} has joint-velocity controls, not pusher actions: the "
            "planner plans pushes (vx, vy), so it needs a push scenario (see `se3push scenarios`)"
        )
    return scenario


def within(errors: tuple[float, float], tolerance: tuple[float, float] = TIGHT) -> bool:
    """Whether a pose error (position m, yaw deg; ``sim.planar.pose_errors``) is within a
    tolerance (one of :data:`TOLERANCES`)."""
    return errors[0] <= tolerance[0] and errors[1] <= tolerance[1]


def push_planner(cfg: PushConfig, scenario: Scenario, world: PushWorld) -> Planner:
    """The planner of a closed-loop push in ``world`` (reset): ``cfg``'s dynamics (the oracle
    and no-motion backends hold this world), optimiser, cost toward ``cfg.goal`` and settings,
    seeded with ``cfg.seed``."""
    if cfg.model in ("oracle", "no-motion"):
        dynamics = make_dynamics(cfg.model, scenario, world=world, object_index=cfg.object_index)
    else:
        dynamics = make_dynamics(
            "se3net",
            scenario,
            model=cfg.model,
            device=cfg.device,
            feedback=cfg.plan.rollout.feedback,
            contact_margin_m=cfg.plan.rollout.contact_margin_m,
        )
    return make_planner(
        cfg.plan.planner,
        dynamics,
        PushCost(scenario, torch.tensor(np.array(cfg.goal, dtype=float)), cfg.plan.cost),
        scenario,
        replace(cfg.plan.optimiser, seed=cfg.seed),
    )


def check_reachable(scenario: Scenario, goal: tuple[float, float, float]) -> None:
    """Refuse a goal that is not finite or outside the scenario's goal region, saying where the
    region is."""
    if len(goal) != 3 or not all(math.isfinite(g) for g in goal):
        raise InputError(f"a goal is three finite numbers x, y, yaw; got {list(goal)}")
    x0, x1, y0, y1 = scenario.goals.region_m
    if not (x0 <= goal[0] <= x1 and y0 <= goal[1] <= y1):
        raise InputError(
            f"goal position ({goal[0]:.3f}, {goal[1]:.3f}) m is outside the reachable region of "
            f"scenario {scenario.name}: x in [{x0}, {x1}], y in [{y0}, {y1}] m"
        )


def run_push(
    cfg: PushConfig,
    *,
    on_step: Callable[[StepRecord], None] | None = None,
    viz: NullVisualiser | None = None,
    on_transition: Callable[[PushWorld, Observation, np.ndarray | None], None] | None = None,
) -> PushResult:
    """Reset the world with ``cfg.seed`` and push object ``cfg.object_index`` to the goal.

    ``on_transition(world, obs, action)`` sees the first observation (action None) and then
    every executed action with the observation it led to (to record planner-visited data).

    Raises:
        InputError: a bad goal, object index, planner or model name.
        CheckpointError: a model file that does not exist or does not fit the scenario.
    """
    scenario = push_scenario(cfg.scenario)
    check_reachable(scenario, cfg.goal)
    world = PushWorld(scenario)
    obs = world.reset(cfg.seed)
    if not 0 <= cfg.object_index < len(world.objects):
        raise InputError(
            f"object {cfg.object_index} does not exist: scenario {scenario.name} with seed "
            f"{cfg.seed} has {len(world.objects)} object(s) (indices 0..{len(world.objects) - 1})"
        )
    planner = push_planner(cfg, scenario, world)
    goal = np.array(cfg.goal, dtype=float)
    period = world.objects[cfg.object_index].yaw_period_rad
    others = [j for j in range(len(world.objects)) if j != cfg.object_index]
    others_start = obs.object_poses[others, :2].copy()

    def errors() -> tuple[float, float]:
        return pose_errors(obs.object_poses[cfg.object_index], goal, period)

    def reached() -> bool:
        return within(errors(), cfg.tolerance)

    noise = np.random.default_rng([cfg.seed, 11])
    bound = scenario.action.max_speed_m_s
    records: list[StepRecord] = []
    reason = "budget"
    if on_transition is not None:
        on_transition(world, obs, None)
    viz = viz or NullVisualiser()
    viz.start(world, obs, goal, object_index=cfg.object_index, horizon=planner.horizon,
              model=getattr(planner.dynamics, "model", None))  # fmt: skip
    try:
        for step in range(cfg.max_steps):
            if reached():
                break
            before, seen = obs.object_poses[cfg.object_index].copy(), obs.pusher_seen
            action, info = planner.plan(plan_state(obs, world, cfg.object_index))
            if cfg.action_noise > 0:
                action = np.clip(action + cfg.action_noise * bound * noise.standard_normal(2),
                                 -bound, bound)  # fmt: skip
                planner.executed(action)
            obs = world.step(action)
            if on_transition is not None:
                on_transition(world, obs, action)
            viz.step(obs, info)
            pose = obs.object_poses[cfg.object_index]
            figures = step_figures(before, info.predicted_poses[0], pose, goal)
            rec = StepRecord(step + 1, action.tolist(), pose.tolist(), *errors(), info.wall_ms,
                             info.predicted_poses.tolist(), **figures,
                             pusher_seen=seen, cost_terms=info.cost_terms)  # fmt: skip
            records.append(rec)
            if on_step is not None:
                on_step(rec)
            if obs.done:
                reason = obs.reason
                break
    finally:
        viz.finish()
    pos_err, yaw_err = errors()
    if reason == "budget" and reached():
        reason = "reached"
    return PushResult(
        seed=cfg.seed,
        success_precise=within((pos_err, yaw_err), PRECISE),
        success_tight=within((pos_err, yaw_err), TIGHT),
        success_loose=within((pos_err, yaw_err), LOOSE),
        final_pos_err_m=pos_err,
        final_yaw_err_deg=yaw_err,
        steps=len(records),
        sim_time_s=obs.time_s,
        replan_ms_median=float(np.median([r.replan_ms for r in records])) if records else 0.0,
        reason=reason,
        tolerance=cfg.tolerance,
        others_moved_m=disturbance(others_start, obs.object_poses[others, :2]),
        pushed_object=asdict(world.objects[cfg.object_index]),
        diagnostics=exploitation([asdict(r) for r in records]),
        records=records,
    )
