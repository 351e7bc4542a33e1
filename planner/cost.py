"""The push cost, written as weighted residuals so that sampling planners sum their squares
and the SQP planner linearises them (Gauss-Newton).

Each term is declared once, in :data:`TERMS`: its name, its residual, the ``CostConfig``
weight that scales it and its norm (the square, for every term today), as MuJoCo MPC declares
residuals and norms. What changes with the state (whether the pusher is behind the object,
the fade near the goal, where the shaping term draws the pusher) is decided once a replan, by
one function, :meth:`PushCost.stage`; the terms read the :class:`Stage` it returns.

Per step h of a rollout: the object's position error and symmetry-aware yaw error to the goal
(the terminal step weighted more than the running steps), a shaping term that draws the pusher
to the object's far side from the goal (once behind it, only while the object is predicted not
to move), penalties
on action size and change, a penalty for the pusher leaving the workspace, one for the pusher
passing through the object while it is not yet behind it (``w_keepout``), and, with an
ensemble of models, a penalty on their disagreement (the planner keeps to what they agree on),
and, among other objects, a penalty on their predicted displacement (it keeps them in place).

The shaping target goes round the object: a pusher on the goal's side of it is drawn to a
waypoint on a circle about the object, a step round toward the far side, not straight at the
pre-push point through the object (which would push it the wrong way, and with a short
horizon trap the planner there). Until the pusher is behind the object, predicted motion does
not fade the shaping term: with the pusher on the wrong side, motion is a push the wrong way
or a learned model's phantom (a few millimetres predicted beside an object nothing touches),
and a quadratic pose cost centimetres from the goal weighs those millimetres above the way
round, so the pusher would hover beside the object chasing them.

The keep-out term is geometry, not the model: until the pusher is behind the object, every
step of its path is kept out of the circle about the object's centre that holds the object's
footprint, widened by the pusher's radius. A learned model can miss that such a path touches
the object (it predicts a held-out box's graze at a fraction of its motion, or none), and the
planner, believing the way is clear, cuts through it and drags the object off, the wrong way.

The shaping and keep-out terms are both about getting behind the object, and an object already
near the goal has no behind worth reaching: what is left is turning it and placing it, which
takes the pusher at its side, inside the keep-out circle. So within ``near_goal_m`` of the goal
both fade out with the object's distance to it (``near_goal_m`` 0: they never fade).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import torch

from planner.dynamics import PlanState, Rollout, segment_distance, to_world
from scenarios import InputError, Scenario
from sim.planar import wrap_angle

SHAPING_FADES = ("behind", "everywhere")
"""where predicted motion may fade the shaping term (``CostConfig.shaping_fade``)"""
PRE_PUSHES = ("surface", "circle")
"""where the pre-push point is (``CostConfig.pre_push``)"""
SHAPING_AT = ("last", "every")
"""which steps of a plan the shaping term charges (``CostConfig.shaping_at``)"""
CHOICES = {"shaping_fade": SHAPING_FADES, "pre_push": PRE_PUSHES, "shaping_at": SHAPING_AT}
"""the ``CostConfig`` settings that name a choice, and their choices (the rest are numbers)"""
PRE_PUSH_CLEARANCE_M = 0.01
"""the gap a ``surface`` pre-push point leaves between pusher and object (the exploration
data's pushes start so: ``sim.explore``)"""


def far_side(state: PlanState, u: torch.Tensor) -> float:
    """How far the pushed object reaches from its centre along the world direction ``u`` (2,),
    as the camera sees it: the furthest of its observed points (its footprint's radius where
    fewer than 3 are seen)."""
    seen = state.object_mask & state.valid
    if int(seen.sum()) < 3:
        return state.footprint_radius_m
    points = state.points[:, seen].T
    xy = to_world(state.T_world_cam.to(points), points)[:, :2]
    return float(((xy - state.object_pose[:2].to(xy)) @ u.to(xy)).max().clamp_min(0.0))


@dataclass(frozen=True)
class CostConfig:
    """Weights and scales of the push cost."""

    pos_scale_m: float = 0.02
    """position error that costs 1 (per step, before weights)"""
    yaw_scale_rad: float = math.radians(10.0)
    """yaw error that costs 1"""
    w_yaw: float = 0.5
    """weight of the yaw error relative to the position error"""
    w_running: float = 0.3
    """weight of the pose error at steps before the last"""
    w_terminal: float = 1.0
    """weight of the pose error at the last step"""
    w_shaping: float = 0.5
    """weight of the pusher's distance to the shaping target (faded as ``shaping_fade`` says)"""
    shaping_scale_m: float = 0.03
    """pusher distance that costs 1 in the shaping term"""
    behind_deg: float = 60.0
    """a pusher within this angle of straight behind the object heads for the pre-push point"""
    round_step_deg: float = 75.0
    """otherwise it heads this far round the object, toward the far side"""
    round_clearance_m: float = 0.02
    """the way round keeps this much clearance between pusher and object footprint"""
    moving_m: float = 0.005
    """predicted object displacement over the horizon above which shaping fades out (where
    ``shaping_fade`` lets it)"""
    shaping_fade: str = "behind"
    """where predicted motion fades the shaping term: ``behind`` (only once the pusher is
    behind the object) or ``everywhere`` (an earlier planner's)"""
    pre_push: str = "surface"
    """where the pusher goes to push from behind (the pre-push point): ``surface``, 1 cm clear
    of the object's far side as the camera sees it, or ``circle``, 2 cm beyond the circle that
    holds its footprint (earlier planners': from there a 0.45 s plan often moves nothing)"""
    shaping_at: str = "last"
    """which steps the shaping term charges: the ``last`` (where the pusher ends the plan), or
    ``every`` step, weighted as the pose terms are (running, then terminal), so that a long
    plan that reaches the target later costs more than one that reaches it now"""
    w_action: float = 0.02
    """weight of |a|^2 / bound^2"""
    w_smooth: float = 0.05
    """weight of |a_h - a_{h-1}|^2 / bound^2 (a_{-1}: the last executed action)"""
    w_workspace: float = 10.0
    """weight of the pusher's distance outside the workspace, per cm"""
    workspace_margin_m: float = 0.03
    """the workspace is the table top shrunk by this margin"""
    w_spread: float = 1.0
    """weight of an ensemble's disagreement per step (scaled like the position error); only
    ensembles report one"""
    w_disturb: float = 1.0
    """weight of how far the other objects are predicted to be moved by the last step
    (scaled like the position error): the planner pushes one object among others and keeps
    the others where they are"""
    w_keepout: float = 10.0
    """weight of how far the pusher's path enters the object's keep-out circle (the circle about
    its centre that holds its footprint, widened by the pusher's radius) while the pusher is not
    behind it, per step (scaled like the position error)"""
    near_goal_m: float = 0.03
    """within this distance of the goal's position the shaping and keep-out terms fade in
    proportion to the object's distance from it (0: they never fade)"""

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if name in CHOICES:
                if value not in CHOICES[name]:
                    raise InputError(
                        f"cost.{name} is one of {', '.join(CHOICES[name])}, got {value!r}"
                    )
            elif not (math.isfinite(value) and value >= 0):
                raise InputError(f"cost.{name} must be a finite number >= 0, got {value}")
        for name in ("pos_scale_m", "yaw_scale_rad", "shaping_scale_m", "moving_m"):
            if not getattr(self, name) > 0:  # the scales divide
                raise InputError(f"cost.{name} must be positive, got {getattr(self, name)}")


def check_goal(scenario: Scenario, goal: torch.Tensor | tuple[float, float, float]) -> torch.Tensor:
    """The goal (x_m, y_m, yaw_rad) as a tensor, or an InputError saying what is wrong."""
    g = torch.as_tensor(goal, dtype=torch.float32).flatten()
    if g.numel() != 3:
        raise InputError(f"a goal is x, y, yaw (3 numbers); got {g.numel()}")
    if not torch.isfinite(g).all():
        raise InputError(f"goal {g.tolist()} is not finite")
    hx, hy = (s / 2 for s in scenario.table.size_m)
    if abs(float(g[0])) > hx or abs(float(g[1])) > hy:
        raise InputError(
            f"goal position ({float(g[0]):.3f}, {float(g[1]):.3f}) m is off the table "
            f"(x in [{-hx}, {hx}], y in [{-hy}, {hy}] for scenario {scenario.name})"
        )
    return g


class PushCost:
    """Residuals (K, m) of rollouts for one goal; ``cost`` is their sum of squares.

    Args:
        scenario: bounds of the actions and the table.
        goal: (3,) goal pose x_m, y_m, yaw_rad.
        cfg: weights.
    """

    def __init__(self, scenario: Scenario, goal: torch.Tensor, cfg: CostConfig = CostConfig()):
        self.cfg, self.goal = cfg, check_goal(scenario, goal)
        self.bound = scenario.action.max_speed_m_s
        self.pusher_radius = scenario.arm.pusher_radius_m
        self.half = torch.tensor(scenario.table.size_m) / 2 - cfg.workspace_margin_m

    def pre_push_point(self, state: PlanState) -> torch.Tensor:
        """Where the pusher should be to push the object toward the goal: behind it, where the
        push starts (``pre_push``: just clear of the object's far side as the camera sees it,
        or 2 cm beyond the circle that holds its footprint)."""
        obj = state.object_pose[:2]
        d = self.goal[:2] - obj
        d = d / d.norm().clamp_min(1e-6)
        if self.cfg.pre_push == "circle":
            back = state.footprint_radius_m + 0.02
        else:
            back = far_side(state, -d) + self.pusher_radius + PRE_PUSH_CLEARANCE_M
        return obj - back * d

    def is_behind(self, state: PlanState) -> bool:
        """Whether the pusher is within ``behind_deg`` of straight behind the object."""
        return self.stage(state).behind

    def shaping_target(self, state: PlanState) -> torch.Tensor:
        """Where the shaping term draws the pusher: the pre-push point when the pusher is
        already behind the object, else a waypoint a step round the object toward it."""
        return self.stage(state).target

    def near_goal_fade(self, state: PlanState) -> float:
        """The factor on the shaping and keep-out terms: 1 while the object is ``near_goal_m``
        or more from the goal's position, falling in proportion to its distance inside that."""
        near = self.cfg.near_goal_m
        if near == 0:
            return 1.0
        return min(1.0, float((self.goal[:2] - state.object_pose[:2].to(self.goal)).norm()) / near)

    def stage(self, state: PlanState) -> Stage:
        """Where the push is (:class:`Stage`): the one place the cost changes with the state.

        The pusher's angle about the object's centre from the pre-push point (0 straight
        behind, +-pi on the goal's side) decides whether it is behind; if not, the shaping
        target is a waypoint ``round_step_deg`` further round a circle about the object."""
        c = self.cfg
        obj = state.object_pose[:2]
        point = self.pre_push_point(state)
        behind = point - obj
        behind = behind / behind.norm().clamp_min(1e-9)
        rel = state.pusher_xy.to(obj) - obj
        phi = math.atan2(float(behind[0] * rel[1] - behind[1] * rel[0]), float(behind @ rel))
        is_behind = abs(phi) <= math.radians(c.behind_deg)
        if is_behind:
            target = point
        else:
            step = phi - math.copysign(math.radians(c.round_step_deg), phi)
            radius = state.footprint_radius_m + self.pusher_radius + c.round_clearance_m
            cs, sn = math.cos(step), math.sin(step)
            way = torch.stack([cs * behind[0] - sn * behind[1], sn * behind[0] + cs * behind[1]])
            target = obj + radius * way
        return Stage(is_behind, self.near_goal_fade(state), target)

    def residual_terms(
        self,
        state: PlanState,
        rollout: Rollout,
        actions: torch.Tensor,
        *,
        last_action: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """The weighted residuals (K, m_i) of each of :data:`TERMS` that applies, for K rollouts
        of ``actions`` (K,H,2); ``last_action`` (2,) is the action executed before this plan
        (the smoothness term's a_{-1})."""
        at = Inputs(self, state, rollout, actions, last_action, self.stage(state))
        out = {}
        for term in TERMS:
            weight = 1.0 if term.weight is None else getattr(self.cfg, term.weight)
            r = term.residual(at, math.sqrt(weight))
            if r is not None:
                out[term.name] = r
        return out

    def residuals(
        self,
        state: PlanState,
        rollout: Rollout,
        actions: torch.Tensor,
        *,
        last_action: torch.Tensor,
    ) -> torch.Tensor:
        """(K, m) every term's residuals side by side (:meth:`residual_terms`)."""
        terms = self.residual_terms(state, rollout, actions, last_action=last_action)
        return torch.cat(list(terms.values()), 1)

    def cost_terms(
        self,
        state: PlanState,
        rollout: Rollout,
        actions: torch.Tensor,
        *,
        last_action: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """(K,) each term's share of the cost (its residuals' sum of squares): they sum to
        :meth:`cost`."""
        terms = self.residual_terms(state, rollout, actions, last_action=last_action)
        return {name: (r**2).sum(1) for name, r in terms.items()}

    def cost(
        self,
        state: PlanState,
        rollout: Rollout,
        actions: torch.Tensor,
        *,
        last_action: torch.Tensor,
    ) -> torch.Tensor:
        """(K,) total cost of each candidate."""
        return (self.residuals(state, rollout, actions, last_action=last_action) ** 2).sum(1)


@dataclass(frozen=True)
class Stage:
    """Where a push is, decided once a replan from the state (:meth:`PushCost.stage`): the
    approach terms (shaping and keep-out) read it; no term decides it for itself."""

    behind: bool
    """the pusher is within ``behind_deg`` of straight behind the object: the keep-out term is
    off, and predicted motion may fade the shaping term"""
    approach: float
    """the factor on the approach terms: 1, falling inside ``near_goal_m`` of the goal"""
    target: torch.Tensor
    """(2,) where the shaping term draws the pusher (``PushCost.shaping_target``)"""


@dataclass(frozen=True)
class Inputs:
    """What a term's residual is computed from."""

    cost: PushCost
    state: PlanState
    rollout: Rollout
    actions: torch.Tensor
    last_action: torch.Tensor
    stage: Stage

    @cached_property
    def step_weights(self) -> torch.Tensor:
        """(H,) the square roots of the pose terms' weights per step: running, then terminal."""
        c, a = self.cost.cfg, self.actions
        w = torch.full((a.shape[1],), math.sqrt(c.w_running), dtype=a.dtype, device=a.device)
        w[-1] = math.sqrt(c.w_terminal)
        return w


def _position(x: Inputs, w: float) -> torch.Tensor:
    pos = x.rollout.object_poses[..., :2] - x.cost.goal.to(x.actions)[:2]
    return (pos / x.cost.cfg.pos_scale_m * x.step_weights[None, :, None]).flatten(1)


def _yaw(x: Inputs, w: float) -> torch.Tensor | None:
    period = x.state.yaw_period_rad
    if period is None:  # a cylinder: no heading to turn
        return None
    goal = x.cost.goal.to(x.actions)[2]
    yaw = wrap_angle(x.rollout.object_poses[..., 2] - goal, period) / x.cost.cfg.yaw_scale_rad
    return w * yaw * x.step_weights


def _shaping(x: Inputs, w: float) -> torch.Tensor:
    c, a = x.cost.cfg, x.actions
    steps = slice(-1, None) if c.shaping_at == "last" else slice(None)
    moved_sq = ((x.rollout.object_poses[:, steps, :2] - x.state.object_pose[:2].to(a)) ** 2).sum(-1)
    # sqrt of the gate exp(-moved^2 / m^2), written without sqrt (its gradient at 0 is NaN);
    # until the pusher is behind the object, predicted motion does not fade the term
    sqrt_gate = torch.exp(-0.5 * moved_sq / c.moving_m**2)
    if c.shaping_fade == "behind" and not x.stage.behind:
        sqrt_gate = torch.ones_like(sqrt_gate)
    dist = (x.rollout.pusher_xy[:, steps] - x.stage.target.to(a)) / c.shaping_scale_m
    r = w * x.stage.approach * sqrt_gate[..., None] * dist
    if c.shaping_at == "every":
        r = r * x.step_weights[None, :, None]
    return r.flatten(1)


def _action(x: Inputs, w: float) -> torch.Tensor:
    return w * x.actions.flatten(1) / x.cost.bound


def _smooth(x: Inputs, w: float) -> torch.Tensor:
    a = x.actions
    prev = torch.cat([x.last_action.to(a).expand(a.shape[0], 1, 2), a[:, :-1]], 1)
    return w * (a - prev).flatten(1) / x.cost.bound


def _workspace(x: Inputs, w: float) -> torch.Tensor:
    out = torch.relu(x.rollout.pusher_xy.abs() - x.cost.half.to(x.actions)) / 0.01
    return w * out.flatten(1)


def _keepout(x: Inputs, w: float) -> torch.Tensor | None:
    if x.stage.behind or w == 0:  # behind the object, the pusher's way is the push
        return None
    a, state = x.actions, x.state
    K, H, _ = a.shape
    path = torch.cat([state.pusher_xy.to(a).expand(K, 1, 2), x.rollout.pusher_xy], 1)
    centre = state.object_pose[:2].to(a).expand(K, 2)
    keep = state.footprint_radius_m + x.cost.pusher_radius
    depth = torch.stack([torch.relu(keep - segment_distance(centre, path[:, h], path[:, h + 1]))
                         for h in range(H)], 1)  # fmt: skip
    return w * x.stage.approach * depth / x.cost.cfg.pos_scale_m


def _spread(x: Inputs, w: float) -> torch.Tensor | None:
    if x.rollout.spread is None or w == 0:  # one model: nothing to disagree about
        return None
    return w * x.rollout.spread / x.cost.cfg.pos_scale_m


def _disturb(x: Inputs, w: float) -> torch.Tensor | None:
    if x.rollout.other_poses is None or not x.state.n_others or w == 0:
        return None
    moved = x.rollout.other_poses[:, -1, :, :2] - x.state.other_poses[:, :2].to(x.actions)
    return w * moved.flatten(1) / x.cost.cfg.pos_scale_m


@dataclass(frozen=True)
class Term:
    """One term of the cost: its residual, the weight that scales it (a ``CostConfig``
    field; None: 1) and its norm (every term's is the square, summed over its residuals)."""

    name: str
    residual: Callable[[Inputs, float], torch.Tensor | None]
    """(K, m) the term's residuals times the square root of its weight (given), or None where
    it does not apply (a term of weight 0 that only some states have drops out)"""
    weight: str | None
    doc: str
    norm: str = "quadratic"


TERMS: tuple[Term, ...] = (
    Term("position", _position, None,
         "the object's position error to the goal, per step (w_running, the last w_terminal)"),
    Term("yaw", _yaw, "w_yaw", "its symmetry-aware yaw error, likewise (objects with a heading)"),
    Term("shaping", _shaping, "w_shaping",
         "the pusher's distance, at the last step (or every step), to the way round to behind "
         "the object"),
    Term("action", _action, "w_action", "the actions' size"),
    Term("smooth", _smooth, "w_smooth",
         "the actions' change from step to step (from the last executed action)"),
    Term("workspace", _workspace, "w_workspace", "the pusher's distance outside the workspace"),
    Term("keepout", _keepout, "w_keepout",
         "the pusher's path inside the object's circle while it is not yet behind it"),
    Term("spread", _spread, "w_spread", "an ensemble's disagreement about the object's poses"),
    Term("disturb", _disturb, "w_disturb", "how far the other objects are predicted to move"),
)  # fmt: skip
"""the cost's terms, each declared once: the cost is the sum of their weighted squares"""
